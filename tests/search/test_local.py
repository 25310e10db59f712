"""Local baselines: the same starts and moves as a policy, a hard budget of FBCPP evaluations, one seed one result."""

from __future__ import annotations

import numpy as np
import pytest

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.protocol import eval_starts
from smorphi_rl.search.local import METHODS, run_local


@pytest.mark.parametrize("method", METHODS)
def test_budget_seed_and_improvement(method):
    env = MorphologyEnv()
    starts = eval_starts(4)
    a = run_local(method, env, starts, budget=150, seed=3)
    b = run_local(method, env, starts, budget=150, seed=3)
    assert a == b
    for outcome, start in zip(a, starts, strict=True):
        assert outcome.start == tuple(start)
        assert outcome.evaluations <= 150  # every method, the walk included: equal budgets
        if method != "random_walk":  # a walk ends where it settles; the others keep their best
            assert env.score(tuple(start)).R1 <= outcome.R1


def test_a_random_walk_stops_at_its_budget_of_distinct_shapes():
    env = MorphologyEnv()
    (short,) = run_local("random_walk", env, eval_starts(1), budget=20, seed=0)
    (long,) = run_local("random_walk", env, eval_starts(1), budget=1_000, seed=0)
    assert short.evaluations == 20
    assert 20 < long.evaluations <= env.config.max_steps + 1  # a whole episode's walk, when the budget allows


def test_hill_climbing_ends_on_a_local_maximum_of_its_neighbourhood():
    env = MorphologyEnv()
    (outcome,) = run_local("hillclimb", env, np.array([[130.0, 50.0, 120.0]]), budget=60, seed=0)
    r1 = env.score(outcome.settled).R1
    assert r1 == outcome.R1 and r1 >= env.score((130.0, 50.0, 120.0)).R1


def test_bad_method_and_budget():
    env = MorphologyEnv()
    with pytest.raises(ValueError, match="unknown local method"):
        run_local("tabu", env, eval_starts(1), 10, 0)
    with pytest.raises(ValueError, match="budget"):
        run_local("hillclimb", env, eval_starts(1), 0, 0)

"""Local baselines: the same starts and moves as a policy, a hard budget of FBCPP evaluations, one seed one result."""

from __future__ import annotations

import contextlib
import itertools
import signal
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.protocol import eval_starts
from smorphi_rl.search.local import METHODS, run_local

MAP_1 = str(Path(__file__).resolve().parents[2] / "maps" / "map-1.yaml")


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


def test_a_designs_compass_search_restarts_in_the_best_region_not_yet_climbed():
    """A climb that ends restarts from the best scored shape far from it (the policy's next region), not a random
    shape: `near` scores higher but lies within 16 degrees of the first climb."""
    from smorphi_rl.search.local import compass_refine

    env = MorphologyEnv()
    start, near, far = (90.0, 90.0, 90.0), (100.0, 90.0, 90.0), (20.0, 150.0, 40.0)
    seen = {start: 1e9, near: 2e8, far: 1e8}  # no neighbour beats `start`: its climb ends after 6 sizes x 6 moves
    refined = compass_refine(env, seen, start, len(seen) + 36 + 6, np.random.default_rng(0))
    first, second = refined[:36], refined[36:]
    assert all(sum(a != b for a, b in zip(t, start, strict=True)) == 1 for t in first)
    assert len(second) == 6 and all(sum(a != b for a, b in zip(t, far, strict=True)) == 1 for t in second)


def test_each_restart_is_a_mark_and_the_next_is_the_best_shape_far_from_every_mark():
    """The second restart skips `far` (climbed) for `other`; the third takes the best shape the climbs scored that
    lies more than 16 degrees from every end and restart (a probe of 32 degrees, here)."""
    from smorphi_rl.search.local import RESTART_SEPARATION_DEG, compass_refine

    env = MorphologyEnv()
    start, far, other = (90.0, 90.0, 90.0), (20.0, 150.0, 40.0), (150.0, 40.0, 140.0)
    seen = {start: 1e9, far: 2e8, other: 1e8}  # no neighbour beats any of them: every climb ends after 36 shapes
    refined = compass_refine(env, seen, start, len(seen) + 3 * 36 + 6, np.random.default_rng(0))

    def probes(t, centre):
        return sum(a != b for a, b in zip(t, centre, strict=True)) == 1

    for i, centre in enumerate((start, far, other)):
        assert all(probes(t, centre) for t in refined[36 * i : 36 * (i + 1)])
    marks = (start, far, other)
    open_ = [t for t in refined[:108] if all(max(abs(a - b) for a, b in zip(t, m, strict=True)) > RESTART_SEPARATION_DEG
                                              for m in marks)]  # fmt: skip
    best = max(open_, key=lambda t: env.score(t).R1)
    assert refined[108] == (best[0] - 32.0, best[1], best[2])  # its climb's first probe: -32 on the first hinge


def test_a_restart_with_every_scored_shape_near_a_mark_draws_a_random_shape():
    from smorphi_rl.search.local import _Budgeted, _Regions

    space = _Budgeted(MorphologyEnv(), 100)
    space.seen.update({(90.0, 90.0, 90.0): 1.0, (100.0, 80.0, 95.0): 2.0})
    regions = _Regions(space)
    assert regions([(90.0, 90.0, 90.0)], np.random.default_rng(0)) == space.random_theta(np.random.default_rng(0))


def test_a_restart_keeps_off_the_whole_path_of_a_climb_not_only_its_end():
    """`near_start` outscores `elsewhere` but lies near where the climb began: that region is climbed."""
    from smorphi_rl.search.local import _Budgeted, _Regions

    space = _Budgeted(MorphologyEnv(), 100)
    near_start, elsewhere = (30.0, 30.0, 35.0), (150.0, 150.0, 150.0)
    space.seen.update({(30.0, 30.0, 30.0): 1.0, (90.0, 90.0, 90.0): 2.0, near_start: 5.0, elsewhere: 3.0})
    path = [(30.0, 30.0, 30.0), (62.0, 30.0, 30.0), (90.0, 90.0, 90.0)]  # the climb moved from 30s to 90s
    assert _Regions(space)(path, np.random.default_rng(0)) == elsewhere


@contextlib.contextmanager
def _deadline(seconds: int):
    """A search that spins for ever fails here instead of stalling the suite."""

    def expired(*_):
        raise TimeoutError(f"still searching after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("method", METHODS)
def test_a_budget_past_the_lattice_ends_once_every_shape_is_scored(method):
    """On a 45-degree lattice (125 shapes) a budget of 1,000 spun for ever in the searches that restart."""
    env = MorphologyEnv({"angle_step_deg": 45.0})
    with _deadline(60):
        (outcome,) = run_local(method, env, np.array([[90.0, 90.0, 90.0]]), budget=1_000, seed=0)
    assert outcome.evaluations <= 125  # every method: a shape is scored once, never past the lattice
    if method in ("hillclimb", "random_search", "pattern"):
        assert outcome.evaluations == 125


def test_a_random_walk_on_a_scored_lattice_walks_its_whole_episode():
    """Revisiting a scored shape costs nothing: a full lattice does not cut the walk short."""
    from smorphi_rl.search.local import _Budgeted, random_walk

    env = MorphologyEnv({"angle_step_deg": 90.0})  # 27 shapes
    space = _Budgeted(env, 1_000)
    space.seen.update({t: 0.0 for t in itertools.product((0.0, 90.0, 180.0), repeat=3)})
    calls: list = []
    scored = space.r1
    space.r1 = lambda theta: calls.append(theta) or scored(theta)  # type: ignore[method-assign]
    random_walk(space, (90.0, 90.0, 90.0), np.random.default_rng(0))
    assert len(calls) == env.config.max_steps + 1


def test_a_designs_compass_search_ends_when_the_lattice_is_scored():
    from smorphi_rl.search.local import compass_refine

    env = MorphologyEnv({"angle_step_deg": 45.0})
    with _deadline(60):
        refined = compass_refine(env, {}, (90.0, 90.0, 90.0), 1_000, np.random.default_rng(0))
    assert len(refined) == 125


def test_moves_land_on_the_lattice_whatever_the_step():
    """At a step of 180/7 degrees, t + d * step drifted off i * step: one shape under two keys, and the lattice
    never counted as scored."""
    from smorphi_rl.search.local import _Budgeted

    step = 180 / 7
    space = _Budgeted(MorphologyEnv({"angle_step_deg": step}), 10)
    theta = (3 * step, 5 * step, 6 * step)
    assert space.moved(theta, (-1, 1, -1)) == (2 * step, 6 * step, 5 * step)


def test_the_top_of_a_180_over_n_lattice_is_180_in_every_search():
    """169 steps of 180/169 made 180.00000000000003: a compass search reaching the edge, or a random restart on it,
    failed the whole design, and `search exhaustive` at that step failed after its keying pass."""
    from smorphi_rl.planning import Lattice, lattice_thetas
    from smorphi_rl.search.local import _Budgeted

    step = 180 / 169
    space = _Budgeted(MorphologyEnv({"angle_step_deg": step}), 10)
    assert space.snap(180.0) == space.moved((180.0, 0.0, 90.0), (1, 0, 0))[0] == 180.0
    assert max(max(space.random_theta(np.random.default_rng(s))) for s in range(300)) == 180.0
    assert space.r1(space.moved((179.0, 179.0, 179.0), (1, 1, 1))) is not None  # scored, not refused
    assert lattice_thetas(step).max() == Lattice(step)[-1:].max() == 180.0


def test_pattern_hands_the_climbs_whole_path_to_its_restart():
    from smorphi_rl.search.local import _Budgeted, pattern

    space = _Budgeted(MorphologyEnv(), 60)
    start, probe = (90.0, 90.0, 90.0), (58.0, 90.0, 90.0)  # the first probe: -32 on the first hinge
    space.seen.update({start: 0.0, probe: 1e9})
    paths = []

    def restart(path, rng):
        paths.append(list(path))
        return (10.0, 10.0, 10.0)

    pattern(space, start, np.random.default_rng(0), restart)
    assert paths[0] == [start, probe]


def test_a_search_records_the_budget_it_ran_with():
    """A budget past the lattice runs as the lattice, and the result says so rather than what was asked."""
    from smorphi_rl.search.local import run_local_search

    result = run_local_search("hillclimb", MAP_1, 1_000, 0, starts=1, env_config={"angle_step_deg": 45.0})
    assert result.params["budget_per_start"] == 125

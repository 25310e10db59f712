"""Greedy roll-outs: a revisited shape ends the stepping, with the same outcome as stepping to the end."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.protocol import eval_starts
from smorphi_rl.training.module import MorphologyModule
from smorphi_rl.training.policy import greedy_outcomes, repeat_cycle


def test_repeat_cycle_continues_the_period_to_truncation():
    history = ["a", "b", "c", "d", "b"]  # step 4 revisits step 1: the cycle b, c, d
    repeat_cycle(history, 1, max_steps=9)
    assert history == ["a", "b", "c", "d", "b", "c", "d", "b", "c", "d"]
    settled = ["x", "y", "y"]  # a policy that stays: period 1
    repeat_cycle(settled, 1, max_steps=5)
    assert settled == ["x", "y", "y", "y", "y", "y"]


def test_stopping_at_a_revisited_shape_changes_no_outcome():
    """Wrapped envs (as when recording) are stepped to truncation; plain ones stop at a revisit."""
    torch.manual_seed(3)
    first = MorphologyEnv({"max_steps": 60})
    module = MorphologyModule(observation_space=first.observation_space, action_space=first.action_space,
                              model_config={})  # fmt: skip
    starts = eval_starts(8)
    plain = [first] + [first.sibling() for _ in range(7)]
    wrapped = [gym.Wrapper(first.sibling()) for _ in range(8)]
    fast, full = greedy_outcomes(module, plain, starts), greedy_outcomes(module, wrapped, starts)
    assert fast == full
    assert sum(env.unwrapped._steps for env in plain) < sum(env.unwrapped._steps for env in wrapped)


def test_a_reused_evaluation_gives_what_a_fresh_one_gives():
    """Training evaluates with one GreedyRollouts whose envs keep their scored shapes: same outcomes as new envs."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.protocol import Optimum
    from smorphi_rl.training.policy import GreedyRollouts, evaluate_policy

    torch.manual_seed(5)
    env = EnvConfig.from_dict({"max_steps": 40})
    first = MorphologyEnv(env.to_dict())
    module = MorphologyModule(observation_space=first.observation_space, action_space=first.action_space,
                              model_config={})  # fmt: skip
    optima = {first.grid_map.name: Optimum((0.0, 0.0, 0.0), 100.0, 100.0, 1)}
    starts = eval_starts(6)
    reused = GreedyRollouts(env, starts, optima)
    once = reused(module)
    with torch.no_grad():
        module._pi.head.bias.add_(torch.linspace(-1, 1, 9))  # another policy, as after an update
    again, fresh = reused(module), evaluate_policy(module, env, starts, optima)
    assert again == fresh and again != once


def test_greedy_actions_are_the_distributions_most_likely_ones():
    from ray.rllib.core.columns import Columns

    from smorphi_rl.training.policy import greedy_actions

    torch.manual_seed(11)
    env = MorphologyEnv({"max_steps": 10})
    module = MorphologyModule(observation_space=env.observation_space, action_space=env.action_space,
                              model_config={})  # fmt: skip
    with torch.no_grad():
        module._pi.head.weight.normal_()  # logits far from uniform, so every hinge's argmax differs somewhere
    observations = [env.reset(seed=s)[0] for s in range(64)]
    batch = {Columns.OBS: {k: torch.from_numpy(np.stack([o[k] for o in observations])) for k in observations[0]}}
    logits = module.forward_inference(batch)[Columns.ACTION_DIST_INPUTS]
    want = module.get_inference_action_dist_cls().from_logits(logits).to_deterministic().sample().numpy()
    got = greedy_actions(module, observations)
    assert got.shape == (64, 3) and np.array_equal(got, want) and len(np.unique(got, axis=0)) > 1


def test_a_policy_of_its_own_floors_on_another_is_warned_of_and_a_generalist_is_not():
    """A per-map policy on a floor it never saw walked to its own floor's shape without a word (R1 -46 on a 25 m
    floor for a 5 m map's policy)."""
    from smorphi_rl.training.policy import unseen_warning

    maps = Path(__file__).resolve().parents[2] / "maps"
    own = EnvConfig.from_dict({"maps": [str(maps / "map-1.yaml")]})
    other = EnvConfig.from_dict({"maps": [str(maps / "map-2.yaml"), str(maps / "map-1.yaml")]})
    assert unseen_warning(own, own) is None
    said = unseen_warning(own, other)
    assert said is not None and said.startswith("warning: the policy was trained on map-1 alone; map-2 is not one")
    generalist = EnvConfig.from_dict({"maps": ["generate:mixed:0-99"]})
    assert unseen_warning(generalist, other) is None  # `design`'s warning, by the floors' sides, is its

"""Independent random streams: each remote env runner samples its actions from its own SeedSequence child of the
run's seed, so seed s on runner 2 never replays seed s + 1 on runner 1 (RLlib's `seed + worker_index` would)."""

from __future__ import annotations

import torch

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env
from smorphi_rl.vector_env import action_seed


def runner_draws(seed: int, worker_index: int) -> tuple[int, list[float]]:
    """The torch seed a real env runner of this run and index ends up with, and its first draws."""
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    register_env()
    cfg = TrainConfig(env=EnvConfig.from_dict({"max_steps": 5}), seed=seed, envs_per_runner=2)
    runner = SingleAgentEnvRunner(config=algorithm_config(cfg), worker_index=worker_index)
    try:
        return torch.initial_seed(), torch.rand(4).tolist()
    finally:
        runner.stop()


def test_each_remote_runner_draws_its_own_actions_stream():
    seeded, draws = runner_draws(7, 2)
    assert seeded == action_seed(7, 2)  # the callback's seed took effect in a real runner, after RLlib's
    other_seeded, other_draws = runner_draws(8, 1)
    assert other_seeded == action_seed(8, 1) != seeded and draws != other_draws
    assert runner_draws(7, 2)[1] == draws  # and a seed repeats


def test_action_seeds_never_repeat_across_seeds_and_runners():
    seeds = {action_seed(s, w) for s in range(50) for w in range(1, 9)}
    assert len(seeds) == 400
    assert all(isinstance(s, int) and 0 <= s < 2**64 for s in seeds)

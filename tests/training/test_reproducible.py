"""A seeded PPO run on the default layout (2 env runners) repeats bit for bit: two tiny iterations, twice, give
identical weights, and the gradient steps move them (IMPALA and APPO learn in a thread while their runners
sample, so they are documented as not bit-reproducible)."""

from __future__ import annotations

import numpy as np
import pytest

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env, standalone_algorithm

pytestmark = pytest.mark.slow


def two_iterations(seed: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(weights at the start, weights after two iterations) of a tiny PPO run."""
    from smorphi_rl import cluster

    register_env()
    cfg = TrainConfig(env=EnvConfig.from_dict({"max_steps": 10}), seed=seed, envs_per_runner=4, eval_every=0,
                      overrides={"train_batch_size": 160, "minibatch_size": 80, "num_epochs": 2})  # fmt: skip
    assert cfg.env_runners == 2  # the default layout
    with cluster.ray_session(None), standalone_algorithm(algorithm_config(cfg)) as algo:

        def weights() -> dict[str, np.ndarray]:
            state = algo.learner_group.get_state(components="learner/rl_module")["learner"]["rl_module"]
            return {k: np.array(v) for k, v in state["default_policy"].items()}

        start = weights()
        algo.train()
        algo.train()
        return start, weights()


def test_one_seed_trains_to_the_same_weights_and_the_steps_move_them():
    start, first = two_iterations(5)
    _, again = two_iterations(5)
    assert first.keys() == again.keys() and all(np.array_equal(first[k], again[k]) for k in first)
    assert any(not np.array_equal(start[k], first[k]) for k in first)  # a gradient step moved the weights

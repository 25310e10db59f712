"""The lean env-runner connectors sample exactly what RLlib's default pipelines sample (same seed, same
module): actions, their log-probabilities, the distribution inputs and the observations, dtypes included."""

from __future__ import annotations

import numpy as np
from ray.rllib.core.columns import Columns
from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env
from smorphi_rl.training.sampling import SampleActions, StackObservations


def _sampled(lean: bool) -> list[list[np.ndarray]]:
    cfg = TrainConfig(env=EnvConfig.from_dict({"max_steps": 20}), seed=3, envs_per_runner=8)
    runner = SingleAgentEnvRunner(config=algorithm_config(cfg, lean=lean))
    assert any(isinstance(c, StackObservations) for c in runner._env_to_module.connectors) == lean
    assert any(isinstance(c, SampleActions) for c in runner._module_to_env.connectors) == lean
    episodes = runner.sample(num_timesteps=400)
    runner.stop()
    return [
        [np.asarray(e.get_actions()), np.asarray(e.get_extra_model_outputs(Columns.ACTION_LOGP)),
         np.asarray(e.get_extra_model_outputs(Columns.ACTION_DIST_INPUTS)), e.get_observations()["angles"],
         e.get_observations()["map"], np.asarray(e.get_rewards())]
        for e in episodes
    ]  # fmt: skip


def test_lean_connectors_sample_what_the_default_ones_do():
    register_env()
    default, lean = _sampled(False), _sampled(True)
    assert len(default) == len(lean) > 8  # episodes ended and the envs reset (NEXT_STEP autoreset)
    for a, b in zip(default, lean, strict=True):
        for x, y in zip(a, b, strict=True):
            assert x.dtype == y.dtype and np.array_equal(x, y)

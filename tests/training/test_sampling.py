"""The lean env runner and its connectors sample exactly what RLlib's default runner and pipelines sample (same
seed, same module): every episode's observations, actions, rewards, infos, model outputs and ends, dtypes
included, and the same episode metrics."""

from __future__ import annotations

import gc
from typing import Any

import numpy as np
from ray.rllib.core.columns import Columns
from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.callbacks import MorphologyCallbacks
from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env
from smorphi_rl.training.result_keys import METRIC_PREFIX
from smorphi_rl.training.sampling import (
    InfoLists,
    LeanEnvRunner,
    SampleActions,
    StackObservations,
    sample_hinges,
    split_by_env,
)
from smorphi_rl.training.topk import EPISODE_BEST_KEY


def _episode(e: Any) -> dict[str, Any]:
    outputs = {k: np.asarray(e.get_extra_model_outputs(k)) for k in (Columns.ACTION_LOGP, Columns.ACTION_DIST_INPUTS)}
    return {
        "observations": e.get_observations(),
        "actions": np.asarray(e.get_actions()),
        "rewards": np.asarray(e.get_rewards()),
        "infos": e.get_infos(),
        "ends": (e.is_terminated, e.is_truncated, e.t_started, len(e)),
    } | outputs


def _sampled(lean: bool) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    cfg = TrainConfig(env=EnvConfig.from_dict({"max_steps": 20}), seed=3, envs_per_runner=8)
    config = algorithm_config(cfg, MorphologyCallbacks, lean=lean)
    runner_cls = config.env_runner_cls or SingleAgentEnvRunner
    assert (runner_cls is LeanEnvRunner) == lean
    runner = runner_cls(config=config)
    assert any(isinstance(c, StackObservations) for c in runner._env_to_module.connectors) == lean
    assert any(isinstance(c, SampleActions) for c in runner._module_to_env.connectors) == lean
    assert isinstance(runner.env, InfoLists) == lean
    episodes = runner.sample(num_timesteps=400) + runner.sample(num_timesteps=100)  # a cut, then continuations
    gc.collect()
    assert not runner.env.unwrapped.closed  # closed by the runner's stop only (recordings finish there)
    metrics = runner.get_metrics()
    runner.stop()
    return [_episode(e) for e in episodes], metrics


def _assert_same(x: Any, y: Any) -> None:
    if isinstance(x, dict):
        assert list(x) == list(y)
        for key in x:
            _assert_same(x[key], y[key])
    elif isinstance(x, list | tuple):
        assert len(x) == len(y)
        for a, b in zip(x, y, strict=True):
            _assert_same(a, b)
    elif isinstance(x, np.ndarray):
        assert x.dtype == y.dtype and np.array_equal(x, y)
    else:
        assert x == y


def test_lean_runner_samples_what_the_default_one_does():
    register_env()
    (default, default_metrics), (lean, lean_metrics) = _sampled(False), _sampled(True)
    assert len(default) == len(lean) > 8  # episodes ended and the envs reset (NEXT_STEP autoreset)
    _assert_same(default, lean)
    for key in (METRIC_PREFIX, EPISODE_BEST_KEY, "num_episodes", "episode_return_mean", "episode_len_mean"):
        _assert_same(_peeked(default_metrics[key]), _peeked(lean_metrics[key]))


def _peeked(stats: Any) -> Any:
    """The values of RLlib's metrics (Stats objects, possibly in dicts)."""
    return {k: _peeked(v) for k, v in stats.items()} if isinstance(stats, dict) else stats.peek()


def test_split_by_env_is_rllibs_unbatch():
    from ray.rllib.utils.spaces.space_utils import unbatch

    obs = {"map": np.arange(24).reshape(3, 2, 4), "angles": np.ones((3, 3), dtype=np.float32)}
    for batched in (obs, np.arange(6).reshape(3, 2), np.arange(3)):
        _assert_same(split_by_env(batched), unbatch(batched))
    nested = {"a": {"b": np.arange(2)}}
    _assert_same(split_by_env(nested), unbatch(nested))


def test_equal_hinges_draw_as_rllibs_multicategorical():
    import torch
    from ray.rllib.core.distribution.torch.torch_distribution import TorchMultiCategorical

    logits = torch.randn(64, 9, generator=torch.Generator().manual_seed(0)) * 2
    for seed in range(3):
        dist = TorchMultiCategorical.from_logits(logits, input_lens=[3, 3, 3])
        torch.manual_seed(seed)
        expected = dist.sample()
        torch.manual_seed(seed)
        actions, logp = sample_hinges(logits, [3, 3, 3])
        assert torch.equal(actions, expected) and torch.equal(logp, dist.logp(expected))

"""The env runners' connector pipelines, lean: what RLlib's default pieces compute for our env and module, in
two steps instead of twelve.

RLlib's default env-to-module pipeline (observations from episodes, time rank, states, batching, tensors) and
module-to-env pipeline (sample actions, numpy, unbatch, time rank, normalise and clip, listify) handle every
kind of module and space, item by item through tree utilities: about 30 % of an env runner's sampling time here.
Our module is stateless, its actions MultiDiscrete and never normalised or clipped, so:
- `StackObservations` stacks the runner's latest observations into one batch of tensors;
- `SampleActions` samples from the module's action distribution and hands the runner numpy arrays it indexes
  by env (actions, their log-probabilities, the distribution inputs).
Both draw from the same generators in the same order as the default pieces, so a seeded run trains exactly as
before (a test checks identical samples).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from ray.rllib.connectors.connector_v2 import ConnectorV2
from ray.rllib.core.columns import Columns
from ray.rllib.utils.numpy import convert_to_numpy


class StackObservations(ConnectorV2):
    """Env-to-module: each env's latest observation (a dict of arrays), stacked into one batch of tensors."""

    def __init__(self, *args: Any, device: Any = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.device = device

    def __call__(
        self, *, rl_module: Any, batch: dict[str, Any], episodes: list[Any], explore: bool | None = None,
        shared_data: dict[str, Any] | None = None, **kwargs: Any,
    ) -> Any:  # fmt: skip
        if Columns.OBS in batch:
            return batch
        observations = kwargs.get(Columns.OBS)
        if observations is None:  # the runner passes them; read them off the episodes otherwise
            observations = [episode.get_observations(-1) for episode in episodes]
        stacked = {key: torch.from_numpy(np.stack([o[key] for o in observations])) for key in observations[0]}
        if self.device is not None:
            stacked = {key: value.to(self.device) for key, value in stacked.items()}
        batch[Columns.OBS] = stacked
        return batch


class SampleActions(ConnectorV2):
    """Module-to-env: actions sampled from the module's distribution (its most likely ones when not exploring),
    their log-probabilities and every module output, as numpy arrays of one row per env (the runner indexes
    them by env)."""

    def __call__(
        self, *, rl_module: Any, batch: dict[str, Any], episodes: list[Any], explore: bool | None = None,
        shared_data: dict[str, Any] | None = None, **kwargs: Any,
    ) -> Any:  # fmt: skip
        if Columns.ACTIONS not in batch:
            module = rl_module
            dist_cls = module.get_exploration_action_dist_cls() if explore else module.get_inference_action_dist_cls()
            dist = dist_cls.from_logits(batch[Columns.ACTION_DIST_INPUTS])
            if not explore:
                dist = dist.to_deterministic()
            batch[Columns.ACTIONS] = dist.sample()
            if Columns.ACTION_LOGP not in batch:
                batch[Columns.ACTION_LOGP] = dist.logp(batch[Columns.ACTIONS])
        return convert_to_numpy(batch)  # as RLlib's TensorToNumpy: int64 becomes int32, float64 float32


def env_to_module(env: Any = None, spaces: Any = None, device: Any = None) -> list[ConnectorV2]:
    """`config.env_runners(env_to_module_connector=...)`, with RLlib's default pieces switched off."""
    return [StackObservations(device=device)]


def module_to_env(env: Any = None, spaces: Any = None) -> list[ConnectorV2]:
    """`config.env_runners(module_to_env_connector=...)`, with RLlib's default pieces switched off."""
    return [SampleActions()]


LEAN_SAMPLING = {
    "env_to_module_connector": env_to_module,
    "add_default_connectors_to_env_to_module_pipeline": False,
    "module_to_env_connector": module_to_env,
    "add_default_connectors_to_module_to_env_pipeline": False,
}
"""The `config.env_runners(...)` settings that put the lean pipelines in place of RLlib's defaults."""

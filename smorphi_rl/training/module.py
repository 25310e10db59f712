"""The one RLModule PPO, IMPALA and APPO share: a small CNN over the map plus an MLP over the shape.

Policy and value are separate networks (no shared trunk), so the value loss, whose scale is the
episode return's, never swamps the policy gradient. The critic is `value_offset + value_scale * head`
(the random-shape return level and its spread), so the head's raw output stays near 0.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.core.distribution.torch.torch_distribution import TorchMultiCategorical
from ray.rllib.core.learner.utils import make_target_network
from ray.rllib.core.rl_module.apis import TARGET_NETWORK_ACTION_DIST_INPUTS, TargetNetworkAPI, ValueFunctionAPI
from ray.rllib.core.rl_module.torch import TorchRLModule
from torch import nn

HIDDEN = 128
MAP_FEATURES = 64


class _Net(nn.Module):
    """Map (2 x S x S) -> CNN -> features; concatenated with angles and metrics -> MLP -> `out` values."""

    def __init__(self, obs_space: gym.spaces.Dict, out: int) -> None:
        super().__init__()
        channels, size, _ = obs_space["map"].shape
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, 8, kernel_size=3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(8, 16, kernel_size=3, stride=2, padding=1),
            nn.ReLU(),
            nn.AdaptiveMaxPool2d(4),  # any obs_size gives the same 16 x 4 x 4 features
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.cnn(torch.zeros(1, channels, size, size)).shape[1]
        self.map_fc = nn.Sequential(nn.Linear(flat, MAP_FEATURES), nn.ReLU())
        shape_inputs = obs_space["angles"].shape[0] + obs_space["metrics"].shape[0]
        self.mlp = nn.Sequential(
            nn.Linear(MAP_FEATURES + shape_inputs, HIDDEN),
            nn.Tanh(),
            nn.Linear(HIDDEN, HIDDEN),
            nn.Tanh(),
        )
        self.head = nn.Linear(HIDDEN, out)
        nn.init.orthogonal_(self.head.weight, gain=0.01)
        nn.init.zeros_(self.head.bias)

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        map_features = self.map_fc(self.cnn(obs["map"]))
        return self.head(self.mlp(torch.cat([map_features, obs["angles"], obs["metrics"]], dim=-1)))


class MorphologyModule(TorchRLModule, ValueFunctionAPI, TargetNetworkAPI):
    """Actor-critic over the env's Dict observation and MultiDiscrete action.

    model_config: `value_offset` and `value_scale` (floats, default 0 and 1), and `env_config` (the validated env
    configuration it was trained for; carried in checkpoints so a policy can be rolled out
    without its run directory).
    """

    def setup(self) -> None:
        space = self.action_space
        if not isinstance(space, gym.spaces.MultiDiscrete):
            raise TypeError(f"MorphologyModule needs a MultiDiscrete action space, got {space}")
        nvec = [int(n) for n in space.nvec]
        self.action_dist_cls = TorchMultiCategorical.get_partial_dist_cls(space=space, input_lens=nvec)
        self._pi = _Net(self.observation_space, sum(nvec))
        self._vf = _Net(self.observation_space, 1)
        model_config = self.model_config or {}
        self._value_offset = float(model_config.get("value_offset", 0.0))
        self._value_scale = float(model_config.get("value_scale", 1.0))

    def _forward(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        return {Columns.ACTION_DIST_INPUTS: self._pi(batch[Columns.OBS])}

    def compute_values(self, batch: dict[str, Any], embeddings: Any = None) -> torch.Tensor:
        return self._value_offset + self._vf(batch[Columns.OBS]).squeeze(-1) * self._value_scale

    # -- TargetNetworkAPI (APPO) -----------------------------------------------------------
    def make_target_networks(self) -> None:
        self._target_pi = make_target_network(self._pi)

    def get_target_network_pairs(self) -> list[tuple[nn.Module, nn.Module]]:
        return [(self._pi, self._target_pi)]

    def forward_target(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        return {TARGET_NETWORK_ACTION_DIST_INPUTS: self._target_pi(batch[Columns.OBS])}

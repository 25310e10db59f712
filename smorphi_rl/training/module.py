"""The one RLModule PPO, IMPALA and APPO share: a small CNN over the map plus an MLP over the shape.

Policy and value are separate networks (no shared trunk), so the value loss, whose scale is the
episode return's, never swamps the policy gradient. The critic is `value_offset + value_scale * head`
(the random-shape return level and its spread), so the head's raw output stays near 0.

The map is constant within an episode and a batch holds a handful of distinct maps, so the CNN runs
once per distinct map in a batch and its features are gathered to the rows: the learner's cost no
longer grows with a CNN pass per row. In a learner the batch's maps arrive as numbers in a `MapTable`
of the distinct maps seen (the learners' `CompactMaps`), so shuffling and slicing minibatches moves
4 bytes a row instead of the map's 8 KB; an env runner's steps keep one map's features until
the map or the weights change.
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.core.learner.utils import make_target_network
from ray.rllib.core.rl_module.apis import TARGET_NETWORK_ACTION_DIST_INPUTS, TargetNetworkAPI, ValueFunctionAPI
from ray.rllib.core.rl_module.torch import TorchRLModule
from torch import nn

from smorphi_rl import rllib_compat
from smorphi_rl.env import EXTRA_KEYS, MAP_LEVELS
from smorphi_rl.numpy_policy import CONV_CHANNELS, HIDDEN, MAP_FEATURES
from smorphi_rl.training.distribution import HingeCategorical
from smorphi_rl.training.presets import ANGLE_FREQUENCIES

# The angles (presets.ANGLE_FREQUENCIES): the critic also sees each angle as sin and cos of k pi theta / 180 for
# k = 1..8, as the R1 landscape is rugged at a few degrees and the value net has to resolve it. What the policy
# net sees is a preset's choice (`policy_angle_frequencies`, in the module's model_config): the fast PPO preset
# gives it the plain angles only. With the critic's 8 frequencies a policy can draw a sink at every ripple of
# the landscape, and PPO's greedy roll-outs settled in whichever basin a start fell into (map-1, 150,000 steps:
# 5-13 of the 20 protocol starts within 1 % of the optimum); smooth in the angles it learns one flow towards the
# best region (docs/decisions.md). IMPALA did worse without them and keeps them. A checkpoint whose model_config
# lacks the key was written with 8 (the layout before the key existed).

MAP_KEY = "map"
"""The observation's map entry."""
WORD = torch.int64


def pack_maps(maps: torch.Tensor) -> torch.Tensor:
    """A uint8 batch of maps (B, C, S, S) as int64 words (B, C S S / 8), the same bytes (no copy), so that
    indexing rows moves words instead of bytes; other tensors come back unchanged."""
    flat = maps.reshape(maps.shape[0], -1) if maps.dim() > 1 else maps
    if maps.dtype != torch.uint8 or maps.dim() < 2 or flat.shape[1] % 8 or not flat.is_contiguous():
        return maps
    return flat.view(WORD)


def unpack_maps(maps: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """The uint8 maps (B, *shape) of a batch that may have been packed by `pack_maps`."""
    if maps.dtype == WORD:
        return maps.view(torch.uint8).reshape(maps.shape[0], *shape)
    return maps


def observation_tensors(arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """A batch of observation arrays as tensors on the same memory. The env's shared map comes as a read-only
    broadcast (`vector_env.stack_observations`); the nets never write to their inputs, so torch's warning about
    non-writable arrays is not raised for it."""
    with warnings.catch_warnings():  # under a microsecond
        warnings.filterwarnings("ignore", "The given NumPy array is not writable", UserWarning)
        return {key: torch.from_numpy(value) for key, value in arrays.items()}


def distinct_rows(maps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(index of one row per distinct map, each row's distinct-map number) of a uint8 batch (B, ...), or
    None when the batch's maps are (nearly) all distinct. A broadcast of one map (batch stride 0) is one map.

    Rows are grouped by a few sampled pixels, then every row is checked equal to its group's first
    row, so the grouping is exact: a batch where the sample misleads is simply not deduplicated."""
    n = maps.shape[0]
    if n > 1 and maps.stride(0) == 0:  # one map seen n times: nothing to compare
        return _one_map(n, maps.device)
    flat = maps.reshape(n, -1)
    words = _as_words(flat)
    if bool((words == words[0]).all()):  # one map: the common case, one cheap check
        return _one_map(n, flat.device)
    if n < MIN_GROUPED_ROWS:
        return None
    probe = _probe(flat.shape[1], flat.device)
    keys = (flat[:, probe[0]].to(torch.int64) * probe[1]).sum(dim=1)
    unique, inverse = torch.unique(keys, return_inverse=True)
    if 2 * unique.shape[0] > n:
        return None
    first = torch.full((unique.shape[0],), n, dtype=torch.long, device=flat.device)
    first.scatter_reduce_(0, inverse, torch.arange(n, device=flat.device), reduce="amin")
    if not bool((words[first][inverse] == words).all()):
        return None
    return first, inverse


def _one_map(n: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """`distinct_rows` of a batch of n rows that all hold one map: row 0, and map 0 for every row."""
    zeros = torch.zeros(n, dtype=torch.long, device=device)
    return zeros[:1], zeros


def _as_words(flat: torch.Tensor) -> torch.Tensor:
    """The rows of a uint8 (B, N) tensor as int64 words when N allows (8x fewer elements to compare)."""
    if flat.shape[1] % 8 == 0 and flat.is_contiguous():
        return flat.view(torch.int64)
    return flat


def _groups(maps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
    """`distinct_rows` of a uint8 batch of more than one map; None for anything else."""
    return distinct_rows(maps) if maps.dtype == torch.uint8 and maps.shape[0] > 1 else None


INDEX = torch.int32
"""The dtype of a batch's map column in index form: (B,) numbers of the rows' maps in the module's MapTable."""


class MapTable:
    """Every distinct map a module's learner has seen, numbered in order: a run trains on a handful, so a batch's
    map column can be each row's map number (`index_maps`). Shared by the policy, value and target nets of one
    module (a deep copy, as for APPO's target net, shares it too). Append-only, so a batch queued for a learner
    thread stays readable; past MAX_MAPS maps, batches keep their maps instead."""

    MAX_MAPS = 1024

    def __init__(self) -> None:
        self._numbers: dict[bytes, int] = {}
        self._maps: torch.Tensor | None = None

    def numbers_of(self, maps: torch.Tensor) -> torch.Tensor | None:
        """The numbers of distinct maps (k, C, S, S), adding the new ones; None when the table would overflow."""
        keys = [m.cpu().numpy().tobytes() for m in maps]
        new = [i for i, key in enumerate(keys) if key not in self._numbers]
        if len(self._numbers) + len(new) > self.MAX_MAPS:
            return None
        if new:
            added = maps[new]  # indexing by a list copies
            self._maps = added if self._maps is None else torch.cat([self._maps, added])  # before the numbers:
            for i in new:  # a reader never meets a number without its map
                self._numbers[keys[i]] = len(self._numbers)
        return torch.tensor([self._numbers[key] for key in keys], dtype=INDEX)

    def lookup(self, numbers: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(the distinct maps a map column in index form names, each row's position among them)."""
        if self._maps is None:
            raise RuntimeError("a batch names maps by number, but this module holds no map table")
        distinct, rows = torch.unique(numbers.long(), return_inverse=True)
        return self._maps[distinct], rows

    def __deepcopy__(self, memo: dict[int, Any]) -> MapTable:
        return self


def index_maps(maps: torch.Tensor, table: MapTable) -> torch.Tensor | None:
    """A uint8 batch of maps (B, C, S, S) as each row's map number in `table`, or None when its maps are (nearly)
    all distinct (`distinct_rows`) or too many for the table."""
    groups = _groups(maps)
    if groups is None:
        return None
    first, inverse = groups
    numbers = table.numbers_of(maps[first])
    return None if numbers is None else numbers[inverse]


MIN_GROUPED_ROWS = 128
"""Below this many rows, grouping several maps costs more than running the CNN on every row."""
PROBE_PIXELS = 256
_PROBES: dict[tuple[int, str], tuple[torch.Tensor, torch.Tensor]] = {}


def _probe(n: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Fixed pixel positions and 40-bit weights that key a map row."""
    key = (n, str(device))
    if key not in _PROBES:
        generator = torch.Generator().manual_seed(0x5EED)
        positions = torch.randperm(n, generator=generator)[: min(n, PROBE_PIXELS)]
        weights = torch.randint(1, 1 << 40, (positions.shape[0],), generator=generator, dtype=torch.int64)
        _PROBES[key] = (positions.to(device), weights.to(device))
    return _PROBES[key]


class _Net(nn.Module):
    """Map (2 x S x S) -> CNN -> features; concatenated with angles and metrics -> MLP -> `out` values."""

    def __init__(
        self, obs_space: gym.spaces.Dict, out: int, frequencies: int = ANGLE_FREQUENCIES,
        map_table: MapTable | None = None,
    ) -> None:  # fmt: skip
        super().__init__()
        map_shape = obs_space["map"].shape
        if map_shape is None:  # pragma: no cover (the env always declares it)
            raise TypeError("the observation's map has no shape")
        channels, size, _ = map_shape
        self._map_shape = tuple(int(d) for d in map_shape)
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, CONV_CHANNELS[0], kernel_size=3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(*CONV_CHANNELS, kernel_size=3, stride=2, padding=1),
            nn.ReLU(),
            nn.AdaptiveMaxPool2d(4),  # any obs_size gives the same 16 x 4 x 4 features
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.cnn(torch.zeros(1, channels, size, size)).shape[1]
        self.map_fc = nn.Sequential(nn.Linear(flat, MAP_FEATURES), nn.ReLU())
        self._map_parameters = [*self.cnn.parameters(), *self.map_fc.parameters()]
        self._kept: tuple[tuple[tuple[int, int], ...], torch.Tensor, torch.Tensor] | None = None
        self.map_table = map_table if map_table is not None else MapTable()
        n_angles = int(np.prod(obs_space["angles"].shape or (1,)))
        self._extras = tuple(k for k in EXTRA_KEYS if k in obs_space.spaces)
        """The observation's entries fed to the MLP as they are (the metrics; the floor layout's scale)."""
        shape_inputs = n_angles * (1 + 2 * frequencies) + sum(int(np.prod(obs_space[k].shape or (1,)))
                                                              for k in self._extras)  # fmt: skip
        self.register_buffer("_freqs", torch.arange(1, frequencies + 1, dtype=torch.float32) * torch.pi)
        self.mlp = nn.Sequential(
            nn.Linear(MAP_FEATURES + shape_inputs, HIDDEN),
            nn.Tanh(),
            nn.Linear(HIDDEN, HIDDEN),
            nn.Tanh(),
        )
        self.head = nn.Linear(HIDDEN, out)
        nn.init.orthogonal_(self.head.weight, gain=0.01)
        nn.init.zeros_(self.head.bias)

    def encode_maps(self, maps: torch.Tensor) -> torch.Tensor:
        """Map features for every row, computing the CNN once per distinct map of the batch."""
        if maps.dtype == INDEX:
            table, rows = self.map_table.lookup(maps)
            return self._features(table)[rows]
        maps = unpack_maps(maps, self._map_shape)
        groups = _groups(maps)
        if groups is not None:
            first, inverse = groups
            return self._features(maps[first])[inverse]
        return self._features(maps)

    def _features(self, maps: torch.Tensor) -> torch.Tensor:
        """The CNN's features of a batch of maps; outside autograd, one map's features are kept until the map or
        the weights change (an env runner steps the same map, with the same weights, for a whole iteration)."""
        if torch.is_grad_enabled() or maps.shape[0] != 1:
            return self.map_fc(self.cnn(maps.float() / MAP_LEVELS))
        # optimiser steps and loads bump a tensor's version
        version = tuple((id(p), rllib_compat.tensor_version(p)) for p in self._map_parameters)
        kept = self._kept
        if kept is not None and kept[0] == version and torch.equal(kept[1], maps):
            return kept[2]
        features = self.map_fc(self.cnn(maps.float() / MAP_LEVELS))
        self._kept = (version, maps.clone(), features)  # one assignment: safe beside a learner thread
        return features

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        map_features = self.encode_maps(obs[MAP_KEY])
        angles = obs["angles"]
        freqs: torch.Tensor = self._freqs  # type: ignore[assignment]  # a registered buffer
        extras = [obs[k] for k in self._extras]
        if freqs.numel():
            phases = (angles.unsqueeze(-1) * freqs).flatten(-2)  # angles are theta / 180, so k pi theta / 180
            features = [map_features, angles, torch.sin(phases), torch.cos(phases), *extras]
        else:  # no frequencies: their empty columns would add nothing
            features = [map_features, angles, *extras]
        return self.head(self.mlp(torch.cat(features, dim=-1)))


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
        self.action_dist_cls = HingeCategorical.get_partial_dist_cls(  # type: ignore[misc]  # RLlib's typing
            space=space, input_lens=nvec
        )
        obs_space = self.observation_space
        if not isinstance(obs_space, gym.spaces.Dict):
            raise TypeError(f"MorphologyModule needs the env's Dict observation space, got {obs_space}")
        model_config: dict[str, Any] = dict(self.model_config or {})  # type: ignore[arg-type]
        table = MapTable()  # one for both nets (and APPO's target net, a deep copy of _pi)
        frequencies = int(model_config.get("policy_angle_frequencies", ANGLE_FREQUENCIES))
        self._pi = _Net(obs_space, sum(nvec), frequencies, table)
        self._vf = _Net(obs_space, 1, map_table=table)
        self._value_offset = float(model_config.get("value_offset", 0.0))
        self._value_scale = float(model_config.get("value_scale", 1.0))

    def index_maps(self, maps: torch.Tensor) -> torch.Tensor | None:
        """A learner batch's maps as numbers in this module's MapTable (None: keep them as they are)."""
        return index_maps(maps, self._pi.map_table)

    def _forward(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        return {Columns.ACTION_DIST_INPUTS: self._pi(batch[Columns.OBS])}

    # RLlib switches a torch module to eval() and back around every sampling forward pass: a walk over all
    # its submodules twice per env-runner step, 7 % of sampling time here. These nets have no layer whose
    # behaviour depends on the mode (no dropout, no batch norm; a test checks), so the switch is skipped.
    def forward_exploration(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        return self._forward_exploration(batch, **kwargs)

    def forward_inference(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        return self._forward_inference(batch, **kwargs)

    def compute_values(self, batch: dict[str, Any], embeddings: Any = None) -> torch.Tensor:
        return self.compute_values_with(self._vf, batch)

    def value_net(self) -> nn.Module:
        """The critic's net (a learner may keep a frozen copy of it: `learners.FrozenCritic`)."""
        return self._vf

    def compute_values_with(self, net: nn.Module, batch: dict[str, Any]) -> torch.Tensor:
        """State values of `batch` by `net` (this module's critic or a copy of it), in return units."""
        return self._value_offset + net(batch[Columns.OBS]).squeeze(-1) * self._value_scale

    # -- TargetNetworkAPI (APPO) -----------------------------------------------------------
    def make_target_networks(self) -> None:
        self._target_pi = make_target_network(self._pi)

    def get_target_network_pairs(self) -> list[tuple[nn.Module, nn.Module]]:
        return [(self._pi, self._target_pi)]

    def forward_target(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        return {TARGET_NETWORK_ACTION_DIST_INPUTS: self._target_pi(batch[Columns.OBS])}

"""The policy net of `training/module.py` in NumPy: greedy actions without torch or Ray.

The same layers in the same order (two stride-2 convolutions with ReLU, an adaptive max pool to 4 x 4, a
linear layer with ReLU for the map; the angles, their Fourier features if the policy has any, the metrics
and the floor's scale beside it; two tanh layers and a linear head), in float32. A test holds its logits to
the torch module's. The map's features are computed once per map (a floor's picture is one shared array).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np

from smorphi_rl.env import EXTRA_KEYS, MAP_LEVELS
from smorphi_rl.errors import SmorphiError

POLICY = "_pi."
POOL = 4
CONV_CHANNELS = (8, 16)
MAP_FEATURES = 64
HIDDEN = 128
"""The policy net's layer sizes (its two convolutions' channels, the map's features, the MLP's width), the torch
module's (`training/module.py` builds from them): weights of other sizes are no policy of ours (a first layer of
50,000 channels in a 400 KB file took gigabytes to run)."""
MISFIT = "the policy's layers do not fit its observation and action sizes, or each other"


class NumpyPolicy:
    """Greedy actions of a policy from its weights (by the torch module's parameter names)."""

    def __init__(self, weights: dict[str, np.ndarray], nvec: Sequence[int], frequencies: int,
                 observation: dict[str, tuple[int, ...]]) -> None:  # fmt: skip
        try:
            self.conv = [(weights[f"{POLICY}cnn.{i}.weight"], weights[f"{POLICY}cnn.{i}.bias"]) for i in (0, 2)]
            self.fc = (weights[f"{POLICY}map_fc.0.weight"], weights[f"{POLICY}map_fc.0.bias"])
            self.mlp = [(weights[f"{POLICY}mlp.{i}.weight"], weights[f"{POLICY}mlp.{i}.bias"]) for i in (0, 2)]
            self.head = (weights[f"{POLICY}head.weight"], weights[f"{POLICY}head.bias"])
        except KeyError as exc:
            raise SmorphiError(f"the policy's weights lack {exc.args[0]} (not a smorphi-rl policy net)") from None
        self.nvec = [int(n) for n in nvec]
        self.freqs = (np.arange(1, frequencies + 1, dtype=np.float32) * np.float32(math.pi)).astype(np.float32)
        self.extras = tuple(k for k in EXTRA_KEYS if k in observation)
        if not self._chained():  # first: the sizes below read each layer's dimensions
            raise SmorphiError(MISFIT)
        width = sum(int(np.prod(observation[k])) for k in self.extras) + 3 * (1 + 2 * frequencies) + self.fc[0].shape[0]
        channels = tuple(observation.get("map", ()))[:1]
        fits_map = self.conv[0][0].ndim == 4 and tuple(self.conv[0][0].shape[1:]) == (*channels, 3, 3)
        if (self.mlp[0][0].shape[1] != width or self.head[0].shape[0] != sum(self.nvec)
                or not fits_map or min(self.nvec, default=0) < 1):  # fmt: skip
            raise SmorphiError(MISFIT)
        self._kept: tuple[np.ndarray, np.ndarray] | None = None

    def _chained(self) -> bool:
        """Each layer's bias fits its weight and each layer's input the layer before's output."""
        (c0, _), (c1, _) = self.conv
        layers = [self.fc, *self.mlp, self.head]
        shapes_ok = c0.ndim == c1.ndim == 4 and c1.shape[2:] == (3, 3) and all(w.ndim == 2 for w, _ in layers)
        sizes = (c0.shape[0], c1.shape[0], self.fc[0].shape[0], self.mlp[0][0].shape[0], self.mlp[1][0].shape[0])
        shapes_ok = shapes_ok and sizes == (*CONV_CHANNELS, MAP_FEATURES, HIDDEN, HIDDEN)
        if not shapes_ok or any(b.shape != (w.shape[0],) for w, b in [*self.conv, *layers]):
            return False
        return (c1.shape[1] == c0.shape[0] and self.fc[0].shape[1] == c1.shape[0] * POOL * POOL
                and self.mlp[1][0].shape[1] == self.mlp[0][0].shape[0]
                and self.head[0].shape[1] == self.mlp[1][0].shape[0])  # fmt: skip

    def map_features(self, picture: np.ndarray) -> np.ndarray:
        """The map branch's 64 features of one (C, S, S) uint8 picture (kept for the last picture seen)."""
        kept = self._kept
        if kept is not None and (kept[0] is picture or np.array_equal(kept[0], picture)):
            return kept[1]
        x = picture.astype(np.float32) / np.float32(MAP_LEVELS)
        for weight, bias in self.conv:
            x = np.maximum(_conv3x3_stride2(x, weight, bias), 0.0)
        pooled = _adaptive_max_pool(x, POOL).reshape(-1)
        features = np.maximum(self.fc[0] @ pooled + self.fc[1], 0.0).astype(np.float32)
        self._kept = (picture, features)
        return features

    def logits(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        try:
            return self._logits(obs)
        except KeyError as exc:  # an observation of another layout: named, checked only when it fails
            raise SmorphiError(
                f"the observation has no {exc.args[0]!r} entry, which this policy reads: it was trained "
                f"on another observation layout (it reads {', '.join(('map', 'angles', *self.extras))})"
            ) from None

    def _logits(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        angles = np.asarray(obs["angles"], dtype=np.float32)
        parts = [self.map_features(obs["map"]), angles]
        if self.freqs.size:
            phases = (angles[:, None] * self.freqs).reshape(-1)
            parts += [np.sin(phases), np.cos(phases)]
        parts += [np.asarray(obs[k], dtype=np.float32) for k in self.extras]
        h = np.concatenate(parts).astype(np.float32)
        for weight, bias in self.mlp:
            h = np.tanh(weight @ h + bias)
        return (self.head[0] @ h + self.head[1]).astype(np.float32)

    def act(self, observations: Sequence[dict[str, np.ndarray]] | dict[str, np.ndarray]) -> np.ndarray:
        """The most likely move of each hinge for every observation (n, 3); for one observation, its move (3,)."""
        if isinstance(observations, Mapping):
            return self.act([observations])[0]
        out = np.empty((len(observations), len(self.nvec)), dtype=np.int64)
        for i, obs in enumerate(observations):
            logits = self.logits(obs)
            edges = np.cumsum([0, *self.nvec])
            out[i] = [int(np.argmax(logits[a:b])) for a, b in itertools.pairwise(edges)]
        return out


def _conv3x3_stride2(x: np.ndarray, weight: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """torch's Conv2d(kernel 3, stride 2, padding 1) of one (C, H, W) input."""
    padded = np.pad(x, ((0, 0), (1, 1), (1, 1)))
    windows = np.lib.stride_tricks.sliding_window_view(padded, (3, 3), axis=(1, 2))[:, ::2, ::2]
    return np.einsum("chwij,ocij->ohw", windows, weight, optimize=True) + bias[:, None, None]


def _adaptive_max_pool(x: np.ndarray, size: int) -> np.ndarray:
    """torch's AdaptiveMaxPool2d(size) of one (C, H, W) input."""
    _, h, w = x.shape
    rows = [(i * h // size, -(-(i + 1) * h // size)) for i in range(size)]
    cols = [(j * w // size, -(-(j + 1) * w // size)) for j in range(size)]
    return np.stack([np.stack([x[:, r0:r1, c0:c1].max(axis=(1, 2)) for c0, c1 in cols], axis=-1)
                     for r0, r1 in rows], axis=-2)  # fmt: skip

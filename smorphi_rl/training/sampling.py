"""The env runner and its connector pipelines, lean: what RLlib's default runner and pieces compute for our env
and module, with the connectors in two steps instead of twelve.

RLlib's default env-to-module pipeline (observations from episodes, time rank, states, batching, tensors) and
module-to-env pipeline (sample actions, numpy, unbatch, time rank, normalise and clip, listify) handle every
kind of module and space, item by item through tree utilities: about 30 % of an env runner's sampling time here.
Our module is stateless, its actions MultiDiscrete and never normalised or clipped, so:
- `StackObservations` stacks the runner's latest observations into one batch of tensors;
- `SampleActions` samples from the module's action distribution and hands the runner numpy arrays it indexes
  by env (actions, their log-probabilities, the distribution inputs); hinges of equal size in one draw.
Both draw from the same generators in the same order as the default pieces, so a seeded run trains exactly as
before (a test checks identical samples).

`LeanEnvRunner` is RLlib's single-agent env runner with these costs cut, none changing what it records:
- it splits each step's batched observations and actions by env with a plain comprehension instead of RLlib's
  tree utilities (`split_by_env`), and `StackObservations` takes the env's batch those rows came from rather
  than stacking them again;
- it skips the per-env, per-step episode callbacks that no callback overrides;
- it takes our vector env's info dicts without gymnasium's round trip through info columns (`InfoLists`);
- episodes stack their steps in one numpy call per column (`stack_items`) instead of RLlib's item-by-item copy.
"""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers.vector import DictInfoToList
from ray.rllib.callbacks.callbacks import RLlibCallback
from ray.rllib.connectors.connector_v2 import ConnectorV2
from ray.rllib.core.columns import Columns
from ray.rllib.core.distribution.torch.torch_distribution import TorchMultiCategorical
from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner
from ray.rllib.env.utils.infinite_lookback_buffer import InfiniteLookbackBuffer
from ray.rllib.utils.numpy import convert_to_numpy

from smorphi_rl.training.heap import settle_heap
from smorphi_rl.training.module import observation_tensors
from smorphi_rl.training.threads import one_torch_thread
from smorphi_rl.vector_env import MorphologyVectorEnv, stack_observations


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
        # Rows: the env's batch that the rows were split from, the very arrays a stack would rebuild
        arrays = observations.batched if isinstance(observations, Rows) else stack_observations(observations)
        stacked = observation_tensors(arrays)
        if self.device is not None:
            stacked = {key: value.to(self.device) for key, value in stacked.items()}
        batch[Columns.OBS] = stacked
        return batch


class SampleActions(ConnectorV2):
    """Module-to-env: actions sampled from the module's distribution (its most likely ones when not exploring),
    their log-probabilities and every module output, as numpy arrays of one row per env (the runner indexes
    them by env)."""

    _sizes: tuple[int, list[int] | None] | None = None
    """(id of the module last seen, its hinges' category counts or None): `_hinge_sizes`, kept between steps."""

    def __call__(
        self, *, rl_module: Any, batch: dict[str, Any], episodes: list[Any], explore: bool | None = None,
        shared_data: dict[str, Any] | None = None, **kwargs: Any,
    ) -> Any:  # fmt: skip
        if Columns.ACTIONS not in batch:
            if self._sizes is None or self._sizes[0] != id(rl_module):
                self._sizes = (id(rl_module), _hinge_sizes(rl_module))  # once per module, not once a step
            sizes = self._sizes[1]
            if explore and sizes is not None and Columns.ACTION_LOGP not in batch:
                batch[Columns.ACTIONS], batch[Columns.ACTION_LOGP] = sample_hinges(
                    batch[Columns.ACTION_DIST_INPUTS], sizes
                )
            else:
                module = rl_module
                dist_cls = (
                    module.get_exploration_action_dist_cls() if explore else module.get_inference_action_dist_cls()
                )
                dist = dist_cls.from_logits(batch[Columns.ACTION_DIST_INPUTS])
                if not explore:
                    dist = dist.to_deterministic()
                batch[Columns.ACTIONS] = dist.sample()
                if Columns.ACTION_LOGP not in batch:
                    batch[Columns.ACTION_LOGP] = dist.logp(batch[Columns.ACTIONS])
        return to_numpy(batch)


def _hinge_sizes(module: Any) -> list[int] | None:
    """The categories of each hinge when `module` samples from RLlib's MultiCategorical (ours does), else None."""
    space = getattr(module, "action_space", None)
    dist_cls = module.get_exploration_action_dist_cls()
    if not (isinstance(space, gym.spaces.MultiDiscrete) and isinstance(dist_cls, type)):
        return None
    return [int(n) for n in space.nvec] if issubclass(dist_cls, TorchMultiCategorical) else None


def sample_hinges(logits: torch.Tensor, sizes: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """(actions, log-probabilities) drawn as RLlib's TorchMultiCategorical draws them from `logits`, op for op
    and so draw for draw (each hinge a torch Categorical: logits normalised by their logsumexp, one multinomial
    draw from their softmax, its log-probability gathered), without building a distribution object per hinge."""
    if len(set(sizes)) == 1 and logits.dim() == 2:
        return _sample_equal_hinges(logits, len(sizes), sizes[0])
    normalised = [part - part.logsumexp(dim=-1, keepdim=True) for part in torch.split(logits, sizes, dim=-1)]
    draws = [
        torch.multinomial(torch.softmax(n, dim=-1).reshape(-1, n.shape[-1]), 1, True).T.reshape(n.shape[:-1])
        for n in normalised
    ]
    logps = [n.gather(-1, d.long().unsqueeze(-1)).squeeze(-1) for n, d in zip(normalised, draws, strict=True)]
    return torch.stack(draws, dim=-1), torch.sum(torch.stack(logps), dim=0)


def _sample_equal_hinges(logits: torch.Tensor, hinges: int, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """`sample_hinges` when every hinge has `size` categories, in a third of the torch calls: the hinges' rows in
    hinge-major order (B, H S) -> (H B, S), so one multinomial call draws them in the order of H calls, hinge by
    hinge (one draw per row: torch's exponential race over its rows, in order)."""
    normalised = logits.reshape(logits.shape[0], hinges, size).transpose(0, 1)
    normalised = normalised - normalised.logsumexp(dim=-1, keepdim=True)
    draws = torch.multinomial(torch.softmax(normalised, dim=-1).reshape(-1, size), 1, True).reshape(hinges, -1)
    logps = normalised.gather(-1, draws.unsqueeze(-1)).squeeze(-1)
    return draws.T, torch.sum(logps, dim=0)


def to_numpy(batch: Any) -> Any:
    """RLlib's `convert_to_numpy` (floats to float32, signed integers to int32) for a flat dict of tensors, without
    its tree utilities; anything else goes to RLlib's."""
    if type(batch) is not dict or not all(isinstance(v, torch.Tensor) and v.dim() > 0 for v in batch.values()):
        return convert_to_numpy(batch)
    out = {}
    for key, value in batch.items():
        array = value.detach().cpu().numpy()
        if np.issubdtype(array.dtype, np.floating):
            array = array.astype(np.float32)
        elif np.issubdtype(array.dtype, np.signedinteger):
            array = array.astype(np.int32)
        out[key] = array
    return out


def env_to_module(env: Any = None, spaces: Any = None, device: Any = None) -> list[ConnectorV2]:
    """`config.env_runners(env_to_module_connector=...)`, with RLlib's default pieces switched off."""
    return [StackObservations(device=device)]


def module_to_env(env: Any = None, spaces: Any = None) -> list[ConnectorV2]:
    """`config.env_runners(module_to_env_connector=...)`, with RLlib's default pieces switched off."""
    return [SampleActions()]


class Rows(list):  # type: ignore[type-arg]
    """`split_by_env`'s rows of a flat dict of arrays, which keep that dict (`batched`): the runner hands these
    rows, the env's latest observations, to `StackObservations`, which need not stack them again."""

    batched: dict[str, np.ndarray]


def split_by_env(batched: Any) -> list[Any]:
    """RLlib's `unbatch` for what our env and connectors hand the runner: a flat dict of arrays becomes one dict
    per env (the same keys in the same order, each value the env's row, a view), an array its rows; anything
    else goes through RLlib's own `unbatch`. Its tree utilities cost about 25 us per env and step here."""
    if isinstance(batched, np.ndarray) and batched.ndim > 0:
        return list(batched)
    if type(batched) is dict and batched and all(isinstance(v, np.ndarray) and v.ndim > 0 for v in batched.values()):
        keys, columns = list(batched), list(batched.values())
        rows = Rows(dict(zip(keys, row, strict=True)) for row in zip(*columns, strict=True))
        rows.batched = batched
        return rows
    return _RLLIB_UNBATCH(batched)


def stack_items(items: list[Any], **kwargs: Any) -> Any:
    """RLlib's `batch` (what an episode's `to_numpy` stacks its lists of steps with) for lists of same-shape arrays
    or of flat dicts of them, in one numpy call per column instead of a Python assignment per item and tree
    utilities; anything else, or a stack whose dtype is not the first item's, goes through RLlib's own `batch`.
    A numpy stack that keeps the first item's dtype holds what RLlib's (which casts into that dtype) holds."""
    first = items[0] if items and not kwargs else None
    if type(first) is np.ndarray:
        stacked = _stack(items, first)
        if stacked is not None:
            return stacked
    elif type(first) is dict and first and all(type(v) is np.ndarray for v in first.values()):
        keys = first.keys()
        if all(type(item) is dict and item.keys() == keys for item in items):
            columns = {key: _stack([item[key] for item in items], first[key]) for key in keys}
            if all(column is not None for column in columns.values()):
                return columns
    return _RLLIB_BATCH(items, **kwargs)


def _stack(column: list[Any], first: np.ndarray) -> np.ndarray | None:
    """`np.stack(column)` if it has the first item's dtype and shape per row; None otherwise."""
    try:
        stacked = np.stack(column)
    except ValueError:
        return None
    return stacked if stacked.dtype == first.dtype and stacked.shape[1:] == first.shape else None


_RUNNER_MODULE = inspect.getmodule(SingleAgentEnvRunner)
_RLLIB_UNBATCH = _RUNNER_MODULE.unbatch  # type: ignore[union-attr]
_BUFFER_MODULE = inspect.getmodule(InfiniteLookbackBuffer)
_RLLIB_BATCH = _BUFFER_MODULE.batch  # type: ignore[union-attr]


class InfoLists(DictInfoToList):  # type: ignore[misc]  # gymnasium's wrapper is generic
    """What RLlib wraps every vector env in (gymnasium's DictInfoToList: one info dict per sub-env), for our
    vector env: it hands over its sub-envs' info dicts as they are, the very dicts DictInfoToList would rebuild
    from its info columns (same keys, order and values), without building the columns. The runner's own wrapper
    becomes one (`install`): a second wrapper around the env would close it when the first is collected."""

    @staticmethod
    def install(wrapper: Any) -> None:
        """Switch RLlib's DictInfoToList around a MorphologyVectorEnv to this class (any other env: left as it is)."""
        inner = getattr(wrapper, "env", None)
        if type(wrapper) is DictInfoToList and type(inner) is MorphologyVectorEnv:
            inner.info_lists = True
            wrapper.__class__ = InfoLists

    def step(self, actions: Any) -> Any:
        return self.env.step(actions)

    def reset(self, *, seed: Any = None, options: Any = None) -> Any:
        return self.env.reset(seed=seed, options=options)


class LeanEnvRunner(SingleAgentEnvRunner):  # type: ignore[misc]  # RLlib's bases are untyped
    """RLlib's SingleAgentEnvRunner, sampling the same episodes faster: its `unbatch` is `split_by_env` for the
    duration of a `_sample` call, and torch runs on one thread for it (`threads`); per-env episode callbacks that
    no callback overrides are not made, and our vector env's infos reach it without a round trip through columns
    (`InfoLists`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if (self.worker_index or 0) > 0:  # a remote runner, alone in its process: its objects live as long (`heap`)
            settle_heap()

    def make_env(self) -> None:
        super().make_env()
        InfoLists.install(self.env)

    def _sample(self, **kwargs: Any) -> Any:
        _RUNNER_MODULE.unbatch = split_by_env  # type: ignore[union-attr]
        _BUFFER_MODULE.batch = stack_items  # type: ignore[union-attr]
        try:
            with one_torch_thread():
                return super()._sample(**kwargs)
        finally:
            _RUNNER_MODULE.unbatch = _RLLIB_UNBATCH  # type: ignore[union-attr]
            _BUFFER_MODULE.batch = _RLLIB_BATCH  # type: ignore[union-attr]

    _step_callbacks: bool | None = None

    def _make_on_episode_callback(self, which: str, idx: int, episodes: list[Any]) -> None:
        if which == "on_episode_step":
            if self._step_callbacks is None:
                self._step_callbacks = self._overridden(which)
            if not self._step_callbacks:
                return
        super()._make_on_episode_callback(which, idx, episodes)

    def _overridden(self, which: str) -> bool:
        """Whether a callback object overrides RLlib's no-op `which`, or a callback function is set for it."""
        base = getattr(RLlibCallback, which)
        objects = self._callbacks or []
        return bool(getattr(self.config, f"callbacks_{which}", None)) or any(
            getattr(type(c), which, base) is not base for c in objects
        )


LEAN_SAMPLING = {
    "env_runner_cls": LeanEnvRunner,
    "env_to_module_connector": env_to_module,
    "add_default_connectors_to_env_to_module_pipeline": False,
    "module_to_env_connector": module_to_env,
    "add_default_connectors_to_module_to_env_pipeline": False,
}
"""The `config.env_runners(...)` settings that put the lean pipelines in place of RLlib's defaults."""

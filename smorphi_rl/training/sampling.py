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
- it takes our vector env's info dicts without gymnasium's round trip through info columns (`InfoLists`).
The first two reach into RLlib's private step loop; they live in `rllib_compat` (`runner_mixin`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers.vector import DictInfoToList
from ray.rllib.connectors.connector_v2 import ConnectorV2
from ray.rllib.core.columns import Columns
from ray.rllib.core.distribution.torch.torch_distribution import TorchMultiCategorical
from ray.rllib.utils.numpy import convert_to_numpy
from ray.rllib.utils.spaces.space_utils import unbatch as rllib_unbatch

from smorphi_rl import rllib_compat
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
    return rllib_unbatch(batched)


class InfoLists(DictInfoToList):  # type: ignore[misc]  # gymnasium's wrapper is generic
    """What RLlib wraps every vector env in (gymnasium's DictInfoToList: one info dict per sub-env), for our
    vector env: it hands over its sub-envs' info dicts as they are, the very dicts DictInfoToList would rebuild
    from its info columns (same keys, order and values), without building the columns. The runner's own wrapper
    is replaced by one (`around`); the runner keeps the replaced one, whose collection would close the env."""

    @staticmethod
    def around(wrapper: Any) -> Any:
        """RLlib's DictInfoToList around a MorphologyVectorEnv replaced by one of these (any other env: as it is)."""
        inner = getattr(wrapper, "env", None)
        if type(wrapper) is not DictInfoToList or type(inner) is not MorphologyVectorEnv:
            return wrapper
        inner.info_lists = True
        return InfoLists(inner)

    def step(self, actions: Any) -> Any:
        return self.env.step(actions)

    def reset(self, *, seed: Any = None, options: Any = None) -> Any:
        return self.env.reset(seed=seed, options=options)


class LeanEnvRunner(rllib_compat.runner_mixin(split_by_env)):  # type: ignore[misc]  # RLlib's bases are untyped
    """RLlib's SingleAgentEnvRunner, sampling the same episodes faster: each step's batch is split by env with
    `split_by_env` (`rllib_compat.treeless_sample`), torch runs on one thread while it samples (`threads`),
    per-env step callbacks that no callback overrides are not made, and our vector env's infos reach it without
    a round trip through columns (`InfoLists`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if (self.worker_index or 0) > 0:  # a remote runner, alone in its process: its objects live as long (`heap`)
            settle_heap()

    def make_env(self) -> None:
        super().make_env()
        wrapper: Any = getattr(self, "env")  # noqa: B009  # RLlib's attribute, untyped
        self._rllib_wrapper = wrapper  # kept: collecting it would close the env it wraps
        self.env = InfoLists.around(wrapper)

    def sample(self, **kwargs: Any) -> Any:
        with one_torch_thread():
            return super().sample(**kwargs)


LEAN_SAMPLING = {
    "env_runner_cls": LeanEnvRunner,
    "env_to_module_connector": env_to_module,
    "add_default_connectors_to_env_to_module_pipeline": False,
    "module_to_env_connector": module_to_env,
    "add_default_connectors_to_module_to_env_pipeline": False,
}
"""The `config.env_runners(...)` settings that put the lean pipelines in place of RLlib's defaults."""

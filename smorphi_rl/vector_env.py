"""Many morphology envs stepped as one gymnasium VectorEnv: the env an RLlib env runner builds.

RLlib registers our env creator with a `vector_entry_point`; with `gym_env_vectorize_mode`
"vector_entry_point" it asks the creator for `num_envs` envs at once, and this class serves them.
Compared with gymnasium's SyncVectorEnv it shares one set of maps, caches and observations among
its sub-envs (a shape planned by one is free for all), stacks observations without deep copies,
and builds the info columns in one pass. Autoreset is gymnasium's NEXT_STEP, as RLlib expects.

Seeds: given a run seed, sub-env i of env runner w draws from
`SeedSequence(run_seed, spawn_key=(w, i))`, so no two runners, sub-envs or seeds share a stream
(RLlib's own `seed + worker_index` would give seed s, runner 2 the stream of seed s + 1, runner 1).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfig, EnvConfigError

RECORDING_KEY = "recording"
"""The env_config key that carries a RecordingConfig dict to the env runners (not an EnvConfig field)."""
SEED_KEY = "run_seed"
"""The env_config key that carries the run's seed to the env runners (not an EnvConfig field)."""
NUM_ENVS_KEY = "num_envs"
"""What RLlib adds to env_config when it asks the creator for a vector env."""


def stack_observations(observations: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Per-env observation dicts as one dict of batched arrays (what a vector env returns and a module reads). An
    entry that every env shares as one read-only array (the map, while all play one map) becomes a read-only
    broadcast of it (batch stride 0), not a copy per env."""
    return {key: _stack_column([o[key] for o in observations]) for key in observations[0]}


def _stack_column(column: list[np.ndarray]) -> np.ndarray:
    """One entry of every env's observation, batched: a broadcast when all are the same read-only array."""
    first = column[0]
    if len(column) > 1 and not first.flags.writeable and all(item is first for item in column):
        return np.broadcast_to(first, (len(column), *first.shape))
    return np.stack(column)


def sub_env_generator(run_seed: int, worker_index: int, env_index: int, generation: int = 0) -> np.random.Generator:
    """The independent random stream of one sub-env of one env runner of one run; `generation` is the iteration
    a resumed run restarted from (0 for a fresh run), so it draws fresh shapes instead of replaying its first ones."""
    key = (worker_index, env_index) if generation == 0 else (worker_index, env_index, generation)
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(run_seed, spawn_key=key)))


ACTIONS_STREAM = 0xAC7
"""The spawn-key word of an env runner's action-sampling stream (sub-envs use their own indices there)."""


def action_seed(run_seed: int, worker_index: int) -> int:
    """The torch seed of one remote env runner's action sampling: its own `SeedSequence` child of the run's seed
    (RLlib's `seed + worker_index` gives seed s, runner 2 the actions of seed s + 1, runner 1)."""
    return int(
        np.random.SeedSequence(run_seed, spawn_key=(worker_index, ACTIONS_STREAM)).generate_state(1, np.uint64)[0]
    )


class MorphologyVectorEnv(VectorEnv):
    """`num_envs` morphology envs (each possibly wrapped for recording) behind gymnasium's VectorEnv API."""

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.NEXT_STEP}  # noqa: RUF012

    def __init__(self, envs: Sequence[gym.Env], run_seed: int | None = None, worker_index: int = 0) -> None:
        if not envs:
            raise ValueError("a vector env needs at least one env")
        self.envs = list(envs)
        self.num_envs = len(self.envs)
        first = self.envs[0]
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(first.observation_space, self.num_envs)
        self.action_space = batch_space(first.action_space, self.num_envs)
        self.run_seed = run_seed
        self.worker_index = worker_index
        self._seeded = False
        self._needs_reset = np.zeros(self.num_envs, dtype=bool)
        self.info_lists = False
        """True: `reset` and `step` return each sub-env's info dict in a list, instead of gymnasium's info columns
        (for a wrapper that would turn the columns back into those dicts: `training/sampling.py`'s InfoLists)."""

    def set_worker_index(self, worker_index: int) -> None:
        """The env runner's index, known only after creation: RLlib's vector entry point hands the creator a
        plain dict without it. Seeds streams and names recordings; call before the first reset."""
        self.worker_index = int(worker_index)
        for env in self.envs:
            if hasattr(env, "worker_index"):
                env.worker_index = self.worker_index

    def reseed(self, generation: int) -> None:
        """Switch every sub-env to the streams of `generation` now (a resumed run: the restored iteration)."""
        if self.run_seed is None:
            return
        for i, env in enumerate(self.envs):
            env.unwrapped.np_random = sub_env_generator(self.run_seed, self.worker_index, i, generation)
        self._seeded = True

    def _seed_envs(self, seed: int | Sequence[int | None] | None) -> list[int | None]:
        """Reset seeds for the sub-envs; with a run seed, each gets its own spawned stream once instead."""
        if self.run_seed is not None:
            if not self._seeded:
                for i, env in enumerate(self.envs):
                    env.unwrapped.np_random = sub_env_generator(self.run_seed, self.worker_index, i)
                self._seeded = True
            return [None] * self.num_envs
        if seed is None or isinstance(seed, int):
            return [None if seed is None else seed + i for i in range(self.num_envs)]
        return list(seed)

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        results = [env.reset(seed=s, options=options) for env, s in zip(self.envs, self._seed_envs(seed), strict=True)]
        self._needs_reset[:] = False
        return stack_observations([r[0] for r in results]), self._infos([r[1] for r in results])

    def step(
        self, actions: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        n = self.num_envs
        rewards = np.zeros(n, dtype=np.float64)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        observations, infos = [], []
        for i, env in enumerate(self.envs):
            if self._needs_reset[i]:  # NEXT_STEP autoreset: this step's action is ignored
                obs, info = env.reset()
            else:
                obs, reward, term, trunc, info = env.step(actions[i])
                rewards[i], terminated[i], truncated[i] = reward, term, trunc
            observations.append(obs)
            infos.append(info)
        self._needs_reset = terminated | truncated
        return stack_observations(observations), rewards, terminated, truncated, self._infos(infos)

    def close_extras(self, **kwargs: Any) -> None:
        for env in self.envs:
            env.close()

    def _infos(self, infos: list[dict[str, Any]]) -> Any:
        return infos if self.info_lists else self._info_columns(infos)

    def _info_columns(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        """gymnasium's vector info, as its SyncVectorEnv lays it out: per key an array of the values' own type
        (numbers as numbers, arrays stacked, anything else as objects; a table a table of such), and `_key`, which
        sub-envs hold it (every one here)."""
        return _columns(infos, self.num_envs)


def _columns(infos: list[dict[str, Any]], n: int) -> dict[str, Any]:
    """`_info_columns` of one level of the sub-envs' infos."""
    columns: dict[str, Any] = {}
    for key, first in infos[0].items():
        values = [info[key] for info in infos]
        if isinstance(first, dict):
            columns[key] = _columns(values, n)
        elif type(first) in (int, float, bool) or isinstance(first, np.number):
            columns[key] = np.array(values, dtype=type(first))
        elif isinstance(first, np.ndarray):
            columns[key] = np.stack(values).astype(first.dtype, copy=False)
        else:
            columns[key] = np.empty(n, dtype=object)
            for i, value in enumerate(values):
                columns[key][i] = value
        columns[f"_{key}"] = np.ones(n, dtype=np.bool_)
    return columns


def make_env(
    env_config: dict[str, Any] | None, wrap: Callable[[MorphologyEnv, int], gym.Env] | None = None
) -> gym.Env | VectorEnv:
    """One MorphologyEnv, or with `num_envs` a MorphologyVectorEnv of them sharing their tables; `wrap(env,
    worker_index)` wraps each (training's env creator records episodes with it). The recording key is the
    caller's to read, and is dropped here."""
    raw = dict(env_config or {})
    raw.pop(RECORDING_KEY, None)
    run_seed = raw.pop(SEED_KEY, None)
    num_envs = raw.pop(NUM_ENVS_KEY, None)
    worker = int(getattr(env_config, "worker_index", 0) or 0)
    wrapped: Callable[[MorphologyEnv], gym.Env] = (lambda env: env) if wrap is None else (lambda env: wrap(env, worker))
    if num_envs is None:
        return wrapped(MorphologyEnv(raw))
    first = MorphologyEnv(raw)
    envs = [first] + [first.sibling() for _ in range(int(num_envs) - 1)]
    return MorphologyVectorEnv([wrapped(e) for e in envs], run_seed=run_seed, worker_index=worker)


def make_vector(
    num_envs: int = 1, env_config: dict[str, Any] | None = None, render_mode: str | None = None, **kwargs: Any
) -> MorphologyVectorEnv:
    """gymnasium's vector entry point of the env (`gymnasium.make_vec(smorphi_rl.ENV_ID, num_envs=8)`): `num_envs`
    envs sharing one set of maps and caches, as an env runner's; `reset(seed=s)` seeds sub-env i with s + i, as
    gymnasium's own vector envs do."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
        raise EnvConfigError(f"num_envs must be a whole number of at least 1, not {num_envs!r}")
    if render_mode is not None:
        raise EnvConfigError("a vector env renders nothing: make one env (gymnasium.make) to render")
    cap = kwargs.pop("max_episode_steps", None)  # gymnasium's TimeLimit: a cap on the env's own max_steps
    own = {**(env_config or {}), **kwargs} if isinstance(env_config, Mapping | None) else None  # else the env refuses
    if cap is not None and own is not None and cap < EnvConfig.from_dict(own).max_steps:  # no maps loaded for it
        kwargs["max_steps"] = cap
    first = MorphologyEnv(env_config, **kwargs)
    return MorphologyVectorEnv([first, *(first.sibling() for _ in range(int(num_envs) - 1))])

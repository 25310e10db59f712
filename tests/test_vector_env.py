"""The env runners' vector env: gymnasium's vector API, NEXT_STEP autoreset, shared tables, independent seeds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfigError
from smorphi_rl.vector_env import MorphologyVectorEnv, make_env, stack_observations, sub_env_generator

ROOT = Path(__file__).resolve().parents[1]


class _Ctx(dict):
    """What RLlib passes: the env_config dict with the worker index as an attribute."""

    def __init__(self, raw: dict, worker_index: int) -> None:
        super().__init__(raw)
        self.worker_index = worker_index


def _starts(run_seed: int, worker: int, envs: int = 4, episodes: int = 3) -> list[tuple[float, ...]]:
    venv = make_env(_Ctx({"max_steps": 1, "run_seed": run_seed, "num_envs": envs}, worker))
    out = []
    _, infos = venv.reset(seed=123)  # RLlib's own seed is ignored when a run seed is given
    out += [tuple(t) for t in infos["theta"]]
    for _ in range(2 * episodes - 1):  # a step truncates (max_steps 1), the next one resets
        _, _, _, _, infos = venv.step(np.ones((envs, 3), dtype=np.int64))
        out += [tuple(t) for t in infos["theta"]]
    return out


def test_vector_env_api_and_next_step_autoreset():
    venv = make_env({"max_steps": 2, "num_envs": 3, "run_seed": 0})
    assert isinstance(venv, MorphologyVectorEnv) and venv.num_envs == 3
    obs, _ = venv.reset()
    assert obs["map"].shape == (3, 2, 64, 64) and obs["map"].dtype == np.uint8
    assert venv.observation_space.contains(obs)
    actions = np.full((3, 3), 2)
    _, rewards, terminated, truncated, _ = venv.step(actions)
    assert not truncated.any()
    _, rewards, terminated, truncated, _ = venv.step(actions)
    assert truncated.all() and not terminated.any()
    _, rewards, terminated, truncated, after = venv.step(actions)  # the reset step: no reward, action ignored
    assert (rewards == 0).all() and not truncated.any()
    assert all(isinstance(t, tuple) for t in after["theta"])


def test_sub_envs_share_one_set_of_tables():
    venv = make_env({"num_envs": 3})
    first, second = (e.unwrapped for e in venv.envs[:2])
    assert first._files is second._files and first.floor is second.floor


def test_seeds_and_runners_draw_independent_streams():
    """Seed s, runner 2 must not replay seed s + 1, runner 1 (RLlib's seed + worker_index did)."""
    a = _starts(0, worker=2)
    b = _starts(1, worker=1)
    assert not set(a) & set(b)  # fixed seeds: no shared start (a chance collision would be 1 in ~10,000)
    assert a != b
    assert _starts(0, worker=2) == a  # and a run is reproducible
    g1, g2 = sub_env_generator(0, 2, 0), sub_env_generator(1, 1, 0)
    assert not np.array_equal(g1.integers(0, 2**32, 64), g2.integers(0, 2**32, 64))
    within = _starts(0, worker=1, envs=4, episodes=1)[:4]
    assert len(set(within)) == 4  # the sub-envs of one runner differ too


def test_a_resumed_run_draws_fresh_streams():
    venv = make_env({"num_envs": 2, "run_seed": 5, "max_steps": 1})
    venv.reset()
    venv.reseed(3)
    venv.step(np.ones((2, 3), dtype=np.int64))
    _, _, _, _, after = venv.step(np.ones((2, 3), dtype=np.int64))  # the autoreset draws from generation 3
    again = make_env({"num_envs": 2, "run_seed": 5, "max_steps": 1})
    again.reset()
    again.step(np.ones((2, 3), dtype=np.int64))
    _, _, _, _, replay = again.step(np.ones((2, 3), dtype=np.int64))
    assert list(after["theta"]) != list(replay["theta"])


def test_one_shared_map_is_broadcast_and_anything_else_stacked():
    """The map all sub-envs share comes as one read-only array seen num_envs times (batch stride 0), equal to the
    stack it replaces; per-env entries, and maps of different maps, are stacked copies."""
    venv = make_env({"num_envs": 4, "run_seed": 0})
    obs, _ = venv.reset()
    maps = obs["map"]
    assert maps.strides[0] == 0 and not maps.flags.writeable
    assert np.array_equal(maps, np.stack([e.unwrapped._observe()["map"] for e in venv.envs]))
    assert obs["angles"].strides[0] != 0 and obs["angles"].flags.writeable
    obs, *_ = venv.step(np.ones((4, 3), dtype=np.int64))
    assert obs["map"].strides[0] == 0
    shared = np.zeros(3, dtype=np.uint8)
    shared.setflags(write=False)
    other = shared.copy()
    other.setflags(write=False)
    writable = np.zeros(3, dtype=np.uint8)
    assert stack_observations([{"m": shared}, {"m": shared}])["m"].strides[0] == 0
    for rows in ([shared, other], [writable, writable], [shared]):  # equal but distinct, writable, alone
        stacked = stack_observations([{"m": r} for r in rows])["m"]
        assert stacked.strides[0] != 0 and stacked.flags.writeable and stacked.shape == (len(rows), 3)


def test_sub_envs_on_different_maps_get_their_own_map_rows():
    maps = [str(ROOT / "maps" / "map-1.yaml"), str(ROOT / "maps" / "map-2.yaml")]
    venv = make_env({"num_envs": 8, "run_seed": 0, "maps": maps})
    obs, _ = venv.reset()
    on_map = [e.unwrapped.grid_map.name for e in venv.envs]
    assert len(set(on_map)) == 2  # seed 0 puts the 8 sub-envs on both maps
    assert obs["map"].strides[0] != 0
    for row, env in zip(obs["map"], venv.envs, strict=True):
        assert np.array_equal(row, env.unwrapped._observe()["map"])


def test_gymnasium_make_vec_builds_ours_seeded_as_gymnasiums_own():
    """`gymnasium.make_vec(ENV_ID)` had no vector entry point: it fell back to gymnasium's SyncVectorEnv, each env with
    its own maps and caches. Ours now, sub-env i of `reset(seed=s)` as one env of `reset(seed=s + i)`."""
    import gymnasium

    import smorphi_rl

    config = {"maps": [str(ROOT / "maps" / "map-2.yaml")]}
    vec = gymnasium.make_vec(smorphi_rl.ENV_ID, num_envs=3, env_config=config)
    assert isinstance(vec, MorphologyVectorEnv) and vec.num_envs == 3
    obs, _ = vec.reset(seed=7)
    for i in range(3):
        single, _ = MorphologyEnv(config).reset(seed=7 + i)
        assert np.array_equal(obs["angles"][i], single["angles"])
    obs, rewards, *_ = vec.step(np.ones((3, 3), dtype=np.int64))
    assert rewards.shape == (3,) and obs["angles"].shape == (3, 3)
    for own, cap in ((None, 2), (2, 50), (2, None)):  # gymnasium's max_episode_steps caps the env's max_steps
        short = gymnasium.make_vec(smorphi_rl.ENV_ID, num_envs=2, env_config=config | {"max_steps": own or 200},
                                   max_episode_steps=cap)  # fmt: skip
        short.reset(seed=0)
        assert [bool(short.step(np.ones((2, 3), dtype=np.int64))[3].all()) for _ in range(2)] == [False, True]
    for bad in ({"num_envs": 0}, {"render_mode": "rgb_array"}):
        with pytest.raises(EnvConfigError):
            gymnasium.make_vec(smorphi_rl.ENV_ID, **({"num_envs": 2} | bad))


def test_a_capped_vector_env_builds_its_maps_once(monkeypatch):
    """With gymnasium's max_episode_steps under the env's own max_steps, the first env was built twice, maps and
    all (a real map's load and planner set-up, thrown away)."""
    import gymnasium

    import smorphi_rl
    from smorphi_rl import vector_env

    built: list[int] = []

    class Counted(MorphologyEnv):
        def __init__(self, *args, **kwargs):
            built.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(vector_env, "MorphologyEnv", Counted)
    vec = gymnasium.make_vec(smorphi_rl.ENV_ID, num_envs=2, env_config={"max_steps": 50}, max_episode_steps=7)
    assert len(built) == 1 and vec.envs[0].config.max_steps == 7


def test_the_info_is_laid_out_as_gymnasium_s_own_vector_envs_lay_it_out():
    """Every column was an object array, and the `_key` masks were missing: `np.exp(info["R1"])` failed, and code
    written for gymnasium's vector envs read `info["_R1"]` in vain."""
    import gymnasium

    import smorphi_rl

    ours = gymnasium.make_vec(smorphi_rl.ENV_ID, num_envs=3)
    sync = gymnasium.make_vec(smorphi_rl.ENV_ID, num_envs=3, vectorization_mode="sync")
    for vec in (ours, sync):
        vec.reset(seed=4)
    ours_info, sync_info = (vec.step(np.ones((3, 3), dtype=np.int64))[4] for vec in (ours, sync))
    assert sorted(ours_info) == sorted(sync_info) and "_R1" in ours_info
    for key, column in sync_info.items():
        assert ours_info[key].dtype == column.dtype and ours_info[key].shape == column.shape, key
        assert [repr(v) for v in ours_info[key]] == [repr(v) for v in column], key
    assert np.exp(ours_info["R1"]).dtype == np.float64

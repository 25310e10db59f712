"""The morphology MDP (docs/spec/env.md): gymnasium contract, determinism, rewards, episode end, config."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from smorphi_rl.coverage import Planner
from smorphi_rl.env import ENV_ID, MorphologyEnv, resample
from smorphi_rl.env_config import EnvConfig, EnvConfigError
from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import Cell, Map, save_map

MAPS = Path(__file__).resolve().parent.parent / "maps"
NOOP = np.array([1, 1, 1])


def test_passes_gymnasium_check_env_unmodified():
    check_env(gym.make(ENV_ID).unwrapped)  # made, for its spec: the render modes are checked too
    check_env(gym.make(ENV_ID, render_mode="rgb_array").unwrapped)


def test_registered_with_gymnasium():
    env = gym.make(ENV_ID, env_config={"max_steps": 3})
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert info["map"] == "map-1"


def test_importing_the_package_registers_the_env():
    """Only `import smorphi_rl.env` registered it: `import smorphi_rl; gymnasium.make(...)` found no namespace."""
    import subprocess
    import sys

    import smorphi_rl

    code = "import gymnasium, smorphi_rl; print(gymnasium.make(smorphi_rl.ENV_ID).reset(seed=0)[1]['map'])"
    made = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0 and made.stdout.split() == ["map-1"], made.stderr[-2000:]
    assert smorphi_rl.ENV_ID == ENV_ID


def test_a_raw_env_refuses_a_step_before_its_first_reset():
    """gymnasium.make's wrapper refused it, but the env itself (RLlib's, a script's) played an episode that had no
    start: the first map at (0, 0, 0) with a state no reset drew."""
    import copy

    from smorphi_rl.env import MorphologyEnv

    env = MorphologyEnv()
    for fresh, action in ((env, [1, 1, 1]), (copy.deepcopy(env), [1, 1, 1]), (env, [9, 9, 9])):
        with pytest.raises(gym.error.ResetNeeded, match="reset"):
            fresh.step(np.array(action))
    env.reset(seed=0)
    assert env.step(np.array([1, 1, 1]))[4]["theta"] is not None


def test_rgb_array_render_draws_the_floor_north_up_with_what_the_shape_covers():
    """gymnasium's `render_mode` was refused as an unknown env_config key, even None."""
    from smorphi_rl.env import RENDER_COLOURS, RENDER_PATH
    from smorphi_rl.maps import Cell

    env = gym.make(ENV_ID, render_mode="rgb_array")
    with pytest.raises(gym.error.ResetNeeded):
        env.render()
    env.reset(seed=0, options={"theta": (0, 180, 0)})  # the O: every free cell of map-1 but a few covered
    image = env.render()
    grid, plan = env.unwrapped.grid_map, env.unwrapped.plan((0, 180, 0))
    scale = image.shape[0] // grid.height
    assert image.shape == (grid.height * scale, grid.width * scale, 3) and image.dtype == np.uint8 and scale * 50 >= 256
    cells = image[scale // 2 :: scale, scale // 2 :: scale][::-1]  # a pixel a cell, row 0 the map's lowest y again
    occupied = np.all(cells == RENDER_COLOURS[Cell.OCCUPIED], axis=-1)
    covered = np.all(cells == RENDER_COLOURS[-1], axis=-1)
    path = np.all(cells == RENDER_PATH, axis=-1)
    assert np.array_equal(occupied | path & (grid.cells == Cell.OCCUPIED), grid.cells == Cell.OCCUPIED)
    assert np.array_equal((covered | path) & ~(grid.cells == Cell.OCCUPIED), plan.covered & (grid.cells == Cell.FREE))
    assert path.sum() > 20
    with pytest.warns(UserWarning, match="render\\(\\) without a render_mode"):
        assert MorphologyEnv().render() is None  # no render mode: gymnasium's warning, no image
    with pytest.raises(EnvConfigError, match="render_mode 'human' is not one of None, 'rgb_array'"):
        MorphologyEnv(render_mode="human")


def test_an_action_of_whole_floats_is_the_same_action():
    """`step(np.array([1., 2., 1.]))` passed the range check and failed indexing a tuple with a float."""
    ints, floats = MorphologyEnv(), MorphologyEnv()
    ints.reset(seed=4)
    floats.reset(seed=4)
    assert ints.step(np.array([2, 0, 1]))[1] == floats.step(np.array([2.0, 0.0, 1.0]))[1]
    assert ints.theta == floats.theta
    with pytest.raises(SmorphiError, match="action must be three values"):
        floats.step(np.array([1.5, 1.0, 1.0]))


def _rollout(seed: int, actions: np.ndarray, config: dict | None = None):
    env = MorphologyEnv(config)
    obs, info = env.reset(seed=seed)
    trace = [(obs, 0.0, info)]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        trace.append((obs, reward, info))
        if terminated or truncated:
            break
    return trace


def test_same_seed_same_episode():
    actions = np.random.default_rng(0).integers(0, 3, size=(60, 3))
    config = {"maps": [str(MAPS / "map-1.yaml"), str(MAPS / "map-2.yaml")]}
    a, b = _rollout(7, actions, config), _rollout(7, actions, config)
    c = _rollout(8, actions, config)
    for (oa, ra, ia), (ob, rb, ib) in zip(a, b, strict=True):
        assert ra == rb and ia == ib
        for key in oa:
            assert np.array_equal(oa[key], ob[key])
    assert a[0][2]["theta"] != c[0][2]["theta"] or a[0][2]["map"] != c[0][2]["map"]


def test_reward_is_r1_minus_beta_for_unchanged_shape():
    env = MorphologyEnv({"reward": "paper", "start_theta": [90, 90, 180], "beta": 2.5, "w1": 1.0, "w2": 0.1})
    env.reset(seed=0)
    _, moved, *_rest, info = env.step(np.array([2, 0, 1]))
    assert info["theta"] == (91.0, 89.0, 180.0)
    assert moved == pytest.approx(info["P_c"] - 0.1 * info["P_len"]) and moved == info["R1"]
    _, still, *_rest, info = env.step(NOOP)
    assert still == pytest.approx(info["R1"] - 2.5)
    _, clipped, *_rest, info = env.step(np.array([1, 1, 2]))  # t3 is already 180
    assert info["theta"] == (91.0, 89.0, 180.0) and clipped == pytest.approx(info["R1"] - 2.5)


def test_angle_step_and_lattice_start():
    env = MorphologyEnv({"angle_step_deg": 15})
    for seed in range(5):
        _, info = env.reset(seed=seed)
        assert all(t % 15 == 0 and 0 <= t <= 180 for t in info["theta"])
    before = env.theta
    _, _, _, _, info = env.step(np.array([0, 2, 1]))
    expected = (max(before[0] - 15, 0), min(before[1] + 15, 180), before[2])
    assert info["theta"] == expected


def test_a_start_halfway_between_two_lattice_angles_rounds_half_to_even():
    """0.35 / 0.1 is 3.4999999999999996 in floats: (0.35, 0.15, 179.95) started at (0.3, 0.1, 179.9), where the spec's
    half to even gives (0.4, 0.2, 180)."""
    env = MorphologyEnv({"angle_step_deg": 0.1})
    theta = env.reset(seed=0, options={"theta": (0.35, 0.15, 179.95)})[1]["theta"]
    assert np.allclose(theta, (0.4, 0.2, 180.0)) and theta[2] == 180.0
    assert MorphologyEnv({"angle_step_deg": 2}).reset(seed=0, options={"theta": (3, 5, 1)})[1]["theta"] == (4, 4, 0)


def test_truncation_and_threshold_termination():
    env = MorphologyEnv({"max_steps": 4})
    env.reset(seed=0)
    ends = [env.step(NOOP)[2:4] for _ in range(4)]
    assert ends == [(False, False)] * 3 + [(False, True)]
    env = MorphologyEnv({"start_theta": [0, 179, 0], "coverage_threshold": 99.0})
    env.reset(seed=0)
    _, _, terminated, _, info = env.step(np.array([1, 2, 1]))  # to the O-shape, P_c = 100
    assert info["P_c"] == 100.0 and terminated


def test_info_tracks_the_best_shape_of_the_episode():
    env = MorphologyEnv()
    _, info = env.reset(seed=3)
    best = info["best_R1"]
    for a in np.random.default_rng(1).integers(0, 3, size=(40, 3)):
        *_, info = env.step(a)
        assert info["best_R1"] == max(best, info["R1"])  # the best so far, never inflated
        assert info["best_R1"] == env.score(info["best_theta"]).R1  # and the shape it names scores it
        best = info["best_R1"]
    keys = {"theta", "P_c", "coverage_free_pct", "P_len", "path_length_m", "feasible", "map", "best_theta"}
    assert keys <= info.keys()


def test_observation_has_one_shape_for_every_map():
    shapes = set()
    for name in ("map-1", "val-3"):
        obs, _ = MorphologyEnv({"maps": str(MAPS / f"{name}.yaml"), "obs_size": 32}).reset(seed=0)
        shapes.add(tuple((k, v.shape) for k, v in sorted(obs.items())))
    assert len(shapes) == 1


def test_resample_keeps_fractions():
    mask = np.zeros((50, 50), bool)
    mask[:25] = True
    out = resample(mask, 64)
    assert out.shape == (64, 64) and out.mean() == pytest.approx(0.5, abs=0.02)
    big = np.random.default_rng(0).random((300, 200)) < 0.3
    assert resample(big, 64).mean() == pytest.approx(big.mean(), abs=0.02)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"colour": 1}, "unknown key 'colour'"),
        ({"angle_step_deg": 7}, "must divide 180"),
        ({"max_steps": 0}, "'max_steps' must be in 1..100,000"),
        ({"max_steps": 2.5}, "'max_steps': bad value"),
        ({"w1": "big"}, "'w1': bad value"),
        ({"start_theta": [0, 0, 200]}, "'start_theta'"),
        ({"coverage_threshold": 150}, "'coverage_threshold'"),
        ({"maps": []}, "at least one map"),
    ],
)
def test_bad_config_names_the_key(config, message):
    with pytest.raises(EnvConfigError, match=message):
        EnvConfig.from_dict(config)


def test_missing_map_file_is_a_clear_error(tmp_path):
    with pytest.raises(SmorphiError, match="map file not found"):
        MorphologyEnv({"maps": [str(tmp_path / "nope.yaml")]})


def test_bad_action():
    env = MorphologyEnv()
    env.reset(seed=0)
    for action in (np.array([3, 0, 0]), [True, 1, 1], [np.True_, 0, 0]):  # a boolean is no move's index
        with pytest.raises(SmorphiError, match="action"):
            env.step(action)


def test_a_step_of_180_over_n_reaches_180_and_no_further():
    """n times 180/n is 180.00000000000003 for 34 whole n up to 1,800: a shape at the top was refused as outside
    [0, 180], and a reset there or a random start on it failed."""
    from smorphi_rl.protocol import eval_starts

    env = MorphologyEnv({"angle_step_deg": 180 / 169})
    assert env.reset(seed=0, options={"theta": (180, 180, 180)})[1]["theta"] == (180.0, 180.0, 180.0)
    assert env.step(np.array([2, 2, 2]))[4]["theta"] == (180.0, 180.0, 180.0)
    assert eval_starts(2_000, 180 / 169).max() == 180.0


def test_map_observation_is_uint8_fractions():
    env = MorphologyEnv()
    obs, _ = env.reset(seed=0)
    assert obs["map"].dtype == np.uint8 and obs["map"].max() == 255  # fully occupied cells
    assert env.observation_space["map"].contains(obs["map"])


def test_improvement_return_telescopes_to_final_minus_start():
    env = MorphologyEnv({"reward": "improvement", "max_steps": 40})
    _, info = env.reset(seed=3)
    start = info["R1"]
    total, done = 0.0, False
    rng = np.random.default_rng(1)
    while not done:
        _, reward, terminated, truncated, info = env.step(rng.integers(0, 3, size=3))
        total += reward
        done = terminated or truncated
    assert total == pytest.approx((info["R1"] - start) / env.sigma_map)
    assert env.sigma_map > 0.5  # R1 spreads over several points on map-1


def test_commit_ends_the_episode_and_pays_the_shape():
    env = MorphologyEnv({"reward": "commit", "step_cost": 0.01, "start_theta": [90, 90, 90]})
    _, info = env.reset(seed=0)
    _, moved, terminated, _, info = env.step(np.array([2, 2, 2]))
    assert moved == pytest.approx(-0.01) and not terminated
    _, paid, terminated, truncated, after = env.step(NOOP)
    assert terminated and not truncated and after["theta"] == info["theta"] == (91.0, 91.0, 91.0)
    assert paid == pytest.approx(info["R1"] / env.sigma_map)


def test_commit_truncation_pays_the_final_shape():
    env = MorphologyEnv({"reward": "commit", "max_steps": 2, "start_theta": [10, 10, 10]})
    env.reset(seed=0)
    env.step(np.array([2, 2, 2]))
    _, paid, terminated, truncated, info = env.step(np.array([2, 2, 2]))
    assert truncated and not terminated and paid == pytest.approx(info["R1"] / env.sigma_map)


def test_commit_ended_by_the_coverage_threshold_pays_the_shape_it_reached():
    """The threshold ends the episode as a commit would: it once paid -step_cost alone, so a policy learned to
    keep away from the coverage it was asked to reach."""
    env = MorphologyEnv({"reward": "commit", "step_cost": 0.01, "coverage_threshold": 1.0, "start_theta": [9, 9, 9]})
    env.reset(seed=0)
    _, paid, terminated, truncated, info = env.step(np.array([2, 2, 2]))
    assert terminated and not truncated and paid == pytest.approx(-0.01 + info["R1"] / env.sigma_map)


def test_level_reward_is_standardised_r1_without_penalty():
    from smorphi_rl.env import r1_stats

    env = MorphologyEnv({"reward": "level", "start_theta": [90, 90, 90]})
    _, info = env.reset(seed=0)
    mu, sigma, _ = r1_stats(env.grid_map, env.config.weights_on(env.grid_map), env.config.planning)
    _, still, *_rest, info = env.step(NOOP)  # standing still costs nothing
    assert still == pytest.approx((info["R1"] - mu) / sigma)


def test_peak_reward_stretches_the_top_and_keeps_the_order():
    from smorphi_rl.env import PEAK_SHARPNESS, r1_stats

    env = MorphologyEnv({"reward": "peak", "start_theta": [90, 90, 90]})
    env.reset(seed=0)
    stats = r1_stats(env.grid_map, env.config.weights_on(env.grid_map), env.config.planning)
    _, paid, *_rest, info = env.step(NOOP)
    assert paid == pytest.approx(math.log1p(math.exp(PEAK_SHARPNESS * (info["R1"] - stats.q90) / stats.sigma)))
    low, q90, high = stats.q90 - stats.sigma, stats.q90, stats.q90 + 0.2 * stats.sigma
    assert 0 < stats.peak(low) < 1e-3 < stats.peak(q90) < stats.peak(high)  # monotone, ~0 below q90
    assert stats.peak(high) - stats.peak(q90) > 5 * 0.2  # 0.2 sigma at the top: 0.2 under `level`, over 1 here


@pytest.mark.parametrize("mode", ["level", "peak"])
def test_a_step_that_changes_the_shape_pays_the_move_cost(mode: str):
    """Standing still and a move into the box's edge pay the shape's reward; a real move pays it less move_cost."""
    costs = {}
    for cost in (0.0, 0.25):
        env = MorphologyEnv({"reward": mode, "start_theta": [90, 90, 180], "move_cost": cost})
        env.reset(seed=0)
        _, still, *_ = env.step(NOOP)
        _, edge, *_ = env.step(np.array([1, 1, 2]))  # hinge 3 pushes past 180: the shape stays
        _, moved, *_ = env.step(np.array([2, 1, 1]))
        costs[cost] = (still, edge, moved)
    assert costs[0.25][:2] == pytest.approx(costs[0.0][:2])
    assert costs[0.25][2] == pytest.approx(costs[0.0][2] - 0.25)


@pytest.mark.parametrize("key", ["move_cost", "step_cost", "beta"])
def test_a_negative_or_huge_cost_is_refused(key: str):
    for value in (-0.1, 1e7):
        with pytest.raises(EnvConfigError, match=rf"env_config '{key}' must be in \[0, 1e\+06\]"):
            MorphologyEnv({key: value})


@pytest.mark.parametrize(
    ("key", "value"), [("max_steps", math.inf), ("moves", [1e400]), ("start_theta", [10**401, 0, 0])]
)
def test_a_number_no_integer_or_float_holds_is_refused_by_name(key, value):
    """A sweep's `env: {max_steps: .inf}` raised OverflowError with a traceback (int(inf), float of 401 digits)."""
    with pytest.raises(EnvConfigError, match=f"env_config '{key}': bad value"):
        MorphologyEnv({key: value})


def test_reset_option_theta_sets_the_start():
    env = MorphologyEnv()
    _, info = env.reset(seed=0, options={"theta": (12.0, 34.0, 56.0)})
    assert info["theta"] == (12.0, 34.0, 56.0)
    with pytest.raises(EnvConfigError, match="reset option 'theta'"):
        env.reset(options={"theta": (12.0, 34.0, 200.0)})


def test_unknown_reward_mode_is_named():
    with pytest.raises(EnvConfigError, match="env_config 'reward': unknown mode 'greedy'"):
        MorphologyEnv({"reward": "greedy"})


def test_unknown_planner_is_named():
    with pytest.raises(EnvConfigError, match="env_config 'planner': unknown planner 'astar'"):
        MorphologyEnv({"planner": "astar"})


def test_fit_planner_scores_every_step_with_the_footprint_safe_plan():
    env = MorphologyEnv({"planner": "fit", "reward": "paper"})
    _, info = env.reset(seed=0, options={"theta": (0.0, 180.0, 0.0)})
    assert info["P_c"] == info["coverage_free_pct"] < 100.0  # the O-shape no longer covers the walls it stood on
    paper = MorphologyEnv({"reward": "paper"})
    _, paper_info = paper.reset(seed=0, options={"theta": (0.0, 180.0, 0.0)})
    assert paper_info["P_c"] == 100.0 and paper_info["P_len"] > info["P_len"]


def test_block_smaller_than_a_cell_is_refused_before_any_planning():
    with pytest.raises(EnvConfigError, match="smaller than one cell"):
        MorphologyEnv({"block_side_m": 0.01})


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"block_side_m": 0.06}, r"'block_side_m' must be in \[0.1, 0.5\] m with generate: floors"),
        ({"block_side_m": 3.0}, r"'block_side_m' must be in \[0.1, 0.5\] m with generate: floors"),
        ({"start_xy": [1.0, 1.0]}, "'start_xy' cannot be used with generate: floors"),
    ],
)
def test_what_a_generated_floor_must_allow_is_checked_when_the_config_is_read(config, message):
    """Seed 8 of `rooms` has 0.065 m cells: a block of 0.06 m built, then failed at a reset mid-run."""
    with pytest.raises(EnvConfigError, match=message):
        EnvConfig.from_dict({"maps": ["generate:rooms:0-10"], **config})
    built = EnvConfig.from_dict({"maps": [str(MAPS / "map-1.yaml")], **config})  # a map file is checked as it is built
    assert all(getattr(built, key) == (tuple(v) if isinstance(v, list) else v) for key, v in config.items())


@pytest.mark.parametrize("reward", ["paper", "peak"])
def test_a_floor_smaller_than_the_robot_is_refused_when_the_env_is_built(tmp_path, reward):
    """Under `paper` no shape is planned to build the env, so the refusal waited for the first reset."""
    cells = np.full((20, 20), Cell.OCCUPIED, dtype=np.uint8)
    cells[5:7, 5:7] = Cell.FREE
    path = save_map(Map(cells, 0.1, (0.0, 0.0, 0.0), "closet"), tmp_path / "closet.yaml")
    with pytest.raises(EnvConfigError, match="env_config 'maps': map closet: its 4 free cells are fewer than"):
        MorphologyEnv({"maps": [str(path)], "reward": reward})


def test_a_map_file_changed_on_disk_is_scaled_anew(tmp_path):
    """The reward scales were cached by the file's path: a map redrawn in one process kept its old sigma."""
    cells = np.full((60, 60), Cell.FREE, dtype=np.uint8)
    cells[[0, -1]] = cells[:, [0, -1]] = Cell.OCCUPIED
    path = save_map(Map(cells, 0.1, (0.0, 0.0, 0.0), "room"), tmp_path / "room.yaml")
    before = MorphologyEnv({"maps": [str(path)]}).floor.stats
    cells = cells.copy()  # a Map holds its cells read-only
    cells[20:40, 10:50] = Cell.OCCUPIED
    save_map(Map(cells, 0.1, (0.0, 0.0, 0.0), "room"), path)
    after = MorphologyEnv({"maps": [str(path)]}).floor.stats
    assert after != before and MorphologyEnv({"maps": [str(path)]}).floor.stats == after


def test_the_planner_cache_of_a_floor_is_bounded(monkeypatch):
    """A long run on a fine map visits up to 954,707 distinct footprints: the floor's planner keeps a bounded
    number, as its score memo does."""
    monkeypatch.setattr("smorphi_rl.env.SCORE_CACHE_SIZE", 4)
    env = MorphologyEnv({"start_theta": [0, 0, 0], "moves": [1, 4, 16]})
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.array([6, 6, 6]))
    evaluator = env.floor.evaluator
    assert evaluator is not None and evaluator.misses >= 8 and 0 < evaluator.cache_size() <= 4


def test_sibling_shares_tables_but_not_state():
    env = MorphologyEnv()
    twin = env.sibling()
    env.reset(seed=1)
    twin.reset(seed=2)
    assert twin._files is env._files and twin._generated is env._generated  # floors, their planners and scores
    assert twin.np_random is not env.np_random and twin.theta != env.theta


def test_start_xy_moves_every_plan_and_must_be_free():
    default = MorphologyEnv({"planner": "fit", "reward": "paper"})
    moved = MorphologyEnv({"planner": "fit", "reward": "paper", "start_xy": [4.65, 4.65]})
    theta = {"theta": (0.0, 180.0, 0.0)}
    assert moved.reset(seed=0, options=theta)[1]["P_len"] != default.reset(seed=0, options=theta)[1]["P_len"]
    with pytest.raises(EnvConfigError, match=r"env_config 'start_xy'.*(occupied|outside)"):
        MorphologyEnv({"start_xy": [-3.0, 0.2]})
    with pytest.raises(EnvConfigError, match="env_config 'start_xy': bad value"):
        MorphologyEnv({"start_xy": [1.0]})


def test_the_paper_planning_keeps_its_cache_key():
    """Optima cached before the planner became a choice stay valid: the default key is the block side alone."""
    from smorphi_rl.planning import Planning

    assert Planning().key() == [0.17] and Planning(planner=Planner.FIT).key() != [0.17]


def test_the_map_view_covers_the_known_cells_not_the_frame(tmp_path):
    """A recorded map is mostly unknown space: the observation resamples the known cells' box only."""
    from conftest import ROOM12

    from smorphi_rl.maps import Map, save_map

    room = Map.from_text(ROOM12, 0.1, name="room")
    framed = np.full((60, 60), 2, dtype=np.uint8)  # the room inside a wide unknown frame
    framed[20:32, 30:42] = room.cells
    paths = [
        save_map(Map(c, 0.1, name=n), tmp_path / f"{n}.yaml") for c, n in ((room.cells, "room"), (framed, "framed"))
    ]
    views = [MorphologyEnv({"maps": [str(p)], "obs_size": 12}).reset(seed=0)[0]["map"] for p in paths]
    assert np.array_equal(views[0], views[1]) and views[1][1].max() == 0  # no unknown left in view


FLOOR_CONFIG = {"maps": ["generate:mixed"], "observation": "floor", "moves": [1, 4, 16], "path_term": "per_area",
                "max_steps": 8}  # fmt: skip


def test_generated_floors_are_drawn_per_episode_and_repeat_with_the_seed():
    a, b = MorphologyEnv(FLOOR_CONFIG), MorphologyEnv(FLOOR_CONFIG)
    names = [a.reset(seed=s)[1]["map"] for s in range(6)]
    assert names == [b.reset(seed=s)[1]["map"] for s in range(6)] and len(set(names)) == 6
    assert all(int(n.split("-")[1]) < 900_000 for n in names)  # training seeds only


def test_the_floor_layout_passes_the_checker_and_carries_the_scale():
    from gymnasium.utils.env_checker import check_env

    env = MorphologyEnv(FLOOR_CONFIG)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"map", "angles", "metrics", "scale"} and obs["scale"].shape == (9,)
    assert env.observation_space.contains(obs)
    grid_map = env.grid_map
    assert obs["scale"][0] == pytest.approx(0.17 / grid_map.resolution_m / 4, rel=1e-6)
    assert obs["metrics"][3] == pytest.approx(min(max(info["R1"] / 100, 0), 1), abs=1e-6)


def test_the_floor_picture_keeps_the_floors_aspect(tmp_path):
    from smorphi_rl.env import map_picture
    from smorphi_rl.maps import Map

    wide = Map(np.zeros((10, 40), dtype=np.uint8), 0.1)
    picture = map_picture(wide, 8, square=True)
    assert picture[1, :2].min() == 255 and picture[1, 3:5].max() == 0  # unknown above and below the floor
    assert map_picture(wide, 8, square=False)[1].max() == 0  # the picture layout stretches it


def test_move_sizes_give_seven_moves_per_hinge():
    env = MorphologyEnv({"moves": [1, 4, 16], "reward": "paper"})
    assert list(env.action_space.nvec) == [7, 7, 7]
    env.reset(seed=0, options={"theta": (90.0, 90.0, 90.0)})
    _, _, _, _, info = env.step(np.array([0, 3, 6]))  # -16, stay, +16
    assert info["theta"] == (74.0, 90.0, 106.0)
    _, _, _, _, info = env.step(np.array([2, 4, 5]))  # -1, +1, +4
    assert info["theta"] == (73.0, 91.0, 110.0)
    with pytest.raises(EnvConfigError, match="increasing step sizes"):
        MorphologyEnv({"moves": [4, 1]})


def test_the_default_layout_is_the_papers():
    env = MorphologyEnv()
    assert set(env.observation_space.spaces) == {"map", "angles", "metrics"} and list(env.action_space.nvec) == [3] * 3


def test_numpy_values_in_env_config_are_read_as_pythons():
    """`w1=np.int64(1)` or `moves=np.array([1, 4])` were refused as bad values while `max_steps=np.int32(50)`
    passed: a value a user's code or a sampler computed is numpy's as often as not."""
    built = EnvConfig.from_dict({"w1": np.int64(2), "w2": np.float64(0.25), "moves": np.array([1, 4]),
                                 "planner": np.str_("fit"), "start_theta": np.array([10, 20, 30])})  # fmt: skip
    assert (built.w1, built.w2, built.moves, built.planner, built.start_theta) == (2.0, 0.25, (1, 4), "fit",
                                                                                   (10.0, 20.0, 30.0))  # fmt: skip
    assert type(built.w1) is float and all(type(m) is int for m in built.moves)
    inside = EnvConfig.from_dict({"moves": list(np.array([1, 4])), "start_xy": (np.float32(1.5), np.int64(2))})
    assert inside.moves == (1, 4) and inside.start_xy == (1.5, 2.0)  # numpy's values in a list too
    deep: list = [1.0]
    for _ in range(5000):  # a crafted policy.json's list: one line, not a RecursionError
        deep = [deep]
    with pytest.raises(EnvConfigError, match="env_config 'start_theta': bad value"):
        EnvConfig.from_dict({"start_theta": deep})
    with pytest.raises(EnvConfigError, match=r"env_config 'w1': bad value \[1, 2\]"):
        EnvConfig.from_dict({"w1": np.array([1, 2])})


def test_the_planning_keys_are_the_planning_fields():
    """A replay plans from a recording's PLANNING_KEYS alone: a field Planning gains must be one of them."""
    from dataclasses import fields

    from smorphi_rl.env_config import PLANNING_KEYS
    from smorphi_rl.planning import Planning

    assert tuple(f.name for f in fields(Planning)) == PLANNING_KEYS


def test_an_env_config_that_is_not_a_dict_is_named():
    """`MorphologyEnv("maps/map-1.yaml")` failed with "'str' object is not a mapping"."""
    with pytest.raises(EnvConfigError, match=r"env_config must be a dict .* not a str \(a map: \{'maps': \[path\]\}\)"):
        MorphologyEnv("maps/map-1.yaml")

"""The evaluation protocol: fixed starts, the settled shape, gaps to the exact optimum, the optimum's cache."""

from __future__ import annotations

import io
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.protocol import (
    MapEvaluation,
    Optimum,
    Outcome,
    eval_starts,
    exact_optimum,
    gaps_to,
    key_of,
    settled_theta,
)
from smorphi_rl.score import Weights

ROOT = Path(__file__).resolve().parents[1]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def test_starts_are_fixed_on_the_lattice_and_their_own_stream():
    a, b = eval_starts(20), eval_starts(20)
    assert np.array_equal(a, b) and a.shape == (20, 3)
    assert ((a >= 0) & (a <= 180) & (a == np.round(a))).all()
    assert len({tuple(r) for r in a}) == 20
    coarse = eval_starts(5, step_deg=10)
    assert (coarse % 10 == 0).all()
    with pytest.raises(ValueError, match="positive integer"):
        eval_starts(0)


def test_the_selection_starts_are_never_the_protocols_own():
    """Drawn from an independent seed, 3 of 20 selection starts were protocol starts at a 45-degree step: the policy
    was partly chosen on the starts it is reported on. At 1 degree nothing collides and nothing moved."""
    from smorphi_rl.protocol import SELECT_SEED, selection_starts

    for step in (45.0, 30.0, 90.0):
        protocol = eval_starts(20, step)
        chosen = selection_starts(20, step, protocol)
        assert chosen.shape == (20, 3) and not {tuple(t) for t in chosen} & {tuple(t) for t in protocol}
    assert np.array_equal(selection_starts(20, 1.0, eval_starts(20)), eval_starts(20, 1.0, SELECT_SEED))
    few = selection_starts(5, 180.0, eval_starts(40, 180.0))  # 8 shapes, all 8 taken: none to spare
    assert few.shape == (5, 3)


def test_settled_is_the_most_held_shape_of_the_last_steps():
    a, b, c = (1.0, 1.0, 1.0), (2.0, 2.0, 2.0), (3.0, 3.0, 3.0)
    assert settled_theta([c] * 50 + [a] * 12 + [b] * 8) == a
    assert settled_theta([a, b] * 10) == b  # a tie: the latest
    assert settled_theta([c]) == c


def test_map_summary_counts_gaps_and_the_1_percent_band():
    opt = Optimum((1.0, 2.0, 3.0), 90.0, 97.0, 70)
    outcomes = tuple(Outcome((0.0, 0.0, 0.0), (1.0, 2.0, 3.0), r1, 95.0, 80, 10) for r1 in (90.0, 89.2, 80.0, 89.0))
    ev = MapEvaluation("map-1", "test", opt, outcomes)
    assert ev.within == 2  # 90.0 and 89.2 are within 0.9 of 90; 89.0 is not
    assert ev.median_gap == pytest.approx(np.median([0.0, 0.8, 10.0, 1.0]))
    assert ev.summary()["share_within_1pct"] == 0.5
    assert json.loads(json.dumps(ev.to_dict()))["starts"] == 4


def test_a_start_in_metres_keys_the_cache_on_the_cell_it_lands_on():
    """A map saved again with another origin keeps its cells, yet `--start-xy` then lands on another cell and the
    plans score differently: the two must not share a cached optimum. The same cell through another origin plans
    alike and shares it; without a start point the origin is moot."""
    from dataclasses import replace

    from smorphi_rl.maps import load_map
    from smorphi_rl.planning import Planning

    grid_map = load_map(MAP_1)
    moved = replace(grid_map, origin=(-1.0, -1.0, 0.0))
    weights, start = Weights(1.0, 0.1), Planning(0.17, start_xy=(0.05, 2.15))
    assert start.start_on(grid_map) != start.start_on(moved)
    assert key_of(grid_map, weights, start) != key_of(moved, weights, start)
    nudged = replace(grid_map, origin=(0.01, 0.01, 0.0))  # (0.05, 2.15) stays in cell (21, 0)
    assert start.start_on(grid_map) == start.start_on(nudged)
    assert key_of(grid_map, weights, start) == key_of(nudged, weights, start)
    assert key_of(grid_map, weights, Planning(0.17)) == key_of(moved, weights, Planning(0.17))
    assert key_of(grid_map, weights, Planning(0.17)) == key_of(MAP_1, weights, Planning(0.17))


@pytest.mark.slow
def test_exact_optimum_is_the_best_of_the_lattice_and_is_cached(tmp_path, monkeypatch):
    from smorphi_rl.maps import load_map
    from smorphi_rl.planning import Evaluator, Planning, lattice_thetas

    opt = exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path)
    thetas = lattice_thetas(10.0)
    batch = Evaluator(load_map(MAP_1)).evaluate_many(thetas)
    coarse = Optimum.of(thetas, batch.P_c, batch.P_len, Weights(1.0, 0.1), 10.0)
    assert opt.R1 >= coarse.R1 and opt.step_deg == 1.0 and math.isfinite(opt.R1)
    (cached,) = tmp_path.glob("optimum-*.json")
    assert key_of(MAP_1, Weights(1.0, 0.1), Planning(0.17)) in cached.name
    assert exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path) == opt
    cached.write_text("{broken")  # a damaged entry is recomputed
    assert exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path) == opt
    planned = Evaluator(load_map(MAP_1), 0.17).evaluate_many(np.array([[1.0, 2.0, 3.0]]))
    p_c, p_len = float(planned.P_c[0]), int(planned.P_len[0])
    entry = {"theta": [1, 2, 3], "R1": p_c - 0.1 * p_len, "P_c": p_c, "P_len": p_len}
    cached.write_text(json.dumps(entry))  # an entry that could be the optimum is what the cache is for: read
    from smorphi_rl import protocol

    with monkeypatch.context() as read_only:  # read, not computed again
        read_only.setattr(protocol, "_optimum_in_process", lambda *a, **k: pytest.fail("computed again"))
        assert entry["R1"] == exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path).R1
    unplanned = {"R1": 100.0 - 0.1 * 5, "P_c": 100.0, "P_len": 5}  # agrees with itself, not with the map
    for doctored in ({"R1": 1e308}, {"theta": [1]}, {"R1": math.nan}, {"P_len": 10**400}, {"P_c": 101.0}, unplanned):
        cached.write_text(json.dumps(entry | doctored))  # once printed as the optimum, or a traceback
        assert exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path) == opt, doctored


def test_a_cache_folder_that_cannot_be_made_names_the_option(tmp_path, monkeypatch):
    """`design --exact` in a read-only working folder said only "Permission denied: .../logs"."""
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.planning import Planning
    from smorphi_rl.protocol import CACHE_ENV

    (tmp_path / "logs").write_text("a file where the folder would go")
    monkeypatch.delenv(CACHE_ENV, raising=False)
    with pytest.raises(SmorphiError, match=r"cannot cache exact optima in .*: give --log-dir a folder"):
        exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path / "logs" / ".cache")
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "logs" / ".cache"))  # the cache the variable names: it is named
    with pytest.raises(SmorphiError, match=f"set {CACHE_ENV} to a folder"):
        exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), tmp_path / "logs" / ".cache")


@pytest.mark.skipif(not Path("/sys/kernel").is_dir(), reason="a folder no one may write into, root included")
def test_a_cache_folder_that_cannot_be_written_into_names_the_option(monkeypatch):
    """An existing folder that took no file (SMORPHI_RL_CACHE_DIR shared read-only) passed, and every run searched
    the optimum again without saying so."""
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.planning import Planning
    from smorphi_rl.protocol import CACHE_ENV

    monkeypatch.setenv(CACHE_ENV, "/sys/kernel")
    with pytest.raises(SmorphiError, match=f"cannot cache exact optima in /sys/kernel .*: set {CACHE_ENV} to a folder"):
        exact_optimum(MAP_1, Weights(1.0, 0.1), Planning(0.17), Path("/sys/kernel"))


def test_train_reads_the_optimum_search_optimum_found_and_shows_its_own_search(tmp_path, monkeypatch):
    """`train` searched again, silently (five minutes on depot), an optimum `search optimum` had just found."""
    from conftest import ROOM12

    from smorphi_rl import protocol
    from smorphi_rl.cli import main
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import Map, save_map
    from smorphi_rl.search import exhaustive
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.run import training_optima

    monkeypatch.delenv(protocol.CACHE_ENV, raising=False)
    monkeypatch.setattr(protocol, "_IN_PROCESS", {})  # whatever ran before in this process: searched here
    room = save_map(Map.from_text(ROOM12, 0.1, name="room"), tmp_path / "room.yaml")
    cfg = TrainConfig(env=EnvConfig.from_dict({"maps": [str(room)]}))
    out = io.StringIO()
    fresh = training_optima(cfg, tmp_path / "first", out)["room"]
    passes = [line.split(" [")[0] for line in out.getvalue().splitlines()[1:]]  # on train's own stream
    assert passes[0] == "exact optimum of room: shapes keyed by footprint"
    assert passes[-1] == "exact optimum of room: shapes settled"

    assert main(["search", "optimum", "--map", str(room), "--log-dir", str(tmp_path / "logs")]) == 0
    monkeypatch.setattr(exhaustive, "run_exhaustive", lambda *a, **k: pytest.fail("searched again"))
    monkeypatch.setattr(protocol, "_IN_PROCESS", {})
    assert training_optima(cfg, tmp_path / "logs", io.StringIO())["room"] == fresh


def test_train_reads_a_cached_optimum_of_a_map_too_large_to_search(tmp_path, monkeypatch):
    """Over OPTIMUM_MAX_CELLS train searches no optimum: the one a `search optimum` run cached is what it has."""
    from smorphi_rl import protocol
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import Map, load_map, save_map
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.run import training_optima

    monkeypatch.delenv(protocol.CACHE_ENV, raising=False)
    side = int(protocol.OPTIMUM_MAX_CELLS**0.5) + 1
    hall = save_map(Map(np.zeros((side, side), dtype=np.uint8), 0.1, name="hall"), tmp_path / "hall.yaml")
    cfg = TrainConfig(env=EnvConfig.from_dict({"maps": [str(hall)]}))
    out = io.StringIO()
    assert math.isnan(training_optima(cfg, tmp_path / "logs", out)["hall"].R1)
    assert "not computed" in out.getvalue()
    assert f"`smorphi-rl search optimum --map {hall} --log-dir {tmp_path / 'logs'}`" in out.getvalue()  # runnable
    swamped = "warning: on hall the path term swamps coverage (a broad shape's R1 "  # said without the optimum too
    assert swamped in out.getvalue()
    per_area = replace(cfg, env=replace(cfg.env, path_term="per_area"))
    out = io.StringIO()
    training_optima(per_area, tmp_path / "logs", out)
    assert "not computed" in out.getvalue() and "swamps" not in out.getvalue()
    room = np.full((side, side), 2, dtype=np.uint8)  # a 10 m room in a SLAM frame of unknown: no swamping there
    room[:100, :100] = np.tile(load_map(Path(__file__).parents[1] / "maps" / "map-1.yaml").cells, (2, 2))
    framed = save_map(Map(room, 0.1, name="framed"), tmp_path / "framed.yaml")
    out = io.StringIO()
    training_optima(TrainConfig(env=EnvConfig.from_dict({"maps": [str(framed)]})), tmp_path / "logs", out)
    assert "not computed" in out.getvalue() and "swamps" not in out.getvalue()  # the O alone read as swamped
    grid_map = load_map(hall)
    weights = cfg.env.weights_on(grid_map)
    planned = cfg.env.planning.evaluator(grid_map).evaluate_many(np.array([[10.0, 20.0, 30.0]]))
    p_c, p_len = float(planned.P_c[0]), int(planned.P_len[0])  # the path term far over coverage's on this hall
    found = Optimum((10.0, 20.0, 30.0), float(weights.r1(p_c, p_len)), p_c, p_len)
    protocol.remember_optimum(grid_map, weights, cfg.env.planning, tmp_path / "logs" / ".cache", found)
    out = io.StringIO()
    assert training_optima(cfg, tmp_path / "logs", out)["hall"] == found
    assert "read from" in out.getvalue() and "warning: on hall the path term swamps coverage" in out.getvalue()
    doctored = Optimum((10.0, 20.0, 30.0), float(weights.r1(99.0, 10)), 99.0, 10)  # no shape plans so short a path
    protocol.remember_optimum(grid_map, weights, cfg.env.planning, tmp_path / "logs" / ".cache", doctored)
    assert math.isnan(training_optima(cfg, tmp_path / "logs", io.StringIO())["hall"].R1)  # refused, as none


def test_train_warns_when_its_plans_start_in_a_room_holding_under_half_the_floor(tmp_path, monkeypatch):
    """Separate rooms: every shape covers the start's room alone, and train said nothing of it."""
    from smorphi_rl import protocol
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import Map, save_map
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.run import training_optima

    monkeypatch.delenv(protocol.CACHE_ENV, raising=False)
    side = int(protocol.OPTIMUM_MAX_CELLS**0.5) + 1  # no optimum searched: the warning comes first regardless
    cells = np.ones((side, side), dtype=np.uint8)
    cells[:150, :150] = 0  # the start's room (the first free cell in row order)
    cells[250:, 250:] = 0  # the larger room, beyond a 10 m wall
    rooms = save_map(Map(cells, 0.1, name="rooms"), tmp_path / "rooms.yaml")
    out = io.StringIO()
    training_optima(TrainConfig(env=EnvConfig.from_dict({"maps": [str(rooms)]})), tmp_path / "logs", out)
    assert "warning: on rooms plans start in a free area holding 26.3 % of the free cells" in out.getvalue()


def test_a_shape_that_ties_the_optimum_has_a_gap_of_zero_not_minus_zero():
    """`compare` printed a run that tied the optimum at a gap of -0.00 (R1 summed in another order)."""
    r1 = 0.1 + 0.2  # 0.30000000000000004
    gaps = gaps_to(0.3, [r1, 0.25])
    assert f"{gaps[0]:.2f}" == "0.00" and gaps[1] == pytest.approx(0.05)
    assert f"{0.3 - r1:.2f}" == "-0.00"  # what it printed


@pytest.mark.slow
def test_the_exact_optimum_and_the_searches_take_a_map_in_memory(tmp_path):
    """They took map files only: a script's Map (cropped, edited, generated) had to be saved first."""
    from smorphi_rl.maps import Cell, Map, load_map, save_map
    from smorphi_rl.planning import Evaluator, Planning, lattice_thetas
    from smorphi_rl.search.nsga2 import run_nsga2
    from smorphi_rl.search.random import run_random

    cells = load_map(MAP_1).cells.copy()
    cells[20:30, 20:23] = Cell.OCCUPIED  # a floor no file holds
    grid = Map(cells, 0.1, name="edited")
    opt = exact_optimum(grid, Weights(1.0, 0.1), Planning())
    path = save_map(grid, tmp_path / "edited.yaml")
    assert key_of(grid, Weights(1.0, 0.1), Planning()) == key_of(path, Weights(1.0, 0.1), Planning())
    thetas = lattice_thetas(10.0)
    coarse = Evaluator(grid).evaluate_many(thetas)
    assert opt.R1 >= Optimum.of(thetas, coarse.P_c, coarse.P_len, Weights(1.0, 0.1), 10.0).R1
    planned = Evaluator(load_map(path)).evaluate_many(np.array([opt.theta]))  # the edited floor's, not map-1's
    assert (float(planned.P_c[0]), int(planned.P_len[0])) == (opt.P_c, opt.P_len)
    for run in (lambda m: run_random(m, samples=40, seed=3), lambda m: run_nsga2(m, pop=8, generations=2, seed=3)):
        a, b = run(grid), run(path)
        assert np.array_equal(a.thetas, b.thetas) and np.array_equal(a.P_c, b.P_c)

"""FBCPP planner (docs/spec/fbcpp.md sections 4-8): golden cases, invariants, fast path == plain reference."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GOLDEN_THETAS, random_map
from hypothesis import given
from hypothesis import strategies as st

from smorphi_rl import _kernels as k
from smorphi_rl.coverage import Footprint, PreparedMap, Start, path_points_m, plan_coverage
from smorphi_rl.coverage_reference import evaluate_reference, plan_reference
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import Morphology
from smorphi_rl.maps import Cell
from smorphi_rl.planning import Evaluator

GOLDEN = {
    ("room12", (0, 0, 0)): (100.0, 11, 100.0, 32),
    ("room12", (0, 180, 0)): (100.0, 15, 100.0, 45),
    ("room12", (90, 90, 90)): (75.6944, 3, 73.4848, 21),
    ("room12", (95, 59, 103)): (80.5556, 5, 78.7879, 24),
    ("room12", (15, 15, 39)): (84.0278, 7, 82.5758, 31),
    ("corridor", (0, 0, 0)): (100.0, 7, 100.0, 24),
    ("corridor", (0, 180, 0)): (100.0, 14, 100.0, 42),
    ("corridor", (90, 90, 90)): (87.5, 1, 66.6667, 7),
    ("corridor", (95, 59, 103)): (94.6429, 3, 85.7143, 12),
    ("corridor", (15, 15, 39)): (94.6429, 5, 85.7143, 25),
}
ROOM12_O_PATH = [
    (0, 0), (0, 1), (0, 2), (0, 3), (1, 3), (2, 3), (3, 3), (3, 2),
    (3, 1), (3, 0), (2, 0), (2, 1), (2, 2), (1, 2), (1, 1), (1, 0),
]  # fmt: skip


@pytest.mark.parametrize(("map_name", "theta"), GOLDEN)
def test_golden_metrics_fast_path(request, map_name, theta):
    grid_map = request.getfixturevalue(map_name)
    p_c, p_len, cov_free, path_cells = GOLDEN[(map_name, theta)]
    ev = Evaluator(grid_map)
    for result in (ev.evaluate(Morphology.of(theta)), ev.plan(Morphology.of(theta))):
        assert round(result.P_c, 4) == p_c
        assert round(result.coverage_free_pct, 4) == cov_free
        assert result.P_len == p_len
        assert result.path_length_cells == path_cells
        assert result.path_length_m == pytest.approx(path_cells * 0.1)
        assert result.feasible


@pytest.mark.parametrize(("map_name", "theta"), GOLDEN)
def test_golden_metrics_reference(request, map_name, theta):
    grid_map = request.getfixturevalue(map_name)
    p_c, p_len, cov_free, path_cells = GOLDEN[(map_name, theta)]
    ref = evaluate_reference(grid_map, theta)
    assert (round(ref["P_c"], 4), ref["P_len"], round(ref["coverage_free_pct"], 4)) == (p_c, p_len, cov_free)
    assert ref["path_length_cells"] == path_cells


def test_golden_path_room12_o_shape(room12):
    result = Evaluator(room12).plan(Morphology.of((0, 180, 0)))
    assert [tuple(t) for t in result.path_tiles.tolist()] == ROOM12_O_PATH
    assert evaluate_reference(room12, (0, 180, 0))["path"] == ROOM12_O_PATH
    pts = path_points_m(result, room12)
    assert pts[0].tolist() == pytest.approx([0.15, 0.15])  # centre of the 3x3-cell tile (0, 0)


def _check_plan_invariants(grid_map, f: np.ndarray) -> None:
    prepared = PreparedMap(grid_map, pad_cells=2 * max(f.shape))
    footprint = Footprint(f, f.shape[1] * 0.1, f.shape[0] * 0.1, True)
    result = plan_coverage(prepared, footprint, (0.0, 0.0, 0.0))
    l, w = f.shape
    cells = grid_map.cells
    tiles = result.path_tiles
    assert result.P_len == len(tiles) - 1
    for a, b in tiles:  # every path tile traversable
        assert (cells[a * l : a * l + l, b * w : b * w + w] == Cell.FREE).any()
    steps = np.abs(np.diff(tiles, axis=0)).sum(axis=1)
    assert (steps == 1).all()  # consecutive tiles 4-adjacent
    assert 0.0 <= result.coverage_free_pct <= 100.0 and 0.0 <= result.P_c <= 100.0
    assert not (result.covered & (cells != Cell.FREE)).any()  # only free cells count as covered
    ref = plan_reference(cells.tolist(), f.tolist())
    assert [tuple(t) for t in tiles.tolist()] == ref.path
    assert int(result.covered.sum()) == ref.n_covered


@given(
    st.integers(0, 2**32 - 1),
    st.integers(3, 30),
    st.integers(3, 30),
    st.floats(0.0, 0.6),
    st.floats(0.0, 0.2),
    st.integers(1, 5),
    st.integers(1, 5),
)
def test_random_maps_and_footprints_match_reference(seed, h, w, p_occ, p_unk, fl, fw):
    rng = np.random.default_rng(seed)
    grid_map = random_map(rng, h, w, p_occ, p_unk)
    f = rng.random((fl, fw)) < 0.6
    f[0, rng.integers(fw)] = f[-1, rng.integers(fw)] = True  # keep F trimmed in rows
    f[rng.integers(fl), 0] = f[rng.integers(fl), -1] = True  # and in columns
    _check_plan_invariants(grid_map, f)


@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.integers(1, 4))
def test_full_footprint_covers_every_reachable_free_cell(seed, fl, fw):
    rng = np.random.default_rng(seed)
    grid_map = random_map(rng, 20, 24, 0.35, 0.1)
    f = np.ones((fl, fw), dtype=bool)
    result = plan_coverage(PreparedMap(grid_map, 8), Footprint(f, fw * 0.1, fl * 0.1, True), (0.0, 0.0, 0.0))
    l, w = f.shape
    reached = np.zeros_like(result.covered)
    for a, b in {tuple(t) for t in result.path_tiles.tolist()}:
        reached[a * l : a * l + l, b * w : b * w + w] = True
    expected = reached & (grid_map.cells == Cell.FREE)
    assert np.array_equal(result.covered, expected)


def _free_component(cells: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    seen = np.zeros(cells.shape, bool)
    stack = [start]
    while stack:
        r, c = stack.pop()
        if 0 <= r < cells.shape[0] and 0 <= c < cells.shape[1] and not seen[r, c] and cells[r, c] == Cell.FREE:
            seen[r, c] = True
            stack += [(r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)]
    return seen


@pytest.mark.parametrize("start", [(0, 6), (2, 1), (4, 3)])
def test_single_cell_footprint_covers_exactly_the_component_of_the_start(corridor, start):
    f = np.ones((1, 1), dtype=bool)
    fp = Footprint(f, 0.1, 0.1, True)
    result = plan_coverage(PreparedMap(corridor, 2), fp, (0.0, 0.0, 0.0), Start.tile(*start))
    assert np.array_equal(result.covered, _free_component(corridor.cells, start))


@given(
    st.integers(0, 2**32 - 1),
    st.lists(st.tuples(*[st.integers(0, 180)] * 3), min_size=1, max_size=4),
)
def test_fast_path_equals_reference_on_random_maps_and_morphologies(seed, thetas):
    rng = np.random.default_rng(seed)
    grid_map = random_map(rng, int(rng.integers(8, 40)), int(rng.integers(8, 40)), float(rng.uniform(0, 0.5)), 0.05)
    ev = Evaluator(grid_map, cache=False)
    batch = ev.evaluate_many(np.array(thetas, dtype=float))
    for theta, got in zip(thetas, batch, strict=True):
        ref = evaluate_reference(grid_map, theta)
        assert got.feasible == ref["feasible"]
        assert got.P_len == ref["P_len"]
        assert got.P_c == ref["P_c"] and got.coverage_free_pct == ref["coverage_free_pct"]
        assert got.path_length_cells == ref["path_length_cells"]
        assert got.footprint_cells == ref["footprint_cells"] and got.footprint_m == ref["footprint_m"]


def test_start_tile_and_point(room12):
    m = Morphology.of((0, 180, 0))  # 3x3 tiles
    from_tile = Evaluator(room12, start=Start.tile(2, 1)).plan(m)
    assert tuple(from_tile.path_tiles[0]) == (2, 1)
    ref = plan_reference(room12.cells.tolist(), np.ones((3, 3), bool).tolist(), (2, 1))
    assert [tuple(t) for t in from_tile.path_tiles.tolist()] == ref.path
    from_point = Evaluator(room12, start=Start.point(room12, 0.75, 0.45)).plan(m)  # cell (4, 7) -> tile (1, 2)
    assert tuple(from_point.path_tiles[0]) == (1, 2)


def test_bad_starts(room12):
    m = Morphology.of((0, 180, 0))
    with pytest.raises(SmorphiError, match="outside"):
        Evaluator(room12, start=Start.tile(9, 0)).evaluate(m)
    with pytest.raises(SmorphiError, match="occupied cell"):
        Start.point(room12, 0.25, 0.25)  # cell (2, 2) is '#'
    with pytest.raises(SmorphiError, match="outside the map"):
        Start.point(room12, 5.0, 0.0)
    blocked = room12.cells.copy()
    blocked[:3, :3] = Cell.OCCUPIED
    from smorphi_rl.maps import Map

    with pytest.raises(SmorphiError, match="not traversable"):
        Evaluator(Map(blocked, 0.1), start=Start.tile(0, 0)).evaluate(m)


def test_infeasible_footprint_plans_nothing(room12):
    f = np.ones((2, 2), bool)
    result = plan_coverage(PreparedMap(room12, 4), Footprint(f, 0.2, 0.2, False), (1.0, 2.0, 3.0))
    assert (result.feasible, result.P_c, result.P_len, result.path_length_m) == (False, 0.0, 0, 0.0)


def test_kernel_refuses_a_too_small_pad(room12):
    f = np.ones((3, 3), np.uint8)
    prepared = PreparedMap(room12, pad_cells=2)
    res = k.plan_into(
        prepared.padded, prepared.free_prefix, f, 0, 0, 0, np.zeros((0, 0), np.uint8), np.zeros((0, 2), np.int32)
    )
    assert res[0] == k.STATUS_PAD_TOO_SMALL


@pytest.mark.parametrize("theta", GOLDEN_THETAS)
def test_unknown_cells_are_not_counted(theta):
    base = np.zeros((10, 10), np.uint8)
    base[4:6, :] = Cell.UNKNOWN
    from smorphi_rl.maps import Map

    grid_map = Map(base, 0.1)
    got = Evaluator(grid_map).evaluate(Morphology.of(theta))
    ref = evaluate_reference(grid_map, theta)
    assert got.P_c == ref["P_c"] and got.coverage_free_pct == ref["coverage_free_pct"]
    assert got.coverage_free_pct <= 100.0
    covered = Evaluator(grid_map).plan(Morphology.of(theta)).covered  # the mask, unknown rows never in it
    assert covered is not None and not covered[4:6].any()
    assert got.P_c == pytest.approx(100 * covered.sum() / 80)  # over the 80 known cells, not the 100 of the frame

"""The footprint-safe planner (docs/fbcpp-fit.md): golden cases, the compiled kernel against the plain-Python
reference, and what it promises on a real floor (the robot never over an occupied, unknown or outside cell)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import GOLDEN_THETAS, random_map, realmap

from smorphi_rl.coverage import Planner, Start, sweep_positions
from smorphi_rl.coverage_reference import plan_fit_reference
from smorphi_rl.geometry import Morphology, footprint_matrix
from smorphi_rl.maps import Cell, Map, load_map
from smorphi_rl.planning import Evaluator

# docs/fbcpp-fit.md section 8: (map, theta, start cell or None) -> P_c, coverable %, P_len, path cells, start
GOLDEN_FIT = {
    ("room12", (0, 0, 0), None): (21.2121, 38.6364, 1, 2, (0, 3)),
    ("room12", (0, 0, 0), (4, 9)): (21.2121, 38.6364, 1, 2, (3, 3)),
    ("room12", (0, 180, 0), None): (40.9091, 61.3636, 7, 21, (1, 3)),
    ("room12", (0, 180, 0), (4, 9)): (40.9091, 61.3636, 5, 15, (2, 9)),
    ("room12", (90, 90, 90), None): (9.0909, 46.2121, 0, 0, (0, 1)),
    ("room12", (90, 90, 90), (4, 9)): (0.0, 0.0, 0, 0, None),
    ("room12", (95, 59, 103), None): (7.5758, 36.3636, 0, 0, (0, 1)),
    ("room12", (15, 15, 39), (4, 9)): (7.5758, 32.5758, 0, 0, (3, 2)),
    ("walled", (0, 0, 0), None): (36.8421, 36.8421, 2, 9, (6, 1)),
    ("walled", (0, 0, 0), (4, 9)): (0.0, 0.0, 0, 0, None),
    ("walled", (0, 180, 0), None): (47.3684, 50.8772, 5, 15, (1, 9)),
    ("walled", (0, 180, 0), (4, 9)): (47.3684, 50.8772, 6, 18, (4, 9)),
    ("walled", (90, 90, 90), None): (10.5263, 28.9474, 0, 0, (1, 7)),
    ("walled", (95, 59, 103), None): (8.7719, 36.8421, 0, 0, (1, 8)),
    ("walled", (15, 15, 39), None): (8.7719, 22.8070, 0, 0, (4, 7)),
}
WALLED_O_PLACEMENTS = [(1, 9), (1, 12), (4, 12), (7, 12), (7, 9), (4, 9)]


def _start(grid_map: Map, cell: tuple[int, int] | None) -> Start:
    if cell is None:
        return Start()
    r = grid_map.resolution_m
    return Start.point(grid_map, (cell[1] + 0.5) * r, (cell[0] + 0.5) * r)


@pytest.mark.parametrize(("key", "want"), list(GOLDEN_FIT.items()), ids=[str(k) for k in GOLDEN_FIT])
def test_golden_cases(key, want, request):
    name, theta, cell = key
    grid_map: Map = request.getfixturevalue(name)
    n_free = grid_map.counts[Cell.FREE]
    p_c, coverable, p_len, cells, start = want
    f = footprint_matrix(Morphology.of(theta), grid_map.resolution_m)
    ref = plan_fit_reference(grid_map.cells.tolist(), f.tolist(), cell)
    assert (round(100 * ref.n_covered / n_free, 4), round(100 * ref.n_bound / n_free, 4)) == (p_c, coverable)
    assert (ref.p_len, ref.n_ew * f.shape[1] + ref.n_ns * f.shape[0], ref.start) == (p_len, cells, start)
    evaluator = Evaluator(grid_map, start=_start(grid_map, cell), planner=Planner.FIT)
    for result in (evaluator.evaluate(Morphology.of(theta)), evaluator.plan(Morphology.of(theta))):
        assert (round(result.P_c, 4), round(result.coverable_pct, 4), result.P_len) == (p_c, coverable, p_len)
        assert result.P_c == result.coverage_free_pct and result.path_length_cells == cells
    batch = evaluator.evaluate_many(np.array([theta], dtype=float))
    assert (round(float(batch.P_c[0]), 4), int(batch.P_len[0])) == (p_c, p_len)


def test_golden_path(walled):
    plan = Evaluator(walled, planner=Planner.FIT).plan(Morphology.of((0, 180, 0)))
    assert [tuple(p) for p in plan.placements.tolist()] == WALLED_O_PLACEMENTS
    assert plan.covered.sum() == round(0.473684 * walled.counts[Cell.FREE])


def test_kernel_matches_the_reference_on_random_maps():
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(8):
        grid_map = random_map(rng, int(rng.integers(8, 24)), int(rng.integers(8, 24)), 0.08, 0.03)
        free = np.argwhere(grid_map.cells == Cell.FREE)
        cell = tuple(int(v) for v in free[len(free) // 2])
        for theta in (*GOLDEN_THETAS, (30, 120, 60)):
            f = footprint_matrix(Morphology.of(theta), 0.1)
            for start in (None, cell):
                ref = plan_fit_reference(grid_map.cells.tolist(), f.tolist(), start)
                plan = Evaluator(grid_map, start=_start(grid_map, start), planner=Planner.FIT).plan(
                    Morphology.of(theta)
                )
                n_free = grid_map.counts[Cell.FREE]
                assert plan.P_len == ref.p_len and plan.covered.sum() == ref.n_covered
                assert round(plan.coverable_pct * n_free / 100) == ref.n_bound
                assert [tuple(p) for p in plan.placements.tolist()] == ref.placements
                checked += 1
    assert checked == 8 * 6 * 2


@pytest.mark.slow
def test_kernel_matches_the_reference_across_64_cell_words():
    """The kernel works on rows of 64 cells: a map 220 cells wide (4 words) and footprints wider than a word
    (85 and 90 cells at 8 mm), so shifts cross words; one plan moves, one fits nowhere."""
    rng = np.random.default_rng(3)
    cells = np.full((50, 220), Cell.FREE, np.uint8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = Cell.OCCUPIED
    for _ in range(3):
        y, x = rng.integers(0, 50), rng.integers(0, 220)
        cells[y : y + rng.integers(2, 9), x : x + rng.integers(2, 9)] = rng.choice([Cell.OCCUPIED, Cell.UNKNOWN])
    grid_map = Map(cells, 0.008, name="wide")
    moved = 0
    for theta in ((0, 0, 0), (30, 120, 60)):
        f = footprint_matrix(Morphology.of(theta), grid_map.resolution_m)
        assert f.shape[1] > 64
        ref = plan_fit_reference(cells.tolist(), f.tolist())
        plan = Evaluator(grid_map, planner=Planner.FIT).plan(Morphology.of(theta))
        assert [tuple(p) for p in plan.placements.tolist()] == ref.placements
        assert plan.P_len == ref.p_len and plan.covered.sum() == ref.n_covered
        assert round(plan.coverable_pct * grid_map.counts[Cell.FREE] / 100) == ref.n_bound
        moved += ref.p_len > 0
    assert moved == 1


def _cells_under(f: np.ndarray, row: int, col: int, shape: tuple[int, int]) -> list[tuple[int, int]]:
    """Map cells under F placed with its corner at (row, col); cells outside the map come back as (-1, -1)."""
    out = []
    for i, j in np.argwhere(f):
        y, x = row + int(i), col + int(j)
        out.append((y, x) if 0 <= y < shape[0] and 0 <= x < shape[1] else (-1, -1))
    return out


@pytest.mark.parametrize("theta", [(0, 180, 0), (0, 0, 0), (95, 59, 103), (45, 45, 45)])
def test_on_a_real_floor_the_robot_never_stands_over_anything_but_free_cells(theta):
    """TurtleBot3's arena (shared/realmaps): every position along the fit path, the starts and every one-cell
    shift between them, lies over free cells only; the paper's path for the same shape does not."""
    grid_map = load_map(str(realmap("tb3_world")))
    morphology = Morphology.of(theta)
    fit = Evaluator(grid_map, planner=Planner.FIT).plan(morphology)
    assert fit.placements is not None and len(fit.placements) > 1 and fit.footprint is not None
    f = fit.footprint.astype(bool)
    positions = sweep_positions(fit.placements.tolist())
    under = {c for p in positions for c in _cells_under(f, *p, grid_map.cells.shape)}
    assert (-1, -1) not in under and all(grid_map.cells[c] == Cell.FREE for c in under)
    assert fit.covered.sum() == len(under)  # coverage is exactly what the robot swept
    assert 0 < fit.coverage_free_pct <= fit.coverable_pct <= 100
    paper = Evaluator(grid_map).plan(morphology)
    paper_under = {c for p in paper.placements.tolist() for c in _cells_under(f, *p, grid_map.cells.shape)}
    assert (-1, -1) in paper_under or any(grid_map.cells[c] != Cell.FREE for c in paper_under)


def test_a_corridor_narrower_than_every_footprint_is_refused(corridor):
    """docs/spec/fbcpp.md section 3: the fit planner needs somewhere the O or the I lies wholly on free cells."""
    from smorphi_rl.errors import MapError

    with pytest.raises(MapError, match="the robot fits nowhere on its free cells"):
        Evaluator(corridor, planner=Planner.FIT)


def test_a_shape_that_fits_nowhere_covers_nothing():
    """A floor holding the O (3 x 3 cells) but no I (2 x 7): every I-like shape covers nothing."""
    room = Map.from_text("#####\n#...#\n#...#\n#...#\n#####", 0.1, name="box")
    batch = Evaluator(room, planner=Planner.FIT).evaluate_many(np.array([(0, 0, 0), (0, 180, 0)], dtype=float))
    assert batch.feasible.all() and list(batch.P_c) == [0.0, 100.0] and not batch.P_len.any()


def test_a_tile_start_is_refused_by_the_fit_planner(room12):
    from smorphi_rl.errors import SmorphiError

    with pytest.raises(SmorphiError, match="fit planner has no tiles"):
        Evaluator(room12, start=Start.tile(0, 0), planner=Planner.FIT).evaluate(Morphology.of((0, 180, 0)))


@pytest.mark.parametrize("name", ["tb3_world", "depot"])
def test_kernel_matches_the_reference_on_crops_of_real_maps(name):
    from smorphi_rl.maptools import crop_to_rect

    grid_map = load_map(str(realmap(name)))
    ox, oy, _ = grid_map.origin
    rows, cols = np.nonzero(grid_map.cells == Cell.FREE)
    cy, cx = oy + rows.mean() * grid_map.resolution_m, ox + cols.mean() * grid_map.resolution_m
    crop = crop_to_rect(grid_map, cx - 1.0, cy - 1.0, cx + 1.0, cy + 1.0)  # 40 x 40 cells at 0.05 m
    for theta in ((0, 180, 0), (95, 59, 103)):
        f = footprint_matrix(Morphology.of(theta), crop.resolution_m)
        ref = plan_fit_reference(crop.cells.tolist(), f.tolist())
        plan = Evaluator(crop, planner=Planner.FIT).plan(Morphology.of(theta))
        assert [tuple(p) for p in plan.placements.tolist()] == ref.placements and plan.covered.sum() == ref.n_covered


def _collisions(grid_map: Map, placements: list[list[int]], f: np.ndarray) -> int:
    """Robot positions along a plan whose footprint leaves the map or touches a cell that is not free."""
    rows, cols = np.nonzero(f)
    bad = 0
    for r, c in sweep_positions(placements):
        y, x = r + rows, c + cols
        inside = (y < grid_map.height) & (x < grid_map.width)
        bad += bool((~inside).any() or (grid_map.cells[y[inside], x[inside]] != Cell.FREE).any())
    return bad


SHIPPED_MAPS = {p.name: p for p in sorted((Path(__file__).resolve().parents[1] / "maps").glob("*.yaml"))}


@pytest.mark.slow
@pytest.mark.parametrize("name", [*SHIPPED_MAPS, "tb3_world", "depot"])
def test_no_collision_on_any_shipped_or_real_map(name):
    """The target: zero collisions on every real and shipped map, checked from the plan's own placements (a real
    map skips where the shared maps are absent; the shipped ones never do)."""
    path = SHIPPED_MAPS[name] if name in SHIPPED_MAPS else realmap(name)
    grid_map = load_map(str(path))
    for theta in ((0, 180, 0), (110, 60, 67)):
        plan = Evaluator(grid_map, planner=Planner.FIT).plan(Morphology.of(theta))
        assert plan.placements is not None and plan.footprint is not None
        assert len(plan.placements) and plan.feasible, (path.name, theta)  # a plan of no placements checks nothing
        assert _collisions(grid_map, plan.placements.tolist(), plan.footprint.astype(bool)) == 0, path.name

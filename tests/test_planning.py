"""Evaluator: the cache by F is exact; batches equal single evaluations; bad batches are refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.errors import MorphologyError, SmorphiError
from smorphi_rl.geometry import Morphology
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Evaluator, lattice_thetas
from smorphi_rl.score import Weights

MAP_1 = Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"


@pytest.fixture(scope="module")
def map_1():
    return load_map(MAP_1)


@pytest.fixture(scope="module")
def thetas():
    rng = np.random.default_rng(0)
    t = rng.integers(0, 181, size=(400, 3)).astype(float)
    return np.vstack([t, t[:50], rng.uniform(0, 180, size=(50, 3))])  # repeats and non-integers


def _fields(batch):
    return (batch.feasible, batch.P_c, batch.coverage_free_pct, batch.P_len, batch.path_length_m, batch.footprint_cells)


def test_cached_equals_uncached(map_1, thetas):
    cached = Evaluator(map_1)
    first, second = cached.evaluate_many(thetas), cached.evaluate_many(thetas)
    plain = Evaluator(map_1, cache=False).evaluate_many(thetas)
    for a, b, c in zip(_fields(first), _fields(second), _fields(plain), strict=True):
        assert np.array_equal(a, c) and np.array_equal(b, c)
    assert cached.cache_size() < len(thetas)  # distinct footprints are fewer than morphologies
    assert cached.hits >= cached.cache_size()  # the second pass was served from the cache


def test_a_bounded_cache_stays_bounded_and_changes_no_result(map_1, thetas):
    bounded = Evaluator(map_1, cache_limit=7)
    results = [bounded.evaluate_many(thetas[i : i + 20]) for i in range(0, 100, 20)]
    assert bounded.cache_size() <= 7
    assert bounded.misses > 7  # more footprints planned than the cache holds
    plain = Evaluator(map_1, cache=False).evaluate_many(thetas[:100])
    for field, whole in zip(zip(*(_fields(r) for r in results), strict=True), _fields(plain), strict=True):
        assert np.array_equal(np.concatenate(field), whole)


def test_single_equals_batch(map_1, thetas):
    ev = Evaluator(map_1)
    batch = ev.evaluate_many(thetas[:60])
    fresh = Evaluator(map_1, cache=False)
    for i, theta in enumerate(thetas[:60]):
        m = Morphology.of(theta)
        for single in (ev.evaluate(m), fresh.evaluate(m)):
            row = batch.result(i)
            assert single.to_dict() == row.to_dict()
            assert single.path_length_cells == row.path_length_cells


def test_the_planner_kernel_is_compiled_once_for_every_caller(map_1, thetas):
    """`plan_any` is most of the first run's 35 s compile: every caller (the batch kernels, a single evaluation,
    a full plan for plots and replays) must reach it with one signature, not each with a variant of its own."""
    from smorphi_rl import _kernels as k

    Evaluator(map_1).evaluate_many(thetas[:5])  # plan_batch
    Evaluator(map_1).evaluate_many(thetas[:1])  # plan_batch of one footprint (its rows are C and F order at once)
    frozen = thetas[5:9].copy()
    frozen.flags.writeable = False  # as Ray hands arrays out
    Evaluator(map_1).evaluate_many(frozen)
    Evaluator(map_1, cache=False).evaluate_many(frozen)
    Evaluator(map_1, cache=False).evaluate_many(thetas[:5])  # evaluate_batch
    one = Evaluator(map_1)
    one.evaluate(Morphology.of(thetas[0]))  # from Python, a view of the evaluator's buffer
    one.plan(Morphology.of((0, 0, 0)))  # from Python, a whole footprint (a view of it would be contiguous)
    assert len(k.plan_any.signatures) == 1, k.plan_any.signatures
    for kernel in (k.plan_batch, k.footprints_batch, k.evaluate_batch):
        assert len(kernel.signatures) == 1, kernel.signatures


def test_plan_agrees_with_evaluate(map_1):
    ev = Evaluator(map_1)
    m = Morphology.of((95, 59, 103))
    full, quick = ev.plan(m), ev.evaluate(m)
    assert full.to_dict() == quick.to_dict()
    assert full.covered.sum() == round(full.coverage_free_pct / 100 * map_1.counts[0])


def test_same_footprint_same_result_cache_hit(map_1):
    ev = Evaluator(map_1)
    a = ev.evaluate(Morphology.of((0, 0, 0)))
    b = ev.evaluate(Morphology.of((0.4, 0.3, 0.2)))  # a hair off straight: same F at 0.1 m
    assert ev.hits == 1 and ev.misses == 1
    assert a.P_c == b.P_c and a.P_len == b.P_len


@pytest.mark.parametrize("bad", [np.zeros((3, 2)), np.array([[0, 0, 181.0]]), np.array([[np.nan, 0, 0]])])
def test_bad_batches(map_1, bad):
    with pytest.raises(MorphologyError):
        Evaluator(map_1).evaluate_many(bad)


def test_bad_block_side(map_1):
    with pytest.raises(SmorphiError, match="block side"):
        Evaluator(map_1, block_side_m=0.0)


def test_other_block_sides_and_resolutions_agree_with_reference():
    from smorphi_rl.coverage_reference import evaluate_reference
    from smorphi_rl.maps import Map

    rng = np.random.default_rng(5)
    cells = (rng.random((60, 45)) < 0.2).astype(np.uint8)
    cells[0, 0] = 0
    for side, res in ((0.25, 0.05), (0.1, 0.1), (0.17, 0.033)):
        grid_map = Map(cells, res)
        ev = Evaluator(grid_map, block_side_m=side)
        for theta in rng.integers(0, 181, size=(4, 3)):
            got = ev.evaluate(Morphology.of(theta))
            ref = evaluate_reference(grid_map, tuple(theta), side)
            assert (got.P_c, got.P_len, got.footprint_cells) == (ref["P_c"], ref["P_len"], ref["footprint_cells"])


def test_lattice_covers_every_triple_once():
    thetas = lattice_thetas(90.0)
    assert thetas.shape == (27, 3)
    assert len({tuple(t) for t in thetas}) == 27 and thetas.min() == 0 and thetas.max() == 180


def test_optimum_of_a_scored_lattice_is_the_brute_force_argmax(room12):
    from smorphi_rl.protocol import Optimum

    evaluator = Evaluator(room12)
    thetas = lattice_thetas(30.0)
    batch = evaluator.evaluate_many(thetas)
    best = Optimum.of(thetas, batch.P_c, batch.P_len, Weights(1.0, 0.5), 30.0)
    scores = [(r.P_c - 0.5 * r.P_len, r.theta) for r in (evaluator.evaluate(Morphology.of(t)) for t in thetas)]
    assert abs(best.R1 - max(s for s, _ in scores)) < 1e-9 and best.step_deg == 30.0
    assert best.theta == tuple(float(v) for v in max(scores, key=lambda s: s[0])[1])


def test_planning_says_where_plans_start_and_what_share_that_area_holds():
    from smorphi_rl.coverage import Planner
    from smorphi_rl.maps import Map
    from smorphi_rl.planning import Planning

    two_rooms = Map.from_text("......#..\n......#..\n......#..", 0.5, name="two")  # 18 and 6 free cells
    assert "first traversable tile" in Planning().describe(two_rooms) and Planning().is_paper_default
    fit = Planning(planner=Planner.FIT)
    assert "largest free area, 75.0 % of the free cells" in fit.describe(two_rooms) and not fit.is_paper_default
    thick = Map.from_text("\n".join(["." * 40 + "#" * 40 + "." * 20] * 40), 0.05, name="thick")  # a 2 m wall
    small = Planning(start_xy=(4.5, 0.5))  # the small room, right of the wall
    assert "at (4.5, 0.5) m, 33.3 % of the free cells" in small.describe(thick)
    assert "holding 33.3 % of the free cells" in (small.start_warning(thick) or "")
    assert small.start_warning(thick, covered_pct=60.0) is None  # a shape found already covers more


def test_the_paper_planners_start_warning_counts_the_walls_its_tiles_cross():
    """Under `paper` a tile is traversable when any of its cells is free, so a wall thinner than a tile is no
    border: a strip below a one-cell wall was warned of as "the rest is out of reach", and the --start-xy it
    suggested lost coverage. A wall over twice the longest tile (0.89 m: tiles straddle it) is one."""
    from smorphi_rl.coverage import Planner
    from smorphi_rl.maps import Map
    from smorphi_rl.planning import Planning

    floor = ["." * 40] * 30
    thin = Map.from_text("\n".join([*floor, "#" * 40, "." * 40]), 0.05, name="thin")  # the strip is row 0
    thick = Map.from_text("\n".join([*floor, *["#" * 40] * 40, "." * 40]), 0.05, name="thick")  # 2 m
    assert Planning().start_warning(thin) is None
    assert "plans start in a free area holding 3.2 % of the free cells" in (Planning().start_warning(thick) or "")
    one_metre = Map.from_text("\n".join([*floor, *["#" * 40] * 20, "." * 40]), 0.05, name="one")
    assert Planning().start_warning(one_metre) is None  # the I along y (0.68 m) straddles a 1 m wall
    assert Planning(planner=Planner.FIT).start_warning(thin) is None  # `fit` starts in the largest free area


def test_a_map_file_a_planners_name_and_three_angles_are_taken_as_they_are_written():
    """From Python, `Evaluator("map.yaml")`, `.evaluate((95, 59, 103))` and `Planning(planner="fit")` failed deep
    inside (an AttributeError on 'resolution_m', 'angles' or 'code'), though env_config takes "fit" as a name."""
    from smorphi_rl.coverage import Planner
    from smorphi_rl.planning import Planning

    by_path = Evaluator(str(MAP_1), planner="fit")
    by_value = Evaluator(load_map(MAP_1), planner=Planner.FIT)
    shape = Morphology(95, 59, 103)
    ours, theirs = by_path.evaluate((95, 59, 103)), by_value.evaluate(shape)
    assert (ours.planner, ours.P_c, ours.P_len) == ("fit", theirs.P_c, theirs.P_len)
    assert by_path.plan(np.array([95, 59, 103])).P_len == by_value.plan(shape).P_len
    assert Planning(planner="fit") == Planning(planner=Planner.FIT) and hash(Planning(planner="fit"))
    with pytest.raises(SmorphiError, match=r"unknown planner 'fast' \(choose from paper, fit\)"):
        Planning(planner="fast")
    with pytest.raises(MorphologyError, match="needs 3 hinge angles, got 2"):
        by_path.evaluate((95, 59))

"""`quick_result`: one shape planned without the compiled kernels reports exactly what the kernels report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.coverage import Planner
from smorphi_rl.coverage_reference import QUICK_MAX_CELLS, quick_result
from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M, Morphology
from smorphi_rl.maps import Map, load_map
from smorphi_rl.planning import Evaluator

MAPS = Path(__file__).resolve().parents[1] / "maps"


@pytest.mark.parametrize("planner", list(Planner))
@pytest.mark.parametrize("name", ["map-1", "val-2"])
def test_quick_result_equals_the_compiled_evaluation(name, planner):
    grid_map = load_map(MAPS / f"{name}.yaml")
    evaluator = Evaluator(grid_map, planner=planner)
    rng = np.random.default_rng(7)
    shapes = [(0, 0, 0), (180, 180, 180), (90, 90, 90), *(tuple(rng.integers(0, 181, 3)) for _ in range(25))]
    for theta in shapes:
        morphology = Morphology.of(tuple(float(t) for t in theta))
        quick = quick_result(grid_map, morphology, DEFAULT_BLOCK_SIDE_M, planner)
        assert quick is not None
        assert quick.to_dict() == evaluator.evaluate(morphology).to_dict(), theta
        if planner is Planner.FIT and quick.feasible:
            assert quick.placements is not None
            assert quick.placements.tolist() == evaluator.plan(morphology).placements.tolist()


def test_quick_result_declines_a_big_map():
    grid_map = load_map(MAPS / "map-1.yaml")
    big = Map(np.zeros((201, 201), dtype=np.uint8), grid_map.resolution_m, name="big")
    assert big.cells.size > QUICK_MAX_CELLS[Planner.PAPER]
    assert quick_result(big, Morphology.of((90, 90, 90)), DEFAULT_BLOCK_SIDE_M, Planner.PAPER) is None

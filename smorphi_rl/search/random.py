"""Random shapes (the paper's Table 4): integer hinge angles drawn uniformly from a seeded generator."""

from __future__ import annotations

import time

import numpy as np

from smorphi_rl.coverage import Planner
from smorphi_rl.errors import SmorphiError
from smorphi_rl.evaluate import Evaluator
from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M
from smorphi_rl.maps import load_map
from smorphi_rl.search.results import SearchResult


def run_random(
    map_path: str, samples: int, seed: int, block_side_m: float = DEFAULT_BLOCK_SIDE_M, planner: str = "paper"
) -> SearchResult:
    """`samples` shapes, each angle uniform on 0..180 degrees, scored with FBCPP (`planner`)."""
    if samples < 1:
        raise SmorphiError(f"--samples must be >= 1, got {samples}")
    grid_map = load_map(map_path)
    thetas = np.random.default_rng(seed).integers(0, 181, size=(samples, 3)).astype(np.float64)
    t0 = time.perf_counter()
    batch = Evaluator(grid_map, block_side_m, planner=Planner(planner)).evaluate_many(thetas)
    params = {"samples": samples, "seed": seed, "planner": planner}
    return SearchResult("random", grid_map.name, thetas, batch.P_c, batch.P_len, batch.feasible, samples,
                        time.perf_counter() - t0, params)  # fmt: skip

"""Random shapes (the paper's Table 4): integer hinge angles drawn uniformly from a seeded generator."""

from __future__ import annotations

import time

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import load_map
from smorphi_rl.planning import PAPER_PLANNING, Planning
from smorphi_rl.search.results import SearchResult


def run_random(map_path: str, samples: int, seed: int, planning: Planning = PAPER_PLANNING) -> SearchResult:
    """`samples` shapes, each angle uniform on 0..180 degrees, scored with FBCPP as `planning` says."""
    if samples < 1:
        raise SmorphiError(f"--samples must be >= 1, got {samples}")
    grid_map = load_map(map_path)
    thetas = np.random.default_rng(seed).integers(0, 181, size=(samples, 3)).astype(np.float64)
    t0 = time.perf_counter()
    batch = planning.evaluator(grid_map).evaluate_many(thetas)
    params = {"samples": samples, "seed": seed, "planner": planning.planner.value}
    return SearchResult("random", grid_map.name, thetas, batch.P_c, batch.P_len, batch.feasible, samples,
                        time.perf_counter() - t0, params)  # fmt: skip

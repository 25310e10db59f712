"""Random shapes (the paper's Table 4): integer hinge angles drawn uniformly from a seeded generator."""

from __future__ import annotations

import time

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import load_map
from smorphi_rl.planning import PAPER_PLANNING, Planning
from smorphi_rl.search.on_ray import evaluator_for
from smorphi_rl.search.results import SearchResult


def run_random(
    map_path: str, samples: int, seed: int, planning: Planning = PAPER_PLANNING, address: str | None = None
) -> SearchResult:
    """`samples` shapes, each angle uniform on 0..180 degrees, scored with FBCPP as `planning` says: here, or on
    the Ray cluster at `address` (the same shapes and scores)."""
    if samples < 1:
        raise SmorphiError(f"--samples must be >= 1, got {samples}")
    grid_map = load_map(map_path)
    thetas = np.random.default_rng(seed).integers(0, 181, size=(samples, 3)).astype(np.float64)
    params: dict[str, object] = {"samples": samples, "seed": seed, "planner": planning.planner.value}
    with evaluator_for(grid_map, planning, address) as evaluator:
        t0 = time.perf_counter()
        batch = evaluator.evaluate_many(thetas)
        wall = time.perf_counter() - t0
    if address is not None:
        params["address"] = address
    return SearchResult("random", grid_map.name, thetas, batch.P_c, batch.P_len, batch.feasible, samples, wall,
                        params)  # fmt: skip

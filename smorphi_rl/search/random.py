"""Random shapes (the paper's Table 4): integer hinge angles drawn uniformly from a seeded generator."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.interrupts import stop_requests
from smorphi_rl.maps import Map, as_map
from smorphi_rl.planning import PAPER_PLANNING, Planning
from smorphi_rl.search.on_ray import evaluator_for
from smorphi_rl.search.results import SearchResult

CHUNK = 50_000
"""Shapes scored at a time (about half a second): Ctrl-C and SIGTERM stop a search between chunks."""


def run_random(
    map_source: str | Path | Map,
    samples: int,
    seed: int,
    planning: Planning = PAPER_PLANNING,
    address: str | None = None,
) -> SearchResult:
    """`samples` shapes, each angle uniform on 0..180 degrees, scored with FBCPP as `planning` says: here, or on
    the Ray cluster at `address` (the same shapes and scores)."""
    if samples < 1:
        raise SmorphiError(f"--samples must be >= 1, got {samples}")
    grid_map = as_map(map_source)
    thetas = np.random.default_rng(seed).integers(0, 181, size=(samples, 3)).astype(np.float64)
    params: dict[str, object] = {"samples": samples, "seed": seed, "planner": planning.planner.value}
    with evaluator_for(grid_map, planning, address) as evaluator, stop_requests() as stop:
        t0 = time.perf_counter()
        parts = []
        for lo in range(0, samples, CHUNK):  # a stop request is honoured between chunks, never inside a kernel
            parts.append(evaluator.evaluate_many(thetas[lo : lo + CHUNK]))
            if stop.is_set():
                raise KeyboardInterrupt
        wall = time.perf_counter() - t0
    p_c, p_len, feasible = (np.concatenate([getattr(b, k) for b in parts]) for k in ("P_c", "P_len", "feasible"))
    if address is not None:
        params["address"] = address
    return SearchResult("random", grid_map.name, thetas, p_c, p_len, feasible, samples, wall, params, grid_map.digest)

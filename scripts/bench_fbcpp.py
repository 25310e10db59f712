"""Benchmark FBCPP on map-1: compiled fast path vs the plain-Python yardstick, in one run.

Measures on one core (the process is pinned to one CPU): uncached evaluations per second
(batch and one-at-a-time, as the env calls it), cached lookups per second, and the ratio
against the plain-Python implementation of the same spec (geometry.py + coverage_reference.py),
whose results must be identical. Targets: paper planner >= 30,000 uncached evaluations/s and >= 30x
plain Python; fit planner (`--planner fit`, docs/fbcpp-fit.md) >= 10,000 evaluations/s.

    .venv/bin/python scripts/bench_fbcpp.py [--map maps/map-1.yaml] [--n 3000] [--n-plain 300] [--planner fit]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import time
from pathlib import Path

import numpy as np
from _benchdocs import check_at_least, run_documented

from smorphi_rl.coverage import PLANNERS, Planner
from smorphi_rl.coverage_reference import evaluate_reference
from smorphi_rl.geometry import Morphology
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Evaluator

TARGET_RATE = {"paper": 30_000, "fit": 10_000}
TARGET_RATIO = {"paper": 30.0, "fit": 1.0}


def best_rate(fn, n_items: int, repeats: int) -> float:
    """Items per second of the median of `repeats` timed calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return n_items / statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"))
    parser.add_argument("--n", type=int, default=3000, help="random morphologies for the fast path")
    parser.add_argument("--n-plain", type=int, default=300, help="of those, how many the plain yardstick runs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--planner", choices=PLANNERS, default="paper")
    args = parser.parse_args()
    check_at_least(("--n", args.n, 1), ("--n-plain", args.n_plain, 1), ("--repeats", args.repeats, 1))
    planner = Planner(args.planner)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    grid_map = load_map(args.map)
    rng = np.random.default_rng(args.seed)
    thetas = rng.integers(0, 181, size=(args.n, 3)).astype(np.float64)
    morphs = [Morphology.of(t) for t in thetas]

    t0 = time.perf_counter()
    Evaluator(grid_map, cache=False, planner=planner).evaluate_many(thetas[:2])
    Evaluator(grid_map, planner=planner).evaluate_many(thetas[:2])
    Evaluator(grid_map, planner=planner).evaluate(morphs[0])
    warmup_s = time.perf_counter() - t0

    plain = thetas[: args.n_plain]
    t0 = time.perf_counter()
    reference = [evaluate_reference(grid_map, tuple(t), planner=planner.value) for t in plain]
    plain_rate = len(plain) / (time.perf_counter() - t0)

    fast = Evaluator(grid_map, cache=False, planner=planner)
    batch = fast.evaluate_many(thetas)
    mismatches = sum(
        (r["P_c"], r["P_len"], r["coverage_free_pct"], r["path_length_cells"], r["footprint_cells"])
        != (b.P_c, b.P_len, b.coverage_free_pct, b.path_length_cells, b.footprint_cells)
        for r, b in zip(reference, batch, strict=False)
    )
    batch_rate = best_rate(lambda: fast.evaluate_many(thetas), len(thetas), args.repeats)
    single_rate = best_rate(lambda: [fast.evaluate(m) for m in morphs], len(morphs), args.repeats)

    cached = Evaluator(grid_map, planner=planner)
    cached.evaluate_many(thetas)
    cached_batch_rate = best_rate(lambda: cached.evaluate_many(thetas), len(thetas), args.repeats)
    cached_single_rate = best_rate(lambda: [cached.evaluate(m) for m in morphs], len(morphs), args.repeats)
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    ratio = batch_rate / plain_rate
    target_rate, target_ratio = TARGET_RATE[planner.value], TARGET_RATIO[planner.value]
    ok = batch_rate >= target_rate and ratio >= target_ratio and mismatches == 0
    print(f"map                         {grid_map.name} ({grid_map.width} x {grid_map.height} cells), "
          f"planner {planner.value}")  # fmt: skip
    print(f"morphologies                {len(thetas)} random integer triples, {cached.cache_size()} distinct F")
    print(f"compile/load (first call)   {warmup_s:.2f} s (excluded below)")
    print(f"plain Python (yardstick)    {plain_rate:10,.0f} evals/s  ({len(plain)} morphologies)")
    print(f"fast, uncached, batch       {batch_rate:10,.0f} evals/s  ({ratio:.1f}x plain)")
    print(f"fast, uncached, one by one  {single_rate:10,.0f} evals/s  ({single_rate / plain_rate:.1f}x plain)")
    print(f"cached lookups, batch       {cached_batch_rate:10,.0f} lookups/s")
    print(f"cached lookups, one by one  {cached_single_rate:10,.0f} lookups/s")
    print(f"identical to plain Python   {len(plain) - mismatches}/{len(plain)}")
    print(f"peak memory                 {peak_mib:.0f} MiB")
    print(f"target                      >= {target_rate:,} evals/s and >= {target_ratio:.0f}x plain: "
          f"{'PASS' if ok else 'FAIL'}")  # fmt: skip


if __name__ == "__main__":
    run_documented("fbcpp", "The planner (`scripts/bench_fbcpp.py`)", main)

"""Benchmark the exhaustive search: every triple at 1 degree (5,929,741 shapes) on map-1, on every core.

Prints the wall time, the distinct footprints and evaluations per second, next to the yardstick
measured in the same run: one process evaluating the 2-degree lattice (753,571 shapes) with the
same batch evaluator. Target (2-core machine): the 1-degree lattice in at most 5 minutes.

    .venv/bin/python scripts/bench_exhaustive.py [--map maps/map-1.yaml] [--step 1]
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

from smorphi_rl.evaluate import Evaluator, lattice_thetas
from smorphi_rl.maps import load_map
from smorphi_rl.score import Weights
from smorphi_rl.search.exhaustive import run_exhaustive

TARGET_S = 300.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"))
    parser.add_argument("--step", type=float, default=1.0)
    args = parser.parse_args()
    grid_map = load_map(args.map)

    yard = lattice_thetas(2.0)
    evaluator = Evaluator(grid_map)
    evaluator.evaluate_many(yard[:2])  # compile or load the kernels outside the timing
    t0 = time.perf_counter()
    evaluator.evaluate_many(yard)
    yard_s = time.perf_counter() - t0
    yard_rate = len(yard) / yard_s
    print(f"yardstick: one process, 2-degree lattice: {len(yard):,} shapes in {yard_s:.1f} s "
          f"({yard_rate:,.0f}/s, {evaluator.cache_size():,} distinct footprints)")  # fmt: skip

    t0 = time.perf_counter()
    result = run_exhaustive(args.map, args.step)
    wall = time.perf_counter() - t0
    rate = result.evaluations / wall
    best = result.best(Weights(1.0, 0.1))
    theta = tuple(int(t) for t in result.thetas[best])
    print(f"exhaustive, {args.step:g}-degree lattice on {grid_map.name}, {result.params['workers']} processes "
          f"({os.cpu_count()} cores): {result.evaluations:,} shapes, "
          f"{result.params['distinct_footprints']:,} distinct footprints")  # fmt: skip
    print(f"  wall {wall:.1f} s ({'meets' if wall <= TARGET_S else 'MISSES'} the {TARGET_S:.0f} s target), "
          f"{rate:,.0f} evaluations/s = {rate / yard_rate:.2f}x the one-process yardstick")  # fmt: skip
    print(f"  exact front: {len(result.front())} points; best R1 (w1 1, w2 0.1): {theta} "
          f"P_c {result.P_c[best]:.2f} % P_len {result.P_len[best]}")  # fmt: skip
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"  peak memory: driver {peak:.0f} MiB, largest worker {children:.0f} MiB")


if __name__ == "__main__":
    main()

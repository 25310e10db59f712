"""Benchmark the exhaustive search: every triple at 1 degree (5,929,741 shapes) on a map, on every core.

Prints the wall time, the distinct footprints and evaluations per second, next to the yardstick
measured in the same run: one process evaluating a coarser lattice (2 degrees, 753,571 shapes, by
default) with the same batch evaluator. Targets (2-core machine): the paper planner on map-1 in at most
5 minutes; the footprint-safe planner on `tb3_world` cropped to its arena (0.05 m) in at most 2 minutes
and 2 GiB (issue 13):

    .venv/bin/python scripts/bench_exhaustive.py [--map maps/map-1.yaml] [--step 1]
    .venv/bin/python scripts/bench_exhaustive.py --map ../shared/realmaps/tb3_world.yaml --crop-known \\
        --planner fit --yard-step 6
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

from _benchdocs import run_documented
from _memory import PeakMemory

from smorphi_rl.coverage import Planner
from smorphi_rl.maps import load_map, save_map
from smorphi_rl.maptools import crop_to_known, drop_islands
from smorphi_rl.planning import Planning, lattice_thetas
from smorphi_rl.score import Weights
from smorphi_rl.search.exhaustive import run_exhaustive

TARGET_S = {Planner.PAPER: 300.0, Planner.FIT: 120.0}
CROP_MARGIN_M, CROP_MIN_ISLAND_M2 = 0.2, 0.05
"""What the README's `maps crop ... --min-island 0.05` does (its default margin)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"))
    parser.add_argument("--step", type=float, default=1.0)
    parser.add_argument("--planner", choices=[p.value for p in Planner], default=Planner.PAPER.value)
    parser.add_argument("--yard-step", type=float, default=2.0, help="the yardstick's lattice step (degrees)")
    crop_help = "first crop the map to its known cells, as `maps crop --min-island 0.05` does"
    parser.add_argument("--crop-known", action="store_true", help=crop_help)
    args = parser.parse_args()
    planning = Planning(planner=Planner(args.planner))
    with tempfile.TemporaryDirectory() as tmp:
        map_path = args.map
        if args.crop_known:
            cropped, _ = drop_islands(crop_to_known(load_map(map_path), CROP_MARGIN_M), CROP_MIN_ISLAND_M2)
            map_path = str(save_map(cropped, Path(tmp) / f"{Path(map_path).stem}-cropped.yaml"))
        run(map_path, args.step, args.yard_step, planning)


def run(map_path: str, step: float, yard_step: float, planning: Planning) -> None:
    grid_map = load_map(map_path)
    print(f"map {grid_map.name}: {grid_map.width} x {grid_map.height} cells at {grid_map.resolution_m:g} m, "
          f"planner {planning.planner.value}")  # fmt: skip
    yard = lattice_thetas(yard_step)
    evaluator = planning.evaluator(grid_map)
    evaluator.evaluate_many(yard[:2])  # compile or load the kernels outside the timing
    t0 = time.perf_counter()
    evaluator.evaluate_many(yard)
    yard_s = time.perf_counter() - t0
    yard_rate = len(yard) / yard_s
    print(f"yardstick: one process, {yard_step:g}-degree lattice: {len(yard):,} shapes in {yard_s:.1f} s "
          f"({yard_rate:,.0f}/s, {evaluator.cache_size():,} distinct footprints)")  # fmt: skip

    t0 = time.perf_counter()
    with PeakMemory() as memory:
        result = run_exhaustive(map_path, step, planning)
    wall = time.perf_counter() - t0
    rate = result.evaluations / wall
    best = result.best(Weights(1.0, 0.1))
    theta = tuple(int(t) for t in result.thetas[best])
    target = TARGET_S[planning.planner]
    print(f"exhaustive, {step:g}-degree lattice on {grid_map.name}, {result.params['workers']} processes "
          f"({os.cpu_count()} cores): {result.evaluations:,} shapes, "
          f"{result.params['distinct_footprints']:,} distinct footprints")  # fmt: skip
    print(f"  wall {wall:.1f} s ({'meets' if wall <= target else 'MISSES'} the {target:.0f} s target), "
          f"{rate:,.0f} evaluations/s = {rate / yard_rate:.2f}x the one-process yardstick")  # fmt: skip
    print(f"  exact front: {len(result.front())} points; best R1 (w1 1, w2 0.1): {theta} "
          f"P_c {result.P_c[best]:.2f} % P_len {result.P_len[best]}")  # fmt: skip
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"  peak memory: {memory.peak_pss / 2**30:.2f} GiB PSS summed over the processes; "
          f"RSS driver {peak:.0f} MiB, largest worker {children:.0f} MiB")  # fmt: skip


if __name__ == "__main__":
    run_documented("exhaustive", "Exhaustive search (`scripts/bench_exhaustive.py`)", main)

"""Benchmark `search exhaustive --address`: the exhaustive search on a local Ray with 1 and 2 CPUs against the
local process pool (the yardstick, measured in the same run), results compared array for array.

Prints each wall time, the ratio of Ray with 2 CPUs to the local pool on 2 cores (target: at most 1.3, the cost
of tasks), the scaling from 1 to 2 CPUs, and, for each real map given (`--project`), its per-plan cost at native
resolution (a sample of random shapes in one process) and the projected 1-degree exhaustive time on clusters
of 2, 16 and 64 CPUs, taking the scaling measured here:

    .venv/bin/python scripts/bench_search_ray.py [--map maps/map-1.yaml] [--step 1]
        [--project ../shared/realmaps/depot.yaml ../shared/realmaps/tb3_world.yaml] [--planner fit]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _benchdocs import run_documented
from _cluster import local_ray_cluster

from smorphi_rl.coverage import Planner
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Planning, lattice_thetas
from smorphi_rl.search.exhaustive import footprint_classes, run_exhaustive
from smorphi_rl.search.lattice_tasks import footprint_keys
from smorphi_rl.words import counted

ROOT = Path(__file__).resolve().parent.parent
REALMAPS = ROOT.parent / "shared" / "realmaps"
TARGET_RATIO = 1.3
SAMPLE = 2000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(ROOT / "maps" / "map-1.yaml"))
    parser.add_argument("--step", type=float, default=1.0)
    parser.add_argument("--planner", choices=[p.value for p in Planner], default=Planner.FIT.value,
                        help="the planner of the projections (the timed runs use the paper's)")  # fmt: skip
    parser.add_argument("--project", nargs="*", default=[str(REALMAPS / "depot.yaml"),
                                                          str(REALMAPS / "tb3_world.yaml")])  # fmt: skip
    args = parser.parse_args()
    planning = Planning()
    t0 = time.perf_counter()
    here = run_exhaustive(args.map, args.step, planning, workers=2)
    local_s = time.perf_counter() - t0
    print(f"yardstick: local pool, 2 processes: {here.evaluations:,} shapes of {here.map_name} in {local_s:.1f} s "
          f"({here.evaluations / local_s:,.0f}/s)")  # fmt: skip
    walls, planning_s = {}, {}
    local_planning = here.wall_s
    for cpus in (1, 2):
        with local_ray_cluster(cpus) as address:
            t0 = time.perf_counter()
            there = run_exhaustive(args.map, args.step, planning, address=address)
            walls[cpus], planning_s[cpus] = time.perf_counter() - t0, there.wall_s
        same = all(np.array_equal(getattr(here, f), getattr(there, f)) for f in ("thetas", "P_c", "P_len", "feasible"))
        actors = counted(there.params["workers"], "actor")
        print(f"local Ray, {counted(cpus, 'CPU')}, {actors}: planning {planning_s[cpus]:.1f} s, "
              f"{walls[cpus]:.1f} s end to end (connect, actors start, planning, shutdown); results identical to the "
              f"pool: {same}")  # fmt: skip
    ratio = planning_s[2] / local_planning
    scaling = planning_s[1] / planning_s[2]
    verdict = "meets" if ratio <= TARGET_RATIO else "MISSES"
    print(f"planning on Ray with 2 CPUs / the local pool's ({local_planning:.1f} s): {ratio:.2f}x ({verdict} the "
          f"{TARGET_RATIO:g}x target, the tasks' overhead); end to end {walls[2] / local_s:.2f}x; 1 -> 2 CPUs: "
          f"{scaling:.2f}x faster")  # fmt: skip
    efficiency = scaling / 2
    lattice = lattice_thetas(1.0)
    distinct: dict[float, int] = {}  # footprints of the lattice at each resolution (each is planned once)
    for path in args.project:
        if not Path(path).is_file():
            print(f"projection: {path} not found (the workplace's shared/realmaps); skipped")
            continue
        grid_map = load_map(path)
        evaluator = Planning(planner=Planner(args.planner)).evaluator(grid_map, cache=False)
        sample = np.random.default_rng(0).integers(0, 181, size=(SAMPLE, 3)).astype(np.float64)
        evaluator.evaluate_many(sample[:2])
        t0 = time.perf_counter()
        evaluator.evaluate_many(sample)
        per_plan = (time.perf_counter() - t0) / SAMPLE
        if grid_map.resolution_m not in distinct:
            keys = footprint_keys(evaluator, lattice)
            distinct[grid_map.resolution_m] = len(footprint_classes(keys[keys.any(axis=1)])[0])
        plans = distinct[grid_map.resolution_m]
        hours = {n: plans * per_plan / (n * max(efficiency, 1e-9)) / 3600 for n in (2, 16, 64)}
        told = ", ".join(f"{n} CPUs {h * 60:.1f} min" for n, h in hours.items())
        print(f"projection: {grid_map.name} at its native {grid_map.resolution_m:g} m ({grid_map.width} x "
              f"{grid_map.height} cells), {args.planner} planner: {per_plan * 1e3:.2f} ms a plan, uncached, "
              f"{plans:,} distinct footprints to plan; 1-degree exhaustive at the measured {efficiency:.0%} per-CPU "
              f"efficiency: {told}")  # fmt: skip


if __name__ == "__main__":
    run_documented("search-ray", "Search on Ray (`scripts/bench_search_ray.py`)", main)

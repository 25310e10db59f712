"""Sweep the design space on a lattice and show what the env's reward weights favour.

Prints the exact Pareto front (max P_c, min P_len) over every triple at `--step` degrees and
the best morphology under R1 = w1 P_c - w2 P_len, next to the O-shape and the shortest path:
the figures behind the README's choice of default weights.

    .venv/bin/python scripts/design_space.py [--map maps/map-1.yaml] [--step 2] [--w1 1] [--w2 0.1]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Evaluator, lattice_thetas
from smorphi_rl.score import Weights
from smorphi_rl.search.pareto import pareto_front


def main() -> None:
    defaults = EnvConfig()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"))
    parser.add_argument("--step", type=float, default=2.0)
    parser.add_argument("--w1", type=float, default=defaults.w1)
    parser.add_argument("--w2", type=float, default=defaults.w2)
    args = parser.parse_args()
    grid_map = load_map(args.map)
    thetas = lattice_thetas(args.step)
    evaluator = Evaluator(grid_map)
    t0 = time.perf_counter()
    batch = evaluator.evaluate_many(thetas)
    elapsed = time.perf_counter() - t0
    r1 = Weights(args.w1, args.w2).r1(batch.P_c, batch.P_len)
    front = pareto_front(batch.P_c, batch.P_len)
    print(f"{grid_map.name}: {len(thetas):,} triples at {args.step:g} deg, {evaluator.cache_size():,} distinct F, "
          f"{elapsed:.1f} s")  # fmt: skip
    print(f"Pareto front ({len(front)} points) and R1 = {args.w1:g} P_c - {args.w2:g} P_len:")
    print("  theta              P_c     P_len  R1")
    for i in front:
        t = "(" + ", ".join(f"{v:g}" for v in thetas[i]) + ")"
        print(f"  {t:<17} {batch.P_c[i]:7.2f} {batch.P_len[i]:6d} {r1[i]:7.2f}")
    best = int(np.argmax(r1))
    t = ", ".join(f"{v:g}" for v in thetas[best])
    print(f"best R1: ({t}) P_c {batch.P_c[best]:.2f} %, P_len {batch.P_len[best]}, R1 {r1[best]:.2f}")


if __name__ == "__main__":
    main()

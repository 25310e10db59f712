"""Draw the paper's planner beside the footprint-safe one on a shipped map and on a real floor (README figure).

Prints, for each map and planner, the shape's coverage, P_len and the share of robot positions (every
one-cell position along the path) whose footprint lies over an occupied, unknown or outside cell.

    .venv/bin/python scripts/plot_planners.py [--realmaps ../shared/realmaps] [--out docs/planners.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from smorphi_rl.coverage import CoverageResult, Planner, sweep_positions
from smorphi_rl.geometry import Morphology
from smorphi_rl.maps import Cell, Map, load_map
from smorphi_rl.maptools import coarsen, crop_to_known, drop_islands
from smorphi_rl.planning import Planning
from smorphi_rl.plots import plot_planners

ROOT = Path(__file__).resolve().parents[1]


def share_over_non_free(result: CoverageResult, grid_map: Map) -> float:
    """Percent of robot positions whose footprint touches a cell that is not free (or leaves the map)."""
    if result.footprint is None:
        return 0.0
    rows, cols = np.nonzero(result.footprint)
    spots = sweep_positions([] if result.placements is None else result.placements.tolist())
    bad = 0
    for r, c in spots:
        y, x = r + rows, c + cols
        inside = (y < grid_map.height) & (x < grid_map.width)
        bad += bool((~inside).any() or (grid_map.cells[y[inside], x[inside]] != Cell.FREE).any())
    return 100.0 * bad / max(len(spots), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realmaps", default=str(ROOT.parent / "shared" / "realmaps"))
    parser.add_argument("--out", default=str(ROOT / "docs" / "planners.png"))
    args = parser.parse_args()
    real, _ = drop_islands(coarsen(crop_to_known(load_map(Path(args.realmaps) / "tb3_world.yaml"), 0.2), 2), 0.05)
    cases = [(load_map(ROOT / "maps" / "map-1.yaml"), (0.0, 180.0, 0.0)), (real, (110.0, 60.0, 67.0))]
    rows = []
    for grid_map, theta in cases:
        morphology = Morphology.of(theta)
        results = [Planning(planner=p).evaluator(grid_map).plan(morphology) for p in Planner]
        for r in results:
            over = share_over_non_free(r, grid_map)
            print(f"{grid_map.name:<10} {theta!s:<18} {r.planner:<6} free covered {r.coverage_free_pct:6.2f} %  "
                  f"P_len {r.P_len:4d}  positions over non-free cells {over:5.1f} %")  # fmt: skip
        rows.append((grid_map, morphology, results))
    figure = plot_planners(rows, 0.17, args.out).resolve()
    print(f"figure: {figure.relative_to(Path.cwd()) if figure.is_relative_to(Path.cwd()) else figure}")


if __name__ == "__main__":
    main()

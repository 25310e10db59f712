"""Draw generated floors of every kind (docs/floors.png): what the designer trains on and is measured on.

.venv/bin/python scripts/plot_floors.py [--seeds 0 1 2] [--out docs/floors.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from smorphi_rl.floorplans import DRAWN_KINDS, generate_floor
from smorphi_rl.maps import Cell
from smorphi_rl.plots import plot_map_grid

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--out", default=str(ROOT / "docs" / "floors.png"))
    args = parser.parse_args()
    floors = [generate_floor(kind, seed) for kind in DRAWN_KINDS for seed in args.seeds]
    titles = [f"{m.name}: {m.width * m.resolution_m:.1f} x {m.height * m.resolution_m:.1f} m at {m.resolution_m:g} m, "
              f"{100 * m.fraction(Cell.FREE):.0f} % free" for m in floors]  # fmt: skip
    print(f"figure: {plot_map_grid(floors, titles, len(args.seeds), args.out)}")


if __name__ == "__main__":
    main()

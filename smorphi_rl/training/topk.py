"""The distinct morphologies training found, best first (the paper's Tables 2-3). No Ray here.

Each finished episode reports its best shape. Shapes with the same P_c and P_len on a map (in
practice: the same footprint F, so the same coverage plan) count as one morphology; the table
keeps the first found and how many distinct angle triples reached it.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

FOUND_CSV = "morphologies.csv"
"""Every distinct morphology a training run found, best first (next to the top-k tables)."""
CSV_FIELDS = (
    "rank", "algorithm", "map", "theta1", "theta2", "theta3", "P_c", "P_len", "R1", "first_seen_env_steps", "variants",
)  # fmt: skip


@dataclass(frozen=True)
class Found:
    """One distinct morphology on one map, with its FBCPP metrics and when it was first found."""

    algorithm: str
    map: str
    theta: tuple[float, float, float]
    P_c: float
    P_len: int
    R1: float
    env_steps: int
    variants: int = 1
    """Distinct angle triples seen with these same metrics."""

    @property
    def angles(self) -> str:
        return "(" + ", ".join(f"{t:g}" for t in self.theta) + ")"


class TopMorphologies:
    """Accumulates episode bests; `top(k)` gives the best distinct ones by R1 (ties: higher P_c)."""

    def __init__(self) -> None:
        self._found: dict[tuple[str, str, float, int], Found] = {}
        self._thetas: dict[tuple[str, str, float, int], set[tuple[float, float, float]]] = {}

    def __len__(self) -> int:
        return len(self._found)

    def add_episode_bests(self, algorithm: str, rows: list[list[Any]], env_steps: int) -> None:
        """Rows as the callbacks send them: [map, t1, t2, t3, P_c, P_len, R1]."""
        for map_name, t1, t2, t3, p_c, p_len, r1 in rows:
            theta = (float(t1), float(t2), float(t3))
            key = (algorithm, str(map_name), round(float(p_c), 9), int(p_len))
            seen = self._thetas.setdefault(key, set())
            seen.add(theta)
            if key not in self._found:
                self._found[key] = Found(algorithm, str(map_name), theta, float(p_c), int(p_len), float(r1), env_steps)
            self._found[key] = replace(self._found[key], variants=len(seen))

    def top(self, k: int, map_name: str | None = None) -> list[Found]:
        found = [f for f in self._found.values() if map_name is None or f.map == map_name]
        return sorted(found, key=lambda f: (-f.R1, -f.P_c, f.env_steps, f.theta))[:k]

    def maps(self) -> list[str]:
        return sorted({f.map for f in self._found.values()})

    def first_reaching(self, r1: float, map_name: str | None = None) -> Found | None:
        """The earliest-found shape with R1 >= r1 (None if training never found one)."""
        hits = [f for f in self._found.values() if r1 <= f.R1 and (map_name is None or f.map == map_name)]
        return min(hits, key=lambda f: (f.env_steps, -f.R1), default=None)


def write_tables(rows: list[Found], csv_path: Path, md_path: Path) -> None:
    """CSV for tools and Markdown for people, both ranked best first."""
    write_csv(rows, csv_path)
    lines = [
        "| # | Algorithm | Map | Hinge angles (θ1, θ2, θ3) (deg) | Area covered P_c (%) | Path length P_len | R1 "
        "| First found (env steps) | Angle triples with these metrics |",
        "|---:|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for rank, f in enumerate(rows, 1):
        lines.append(f"| {rank} | {f.algorithm.upper()} | {f.map} | {f.angles} | {f.P_c:.2f} | {f.P_len} "
                     f"| {f.R1:.2f} | {f.env_steps:,} | {f.variants} |")  # fmt: skip
    md_path.write_text("\n".join(lines) + "\n")


def write_csv(rows: list[Found], csv_path: Path) -> None:
    """Ranked rows as CSV (CSV_FIELDS)."""
    with csv_path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(CSV_FIELDS)
        for rank, f in enumerate(rows, 1):
            writer.writerow([rank, f.algorithm, f.map, *(f"{t:g}" for t in f.theta), f"{f.P_c:.4f}", f.P_len,
                             f"{f.R1:.4f}", f.env_steps, f.variants])  # fmt: skip


def read_csv(csv_path: Path) -> list[Found]:
    """Rows written by `write_csv` (for `compare`)."""
    with csv_path.open(newline="") as fh:
        return [
            Found(
                row["algorithm"],
                row["map"],
                (float(row["theta1"]), float(row["theta2"]), float(row["theta3"])),
                float(row["P_c"]),
                int(row["P_len"]),
                float(row["R1"]),
                int(row["first_seen_env_steps"]),
                int(row["variants"]),
            )
            for row in csv.DictReader(fh)
        ]

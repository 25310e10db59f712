"""The distinct morphologies training found, best first (the paper's Tables 2-3). No Ray here.

Each finished episode reports its best shape. Shapes with the same P_c and P_len on a map (in
practice: the same footprint F, so the same coverage plan) count as one morphology; the table
keeps the first found and how many distinct angle triples reached it.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import angles_text
from smorphi_rl.rundir import atomic_text, write_text_atomic

FOUND_CSV = "morphologies.csv"
"""Every distinct morphology a training run found, best first (next to the top-k tables)."""
CSV_FIELDS = (
    "rank", "algorithm", "map", "theta1", "theta2", "theta3", "P_c", "P_len", "R1", "first_seen_env_steps", "variants",
)  # fmt: skip


EPISODE_BEST_KEY = "smorphi_episode_best"
"""Result key holding, as a JSON string, the best shape of each episode finished in an iteration (rows of
`EpisodeBest.to_row`). A string, so TensorBoard skips it and the driver parses it."""


@dataclass(frozen=True)
class EpisodeBest:
    """The best shape one episode reached (by R1), as the env runners report it to the driver."""

    map: str
    theta: tuple[float, float, float]
    P_c: float
    P_len: int
    R1: float

    def to_row(self) -> list[Any]:
        """[map, t1, t2, t3, P_c, P_len, R1]: compact in every iteration's result."""
        return [self.map, *self.theta, self.P_c, self.P_len, self.R1]

    @classmethod
    def from_row(cls, row: Any) -> EpisodeBest | None:
        """The value of one row, or None for a row that is not one (RLlib reports NaN for none)."""
        if not isinstance(row, list | tuple) or len(row) != 7:
            return None
        map_name, t1, t2, t3, p_c, p_len, r1 = row
        return cls(str(map_name), (float(t1), float(t2), float(t3)), float(p_c), int(p_len), float(r1))

    @property
    def angles(self) -> str:
        return angles_text(self.theta)


def encode_bests(rows: Iterable[Any]) -> str:
    """The result value for the episode bests of an iteration (rows that are not bests are dropped)."""
    return json.dumps([b.to_row() for b in map(EpisodeBest.from_row, rows) if b is not None])


def episode_bests(result: Mapping[str, Any]) -> list[EpisodeBest]:
    """The episode bests of one training result (the one reader of EPISODE_BEST_KEY)."""
    raw = result.get(EPISODE_BEST_KEY) or "[]"
    rows = json.loads(raw) if isinstance(raw, str) else raw
    return [b for b in map(EpisodeBest.from_row, rows) if b is not None]


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
        return angles_text(self.theta)


class TopMorphologies:
    """Accumulates episode bests; `top(k)` gives the best distinct ones by R1 (ties: higher P_c)."""

    def __init__(self) -> None:
        self._found: dict[tuple[str, str, float, int], Found] = {}
        self._thetas: dict[tuple[str, str, float, int], set[tuple[float, float, float]]] = {}

    def __len__(self) -> int:
        return len(self._found)

    def add_episode_bests(self, algorithm: str, bests: Iterable[EpisodeBest], env_steps: int) -> None:
        """Count each episode's best shape, found at `env_steps`."""
        for b in bests:
            key = (algorithm, b.map, round(b.P_c, 9), b.P_len)
            seen = self._thetas.setdefault(key, set())
            seen.add(b.theta)
            if key not in self._found:
                self._found[key] = Found(algorithm, b.map, b.theta, b.P_c, b.P_len, b.R1, env_steps)
            self._found[key] = replace(self._found[key], variants=len(seen))

    def top(self, k: int, map_name: str | None = None) -> list[Found]:
        found = [f for f in self._found.values() if map_name is None or f.map == map_name]
        return sorted(found, key=lambda f: (-f.R1, -f.P_c, f.env_steps, f.theta))[:k]

    def maps(self) -> list[str]:
        return sorted({f.map for f in self._found.values()})


def write_found(top: TopMorphologies, folder: Path, k: int) -> dict[str, Path]:
    """A run's top-k tables per map (top_morphologies.csv and .md) and every distinct shape it found (FOUND_CSV, for
    `compare`), in `folder`; the files written, by key (none when nothing was found)."""
    rows = [f for m in top.maps() for f in top.top(k, m)]
    if not rows:
        return {}
    files = {"top_csv": folder / "top_morphologies.csv", "top_md": folder / "top_morphologies.md",
             "found_csv": folder / FOUND_CSV}  # fmt: skip
    write_tables(rows, files["top_csv"], files["top_md"])
    write_csv(top.top(len(top)), files["found_csv"])
    return files


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
    write_text_atomic(md_path, "\n".join(lines) + "\n")


def write_csv(rows: list[Found], csv_path: Path) -> None:
    """Ranked rows as CSV (CSV_FIELDS)."""
    with atomic_text(csv_path) as fh:
        writer = csv.writer(fh)
        writer.writerow(CSV_FIELDS)
        for rank, f in enumerate(rows, 1):
            writer.writerow([rank, f.algorithm, f.map, *(f"{t:g}" for t in f.theta), f"{f.P_c:.4f}", f.P_len,
                             f"{f.R1:.4f}", f.env_steps, f.variants])  # fmt: skip


MAX_CSV_BYTES = 1 << 26
"""The largest morphologies.csv read (64 MiB, some 800,000 rows of 80 bytes): the table holds every distinct shape
a run's episodes ended on, so the designer's 2,000,000 steps on a fresh floor an episode write about 42,000; a
crafted table's size bounds its memory (55 MB took `compare --runs` to 1 GB)."""


def read_csv(csv_path: Path) -> list[Found]:
    """Rows written by `write_csv` (for `compare`), checked: angles in 0-180, P_c in 0-100, P_len and counts
    whole and not negative; anything else is refused in one line naming the file and the row."""
    rows: list[Found] = []
    try:
        if csv_path.stat().st_size > MAX_CSV_BYTES:
            raise SmorphiError(f"{csv_path}: {csv_path.stat().st_size:,} bytes, more than a table smorphi-rl writes "
                               f"({MAX_CSV_BYTES:,} at most)")  # fmt: skip
        with csv_path.open(newline="") as fh:
            for i, row in enumerate(csv.DictReader(fh), 2):
                if None in row or None in row.values():  # more fields than the header, or fewer
                    raise SmorphiError(f"{csv_path}, line {i}: not a row smorphi-rl writes (fewer or more fields than "
                                       "its header)")  # fmt: skip
                try:
                    found = Found(row["algorithm"], row["map"],
                                  (float(row["theta1"]), float(row["theta2"]), float(row["theta3"])),
                                  float(row["P_c"]), int(row["P_len"]), float(row["R1"]),
                                  int(row["first_seen_env_steps"]), int(row["variants"]))  # fmt: skip
                except (KeyError, TypeError, ValueError) as exc:
                    raise SmorphiError(f"{csv_path}, line {i}: not a row smorphi-rl writes ({type(exc).__name__}: "
                                       f"{exc})") from None  # fmt: skip
                ok = (all(0 <= t <= 180 for t in found.theta) and 0 <= found.P_c <= 100 and found.P_len >= 0
                      and math.isfinite(found.R1) and found.env_steps >= 0 and found.variants >= 1)  # fmt: skip
                if not ok:
                    raise SmorphiError(f"{csv_path}, line {i}: values out of range (angles 0-180, P_c 0-100, "
                                       "P_len and steps not negative, variants at least 1)")  # fmt: skip
                rows.append(found)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise SmorphiError(f"{csv_path}: not a readable table ({type(exc).__name__})") from None
    return rows

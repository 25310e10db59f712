"""What every search method produces, and how it is written to and read back from its run directory."""

from __future__ import annotations

import csv
import io
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl import jsontext
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import LATTICE_TOLERANCE_DEG, check_step, lattice_size, nearest_on_lattice
from smorphi_rl.rundir import atomic_text, write_atomic, write_text_atomic
from smorphi_rl.score import MAX_P_LEN, Weights
from smorphi_rl.search.pareto import pareto_front

RESULTS_FILE = "results.npz"
MAX_EVALUATIONS = 50_000_000
"""A search scores at most this many shapes (about 20 minutes of planning on 2 cores on a 5 m map; the whole
1-degree lattice is 5,929,741); beyond it the run is a typo or a job for `--address` and a cluster. A results file
claiming more is not one a search wrote."""
MAX_WALL_S = 1e9
"""A search's recorded wall time is at most this (31 years)."""
MAX_INFLATION = 64
"""A results archive unpacks to at most this many times its size: the whole 1-degree lattice with one P_c and P_len
everywhere (the most regular figures a search can give) unpacks 10.3x, random figures 2.2x."""


@dataclass(frozen=True)
class SearchResult:
    """Every shape a method evaluated (in its order) with its FBCPP metrics."""

    method: str
    map_name: str
    thetas: np.ndarray
    P_c: np.ndarray
    P_len: np.ndarray
    feasible: np.ndarray
    evaluations: int
    """FBCPP evaluations the method asked for (repeats included)."""
    wall_s: float
    params: dict[str, Any] = field(default_factory=dict)
    map_digest: str | None = None
    """`Map.digest` of the map searched (None in runs written before it was recorded)."""

    def front(self) -> np.ndarray:
        """Indices of the non-dominated shapes (max P_c, min P_len), sorted by P_len."""
        ok = np.flatnonzero(self.feasible)
        return ok[pareto_front(self.P_c[ok], self.P_len[ok])]

    def best(self, weights: Weights) -> int:
        """Index of the best R1 (the first among ties)."""
        scores = np.where(self.feasible, weights.r1(self.P_c, self.P_len), -np.inf)
        return int(np.argmax(scores))

    def front_records(self, weights: Weights) -> list[dict[str, Any]]:
        """The front as JSON-ready rows: theta, P_c, P_len, R1."""
        return [
            {
                "theta": [float(t) for t in self.thetas[i]],
                "P_c": float(self.P_c[i]),
                "P_len": int(self.P_len[i]),
                "R1": float(weights.r1(self.P_c[i], self.P_len[i])),
            }
            for i in self.front()
        ]


def save(result: SearchResult, run_dir: Path, weights: Weights, best_extra: dict[str, float] | None = None
         ) -> dict[str, Path]:  # fmt: skip
    """results.npz (every evaluation, compressed), front.csv and summary.json (its best shape with `best_extra`:
    the free floor it covers, its coverable bound); returns the paths."""
    files = {"results": run_dir / RESULTS_FILE, "front": run_dir / "front.csv", "summary": run_dir / "summary.json"}
    arrays = {"thetas": result.thetas.astype(np.float32), "P_c": result.P_c, "P_len": result.P_len.astype(np.int32),
              "feasible": result.feasible}  # fmt: skip
    write_atomic(files["results"], _npz(arrays))  # a reader never sees half an archive
    front = result.front_records(weights)
    with atomic_text(files["front"]) as fh:
        writer = csv.writer(fh)
        writer.writerow(["theta1", "theta2", "theta3", "P_c", "P_len", "R1"])
        for row in front:
            writer.writerow([*(f"{t:g}" for t in row["theta"]), f"{row['P_c']:.4f}", row["P_len"], f"{row['R1']:.4f}"])
    b = result.best(weights)
    summary = {
        "method": result.method,
        "map": result.map_name,
        **({} if result.map_digest is None else {"map_digest": result.map_digest}),
        "params": result.params,
        "evaluations": result.evaluations,
        "rows": len(result.thetas),
        "distinct_shapes": len(distinct_rows(result)),
        "wall_s": round(result.wall_s, 3),
        "weights": {"w1": weights.w1, "w2": weights.w2},
        "best": {"theta": [float(t) for t in result.thetas[b]], "P_c": float(result.P_c[b]),
                 "P_len": int(result.P_len[b]), "R1": float(weights.r1(result.P_c[b], result.P_len[b])),
                 **(best_extra or {})},
        "front_size": len(front),
    }  # fmt: skip
    write_text_atomic(files["summary"], jsontext.dumps(summary, indent=2))
    return files


REPEATING = ("random", "nsga2")
"""The methods whose rows may hold a shape twice (a random draw repeated, an NSGA-II child equal to a parent): every
other keeps one row a shape (a local search scores a shape once; exhaustive and optimum, a lattice)."""


def distinct_rows(result: SearchResult) -> np.ndarray:
    """The row of each different shape `result` scored, its first (every row, but for the methods that repeat)."""
    if result.method not in REPEATING or len(result.thetas) == 0:
        return np.arange(len(result.thetas))
    return np.sort(np.unique(np.asarray(result.thetas, dtype=np.float64), axis=0, return_index=True)[1])


def _npz(arrays: dict[str, np.ndarray]) -> bytes:
    """An .npz archive (what np.load reads) deflated at level 1: for the 5.9 million rows of a 1-degree
    exhaustive, 1 s and 27 MB against np.savez_compressed's 4.6 s and 21 MB."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, array in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(array), allow_pickle=False)
    return buffer.getvalue()


def check_archive(path: Path, rows: Any) -> None:
    """Refuse (ValueError) a results archive that would unpack to more than `rows` shapes hold, before numpy
    allocates anything: packed otherwise than `save` packs it, or its entries' sizes or arrays' headers beyond."""
    header_readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    with zipfile.ZipFile(path) as archive:
        entries = archive.infolist()
        if any(info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED) for info in entries):
            raise ValueError("its arrays are packed otherwise than `save` packs them (stored or deflated)")
        inflated = sum(info.file_size for info in entries)
        if not (isinstance(rows, int) and 0 <= rows <= MAX_EVALUATIONS and inflated <= 32 * rows + (1 << 16)):
            raise ValueError(f"its arrays unpack to {inflated:,} bytes, more than its summary's {rows!r} shapes hold")
        packed = path.stat().st_size
        if inflated > max(MAX_INFLATION * packed, 1 << 20):  # a summary may claim any count: the file's own size too
            raise ValueError(f"its arrays unpack to {inflated:,} bytes from {packed:,}: more than {MAX_INFLATION}x, "
                             "which no search's figures compress to")  # fmt: skip
        for info in entries:
            with archive.open(info) as member:
                read = header_readers.get(np.lib.format.read_magic(member))  # `save` writes 1.0 (2.0: long headers)
                if read is None:
                    raise ValueError(f"{info.filename} is not an array of the formats `save` writes")
                shape = read(member)[0]
            if math.prod(shape) > 3 * rows:
                raise ValueError(f"{info.filename} declares {math.prod(shape):,} values for {rows:,} shapes")


def _on_lattice(thetas: np.ndarray, step: Any) -> np.ndarray:
    """`thetas` as float64; those of a lattice search (its `step`) as the lattice's own angles. The file holds float32,
    which for a step such as 0.9 or 180/31 rounds a few shapes onto another footprint: planned again, they scored
    otherwise than recorded, and `compare` took the run for a hand-edited one."""
    wide = thetas.astype(np.float64)
    try:
        step = check_step(float(step)) if isinstance(step, int | float) and not isinstance(step, bool) else None
    except (SmorphiError, OverflowError):
        step = None
    if step is None or 180 / step > 10_000:  # no lattice, or one finer than any search holds
        return wide
    snapped = nearest_on_lattice(wide, step)
    return snapped if np.abs(snapped - wide).max() <= LATTICE_TOLERANCE_DEG else wide


def load(run_dir: str | Path) -> SearchResult:
    """A search run written by `save` (for `compare`), checked: a summary of the right types, arrays of one length
    with finite angles in [0, 180], coverage in [0, 100] and non-negative path lengths."""
    from smorphi_rl.inputs import is_finite_number, read_json_object

    root = Path(run_dir)

    def bad(why: str) -> SmorphiError:
        return SmorphiError(f"{root}: holds no readable search results ({why})")

    try:
        summary = read_json_object(root / "summary.json", "search summary")
        rows = summary.get("rows", summary.get("distinct_shapes", summary.get("evaluations")))  # older: no "rows"
        check_archive(root / RESULTS_FILE, rows)
        with np.load(root / RESULTS_FILE, allow_pickle=False) as data:
            arrays = {k: data[k] for k in ("thetas", "P_c", "P_len", "feasible")}
    except SmorphiError as exc:
        raise bad(str(exc).removeprefix(f"{root / 'summary.json'}: ")) from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # missing, cut short, not ours
        raise bad(f"{type(exc).__name__}: {exc}") from None
    fields = {"method": str, "map": str, "evaluations": int, "wall_s": int | float}
    for key, kind in fields.items():
        if not isinstance(summary.get(key), kind) or isinstance(summary.get(key), bool):
            raise bad(f"summary '{key}' is {summary.get(key)!r}")
    if not 0 <= summary["evaluations"] <= MAX_EVALUATIONS or not (
        is_finite_number(summary["wall_s"]) and 0 <= summary["wall_s"] <= MAX_WALL_S
    ):
        shown = ", ".join(f"'{k}' {str(summary[k])[:16]}" for k in ("evaluations", "wall_s"))
        raise bad(f"summary {shown}: out of range")
    if not isinstance(summary.get("params", {}), dict):
        raise bad("summary 'params' is not a table")
    thetas, p_c, p_len, feasible = (np.asarray(arrays[k]) for k in ("thetas", "P_c", "P_len", "feasible"))
    n = thetas.shape[0] if thetas.ndim == 2 else -1
    if thetas.ndim != 2 or thetas.shape[1] != 3 or any(a.shape != (n,) for a in (p_c, p_len, feasible)):
        raise bad("arrays of mismatched shapes")
    if n == 0:
        raise bad("no shapes")
    numeric = all(a.dtype.kind in "biuf" for a in (thetas, p_c, p_len, feasible))
    if not numeric or not (np.isfinite(thetas).all() and np.isfinite(p_c).all() and np.isfinite(p_len).all()):
        raise bad("values that are not finite numbers")
    if (
        (thetas < 0).any()
        or (thetas > 180).any()
        or (p_c < 0).any()
        or (p_c > 100).any()
        or (p_len < 0).any()
        or (p_len > MAX_P_LEN).any()
    ):
        raise bad(f"angles, coverage or path lengths out of range (path lengths 0..{MAX_P_LEN:,} tile moves)")
    params = summary.get("params", {})
    if summary["method"] == "exhaustive":
        step = params.get("step_deg")
        try:
            whole = isinstance(step, int | float) and check_step(float(step)) > 0
        except (SmorphiError, OverflowError):  # OverflowError: an integer of hundreds of digits
            whole = False
        if not whole or n != lattice_size(step):
            raise bad(f"an exhaustive run whose step {step!r} does not divide 180 or does not match its {n:,} shapes")
    return SearchResult(
        summary["method"], summary["map"], _on_lattice(thetas, params.get("step_deg")), p_c.astype(np.float64),
        p_len.astype(np.int64),
        feasible.astype(bool), int(summary["evaluations"]), float(summary["wall_s"]), summary.get("params", {}),
        digest if isinstance(digest := summary.get("map_digest"), str) else None,
    )  # fmt: skip

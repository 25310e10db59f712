"""`evaluate`: FBCPP on one shape or a file of them."""

from __future__ import annotations

import argparse
import csv
import math
import stat
import sys
import warnings
from array import array
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl import jsontext
from smorphi_rl.cli.common import (
    DEFAULT_MAP,
    clipped,
    number,
    planner_option,
    say_warnings,
    start_option,
    weight_options,
    weights,
)
from smorphi_rl.cli.fields import finite_arg, option
from smorphi_rl.coverage import AUTO_START, CoverageResult, Planner, Start
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.geometry import Morphology, angles_text, check_block_side
from smorphi_rl.inputs import FORCE_HELP, output_file
from smorphi_rl.maps import Cell, Map, load_map, map_inputs
from smorphi_rl.progress import progress_line
from smorphi_rl.score import Weights


def register(sub: Any) -> None:
    """Add `evaluate` to the command line."""
    ev = sub.add_parser("evaluate", help="coverage (P_c) and path length (P_len) of morphologies on a map")
    ev.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
    which = ev.add_one_of(required=True)  # neither, or both: a usage error (exit 2)
    which.add_argument("--angles", nargs=3, type=finite_arg, metavar=("T1", "T2", "T3"),
                       help="hinge angles in degrees, each 0-180")  # fmt: skip
    which.add_argument("--angles-file", help="CSV of t1,t2,t3 rows (optional header): evaluate them all")
    ev.add_argument("--json", action="store_true", help="print JSON (one object per morphology, one per line)")
    ev.add_argument("--plot", help="write a PNG of the footprint, covered area and path")
    ev.add_argument("--force", action="store_true", help=FORCE_HELP)
    option(ev, EnvConfig, "block_side_m", "--block-side", metavar="M")
    where = ev.add_one_of()
    where.add_argument("--start", help="start tile 'tile:A,B' (paper planner) or free point 'xy:X,Y' in metres "
                       "(default: paper, the first traversable tile; fit, in the largest free area)")  # fmt: skip
    start_option(where)  # --start-xy X Y, as `search`, `design`, `train` and their warnings spell it
    planner_option(ev, start=False)
    weight_options(ev)
    ev.add_argument("--path", action="store_true",
                    help="with --json: add F ('footprint', rows of 0/1, row 0 the lowest y) and 'placements' (the "
                         "cell [row, col] of F's corner at every tile of the path, in order; between two, the "
                         "straight move)")  # fmt: skip
    ev.set_defaults(func=cmd_evaluate)


MAX_ANGLES_FILE_BYTES = 100_000_000
"""The largest angles file `evaluate --angles-file` reads."""
MAX_ANGLES_LINE = 1_000
"""The longest line of an angles file (a row of three angles is a few dozen characters): one line of 10 MB was
split whole to look for a header (6 s, 300 MB) and shown whole in its refusal."""


def read_angles_file(path: Path) -> np.ndarray:
    """(N, 3) angles from a CSV file of three columns with an optional header row.

    numpy reads well-formed files fast; anything it refuses is re-read row by row to name the line. Only a
    regular file of at most MAX_ANGLES_FILE_BYTES is read (a device or a pipe would never end)."""
    try:
        info = path.stat()
    except FileNotFoundError:
        raise SmorphiError(f"angles file not found: {path}") from None
    except OSError as exc:
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    if not stat.S_ISREG(info.st_mode):
        raise SmorphiError(f"{path}: not a regular file (give a CSV file of three angle columns)")
    if info.st_size > MAX_ANGLES_FILE_BYTES:
        raise SmorphiError(f"{path}: {info.st_size:,} bytes; an angles file is at most {MAX_ANGLES_FILE_BYTES:,} "
                           "(about 4 million rows)")  # fmt: skip
    try:
        with path.open(encoding="utf-8-sig") as fh:  # a spreadsheet's byte-order mark is not part of row 1
            first = fh.readline(MAX_ANGLES_LINE + 2).rstrip("\r\n")
        header = int(len(first) <= MAX_ANGLES_LINE and _is_header(first.split(",")))
        with warnings.catch_warnings(), path.open(encoding="utf-8-sig") as fh:
            warnings.simplefilter("ignore")  # an empty file: reported below, with its name
            values = np.loadtxt(fh, delimiter=",", skiprows=header, ndmin=2, dtype=np.float64)
        in_range = np.isfinite(values).all() and (values >= 0).all() and (values <= 180).all()
        if values.shape[0] > 0 and values.shape[1] == 3 and in_range:
            return values  # anything else is re-read row by row below, to name the file and line
    except (ValueError, UnicodeDecodeError):
        pass
    except OSError as exc:  # a missing file is named by the stat above
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    return _read_angles_rows(path)


def _read_angles_rows(path: Path) -> np.ndarray:
    """The slow, exact reading of an angles file: the first bad line is named. Row by row into an array of floats
    (24 bytes a shape): held as lists of strings first, a 10 MB file took 430 MB."""
    values, first = array("d"), True
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            for n, row in enumerate(csv.reader(_short_lines(path, fh)), start=1):
                if not any(c.strip() for c in row):
                    continue
                header, first = first and _is_header(row), False
                if not header:
                    values.extend(_angles_row(path, n, row))
    except FileNotFoundError:
        raise SmorphiError(f"angles file not found: {path}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    if not values:
        raise SmorphiError(f"{path}: no angles in the file (expected rows of t1,t2,t3)")
    return np.array(values, dtype=float).reshape(-1, 3)


def _short_lines(path: Path, lines: Iterable[str]) -> Iterator[str]:
    """`lines`, refused at the first longer than MAX_ANGLES_LINE before the CSV reader splits it."""
    for n, line in enumerate(lines, start=1):
        if (size := len(line.rstrip("\r\n"))) > MAX_ANGLES_LINE:
            raise SmorphiError(f"{path} line {n}: {size:,} characters, where a row of three angles t1,t2,t3 "
                               f"takes a few dozen (at most {MAX_ANGLES_LINE:,})")  # fmt: skip
        yield line


def _angles_row(path: Path, n: int, row: list[str]) -> list[float]:
    """Line `n` of an angles file as three angles in 0-180, or one line naming what is wrong with it."""
    cells = [c.strip() for c in row]
    if len(cells) != 3 or not _is_numeric_row(cells):
        raise SmorphiError(f"{path} line {n}: expected three numbers t1,t2,t3, got {clipped(repr(','.join(row)))}")
    angles = [float(c) for c in cells]
    for j, v in enumerate(angles):
        if not 0 <= v <= 180:
            raise SmorphiError(f"{path} line {n}: hinge angle t{j + 1}={v:g} is outside [0, 180] degrees")
    return angles


def _is_numeric_row(row: Sequence[str]) -> bool:
    try:
        return all(math.isfinite(float(c)) for c in row)
    except ValueError:
        return False


def _is_header(cells: Sequence[str]) -> bool:
    """A first row of words and no number (`t1,t2,t3`); a row with a NaN, an infinity or `90;90;90` is data, and
    refused with its line, as on any other line (the fast reading once skipped it as a header)."""
    return not any(_is_number(c) for c in cells) and any(ch.isalpha() for c in cells for ch in c)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


EMPTY_START = "--start: give tile:A,B or xy:X,Y (or leave the option out for the planner's default)"
"""The line for an empty --start (checked before the map is read, and by `parse_start`)."""


def parse_start(text: str | None, grid_map: Map) -> Start:
    """--start tile:A,B (a tile of the resized map) or xy:X,Y (a free point, metres)."""
    if text is None:
        return Start()
    if not text.strip():
        raise SmorphiError(EMPTY_START)
    kind, _, rest = text.partition(":")
    parts = rest.split(",")
    if kind not in ("tile", "xy") or len(parts) != 2:
        raise SmorphiError(f"--start {text!r}: use tile:A,B or xy:X,Y")
    if kind == "tile":
        try:
            a, b = int(parts[0]), int(parts[1])
        except ValueError:
            raise SmorphiError(f"--start {text!r}: tile indices must be integers") from None
        if a < 0 or b < 0:
            raise SmorphiError(f"--start {text!r}: tile indices count from 0")
        if max(a, b) >= grid_map.height * grid_map.width:  # beyond any tile grid (and any int64 the planner takes)
            raise SmorphiError(f"--start {text!r}: tile indices outside the map ({grid_map.width} x "
                               f"{grid_map.height} cells)")  # fmt: skip
        return Start.tile(a, b)
    x, y = (number(p, "--start coordinate") for p in parts)
    return Start.point(grid_map, x, y)


FILE_CHUNK = 50_000
"""An angles file is planned and written this many rows at a time (progress on stderr past one chunk)."""


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate one morphology (or a file of them) with FBCPP on a map."""
    start_spec = args.start  # --start-xy X Y is --start xy:X,Y
    if args.start_xy is not None:
        start_spec = f"xy:{args.start_xy[0]!r},{args.start_xy[1]!r}"
    if start_spec is not None and not start_spec.strip():
        raise SmorphiError(EMPTY_START)
    if args.angles_file is not None and args.plot is not None:
        raise SmorphiError("--plot draws one morphology: use it with --angles")
    if args.path and not (args.json and args.angles):
        raise SmorphiError("--path adds the plan to --json output of one morphology: use it with --angles and --json")
    if not args.block_side > 0:
        raise SmorphiError(f"--block-side must be > 0 m, got {args.block_side}")
    plot_file = None
    if args.plot is not None:
        inputs = map_inputs(args.map) + ((Path(args.angles_file),) if args.angles_file else ())
        plot_file = str(output_file(args.plot, "--plot", (".png",), inputs, args.force))
    if args.angles_file == "":
        raise SmorphiError("--angles-file: give the path of a CSV of t1,t2,t3 rows")
    thetas = read_angles_file(Path(args.angles_file)) if args.angles_file is not None else None
    morphology = Morphology.of(tuple(args.angles)) if args.angles else None  # finite numbers (argparse)
    grid_map = load_map(args.map)
    score = weights(args).weights_on(grid_map)  # R1, as search, design and train rank shapes
    from smorphi_rl.maps import check_fits

    check_fits(grid_map, args.block_side, whole_footprint=args.planner == Planner.FIT.value)  # it holds a robot
    say_warnings(grid_map)  # on stderr: --json's stdout stays one object a line
    if thetas is not None:
        from smorphi_rl.interrupts import stop_requests

        # a stop waits for the chunk under way: raised inside the compiled planner's loading or a kernel's return, it
        # crashed the process (a segmentation fault) or was dropped
        with stop_requests(again=True) as stop:
            from smorphi_rl.planning import Evaluator

            evaluator = Evaluator(grid_map, block_side_m=args.block_side, start=parse_start(start_spec, grid_map),
                                  planner=Planner(args.planner))  # fmt: skip
            if not args.json:
                sys.stdout.write("t1,t2,t3,P_c,coverage_free_pct,P_len,path_length_m,feasible,footprint_l,footprint_w,"
                                 "R1\n")  # fmt: skip
            show = progress_line("evaluate: shapes") if len(thetas) > FILE_CHUNK else None
            formula = score.formula()
            for lo in range(0, len(thetas), FILE_CHUNK):  # written as planned: a long file shows progress and streams
                batch = evaluator.evaluate_many(thetas[lo : lo + FILE_CHUNK])
                if args.json:
                    scored = [
                        r | {"R1": float(score.r1(r["P_c"], r["P_len"])), "weights": formula} for r in batch.records()
                    ]
                    lines = [jsontext.dumps(r) for r in scored]
                else:
                    lines = [_csv_row(r, score) for r in batch]
                sys.stdout.write("\n".join(lines) + "\n")
                if show is not None:
                    show(min(lo + FILE_CHUNK, len(thetas)), len(thetas))
                if stop.is_set():  # the last chunk's too: a stop is never lost
                    done = f"{min(lo + FILE_CHUNK, len(thetas)):,} of {len(thetas):,}"
                    raise Interrupted(f"after {done} shapes, whose rows are written whole")
        return 0
    if morphology is None:  # unreachable: exactly one of --angles / --angles-file was given
        raise SmorphiError("give --angles T1 T2 T3")
    return _one_shape(args, grid_map, morphology, score, start_spec, plot_file)


def _one_shape(args: argparse.Namespace, grid_map: Map, morphology: Morphology, score: Weights,
               start_spec: str | None, plot_file: str | None) -> int:  # fmt: skip
    """Report one shape, planned from `start_spec` (`--start`'s form) and drawn to `plot_file` (a checked path).
    Without a plot, a path or a chosen start, a small map is planned in plain Python
    (`coverage_reference.quick_result`, equal to the kernels by test), so the answer skips numba's start-up."""
    planner = Planner(args.planner)
    check_block_side(args.block_side, grid_map.resolution_m)
    result: CoverageResult | None = None
    if not (plot_file or args.path or start_spec):
        from smorphi_rl.coverage_reference import largest_free_area_pct, quick_result

        result = quick_result(grid_map, morphology, args.block_side, planner)
        start = AUTO_START
        area_pct = largest_free_area_pct(grid_map) if result is not None and planner is Planner.FIT else 0.0
    if result is None:
        from smorphi_rl.planning import Evaluator

        evaluator = Evaluator(grid_map, block_side_m=args.block_side, start=parse_start(start_spec, grid_map),
                              planner=planner)  # fmt: skip
        start, prepared = evaluator.start, evaluator.prepared
        area_pct = 100 * prepared.n_area / max(prepared.n_free, 1)
        fit = planner is Planner.FIT
        result = evaluator.plan(morphology) if plot_file or args.path or fit else evaluator.evaluate(morphology)
    if planner is Planner.FIT and result.feasible and result.placements is not None and not len(result.placements):
        where = "fits nowhere on" if start.kind == 0 else f"does not fit at {start.describe()} on"
        l, w = result.footprint_cells
        raise SmorphiError(f"shape {angles_text(morphology.angles)}: its footprint ({l} x {w} cells) {where} map "
                           f"{grid_map.name} without touching an occupied, unknown or outside cell")  # fmt: skip
    plot_path = None
    if plot_file:
        from smorphi_rl.plots import plot_coverage

        plot_path = plot_coverage(result, grid_map, morphology, args.block_side, plot_file)
    from smorphi_rl.score import swamped_warning

    swamped = swamped_warning(score, result.P_c, result.P_len, weights(args).path_term, grid_map.name, "its")
    if swamped:  # on stderr: --json's stdout stays one object
        print(swamped, file=sys.stderr)
    if args.json:
        record = result.to_dict() | {"R1": float(score.r1(result.P_c, result.P_len)), "weights": score.formula()}
        if plot_path is not None:  # as design's --json names its plot
            record["plot"] = str(plot_path)
        if args.path:
            record["footprint"] = [] if result.footprint is None else result.footprint.astype(int).tolist()
            record["placements"] = [] if result.placements is None else result.placements.tolist()
        print(jsontext.dumps(record))
        return 0
    print(format_result(result, grid_map, start_text(start, area_pct, result), plot_path, score))
    return 0


def start_text(start: Start, area_pct: float, result: CoverageResult) -> str:
    """Where the plan starts, as the report says it (the fit planner names the area and the placement)."""
    if result.planner != Planner.FIT.value:
        return str(start.describe())
    where = f"the largest free area ({area_pct:.1f} % of the free cells)" if start.kind == 0 else start.describe()
    if result.placements is None or not len(result.placements):
        return f"{where}: no safe position for this footprint, nothing covered"
    row, col = (int(v) for v in result.placements[0])
    return f"{where}, F's corner on cell ({row}, {col})"


def _csv_row(r: CoverageResult, score: Weights) -> str:
    theta = [f"{t:g}" for t in r.theta]
    fields = [*theta, f"{r.P_c:.6f}", f"{r.coverage_free_pct:.6f}", r.P_len, f"{r.path_length_m:.4f}"]
    return ",".join(str(v) for v in [*fields, int(r.feasible), *r.footprint_cells, f"{score.r1(r.P_c, r.P_len):.6f}"])


def format_result(result: CoverageResult, grid_map: Map, start: str, plot_path: Path | None, score: Weights) -> str:
    """The human-readable report of one evaluation."""
    pct = {c: 100 * grid_map.fraction(c) for c in Cell}
    l, w = result.footprint_cells
    size = f"{grid_map.width} x {grid_map.height} cells at {grid_map.resolution_m:g} m"
    fractions = ", ".join(f"{c.name.lower()} {pct[c]:.1f} %" for c in Cell)
    rows = [
        ("map", f"{grid_map.name} ({size}; {fractions})"),
        ("theta", f"{angles_text(result.theta)} deg"),
        ("feasible", "yes" if result.feasible else "no: blocks overlap, metrics are 0"),
        ("footprint", f"{result.footprint_m[0]:.3f} x {result.footprint_m[1]:.3f} m (w x l), F {l} x {w} cells"),
        ("planner", result.planner),
        ("start", start),
        ("P_c", f"{result.P_c:.4f} % " + ("(covered free cells over all free cells)" if result.planner == "fit"
                                          else "(covered + obstacle cells over all known cells)")),
        ("coverage", f"{result.coverage_free_pct:.4f} % of free cells"),
        ("coverable", f"{result.coverable_pct:.4f} % of free cells (every safe position the start reaches)"
                      if result.planner == "fit" else "every reachable tile (the paper's planner covers them all)"),
        ("P_len", f"{result.P_len} tile moves"),
        ("path length", f"{result.path_length_m:.2f} m ({result.path_length_cells} cells)"),
        ("R1", f"{score.r1(result.P_c, result.P_len):.4f} ({score.formula()})"),
    ]  # fmt: skip
    if plot_path is not None:
        rows.append(("plot", str(plot_path)))
    return "\n".join(f"{k:<12} {v}" for k, v in rows)

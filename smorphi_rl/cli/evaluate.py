"""`evaluate` (FBCPP on one shape or a file of them) and `maps generate|show`."""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.cli.common import DEFAULT_LOG_DIR, DEFAULT_MAP, Parser, number, planner_option, seed_arg
from smorphi_rl.cli.fields import option, param_default
from smorphi_rl.coverage import AUTO_START, CoverageResult, Planner, Start
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.floorplans import FloorKind
from smorphi_rl.geometry import Morphology, angles_text, check_block_side
from smorphi_rl.inputs import finite, output_file
from smorphi_rl.maps import Cell, Map, generate_map, load_map, map_inputs


def register(sub: Any) -> None:
    """Add `evaluate` and `maps` to the command line."""
    ev = sub.add_parser("evaluate", help="coverage (P_c) and path length (P_len) of morphologies on a map")
    ev.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
    ev.add_argument("--angles", nargs=3, metavar=("T1", "T2", "T3"), help="hinge angles in degrees, each 0-180")
    ev.add_argument("--angles-file", help="CSV of t1,t2,t3 rows (optional header): evaluate them all")
    ev.add_argument("--json", action="store_true", help="print JSON (one object per morphology, one per line)")
    ev.add_argument("--plot", help="write a PNG of the footprint, covered area and path")
    option(ev, EnvConfig, "block_side_m", "--block-side", metavar="M")
    ev.add_argument("--start", help="start tile 'tile:A,B' (paper planner) or free point 'xy:X,Y' in metres "
                    "(default: paper, the first traversable tile; fit, in the largest free area)")  # fmt: skip
    planner_option(ev, start=False)
    ev.add_argument("--path", action="store_true",
                    help="with --json: add F ('footprint', rows of 0/1, row 0 the lowest y) and 'placements' (the "
                    "cell [row, col] of F's corner at every robot position along the path)")  # fmt: skip
    ev.set_defaults(func=cmd_evaluate)

    maps = sub.add_parser("maps", help="generate or inspect maps")
    maps_sub = maps.add_subparsers(dest="maps_command", required=True, parser_class=Parser)
    gen = maps_sub.add_parser("generate", help="write a map of rectangular obstacles, or a set of floor plans")
    gen.add_argument("--out", required=True, help="YAML path to write (image written beside it); with --kind, the "
                     "folder the set goes to")  # fmt: skip
    gen.add_argument("--kind", choices=[k.value for k in FloorKind], help="write a set of seeded indoor floor plans "
                     "of this kind (smorphi_rl/floorplans.py): rooms, corridor, hall, furniture or mixed")  # fmt: skip
    gen.add_argument("--count", type=int, default=1, metavar="N", help="with --kind: floors to write, seeds S, "
                     "S+1, ... (default 1)")  # fmt: skip
    for flag, param, text in (("--width-m", "width_m", "metres"), ("--height-m", "height_m", "metres"),
                              ("--resolution", "resolution_m", "metres per cell"),
                              ("--density", "obstacle_density", "target fraction of occupied cells")):  # fmt: skip
        default = param_default(generate_map, param)
        gen.add_argument(flag, type=finite, default=default, help=f"{text} (default: {default:g})")
    gen.add_argument("--seed", type=seed_arg, default=0)
    gen.add_argument("--format", choices=("pgm", "png"), default="pgm")
    gen.add_argument("--force", action="store_true", help="overwrite an existing map")
    gen.set_defaults(func=cmd_maps_generate)
    show = maps_sub.add_parser("show", help="print a map's size and fractions and draw it")
    show.add_argument("map", help="map_server YAML")
    show.add_argument("--png", help="where to draw it (default: logs/maps/NAME.png)")
    show.set_defaults(func=cmd_maps_show)
    crop = maps_sub.add_parser("crop", help="cut a map to its recorded (known) area or to a rectangle")
    crop.add_argument(
        "--rect",
        nargs=4,
        type=finite,
        metavar=("X0", "Y0", "X1", "Y1"),
        help="keep this rectangle, metres in the map frame (default: the known cells and a margin)",
    )
    crop.add_argument("--margin", type=finite, default=0.2, metavar="M",
                      help="metres kept around the known cells (default 0.2)")  # fmt: skip
    resample = maps_sub.add_parser("resample", help="coarsen a map to a whole multiple of its resolution")
    resample.add_argument("--resolution", type=finite, required=True, metavar="R",
                          help="metres a cell; a coarse cell is free only if every cell under it is")  # fmt: skip
    for tool, run in ((crop, cmd_maps_crop), (resample, cmd_maps_resample)):
        tool.add_argument("map", help="map_server YAML to read (left as it is)")
        tool.add_argument("--out", required=True, help="YAML path to write (image written beside it)")
        tool.add_argument(
            "--min-island",
            type=finite,
            default=0.0,
            metavar="M2",
            help="also drop free areas smaller than this many square metres (default 0: keep all)",
        )
        tool.add_argument("--force", action="store_true", help="overwrite an existing map")
        tool.set_defaults(func=run)


def parse_angles(values: Sequence[str]) -> tuple[float, float, float]:
    """Three hinge angles from the command line, each a number in [0, 180]."""
    t1, t2, t3 = (number(v, f"hinge angle t{i + 1}") for i, v in enumerate(values))
    return (t1, t2, t3)


def read_angles_file(path: Path) -> np.ndarray:
    """(N, 3) angles from a CSV file of three columns with an optional header row.

    numpy reads well-formed files fast; anything it refuses is re-read row by row to name the line."""
    try:
        with path.open(encoding="utf-8-sig") as fh:  # a spreadsheet's byte-order mark is not part of row 1
            first = fh.readline()
        header = 0 if _is_numeric_row(first.split(",")) else 1
        with warnings.catch_warnings(), path.open(encoding="utf-8-sig") as fh:
            warnings.simplefilter("ignore")  # an empty file: reported below, with its name
            values = np.loadtxt(fh, delimiter=",", skiprows=header, ndmin=2, dtype=np.float64)
        in_range = np.isfinite(values).all() and (values >= 0).all() and (values <= 180).all()
        if values.shape[0] > 0 and values.shape[1] == 3 and in_range:
            return values  # anything else is re-read row by row below, to name the file and line
    except (ValueError, UnicodeDecodeError):
        pass
    except FileNotFoundError:
        raise SmorphiError(f"angles file not found: {path}") from None
    except OSError as exc:
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    return _read_angles_rows(path)


def _read_angles_rows(path: Path) -> np.ndarray:
    """The slow, exact reading of an angles file: the first bad line is named."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = [(n, row) for n, row in enumerate(csv.reader(fh), start=1) if any(c.strip() for c in row)]
    except FileNotFoundError:
        raise SmorphiError(f"angles file not found: {path}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    if rows and not _is_numeric_row(rows[0][1]):
        rows = rows[1:]  # header
    if not rows:
        raise SmorphiError(f"{path}: no angles in the file (expected rows of t1,t2,t3)")
    out = np.empty((len(rows), 3))
    for i, (n, row) in enumerate(rows):
        cells = [c.strip() for c in row]
        if len(cells) != 3 or not _is_numeric_row(cells):
            raise SmorphiError(f"{path} line {n}: expected three numbers t1,t2,t3, got {','.join(row)!r}")
        out[i] = [float(c) for c in cells]
        for j, v in enumerate(out[i]):
            if not 0 <= v <= 180:
                raise SmorphiError(f"{path} line {n}: hinge angle t{j + 1}={v:g} is outside [0, 180] degrees")
    return out


def _is_numeric_row(row: Sequence[str]) -> bool:
    try:
        return all(math.isfinite(float(c)) for c in row)
    except ValueError:
        return False


def parse_start(text: str | None, grid_map: Map) -> Start:
    """--start tile:A,B (a tile of the resized map) or xy:X,Y (a free point, metres)."""
    if text is None:
        return Start()
    kind, _, rest = text.partition(":")
    parts = rest.split(",")
    if kind not in ("tile", "xy") or len(parts) != 2:
        raise SmorphiError(f"--start {text!r}: use tile:A,B or xy:X,Y")
    if kind == "tile":
        try:
            return Start.tile(int(parts[0]), int(parts[1]))
        except ValueError:
            raise SmorphiError(f"--start {text!r}: tile indices must be integers") from None
    x, y = (number(p, "--start coordinate") for p in parts)
    return Start.point(grid_map, x, y)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate one morphology (or a file of them) with FBCPP on a map."""
    if (args.angles is None) == (args.angles_file is None):
        raise SmorphiError("give either --angles T1 T2 T3 or --angles-file FILE")
    if args.angles_file is not None and args.plot is not None:
        raise SmorphiError("--plot draws one morphology: use it with --angles")
    if args.path and not (args.json and args.angles):
        raise SmorphiError("--path adds the plan to --json output of one morphology: use it with --angles and --json")
    if not args.block_side > 0:
        raise SmorphiError(f"--block-side must be > 0 m, got {args.block_side}")
    if args.plot is not None:
        inputs = map_inputs(args.map) + ((Path(args.angles_file),) if args.angles_file else ())
        args.plot = str(output_file(args.plot, "--plot", (".png",), inputs))
    thetas = read_angles_file(Path(args.angles_file)) if args.angles_file else None
    morphology = Morphology.of(parse_angles(args.angles)) if args.angles else None
    grid_map = load_map(args.map)
    if thetas is not None:
        from smorphi_rl.evaluate import Evaluator

        evaluator = Evaluator(grid_map, block_side_m=args.block_side, start=parse_start(args.start, grid_map),
                              planner=Planner(args.planner))  # fmt: skip
        batch = evaluator.evaluate_many(thetas)
        if args.json:
            lines = [json.dumps(r) for r in batch.records()]
        else:
            header = "t1,t2,t3,P_c,coverage_free_pct,P_len,path_length_m,feasible,footprint_l,footprint_w"
            lines = [header, *(_csv_row(r) for r in batch)]
        sys.stdout.write("\n".join(lines) + "\n")
        return 0
    if morphology is None:  # unreachable: exactly one of --angles / --angles-file was given
        raise SmorphiError("give --angles T1 T2 T3")
    return _one_shape(args, grid_map, morphology)


def _one_shape(args: argparse.Namespace, grid_map: Map, morphology: Morphology) -> int:
    """Report one shape. Without a plot, a path or a chosen start, a small map is planned in plain Python
    (`coverage_reference.quick_result`, equal to the kernels by test), so the answer skips numba's start-up."""
    planner = Planner(args.planner)
    check_block_side(args.block_side, grid_map.resolution_m)
    result: CoverageResult | None = None
    if not (args.plot or args.path or args.start):
        from smorphi_rl.coverage_reference import largest_free_area_pct, quick_result

        result = quick_result(grid_map, morphology, args.block_side, planner)
        start = AUTO_START
        area_pct = largest_free_area_pct(grid_map) if result is not None and planner is Planner.FIT else 0.0
    if result is None:
        from smorphi_rl.evaluate import Evaluator

        evaluator = Evaluator(grid_map, block_side_m=args.block_side, start=parse_start(args.start, grid_map),
                              planner=planner)  # fmt: skip
        start, prepared = evaluator.start, evaluator.prepared
        area_pct = 100 * prepared.n_area / max(prepared.n_free, 1)
        fit = planner is Planner.FIT
        result = evaluator.plan(morphology) if args.plot or args.path or fit else evaluator.evaluate(morphology)
    if planner is Planner.FIT and result.feasible and result.placements is not None and not len(result.placements):
        where = "nowhere on the map" if start.kind == 0 else f"at {start.describe()}"
        l, w = result.footprint_cells
        raise SmorphiError(f"shape {angles_text(morphology.angles)}: its footprint ({l} x {w} cells) fits {where} "
                           f"{grid_map.name} without touching an occupied, unknown or outside cell")  # fmt: skip
    plot_path = None
    if args.plot:
        from smorphi_rl.plots import plot_coverage

        plot_path = plot_coverage(result, grid_map, morphology, args.block_side, args.plot)
    if args.json:
        record = result.to_dict()
        if args.path:
            record["footprint"] = [] if result.footprint is None else result.footprint.astype(int).tolist()
            record["placements"] = [] if result.placements is None else result.placements.tolist()
        print(json.dumps(record))
        return 0
    print(format_result(result, grid_map, start_text(start, area_pct, result), plot_path))
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


def _csv_row(r: CoverageResult) -> str:
    theta = [f"{t:g}" for t in r.theta]
    fields = [*theta, f"{r.P_c:.6f}", f"{r.coverage_free_pct:.6f}", r.P_len, f"{r.path_length_m:.4f}"]
    return ",".join(str(v) for v in [*fields, int(r.feasible), *r.footprint_cells])


def format_result(result: CoverageResult, grid_map: Map, start: str, plot_path: Path | None) -> str:
    """The human-readable report of one evaluation."""
    pct = {c: 100 * grid_map.fraction(c) for c in Cell}
    theta = ", ".join(f"{t:g}" for t in result.theta)
    l, w = result.footprint_cells
    size = f"{grid_map.width} x {grid_map.height} cells at {grid_map.resolution_m:g} m"
    fractions = ", ".join(f"{c.name.lower()} {pct[c]:.1f} %" for c in Cell)
    rows = [
        ("map", f"{grid_map.name} ({size}; {fractions})"),
        ("theta", f"({theta}) deg"),
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
    ]  # fmt: skip
    if plot_path is not None:
        rows.append(("plot", str(plot_path)))
    return "\n".join(f"{k:<12} {v}" for k, v in rows)


def cmd_maps_generate(args: argparse.Namespace) -> int:
    """Write an indoor-like map of rectangular obstacles, or with --kind a set of floor plans."""
    from smorphi_rl.maps import save_map

    if args.kind is not None:
        return _generate_floors(args)

    out = Path(args.out)
    if out.suffix != ".yaml":
        raise SmorphiError(f"--out {out}: give the map's YAML path, ending in .yaml")
    image = out.with_suffix(f".{args.format}")
    if not args.force and (out.exists() or image.exists()):
        raise SmorphiError(f"{out if out.exists() else image} exists; pass --force to overwrite it")
    rng = np.random.default_rng(args.seed)
    from smorphi_rl.rundir import claimed_files

    grid_map = generate_map(
        rng,
        width_m=args.width_m,
        height_m=args.height_m,
        resolution_m=args.resolution,
        obstacle_density=args.density,
        name=out.stem,
    )
    with claimed_files([out], args.force):  # of two runs writing one map at once, exactly one writes it
        save_map(grid_map, out, image_format=args.format)
    occupied = 100 * grid_map.fraction(Cell.OCCUPIED)
    print(f"wrote {out} and {image}: {grid_map.width} x {grid_map.height} cells at {args.resolution:g} m, "
          f"occupied {occupied:.2f} % (seed {args.seed})")  # fmt: skip
    return 0


MAX_FLOORS = 10_000
"""`maps generate --kind` writes at most this many floors at once."""


def _generate_floors(args: argparse.Namespace) -> int:
    """`maps generate --kind K --count N --seed S --out DIR`: floors K-S .. K-(S+N-1), each a YAML and its image."""
    from smorphi_rl.floorplans import floor_name, generate_floor
    from smorphi_rl.maps import save_map

    if not 1 <= args.count <= MAX_FLOORS:
        raise SmorphiError(f"--count must be in 1..{MAX_FLOORS:,}, got {args.count}")
    if args.seed + args.count > 2**63:
        raise SmorphiError(f"--seed {args.seed} + --count {args.count} passes 2^63, the largest floor seed")
    out = Path(args.out)
    if out.suffix in (".yaml", ".yml") or (out.exists() and not out.is_dir()):
        raise SmorphiError(f"--out {out}: with --kind, give the folder the floors go to")
    names = [floor_name(args.kind, args.seed + i) for i in range(args.count)]
    if not args.force:
        taken = [n for n in names if (out / f"{n}.yaml").exists() or (out / f"{n}.{args.format}").exists()]
        if taken:
            raise SmorphiError(f"{out / taken[0]}.yaml exists ({len(taken)} of the {len(names)} floors do); pass "
                               "--force to overwrite them")  # fmt: skip
    from smorphi_rl.rundir import claimed_files

    cells = 0
    with claimed_files([out / f"{n}.yaml" for n in names], args.force):  # two runs into one folder: one writes
        for i, name in enumerate(names):
            grid_map = generate_floor(args.kind, args.seed + i)
            save_map(grid_map, out / f"{name}.yaml", image_format=args.format)
            cells += grid_map.cells.size
    print(f"wrote {len(names)} {args.kind} floors to {out} (seeds {args.seed}-{args.seed + len(names) - 1}, "
          f"{cells / len(names):,.0f} cells on average)")  # fmt: skip
    return 0


def cmd_maps_crop(args: argparse.Namespace) -> int:
    """Cut a map to its known area (or a rectangle) into a new map_server YAML."""
    from smorphi_rl.maptools import crop_to_known, crop_to_rect

    def crop(source: Map) -> Map:
        return crop_to_known(source, args.margin) if args.rect is None else crop_to_rect(source, *args.rect)

    return _write_prepared(args, crop)


def cmd_maps_resample(args: argparse.Namespace) -> int:
    """Coarsen a map, conservatively, into a new map_server YAML."""
    from smorphi_rl.maptools import resample

    return _write_prepared(args, lambda source: resample(source, args.resolution))


def _write_prepared(args: argparse.Namespace, transform: Any) -> int:
    """Read the map, transform it, drop small islands, write it (never over the input or an existing map
    without --force) and print both maps' sizes."""
    from smorphi_rl.maps import save_map
    from smorphi_rl.maptools import drop_islands

    out = Path(args.out)
    if out.suffix != ".yaml":
        raise SmorphiError(f"--out {out}: give the map's YAML path, ending in .yaml")
    if Path(args.map).resolve() == out.resolve():
        raise SmorphiError(f"--out {out} is the input map: write the new map somewhere else")
    if not args.force and (out.exists() or out.with_suffix(".pgm").exists()):
        raise SmorphiError(f"{out} exists; pass --force to overwrite it")
    if out.with_suffix(".pgm").resolve() in {p.resolve() for p in map_inputs(args.map)}:
        raise SmorphiError(f"--out {out}: its image would replace the input map's image; write it elsewhere")
    source = load_map(args.map)
    grid_map, islands = drop_islands(transform(source), args.min_island)
    from smorphi_rl.rundir import claimed_files

    with claimed_files([out], args.force):
        save_map(grid_map, out)

    def size(m: Map) -> str:
        r = m.resolution_m
        free = 100 * m.fraction(Cell.FREE)
        return f"{m.width} x {m.height} cells at {r:g} m ({m.width * r:g} x {m.height * r:g} m), {free:.1f} % free"

    print(f"{'read':<8} {args.map}: {size(source)}")
    print(f"{'wrote':<8} {out}: {size(grid_map)}")
    print(f"{'islands':<8} {islands.count} dropped ({islands.area_m2:.2f} m^2 of free floor marked unknown)")
    return 0


def cmd_maps_show(args: argparse.Namespace) -> int:
    """Print a map's size and cell fractions, and draw it."""
    from smorphi_rl.plots import plot_map

    if args.png is not None:
        output_file(args.png, "--png", (".png",), map_inputs(args.map))
    grid_map = load_map(args.map)
    png = Path(args.png) if args.png else Path(DEFAULT_LOG_DIR) / "maps" / f"{grid_map.name}.png"
    r = grid_map.resolution_m
    rows = [
        ("map", f"{args.map}"),
        ("size", f"{grid_map.width} x {grid_map.height} cells, {grid_map.width * r:g} x {grid_map.height * r:g} m"),
        ("resolution", f"{r:g} m/cell"),
        ("origin", ", ".join(f"{v:g}" for v in grid_map.origin)),
        *((c.name.lower(), f"{100 * grid_map.fraction(c):.2f} % ({grid_map.counts[c]} cells)") for c in Cell),
        ("png", str(plot_map(grid_map, png))),
    ]
    print("\n".join(f"{k:<11} {v}" for k, v in rows))
    return 0

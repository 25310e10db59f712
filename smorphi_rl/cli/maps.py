"""`maps generate|show|crop|resample`: write floors, look at them, cut and coarsen real maps."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.cli.common import DEFAULT_LOG_DIR, Parser, name_choices, one_line, say_warnings, seed_arg
from smorphi_rl.cli.fields import finite_arg, param_default
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.floorplans import FloorKind
from smorphi_rl.inputs import FORCE_HELP, MAX_SEED, output_file, resolved
from smorphi_rl.maps import Cell, Map, generate_map, load_map, map_inputs, obstacle_target

PROGRESS_FROM_CELLS = 1_000_000
"""`maps generate` shows its progress on maps of more cells than this (a few seconds' work)."""

CROP_MARGIN_M = 0.2
"""`maps crop`'s margin around the known cells, metres."""


def register(sub: Any) -> None:
    """Add `maps` and its subcommands to the command line."""
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
        gen.add_argument(flag, type=finite_arg, default=default, help=f"{text} (default: {default:g})")
    gen.add_argument("--seed", type=seed_arg, default=0, help="the floor's seed, or the first of --count (default: 0)")
    gen.add_argument("--format", choices=("pgm", "png"), default="pgm", help="the image's format (default: pgm)")
    gen.add_argument("--force", action="store_true", help="overwrite an existing map")
    gen.set_defaults(func=cmd_maps_generate)
    show = maps_sub.add_parser("show", help="print a map's size and fractions and draw it")
    show.add_argument("map", help="map_server YAML")
    show.add_argument(
        "--png",
        help="where to draw it (default: logs/maps/NAME.png, redrawn each time; a file named here that "
        "exists is replaced only with --force)",
    )
    show.add_argument("--force", action="store_true", help=FORCE_HELP)
    show.set_defaults(func=cmd_maps_show)
    crop = maps_sub.add_parser("crop", help="cut a map to its recorded (known) area or to a rectangle")
    crop.add_argument(
        "--rect",
        nargs=4,
        type=finite_arg,
        metavar=("X0", "Y0", "X1", "Y1"),
        help="keep this rectangle, metres in the map frame (default: the known cells and a margin)",
    )
    crop.add_argument("--margin", type=finite_arg, default=CROP_MARGIN_M, metavar="M",
                      help="metres kept around the known cells (default 0.2)")  # fmt: skip
    resample = maps_sub.add_parser("resample", help="coarsen a map to a whole multiple of its resolution")
    name_choices(maps, maps_sub)
    resample.add_argument("--resolution", type=finite_arg, required=True, metavar="R",
                          help="metres a cell; a coarse cell is free only if every cell under it is")  # fmt: skip
    for tool, run in ((crop, cmd_maps_crop), (resample, cmd_maps_resample)):
        tool.add_argument("map", help="map_server YAML to read (left as it is)")
        tool.add_argument("--out", required=True, help="YAML path to write (image written beside it)")
        tool.add_argument(
            "--min-island",
            type=finite_arg,
            default=0.0,
            metavar="M2",
            help="also drop free areas smaller than this many square metres (default 0: keep all)",
        )
        tool.add_argument("--force", action="store_true", help="overwrite an existing map")
        tool.set_defaults(func=run)


def cmd_maps_generate(args: argparse.Namespace) -> int:
    """Write an indoor-like map of rectangular obstacles, or with --kind a set of floor plans."""
    from smorphi_rl.maps import check_resolution, save_map

    if args.kind is not None:
        return _generate_floors(args)
    if args.count != 1:
        raise SmorphiError("--count: writes a set of --kind floor plans; the rectangle generator writes one map")

    out = Path(args.out)
    if out.suffix != ".yaml":
        raise SmorphiError(f"--out {out}: give the map's YAML path, ending in .yaml")
    image = out.with_suffix(f".{args.format}")
    if not args.force and (out.exists() or image.exists()):
        raise SmorphiError(f"{out if out.exists() else image} exists; pass --force to overwrite it")
    check_resolution(args.resolution, "--resolution")  # before the size it divides by
    rng = np.random.default_rng(args.seed)
    from smorphi_rl.progress import progress_line
    from smorphi_rl.rundir import claimed_files

    large = args.width_m * args.height_m / args.resolution**2 > PROGRESS_FROM_CELLS
    grid_map = generate_map(
        rng,
        width_m=args.width_m,
        height_m=args.height_m,
        resolution_m=args.resolution,
        obstacle_density=args.density,
        name=out.stem,
        progress=progress_line("obstacle cells placed") if large else None,
    )
    short = grid_map.counts[Cell.OCCUPIED] < obstacle_target(args.density, grid_map.width, grid_map.height)
    if large and short and sys.stderr.isatty():
        sys.stderr.write("\n")  # the bar, rewritten in place, ends its line only when full
    with claimed_files([out], args.force):  # of two runs writing one map at once, exactly one writes it
        save_map(grid_map, out, image_format=args.format)
    occupied = 100 * grid_map.fraction(Cell.OCCUPIED)
    print(f"wrote {out} and {image}: {grid_map.width} x {grid_map.height} cells at {args.resolution:g} m, "
          f"occupied {occupied:.2f} % (seed {args.seed})")  # fmt: skip
    if short:
        print(f"smorphi-rl: warning: {out}: occupied {occupied:.2f} % where --density asked {100 * args.density:g} %: "
              "no more rectangles fitted without cutting the free space in two", file=sys.stderr)  # fmt: skip
    warn_coarser_than_a_block(args.resolution)
    return 0


MAX_FLOORS = 10_000
"""`maps generate --kind` writes at most this many floors at once."""


def _generate_floors(args: argparse.Namespace) -> int:
    """`maps generate --kind K --count N --seed S --out DIR`: floors K-S .. K-(S+N-1), each a YAML and its image."""
    from smorphi_rl.floorplans import floor_name, generate_floor
    from smorphi_rl.maps import generate_map, save_map

    shaped = [flag for flag, param, value in (("--width-m", "width_m", args.width_m), ("--height-m", "height_m",
              args.height_m), ("--resolution", "resolution_m", args.resolution), ("--density", "obstacle_density",
              args.density)) if value != param_default(generate_map, param)]  # fmt: skip
    if shaped:
        raise SmorphiError(f"{', '.join(shaped)}: options of the rectangle generator; a --kind floor plan draws its "
                           "own size, resolution and furniture from its seed")  # fmt: skip
    if not 1 <= args.count <= MAX_FLOORS:
        raise SmorphiError(f"--count must be in 1..{MAX_FLOORS:,}, got {args.count}")
    if args.seed + args.count - 1 > MAX_SEED:
        raise SmorphiError(f"--seed {args.seed} with --count {args.count} passes 2^32-1, the largest floor seed")
    out = Path(args.out)
    if out.suffix in (".yaml", ".yml") or (out.exists() and not out.is_dir()):
        raise SmorphiError(f"--out {out}: with --kind, give the folder the floors go to")
    names = [floor_name(args.kind, args.seed + i) for i in range(args.count)]
    if not args.force:
        taken = [f for n in names for f in (out / f"{n}.yaml", out / f"{n}.{args.format}") if f.exists()]
        if taken:  # the file named is one that exists, the YAML or its image
            floors = len({f.stem for f in taken})
            raise SmorphiError(f"{taken[0]} exists ({floors} of the {len(names)} floors have a file there); pass "
                               "--force to overwrite them")  # fmt: skip
    from smorphi_rl.interrupts import stop_requests
    from smorphi_rl.maps import check_not_folders
    from smorphi_rl.rundir import claimed_files

    check_not_folders([f for n in names for f in (out / f"{n}.yaml", out / f"{n}.{args.format}")])
    cells, done = 0, 0
    try:
        with claimed_files([out / f"{n}.yaml" for n in names], args.force):  # two runs into one folder: one writes
            for i, name in enumerate(names):
                grid_map = generate_floor(args.kind, args.seed + i)
                with stop_requests(again=True) as stop:  # a stop waits for the floor's image and YAML (a second:
                    save_map(grid_map, out / f"{name}.yaml", image_format=args.format)  # neither is left)
                cells, done = cells + grid_map.cells.size, done + 1
                if stop.is_set():
                    raise KeyboardInterrupt
    except KeyboardInterrupt:  # every floor written is whole (a YAML and its image): say which
        last = f" (seeds {args.seed}-{args.seed + done - 1})" if done else ""
        raise Interrupted(f"wrote {done} of the {len(names)} {args.kind} floors to {out}{last}, each whole") from None
    print(f"wrote {len(names)} {args.kind} floors to {out} (seeds {args.seed}-{args.seed + len(names) - 1}, "
          f"on average {cells / len(names):,.0f} cells a floor, unknown margin included)")  # fmt: skip
    return 0


def cmd_maps_crop(args: argparse.Namespace) -> int:
    """Cut a map to its known area (or a rectangle) into a new map_server YAML."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.errors import MapError, SmorphiError
    from smorphi_rl.maps import check_fits
    from smorphi_rl.maptools import crop_to_known, crop_to_rect

    if args.rect is not None and args.margin != CROP_MARGIN_M:
        raise SmorphiError("--margin: applies to a crop to the known area; --rect gives the rectangle itself")

    def crop(source: Map) -> Map:
        return crop_to_known(source, args.margin) if args.rect is None else crop_to_rect(source, *args.rect)

    def holds_robot(source: Map, cropped: Map) -> None:
        block = EnvConfig.block_side_m
        if source.resolution_m <= block:  # a crop no robot fits on is refused (a coarse map: resample's warning)
            try:
                check_fits(replace(cropped, name=Path(args.out).stem), block)  # named as the map it would write
            except SmorphiError as exc:
                raise MapError(f"maps crop: nothing written, the crop holds no robot of {block:g} m blocks ({exc})") \
                    from None  # fmt: skip

    whole = None if args.rect is not None else f"nothing cut: no unknown margin beyond --margin {args.margin:g} m"
    return _write_prepared(args, crop, holds_robot, whole)


def cmd_maps_resample(args: argparse.Namespace) -> int:
    """Coarsen a map, conservatively, into a new map_server YAML."""
    from smorphi_rl.maptools import resample

    return _write_prepared(args, lambda source: resample(source, args.resolution))


def warn_coarser_than_a_block(resolution_m: float) -> None:
    """A warning line when a map's cells are larger than Smorphi's block: every planning command refuses it then
    (a footprint under one cell has no tiles), unless a larger block side is given."""
    from smorphi_rl.env_config import EnvConfig

    block = EnvConfig.block_side_m  # the default block
    if resolution_m > block:
        print(f"warning: at {resolution_m:g} m a cell, Smorphi's {block:g} m block is smaller than one cell: "
              f"planning commands refuse this map (a resolution of at most {block:g} m, or `evaluate --block-side` "
              f"of at least {resolution_m:g}, plans on it)", file=sys.stderr)  # fmt: skip


def _write_prepared(args: argparse.Namespace, transform: Any, check: Any = None, whole: str | None = None) -> int:
    """Read the map, transform it, drop small islands, `check(source, result)` it, write it (never over the input
    or an existing map without --force) and print both maps' sizes; `whole`, a note when the transform kept the size
    (islands dropped later may leave a new margin, which a second crop cuts)."""
    from smorphi_rl.maps import save_map
    from smorphi_rl.maptools import drop_islands

    out = Path(args.out)
    if out.suffix != ".yaml":
        raise SmorphiError(f"--out {out}: give the map's YAML path, ending in .yaml")
    if resolved(Path(args.map), "map") == resolved(out, "--out"):
        raise SmorphiError(f"--out {out} is the input map: write the new map somewhere else")
    if resolved(out.with_suffix(".pgm"), "--out") in {resolved(Path(p), "map") for p in map_inputs(args.map)}:
        raise SmorphiError(f"--out {out}: its image would replace the input map's image; write it elsewhere")
    taken = next((p for p in (out, out.with_suffix(".pgm")) if p.exists()), None)
    if not args.force and taken is not None:
        raise SmorphiError(f"{taken} exists; pass --force to overwrite it")
    source = load_map(args.map)
    if (unknown := source.unknown_warning()) is not None:  # the new map reads them as free too, and no longer says so
        print(one_line(unknown), file=sys.stderr)
    transformed = transform(source)
    grid_map, islands = drop_islands(transformed, args.min_island)
    if check is not None:
        check(source, grid_map)
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
    if whole and transformed.cells.shape == source.cells.shape:
        print(f"{'note':<8} {whole}")
    warn_coarser_than_a_block(grid_map.resolution_m)
    return 0


def cmd_maps_show(args: argparse.Namespace) -> int:
    """Print a map's size and cell fractions, and draw it."""
    from smorphi_rl.plots import plot_map

    if args.png is not None:
        png = output_file(args.png, "--png", (".png",), map_inputs(args.map), args.force)
    else:  # redrawn each time, but never over a map's image (maps generated into logs/maps as PNG, of any name)
        png = Path(DEFAULT_LOG_DIR) / "maps" / f"{Path(args.map).stem}.png"
        owner = next((m for m in (Path(args.map), *sorted(png.parent.glob("*.yaml")))
                      if resolved(png, "--png") in {resolved(p, "map") for p in map_inputs(m)}), None)  # fmt: skip
        if owner is not None:
            raise SmorphiError(f"the default drawing {png} is the image of map {owner}: give --png elsewhere")
        output_file(str(png), "the default drawing", (".png",), force=True)
    grid_map = load_map(args.map)
    say_warnings(grid_map)
    r = grid_map.resolution_m
    rows = [
        ("map", f"{args.map}"),
        ("size", f"{grid_map.width} x {grid_map.height} cells, {grid_map.width * r:g} x {grid_map.height * r:g} m"),
        ("resolution", f"{r:g} m/cell"),
        ("origin", ", ".join(f"{v:g}" for v in grid_map.origin)),
        *((c.name.lower(), f"{100 * grid_map.fraction(c):.2f} % ({grid_map.counts[c]:,} cells)") for c in Cell),
        ("png", str(plot_map(grid_map, png))),
    ]
    print("\n".join(f"{k:<11} {v}" for k, v in rows))
    return 0

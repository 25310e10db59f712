"""Floor maps: the Map value, ROS map_server / nav2 YAML + PGM/PNG loading and saving, a generator.

Cells are free, occupied or unknown (docs/spec/fbcpp.md section 3); row 0 is the lowest y, as nav2
stores it after flipping the image.
"""

from __future__ import annotations

import contextlib
import enum
import math
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from smorphi_rl.errors import MapError
from smorphi_rl.inputs import MAP_IMAGE_FORMATS, is_finite_number

EDGE_TOLERANCE_CELLS = 1e-9
"""A point within this many cells of a cell's edge lies on it: the same point names one cell on every frame."""

_PACKAGE = Path(__file__).resolve().parent
SHIPPED_MAPS = _PACKAGE / "shipped_maps" if (_PACKAGE / "shipped_maps").is_dir() else _PACKAGE.parent / "maps"
"""The maps shipped with smorphi-rl: the clone's maps/, which an installed wheel holds as smorphi_rl/shipped_maps
(pyproject.toml)."""
SHIPPED_DEFAULT_MAP = SHIPPED_MAPS / "map-1.yaml"
"""The default map of every command and of the env: map-1."""


def shipped_hint(path: Path) -> str:
    """For a map path of the README's (`maps/...`, relative) that is not there: where the shipped one is (run from
    elsewhere than the clone, or from an installed wheel); "" when there is none."""
    parts = path.parts
    if path.is_absolute() or len(parts) < 2 or parts[0] != "maps" or not (SHIPPED_MAPS / Path(*parts[1:])).exists():
        return ""
    return f" (the shipped one is {SHIPPED_MAPS / Path(*parts[1:])})"


MIN_RESOLUTION_M, MAX_RESOLUTION_M = 0.001, 10.0
"""A map file's cell size: a millimetre to ten metres (ROS maps are 0.01-0.1 m); beyond, the file is wrong."""


def check_resolution(resolution_m: float, what: str) -> None:
    """Refuse a cell size a map file may not hold (MIN_RESOLUTION_M-MAX_RESOLUTION_M): what reads maps refuses it,
    and what writes them refuses it before any work, rather than leave a map no command can read."""
    if not (is_finite_number(resolution_m) and MIN_RESOLUTION_M <= resolution_m <= MAX_RESOLUTION_M):
        shown = f"{resolution_m:g}" if isinstance(resolution_m, int | float) else repr(resolution_m)
        raise MapError(f"{what} must be {MIN_RESOLUTION_M:g}-{MAX_RESOLUTION_M:g} m a cell, got {shown}")


class Cell(enum.IntEnum):
    """State of one map cell."""

    FREE = 0
    OCCUPIED = 1
    UNKNOWN = 2


CELL_COLOURS = ("#ffffff", "#202020", "#b0b0b0", "#7bd389")
"""Free, occupied and unknown cells (Cell's values), then covered free cells, as every figure and the env's render
draw them."""
PATH_COLOUR = "#d62728"
"""The coverage path, as every figure and the env's render draw it."""


class MapMode(enum.Enum):
    """How image pixels become cells (nav2 map_server's `mode`)."""

    TRINARY = "trinary"
    SCALE = "scale"
    RAW = "raw"


# What `map_saver` writes for each state, and the thresholds we write beside it. free_thresh
# 0.196 keeps 205 (p = 0.19608) unknown: it is not under the threshold.
SAVED_PIXEL = {Cell.FREE: 254, Cell.OCCUPIED: 0, Cell.UNKNOWN: 205}
SAVED_OCCUPIED_THRESH = 0.65
SAVED_FREE_THRESH = 0.196
SAVED_UNKNOWN_P = 1 - SAVED_PIXEL[Cell.UNKNOWN] / 255
"""The p of map_saver's unknown grey, in nav2's own arithmetic: 0.19607843..."""
CLASSIFYING_HINT = (f"map_saver writes negate: 0, occupied_thresh: {SAVED_OCCUPIED_THRESH}, "
                    f"free_thresh: {SAVED_FREE_THRESH}")  # fmt: skip
"""Said when `negate`, `occupied_thresh` or `free_thresh` is missing: they decide which grey is free, occupied or
unknown, so they are required, as ROS's map_server and nav2 require them."""
UNKNOWN_READ_FREE = {
    "scale": ("mode scale reads the grey as 0 % occupied", "mode: trinary in its YAML"),
    "free_thresh": ("its free_thresh is above the grey's p of {p:.5f}",
                    f"free_thresh: {SAVED_FREE_THRESH} in its YAML"),
    "alpha": ("its image has an opaque alpha channel, which trinary mode averages into the grey",
              "the image saved without its alpha channel"),
}  # fmt: skip
"""Each part of a map file that reads map_saver's unknown grey as free, as nav2 reads it: why, and the fix."""
IMAGE_SUFFIXES = (".pgm", ".png")
MAX_ORIGIN_M = 1_000_000.0
"""A map frame's origin lies within 1,000 km of its zero (ROS maps: metres to a few km)."""
READ_IMAGE_SUFFIXES = (*IMAGE_SUFFIXES, ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".gif")
"""The image files a map YAML may name (what map_saver writes and what nav2's image loader is used with)."""


SPARSE_FRAME_CELLS = 250_000
"""Frames larger than this (500 x 500 cells) whose known area is small get `Map.frame_warning`."""
SPARSE_SHARE = 0.25
"""A known area under this share of such a frame is warned of."""


@dataclass(frozen=True, eq=False)
class Map:
    """An occupancy grid: `cells[row, col]` holds a `Cell` value, row 0 at the lowest y."""

    cells: np.ndarray
    resolution_m: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "map"
    unknown_read_free: int = 0
    """Cells of map_saver's unknown grey (205) that the map file reads as free (`unknown_warning`)."""
    unknown_read_by: tuple[str, ...] = ("free_thresh",)
    """The parts of the map file that read them as free: keys of UNKNOWN_READ_FREE."""
    counts: dict[Cell, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not is_finite_number(self.resolution_m):
            raise MapError(f"map {self.name}: resolution {self.resolution_m!r} is not a number")
        if self.resolution_m <= 0:
            raise MapError(f"map {self.name}: resolution must be > 0, got {self.resolution_m}")
        cells = np.ascontiguousarray(self.cells, dtype=np.uint8)
        if cells.ndim != 2 or cells.size == 0:
            raise MapError(f"map {self.name}: the grid must be a non-empty 2-D array")
        if cells.max() > Cell.UNKNOWN:
            raise MapError(f"map {self.name}: cell values must be 0 (free), 1 (occupied) or 2 (unknown)")
        cells.setflags(write=False)
        object.__setattr__(self, "cells", cells)
        counts = np.bincount(cells.ravel(), minlength=3)
        object.__setattr__(self, "counts", {c: int(counts[c]) for c in Cell})
        if self.counts[Cell.FREE] == 0:
            raise MapError(f"map {self.name}: has no free cell, nothing to cover")

    @property
    def height(self) -> int:
        return int(self.cells.shape[0])

    @property
    def digest(self) -> str:
        """A digest of the cells and the resolution: what tells two maps of one name apart (results name a map by
        its file name, and ROS maps are often all `map.yaml`). `protocol.key_of` hashes the same with the weights
        and planning, for the optima's cache (its keys stay as they were)."""
        import hashlib

        h = hashlib.blake2b(digest_size=12)
        h.update(repr((self.cells.shape, self.resolution_m)).encode())
        h.update(self.cells.tobytes())
        return h.hexdigest()

    @property
    def width(self) -> int:
        return int(self.cells.shape[1])

    def fraction(self, cell: Cell) -> float:
        return self.counts[cell] / self.cells.size

    def known_box(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1), ends excluded, of the known (free or occupied) cells: the floor a recorded map
        holds, which is mostly unknown space around it (a map always has a free cell, so the box is never empty)."""
        rows, cols = np.nonzero(self.cells != Cell.UNKNOWN)
        return int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1

    def frame_warning(self) -> str | None:
        """A warning when the known area fills under SPARSE_SHARE of a frame of over SPARSE_FRAME_CELLS cells: the
        planner works on the whole frame, so every plan (and an exact search above all) costs what the frame does."""
        r0, r1, c0, c1 = self.known_box()
        known = (r1 - r0) * (c1 - c0)
        if self.cells.size <= SPARSE_FRAME_CELLS or known >= SPARSE_SHARE * self.cells.size:
            return None
        share = 100 * known / self.cells.size
        return (f"warning: {self.name}: its known area ({c1 - c0} x {r1 - r0} cells) is {share:.1f} % of its "
                f"{self.width} x {self.height} frame, and the planner works on the whole frame: `smorphi-rl maps crop` "
                "cuts it to the known area and plans many times faster (under the paper planner the tiles then start "
                "at the crop's corner, so scores move a little)")  # fmt: skip

    def unknown_warning(self) -> str | None:
        """A warning when the map file reads map_saver's unknown grey as free (nav2's depot map: its free_thresh of
        0.25; an image given an opaque alpha channel by an editor; mode scale): the planner then covers, and scores,
        floor no robot has seen."""
        if not self.unknown_read_free:
            return None
        grey = SAVED_PIXEL[Cell.UNKNOWN]
        why = "; ".join(UNKNOWN_READ_FREE[k][0].format(p=SAVED_UNKNOWN_P) for k in self.unknown_read_by)
        fix = " and ".join(UNKNOWN_READ_FREE[k][1] for k in self.unknown_read_by)
        return (f"warning: {self.name}: {self.unknown_read_free:,} cells of grey {grey}, which map_saver writes for "
                f"unknown space, read as free floor ({why}, as nav2 reads it); {fix} "
                f"read{'s' if len(self.unknown_read_by) == 1 else ''} them as unknown")  # fmt: skip

    def warnings(self) -> list[str]:
        """What a command that plans on this map says first, on stderr (`frame_warning`, `unknown_warning`)."""
        return [w for w in (self.frame_warning(), self.unknown_warning()) if w]

    def known_sides_m(self) -> tuple[float, float]:
        """(height, width) of `known_box` in metres."""
        r0, r1, c0, c1 = self.known_box()
        return (r1 - r0) * self.resolution_m, (c1 - c0) * self.resolution_m

    def world_of(self, row: int, col: int) -> tuple[float, float]:
        """The centre of cell (row, col) in metres, map frame (the inverse of `cell_of`)."""
        return (self.origin[0] + (col + 0.5) * self.resolution_m, self.origin[1] + (row + 0.5) * self.resolution_m)

    def cell_of(self, x_m: float, y_m: float) -> tuple[int, int]:
        """(row, col) of the cell holding a point in the map frame (yaw ignored, as nav2 does); a point on a cell's
        edge is in the cell that edge starts, whatever the float division makes of it (1.2 / 0.1 is 11.999...)."""
        col = (x_m - self.origin[0]) / self.resolution_m + EDGE_TOLERANCE_CELLS  # floats: 1e308 m is inf cells
        row = (y_m - self.origin[1]) / self.resolution_m + EDGE_TOLERANCE_CELLS
        if not (0 <= row < self.height and 0 <= col < self.width):
            raise MapError(f"map {self.name}: point ({x_m}, {y_m}) m lies outside the map")
        return math.floor(row), math.floor(col)

    @classmethod
    def from_text(cls, text: str, resolution_m: float, name: str = "map") -> Map:
        """A map drawn top row first: '.' free, '#' occupied, '?' unknown (as in docs/spec/fbcpp.md)."""
        symbols = {".": Cell.FREE, "#": Cell.OCCUPIED, "?": Cell.UNKNOWN}
        lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
        if len({len(ln) for ln in lines}) != 1:
            raise MapError(f"map {name}: rows of the text map differ in length")
        try:
            rows = [[symbols[ch] for ch in ln] for ln in lines]
        except KeyError as exc:
            raise MapError(f"map {name}: unknown symbol {exc.args[0]!r} (use . # ?)") from None
        return cls(np.array(rows[::-1], dtype=np.uint8), resolution_m, name=name)


def _require(meta: dict[str, Any], key: str, path: Path, hint: str = "") -> Any:
    if key not in meta:
        raise MapError(f"{path}: missing key '{key}'" + (f" ({hint})" if hint else ""))
    return meta[key]


def _shown(value: Any, limit: int = 40) -> str:
    """A YAML value as a message shows it: its repr, cut at `limit` characters (a crafted file's value can be
    megabytes long)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _as_number(value: Any) -> Any:
    """YAML 1.1 reads 1e-9 or 1e3 (no dot) as a string; a string that is a number is that number."""
    if isinstance(value, str):
        with contextlib.suppress(ValueError):
            return float(value)
    return value


def _number(meta: dict[str, Any], key: str, path: Path, default: float | None = None, hint: str = "") -> float:
    value = _as_number(meta.get(key, default) if default is not None else _require(meta, key, path, hint))
    if not is_finite_number(value):
        raise MapError(f"{path}: '{key}' must be a number, got {_shown(value)}")
    return float(value)


_PGM_FIELD = re.compile(rb"(?:\s|#[^\n]*\n)*(\d+)")
"""One header field of a binary PGM (whitespace and comments before it)."""


def _pgm_samples(data: bytes) -> tuple[int, np.ndarray] | None:
    """(maxval, samples) of a PGM file's bytes; None when it is not a PGM or its header is malformed (Pillow
    names that)."""
    if data[:2] == b"P2":  # parsed in C: a list of 25 million Python numbers once took a gigabyte
        text = re.sub(rb"#[^\n]*", b" ", data[2:]).decode("ascii", "replace")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # numpy before 2.3 ends the parse at a token that is no number
                numbers = np.fromstring(text, dtype=np.int64, sep=" ")
        except ValueError:  # numpy 2.3 on: such a token (a damaged sample, bytes after the raster): Pillow judges it
            return None
        if len(numbers) < 3 or min(numbers[:2]) < 1 or len(numbers) < 3 + int(numbers[0]) * int(numbers[1]):
            return None  # malformed or cut short: Pillow names it
        return int(numbers[2]), numbers[3 : 3 + int(numbers[0]) * int(numbers[1])]
    if data[:2] != b"P5":
        return None
    fields, pos = [], 2
    for _ in range(3):  # width, height, maxval
        match = _PGM_FIELD.match(data, pos)
        if match is None:
            return None
        if len(match.group(1)) > 18:  # no image has such a side (and `int` refuses 4,300 digits): Pillow names it
            return None
        fields.append(int(match.group(1)))
        pos = match.end() + 1  # one whitespace byte, then the raster
    width, height, maxval = fields
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
    if len(data) - pos < width * height * dtype.itemsize:
        return None
    return maxval, np.frombuffer(data, dtype=dtype, count=width * height, offset=pos)


def _check_pgm_samples(path: Path) -> None:
    """Refuse a PGM holding a sample above its declared maxval: a corrupt file that Pillow reads without a word
    (samples of 254 under maxval 100 came out as free floor)."""
    from smorphi_rl.inputs import MAX_IMAGE_PIXELS

    with path.open("rb") as fh:  # no more than the largest image read holds (what follows it is never read)
        read = _pgm_samples(fh.read(8 * MAX_IMAGE_PIXELS + (1 << 16)))
    if read is not None and read[1].size and int(read[1].max()) > read[0]:
        raise MapError(f"{path}: a sample of {int(read[1].max())} above the PGM's maxval {read[0]} (a corrupt "
                       "image)")  # fmt: skip


def _read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None, float]:
    """(mean colour per pixel, alpha or None, maximum value) of a PGM or PNG image."""
    from PIL import Image, UnidentifiedImageError

    if path.suffix.lower() == ".pgm" and path.is_file():
        _check_pgm_samples(path)
    try:
        with Image.open(path, formats=MAP_IMAGE_FORMATS) as opened:
            opened.load()
            img: Image.Image = opened
            if img.mode == "P":
                img = img.convert("RGBA" if "transparency" in img.info else "RGB")
            elif img.mode in ("L", "RGB") and "transparency" in img.info:  # a PNG's tRNS colour key: nav2's image
                img = img.convert(img.mode + "A")  # library reads the image as having alpha, 0 on that colour
            elif img.mode == "1":
                img = img.convert("L")
            data = np.asarray(img)
            mode = img.mode
            key = img.info.get("transparency") if mode.startswith("I") else None  # a 16-bit grey's transparent grey
    except FileNotFoundError:
        raise MapError(f"map image not found: {path}") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:  # SyntaxError: Pillow's damaged PNG
        other = path.suffix.lower() not in IMAGE_SUFFIXES  # a .jpg a map YAML may name: never decoded as one
        why = "map images are read as PGM or PNG only: convert it to one" if other else str(exc)
        raise MapError(f"{path}: not a readable PGM/PNG image ({why})") from None
    max_value = 65535.0 if data.dtype == np.uint16 or mode.startswith("I") else 255.0
    alpha = None
    if mode in ("RGBA", "LA"):
        alpha, data = data[..., -1], data[..., :-1]
    elif isinstance(key, int) and data.ndim == 2:  # Pillow keeps a 16-bit grey's key aside: alpha 0 there, as nav2
        alpha = np.where(data == key, 0.0, max_value)
    if data.ndim == 3:  # map_server averages the colour channels; summed a channel at a time (integers: exact), so
        gray = data[..., 0].astype(np.float64)  # a 5,000 x 5,000 16-bit RGBA image takes 0.2 GB of floats, not 0.8
        for channel in range(1, data.shape[2]):
            gray += data[..., channel]
        gray /= data.shape[2]
    else:
        gray = data.astype(np.float64)
    if gray.ndim != 2 or gray.size == 0:
        raise MapError(f"{path}: image has no pixels")
    return gray, alpha, max_value


def cells_from_image(
    gray: np.ndarray,
    alpha: np.ndarray | None,
    max_value: float,
    mode: MapMode,
    negate: bool,
    occupied_thresh: float,
    free_thresh: float,
) -> np.ndarray:
    """nav2's map_io, to its arithmetic: a pixel's shade is the mean of its colour channels over `max_value` (in
    trinary mode the alpha averaged in as a fourth channel), p = 1 - shade (shade if negate); p > occupied is
    occupied and p < free is free, both strictly, else unknown. Scale: a pixel not opaque is unknown, and one in
    between holds rint(100 (p - free) / (occupied - free)), free where that is 0, occupied (known, not free)
    otherwise. Raw: round(255 shade) is 0 free, 1-100 occupied, else unknown. A cell is free only where nav2's
    OccupancyGrid would hold 0."""
    cells = np.full(gray.shape, Cell.UNKNOWN, dtype=np.uint8)
    if mode is MapMode.RAW:
        value = np.floor(gray * (255.0 / max_value) + 0.5)  # std::round: halves away from zero
        cells[value == 0] = Cell.FREE
        cells[(value > 0) & (value <= 100)] = Cell.OCCUPIED
    else:
        if mode is MapMode.TRINARY and alpha is not None:  # nav2 averages alpha in as a channel (grey: three copies)
            gray = (3.0 * gray + alpha) / 4.0
        shade = gray / max_value
        p = shade if negate else 1.0 - shade
        occupied, free = p > occupied_thresh, p < free_thresh
        if mode is MapMode.SCALE:
            between = ~occupied & ~free
            free |= between & (np.rint(100.0 * (p - free_thresh) / (occupied_thresh - free_thresh)) == 0)
            cells[:] = Cell.OCCUPIED
        cells[occupied] = Cell.OCCUPIED
        cells[free & ~occupied] = Cell.FREE
        if mode is MapMode.SCALE and alpha is not None:
            cells[alpha < (255 if alpha.dtype == np.uint8 else 65535)] = Cell.UNKNOWN
    return np.flipud(cells)  # image row 0 is the top of the map


def load_map(yaml_path: str | Path) -> Map:
    """Load a ROS map_server / nav2 map: YAML with `image` (relative to it), `resolution`, ..."""
    path = Path(yaml_path)
    if path.suffix.lower() in READ_IMAGE_SUFFIXES:
        beside = path.with_suffix(".yaml")
        hint = f" (is {beside} its YAML?)" if beside.is_file() else ""
        raise MapError(f"{path} is an image: give the map_server YAML that names it{hint}")
    from smorphi_rl.inputs import MAX_YAML_BYTES, check_image_size, check_not_special, strict_yaml

    check_not_special(path, "map YAML", MapError)
    if path.is_dir():
        raise MapError(f"{path} is a folder: give one map YAML (train and sweep also take a folder of them)")
    try:
        if path.stat().st_size > MAX_YAML_BYTES:
            raise MapError(f"{path}: {path.stat().st_size:,} bytes; a map YAML is at most {MAX_YAML_BYTES:,}")
        text = path.read_text()
    except FileNotFoundError:
        generator = str(yaml_path).startswith("generate:")  # map_sources' floor generators: no file to read
        hint = " (a generator is for train and sweep; `maps generate` writes floors to files)" if generator else ""
        raise MapError(f"map file not found: {path}{hint or shipped_hint(path)}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MapError(f"{path}: cannot read map YAML ({exc})") from None
    try:
        meta = strict_yaml(text)
    except yaml.YAMLError as exc:
        problem = str(getattr(exc, "problem", "") or "").strip() or str(exc).splitlines()[0]
        raise MapError(f"{path}: malformed YAML ({problem})") from None
    if not isinstance(meta, dict):
        raise MapError(f"{path}: not a map_server YAML (expected a mapping with 'image' and 'resolution')")
    image = _require(meta, "image", path)
    if not isinstance(image, str) or not image:
        raise MapError(f"{path}: 'image' must be a file name, got {_shown(image)}")
    if Path(image).suffix.lower() not in READ_IMAGE_SUFFIXES:
        raise MapError(f"{path}: 'image' {_shown(image)} is not an image file name (map images are read as PGM "
                       "or PNG, as map_saver writes them)")  # fmt: skip
    resolution = _number(meta, "resolution", path)
    check_resolution(resolution, f"{path}: 'resolution'")
    origin = meta.get("origin", [0.0, 0.0, 0.0])
    origin = [_as_number(v) for v in origin] if isinstance(origin, list) and len(origin) == 3 else origin
    if (
        not isinstance(origin, list)
        or len(origin) != 3
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in origin)
    ):
        raise MapError(f"{path}: 'origin' must be [x, y, yaw], got {_shown(origin)}")
    if not all(is_finite_number(v) for v in origin):
        raise MapError(f"{path}: 'origin' must be three finite numbers, got {_shown(origin, 80)}")
    if max(abs(origin[0]), abs(origin[1])) > MAX_ORIGIN_M:  # a robot's map, not a planet's: no plot or plan is sane
        raise MapError(f"{path}: 'origin' x and y must lie within {MAX_ORIGIN_M:,.0f} m of the map frame's zero, got "
                       f"{_shown(origin, 80)}")  # fmt: skip
    mode_name = meta.get("mode", MapMode.TRINARY.value)
    try:
        mode = MapMode(mode_name.lower() if isinstance(mode_name, str) else mode_name)  # nav2 lower-cases it too
    except ValueError:
        raise MapError(f"{path}: 'mode' must be trinary, scale or raw, got {_shown(mode_name)}") from None
    # negate and the thresholds decide which cell is floor: a default would guess it (ROS refuses too)
    negate = _require(meta, "negate", path, CLASSIFYING_HINT)
    if not isinstance(negate, int):  # an integer, any but 0 true, as map_server reads it (bool is an int)
        raise MapError(f"{path}: 'negate' must be an integer (0, or any other to negate), got {_shown(negate)}")
    occupied_thresh = _number(meta, "occupied_thresh", path, hint=CLASSIFYING_HINT)
    free_thresh = _number(meta, "free_thresh", path, hint=CLASSIFYING_HINT)
    if not 0.0 < free_thresh < occupied_thresh < 1.0:  # compared strictly: at 0 no grey is free, at 1 none occupied
        raise MapError(f"{path}: need 0 < free_thresh < occupied_thresh < 1 (a cell is free where p < free_thresh and "
                       f"occupied where p > occupied_thresh), got {free_thresh} and {occupied_thresh}")  # fmt: skip
    check_not_special(path.parent / image, "map image", MapError)
    try:
        (path.parent / image).stat()
    except FileNotFoundError:
        pass  # named by the reader, with the path it looked at
    except OSError as exc:  # a name too long, a folder that cannot be entered: the OS's words alone name neither
        raise MapError(f"{path}: its 'image' {_shown(str(image))} cannot be read ({exc.strerror or exc})") from None
    check_image_size(path.parent / image)  # a declared size too large for memory fails before decoding
    gray, alpha, max_value = _read_image(path.parent / image)
    cells = cells_from_image(gray, alpha, max_value, mode, bool(negate), occupied_thresh, free_thresh)
    origin_t = (float(origin[0]), float(origin[1]), float(origin[2]))
    saved_unknown = max_value == 255 and mode is not MapMode.RAW and not negate  # map_saver's images
    unknown_free = np.flipud(gray == SAVED_PIXEL[Cell.UNKNOWN]) & (cells == Cell.FREE) if saved_unknown else None
    by = (
        (("scale",) if mode is MapMode.SCALE else ())
        + (("free_thresh",) if free_thresh > SAVED_UNKNOWN_P else ())
        + (("alpha",) if alpha is not None else ())
    )  # each a fix the others need: trinary mode averages alpha in
    return Map(cells, resolution, origin_t, name=path.stem, unknown_read_by=by,
               unknown_read_free=0 if unknown_free is None else int(np.count_nonzero(unknown_free)))  # fmt: skip


def as_map(source: str | Path | Map) -> Map:
    """A Map as given, or the map_server YAML at a path loaded (`load_map`): what the searches and the exact optimum
    take, so a script's Map in memory needs no file."""
    return source if isinstance(source, Map) else load_map(source)


def map_inputs(yaml_path: str | Path) -> tuple[Path, ...]:
    """The files a map is read from: its YAML and (when the YAML names one) its image; what no output may replace."""
    from smorphi_rl.inputs import MAX_YAML_BYTES, strict_yaml

    path = Path(yaml_path)
    try:  # only a plain file of a map YAML's size is read here (a FIFO would block): `load_map` names the others
        plain = path.is_file() and path.stat().st_size <= MAX_YAML_BYTES
        meta = strict_yaml(path.read_text()) if plain else None
        image = meta.get("image") if isinstance(meta, dict) else None
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError):
        image = None
    return (path, path.parent / image) if isinstance(image, str) and image else (path,)


def check_not_folders(paths: list[Path]) -> None:
    """Refuse, before anything is written, a map file or image to be written where a folder is: found only mid-way,
    it left part of a map, or of a set of maps, behind."""
    folders = [p for p in paths if p.is_dir()]
    if folders:
        more = f" (and {len(folders) - 1} more of the files to write)" if len(folders) > 1 else ""
        raise MapError(f"cannot write {folders[0]}: a folder is there{more}; nothing was written")


def save_map(grid_map: Map, yaml_path: str | Path, image_format: str = "pgm") -> Path:
    """Write `NAME.yaml` and `NAME.pgm|png` as map_saver does (trinary: 254/0/205), each through a temporary file
    and a rename."""
    from PIL import Image

    path = Path(yaml_path)
    check_resolution(grid_map.resolution_m, f"map {grid_map.name}: its resolution (to be written to {path})")
    if image_format not in ("pgm", "png"):
        raise MapError(f"image format must be pgm or png, got {image_format!r}")
    check_not_folders([path, path.with_suffix(f".{image_format}")])
    pixels = np.zeros(grid_map.cells.shape, dtype=np.uint8)
    for cell, value in SAVED_PIXEL.items():
        pixels[grid_map.cells == cell] = value
    import io

    from smorphi_rl.rundir import write_atomic

    image_path = path.with_suffix(f".{image_format}")
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    Image.fromarray(np.flipud(pixels), mode="L").save(buffer, format={"pgm": "PPM", "png": "PNG"}[image_format])
    meta = {
        "image": image_path.name,
        "mode": MapMode.TRINARY.value,
        "resolution": grid_map.resolution_m,
        "origin": list(grid_map.origin),
        "negate": 0,
        "occupied_thresh": SAVED_OCCUPIED_THRESH,
        "free_thresh": SAVED_FREE_THRESH,
    }
    image_is_new = not image_path.exists()
    write_atomic(image_path, buffer.getvalue())  # each file whole or not at all: a full disk leaves the old one
    try:
        write_atomic(path, yaml.safe_dump(meta, sort_keys=False, default_flow_style=None).encode())
    except BaseException:  # a full disk, a stop
        if image_is_new:
            image_path.unlink(missing_ok=True)  # no image without its YAML
        raise
    return path


def _free_is_connected(occupied: np.ndarray) -> bool:
    """True when the free cells form one 4-connected region."""
    from scipy.ndimage import label

    free = ~occupied
    if not free.any():
        return False
    return int(label(free)[1]) == 1  # scipy's default structure: 4-connectivity


def _ring(occupied: np.ndarray, r: int, c: int, rh: int, rw: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The one-cell ring around a rectangle, in order around it: its rows, its columns, and which of its cells are
    free (a cell outside the map is not)."""
    h, w = occupied.shape
    rows = np.concatenate([np.full(rw + 2, r - 1), np.arange(r, r + rh), np.full(rw + 2, r + rh),
                           np.arange(r + rh - 1, r - 1, -1)])  # fmt: skip
    cols = np.concatenate([np.arange(c - 1, c + rw + 1), np.full(rh, c + rw), np.arange(c + rw, c - 2, -1),
                           np.full(rh, c - 1)])  # fmt: skip
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    free = np.zeros(len(rows), dtype=bool)
    free[inside] = ~occupied[rows[inside], cols[inside]]
    return rows, cols, free


LOCAL_MARGIN = 16
"""Cells around a rectangle in the first window `_keeps_free_connected` labels; each next window is four times as
wide, up to the whole map."""


def _keeps_free_connected(occupied: np.ndarray, r: int, c: int, rh: int, rw: int) -> bool:
    """Whether adding the rectangle leaves the free cells one 4-connected region (they are one before). Every path
    the rectangle cuts enters and leaves it through free cells of the ring around it, so the question is whether
    those stay joined. Joined along the ring itself (one unbroken run of free cells): yes. Else the free cells of a
    window around it are labelled, the window growing until it answers: the ring's cells all in one region, yes; one
    of them in a region that reaches no cut edge of the window (closed within it), no; the window the whole map,
    no. Each answer is exact, so the maps are a whole-map flood fill's, at a fraction of its cost."""
    rows, cols, free = _ring(occupied, r, c, rh, rw)
    if not free.any():  # no path crosses it (already occupied, or the map's only free cells): the whole map decides
        trial = occupied.copy()
        trial[r : r + rh, c : c + rw] = True
        return _free_is_connected(trial)
    if int((free & ~np.roll(free, 1)).sum()) <= 1:  # the runs' starts around it: none (all free) or one
        return True
    from scipy.ndimage import label

    h, w = occupied.shape
    margin = LOCAL_MARGIN
    while True:
        r0, c0 = max(0, r - 1 - margin), max(0, c - 1 - margin)
        r1, c1 = min(h, r + rh + 1 + margin), min(w, c + rw + 1 + margin)
        window = occupied[r0:r1, c0:c1].copy()
        window[r - r0 : r - r0 + rh, c - c0 : c - c0 + rw] = True
        labels = label(~window)[0]
        ring = np.unique(labels[rows[free] - r0, cols[free] - c0])
        if len(ring) == 1:
            return True
        cut = [
            edge
            for edge, inside in (
                (labels[0], r0 > 0),
                (labels[-1], r1 < h),
                (labels[:, 0], c0 > 0),
                (labels[:, -1], c1 < w),
            )
            if inside
        ]  # the map's own edges bound all paths
        if not np.isin(ring, np.concatenate(cut) if cut else []).all():  # a region closed within the window
            return False
        margin *= 4


MAX_GENERATED_CELLS = 25_000_000
"""`maps generate` refuses larger maps (5,000 x 5,000 cells is a 500 m square at 0.1 m)."""


def obstacle_target(density: float, width: int, height: int) -> int:
    """The occupied cells `generate_map` places for a density on a map of so many cells."""
    return round(density * width * height)


def generate_map(
    rng: np.random.Generator,
    width_m: float = 5.0,
    height_m: float = 5.0,
    resolution_m: float = 0.1,
    obstacle_density: float = 0.2,
    min_obstacle_m: float = 0.2,
    max_obstacle_m: float = 1.2,
    name: str = "generated",
    progress: Callable[[int, int], None] | None = None,
) -> Map:
    """An indoor-like map: axis-aligned rectangular obstacles (furniture) added until the
    occupied fraction reaches `obstacle_density`, never cutting the free space in two (a dense map may end short
    of it: its caller says so); `progress(occupied cells, target)` now and then."""
    if not 0.0 <= obstacle_density < 0.9:
        raise MapError(f"obstacle density must be in [0, 0.9), got {obstacle_density}")
    check_resolution(resolution_m, "a map's resolution")
    if width_m <= 0 or height_m <= 0:
        raise MapError("map width and height must be > 0")
    if not 0 < min_obstacle_m <= max_obstacle_m:
        raise MapError("need 0 < min obstacle size <= max obstacle size")
    if not all(math.isfinite(v) for v in (width_m, height_m, resolution_m)):
        raise MapError("map width and height must be finite numbers")
    rows, cols = height_m / resolution_m, width_m / resolution_m  # floats: 1e308 / 0.05 is inf, not an integer
    if rows * cols > MAX_GENERATED_CELLS:
        raise MapError(f"a {width_m:g} x {height_m:g} m map at {resolution_m:g} m is {cols:,.0f} x {rows:,.0f} cells; "
                       f"generate at most {MAX_GENERATED_CELLS:,} cells (a coarser --resolution)")  # fmt: skip
    h, w = round(rows), round(cols)
    if h < 2 or w < 2:
        raise MapError("the map must be at least 2 x 2 cells")
    lo = max(1, round(min_obstacle_m / resolution_m))
    hi = max(lo, min(round(max_obstacle_m / resolution_m), h - 1, w - 1))
    occupied = np.zeros((h, w), dtype=bool)
    target = obstacle_target(obstacle_density, w, h)
    count = 0
    tries = max(20_000, 20 * target // ((lo + hi) ** 2 // 4))  # twenty times the rectangles of a mean size it takes
    for n in range(tries):
        if count >= target:
            break
        if progress is not None and n % 500 == 0:
            progress(count, target)
        rh, rw = (int(v) for v in rng.integers(lo, hi + 1, size=2))
        remaining = target - count
        if rh * rw > remaining:  # shrink the last pieces to land on the target
            rw = max(1, min(rw, remaining // rh))
            rh = max(1, min(rh, remaining // rw))
        r, c = int(rng.integers(0, h - rh + 1)), int(rng.integers(0, w - rw + 1))
        added = rh * rw - int(occupied[r : r + rh, c : c + rw].sum())  # the rectangle's cost, not the map's
        if added == 0 or count + added > target:
            continue
        if not _keeps_free_connected(occupied, r, c, rh, rw):
            continue
        occupied[r : r + rh, c : c + rw] = True
        count += added
    if progress is not None:
        progress(count, target)
    cells = np.where(occupied, Cell.OCCUPIED, Cell.FREE).astype(np.uint8)
    return Map(cells, resolution_m, name=name)


def holds_free_rect(free_prefix: np.ndarray, rows: int, cols: int) -> bool:
    """True when some `rows` x `cols` rectangle of cells is wholly free (`free_prefix`: the 2-D prefix sum of the
    free cells with a zero first row and column)."""
    p = free_prefix
    if rows > p.shape[0] - 1 or cols > p.shape[1] - 1:
        return False
    sums = p[rows:, cols:] - p[:-rows, cols:] - p[rows:, :-cols] + p[:-rows, :-cols]
    return bool((sums == rows * cols).any())


def free_prefix_sum(grid_map: Map) -> np.ndarray:
    """The 2-D prefix sum of the free cells, with a zero first row and column (int32)."""
    free = grid_map.cells == Cell.FREE
    prefix = np.zeros((free.shape[0] + 1, free.shape[1] + 1), dtype=np.int32)
    prefix[1:, 1:] = free.astype(np.int32).cumsum(axis=0).cumsum(axis=1)
    return prefix


def check_robot_fits(grid_map: Map, block_side_m: float, whole_footprint: bool) -> None:
    """Refuse a floor smaller than the robot (docs/spec/fbcpp.md section 3), where every score means nothing
    (under the paper's P_c one free cell among obstacles scores 100 %): its free cells must be at least as many as
    the cells of Smorphi's smallest footprint matrix, the O (2 x 2 blocks) or the I (1 x 4), and with
    `whole_footprint` (the fit planner, which places F only on free cells) one of them must lie wholly on free
    cells somewhere."""
    from smorphi_rl.geometry import cells_along

    o, i1, i4 = (cells_along(n * block_side_m, grid_map.resolution_m) for n in (2, 1, 4))
    smallest = f"the O, {o} x {o} cells" if o * o <= i1 * i4 else f"the I, {i1} x {i4} cells"
    if grid_map.counts[Cell.FREE] < min(o * o, i1 * i4):
        raise MapError(f"map {grid_map.name}: its {grid_map.counts[Cell.FREE]} free cells are fewer than the robot's "
                       f"smallest footprint ({smallest}): the floor is smaller than the robot")  # fmt: skip
    if not whole_footprint:
        return
    prefix = free_prefix_sum(grid_map)
    if any(holds_free_rect(prefix, rows, cols) for rows, cols in ((o, o), (i1, i4), (i4, i1))):
        return
    raise MapError(f"map {grid_map.name}: the robot fits nowhere on its free cells (neither Smorphi's O, {o} x {o} "
                   f"cells, nor its I, {i1} x {i4} either way, lies wholly on free cells), as the fit planner "
                   "needs")  # fmt: skip


def check_fits(grid_map: Map, block_side_m: float, whole_footprint: bool = False) -> float:
    """The block side, checked against the map's cells (`geometry.check_block_side`) and its size: a map narrower
    than one block, or whose free floor is smaller than the robot (`check_robot_fits`), holds no robot."""
    from smorphi_rl.geometry import check_block_side

    side = check_block_side(block_side_m, grid_map.resolution_m)
    if min(grid_map.cells.shape) * grid_map.resolution_m < side:
        h, w = grid_map.cells.shape
        size = f"{w} x {h} cells of {grid_map.resolution_m:g} m"
        raise MapError(f"map {grid_map.name} ({size}) is narrower than one block ({side:g} m): the robot does not "
                       "fit on it")  # fmt: skip
    check_robot_fits(grid_map, side, whole_footprint)
    return side

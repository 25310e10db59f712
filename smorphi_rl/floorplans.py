"""Seeded indoor floor plans: the distribution a generalist designer trains on and is measured on.

Each floor is a function of (kind, seed) alone, so a set is regenerated bit for bit from its seeds.
Kinds:
- `rooms`: a building split into rooms by walls (binary space partition), one doorway in every wall,
  furniture in the rooms (beds and sofas against walls, tables with chairs, round tables);
- `corridor`: a corridor along the building with rooms on one or both sides, a door from each;
- `hall`: an open hall with round pillars on a grid and clusters of desks;
- `furniture`: one room cluttered with rectangular and round furniture (like `maps generate`'s boxes);
- `mixed`: one of the four, drawn per floor.
Every floor has an outer wall, a margin of unknown space outside it as a SLAM map has, furniture whose
inside the laser never saw (unknown) on about half the pieces, and one connected free area. Sizes are
3-15 m a side and resolutions 0.05-0.1 m a cell, coarsened where a floor would exceed MAX_CELLS.

Seeds: training draws floors from [0, 900,000), validation from [900,000, HELD_OUT_SEED) and held-out floors
from HELD_OUT_SEED up (`map_sources`), so no two share a floor.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from smorphi_rl.errors import MapError
from smorphi_rl.inputs import check_seed, is_finite_number
from smorphi_rl.maps import Cell, Map

HELD_OUT_SEED = 1_000_000
"""Held-out floors have seeds from here up; training floors, below it."""
MAX_CELLS = 40_000
"""A floor's area, margin included, is at most this many cells before its sides are rounded to whole cells (which
adds up to about 1.3 %; a 15 m floor is drawn at 0.08 m or coarser)."""
FOUR_CONNECTED = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]])


class FloorKind(str, enum.Enum):
    """What a generated floor looks like (module docstring)."""

    ROOMS = "rooms"
    CORRIDOR = "corridor"
    HALL = "hall"
    FURNITURE = "furniture"
    MIXED = "mixed"


DRAWN_KINDS = (FloorKind.ROOMS, FloorKind.CORRIDOR, FloorKind.HALL, FloorKind.FURNITURE)
"""What `mixed` draws from, in this order."""


@dataclass(frozen=True)
class FloorRange:
    """The sizes and resolutions floors are drawn from (uniformly)."""

    min_side_m: float = 3.0
    max_side_m: float = 15.0
    min_resolution_m: float = 0.05
    max_resolution_m: float = 0.1
    max_cells: int = MAX_CELLS

    def __post_init__(self) -> None:
        values = (self.min_side_m, self.max_side_m, self.min_resolution_m, self.max_resolution_m)
        if not all(is_finite_number(v) and v > 0 for v in values):
            raise MapError(f"floor sizes and resolutions must be positive numbers, got {values}")
        if not (self.min_side_m <= self.max_side_m and self.min_resolution_m <= self.max_resolution_m):
            raise MapError("need min_side_m <= max_side_m and min_resolution_m <= max_resolution_m")
        if not (self.min_side_m >= 2.0 and self.max_side_m <= 100.0):
            raise MapError(f"floor sides must lie in [2, 100] m, got {self.min_side_m}-{self.max_side_m}")
        if not (self.min_resolution_m >= 0.02 and self.max_resolution_m <= 0.17):
            raise MapError("floor resolutions must lie in [0.02, 0.17] m (a block of 0.17 m spans a cell or more)")


DEFAULT_RANGE = FloorRange()
MAX_BLOCK_SIDE_M = 0.5
"""The largest block side every generated floor of DEFAULT_RANGE holds under both planners (checked on 10,000 floors,
2,500 of each kind: none refused a 0.5 m block; at 0.75 m the fit planner refused 5, at 1 m 270)."""


def floor_name(kind: FloorKind | str, seed: int) -> str:
    """The name (and file stem) of a generated floor: its kind and seed say how to make it again."""
    return f"{FloorKind(kind).value}-{seed:07d}"


def generate_floor(kind: FloorKind | str, seed: int, floor_range: FloorRange = DEFAULT_RANGE) -> Map:
    """The floor of this kind and seed (the same bits on every machine)."""
    kind = FloorKind(kind)
    rng = np.random.default_rng([check_seed(seed, "a floor seed", MapError), list(FloorKind).index(kind)])
    drawn = DRAWN_KINDS[int(rng.integers(len(DRAWN_KINDS)))] if kind is FloorKind.MIXED else kind
    plan = _Plan.draw(rng, floor_range)
    {
        FloorKind.ROOMS: _rooms,
        FloorKind.CORRIDOR: _corridor,
        FloorKind.HALL: _hall,
        FloorKind.FURNITURE: _furniture,
    }[drawn](plan, rng)
    return plan.to_map(rng, floor_name(kind, int(seed)))


class _Plan:
    """A floor being drawn: occupied and unknown masks over the building plus its unknown margin."""

    def __init__(self, width_m: float, height_m: float, resolution_m: float, margin_m: float) -> None:
        self.r = resolution_m
        self.margin = max(1, round(margin_m / resolution_m))
        self.h, self.w = max(8, round(height_m / resolution_m)), max(8, round(width_m / resolution_m))
        self.occupied = np.zeros((self.h, self.w), dtype=bool)
        self.unknown = np.zeros((self.h, self.w), dtype=bool)
        self.wall = max(1, round(0.1 / resolution_m))
        self.occupied[: self.wall] = self.occupied[-self.wall :] = True
        self.occupied[:, : self.wall] = self.occupied[:, -self.wall :] = True
        self.doors = np.zeros((self.h, self.w), dtype=bool)
        """Cells kept free in and just before every doorway, so furniture never blocks one."""

    @classmethod
    def draw(cls, rng: np.random.Generator, fr: FloorRange) -> _Plan:
        width, height = (float(v) for v in rng.uniform(fr.min_side_m, fr.max_side_m, size=2))
        if max(width, height) > 3 * min(width, height):  # at most 3:1
            width, height = (min(width, 3 * height), min(height, 3 * width))
        resolution = round(float(rng.uniform(fr.min_resolution_m, fr.max_resolution_m)) / 0.005) * 0.005
        margin = float(rng.uniform(0.1, 1.0))
        cells = (width + 2 * margin) * (height + 2 * margin) / resolution**2
        if cells > fr.max_cells:  # coarsen to fit, in steps of 5 mm
            resolution = math.ceil(math.sqrt((width + 2 * margin) * (height + 2 * margin) / fr.max_cells) / 0.005)
            resolution *= 0.005
        return cls(width, height, round(max(resolution, fr.min_resolution_m), 4), margin)

    def cells_of(self, metres: float) -> int:
        return max(1, round(metres / self.r))

    def box(self, r0: int, c0: int, rh: int, rw: int) -> tuple[slice, slice]:
        return slice(max(r0, 0), min(r0 + rh, self.h)), slice(max(c0, 0), min(c0 + rw, self.w))

    def wall_with_door(self, rng: np.random.Generator, horizontal: bool, at: int, lo: int, hi: int) -> None:
        """A wall along row `at` (or column) from `lo` to `hi` with one doorway of 0.8-1.1 m in it."""
        t = self.wall
        door = self.cells_of(float(rng.uniform(0.8, 1.1)))
        span = hi - lo
        start = lo + int(rng.integers(0, max(1, span - door))) if span > door + 2 else lo
        keep = self.cells_of(0.6)  # free approach on both sides of the doorway
        if horizontal:
            self.occupied[at : at + t, lo:hi] = True
            self.occupied[at : at + t, start : start + door] = False
            self.doors[max(at - keep, 0) : at + t + keep, start : start + door] = True
        else:
            self.occupied[lo:hi, at : at + t] = True
            self.occupied[start : start + door, at : at + t] = False
            self.doors[start : start + door, max(at - keep, 0) : at + t + keep] = True

    def place(self, mask: np.ndarray, rng: np.random.Generator) -> bool:
        """Add a piece of furniture (a mask over the grid) unless it covers a doorway or cuts the free area in
        two; about half the pieces keep their inside unknown (the laser saw only their outline)."""
        if (mask & self.doors).any() or not mask.any():
            return False
        occupied = self.occupied | mask
        n = ndimage.label(~occupied, structure=FOUR_CONNECTED)[1]
        if n != 1:
            before = ndimage.label(~self.occupied, structure=FOUR_CONNECTED)[1]
            if n > before:
                return False
        self.occupied = occupied
        if rng.random() < 0.5:
            inside = ndimage.binary_erosion(mask, structure=FOUR_CONNECTED)
            self.unknown |= inside
        return True

    def rect(self, r0: int, c0: int, rh: int, rw: int) -> np.ndarray:
        mask = np.zeros((self.h, self.w), dtype=bool)
        mask[self.box(r0, c0, rh, rw)] = True
        return mask

    def disk(self, rc: float, cc: float, radius: float) -> np.ndarray:
        rows, cols = np.ogrid[: self.h, : self.w]
        return (rows + 0.5 - rc) ** 2 + (cols + 0.5 - cc) ** 2 <= radius**2

    def to_map(self, rng: np.random.Generator, name: str) -> Map:
        """The floor with its unknown margin; free cells cut off from the main area become furniture."""
        free = ~self.occupied
        labels, n = ndimage.label(free, structure=FOUR_CONNECTED)
        if n > 1:
            sizes = np.bincount(labels.ravel())[1:]
            self.occupied |= free & (labels != 1 + int(np.argmax(sizes)))
        m = self.margin
        cells = np.full((self.h + 2 * m, self.w + 2 * m), Cell.UNKNOWN, dtype=np.uint8)
        inner = np.where(self.occupied, Cell.OCCUPIED, Cell.FREE).astype(np.uint8)
        inner[self.unknown & self.occupied] = Cell.UNKNOWN
        cells[m : m + self.h, m : m + self.w] = inner
        return Map(cells, self.r, (-m * self.r, -m * self.r, 0.0), name=name)


def _split(rng: np.random.Generator, plan: _Plan, r0: int, c0: int, r1: int, c1: int, rooms: list) -> None:
    """Binary space partition of [r0, r1) x [c0, c1) into rooms of at least ~1.8 m, a door in every wall."""
    least = plan.cells_of(1.8)
    h, w = r1 - r0, c1 - c0
    can_rows, can_cols = h >= 2 * least + plan.wall, w >= 2 * least + plan.wall
    big = max(h, w) * plan.r > 4.5 or rng.random() < 0.6
    if not (can_rows or can_cols) or not big:
        rooms.append((r0, c0, r1, c1))
        return
    horizontal = can_rows and (not can_cols or h > w or (h == w and rng.random() < 0.5))
    if horizontal:
        at = int(rng.integers(r0 + least, r1 - least - plan.wall + 1))
        plan.wall_with_door(rng, True, at, c0, c1)
        _split(rng, plan, r0, c0, at, c1, rooms)
        _split(rng, plan, at + plan.wall, c0, r1, c1, rooms)
    else:
        at = int(rng.integers(c0 + least, c1 - least - plan.wall + 1))
        plan.wall_with_door(rng, False, at, r0, r1)
        _split(rng, plan, r0, c0, r1, at, rooms)
        _split(rng, plan, r0, at + plan.wall, r1, c1, rooms)


def _furnish(rng: np.random.Generator, plan: _Plan, room: tuple[int, int, int, int], pieces: int) -> None:
    """Beds and sofas against a wall, tables with chairs, round tables: up to `pieces` of them in the room."""
    r0, c0, r1, c1 = room
    for _ in range(pieces):
        choice = rng.random()
        if choice < 0.4:  # against a wall
            long, short = plan.cells_of(float(rng.uniform(0.8, 2.0))), plan.cells_of(float(rng.uniform(0.4, 1.4)))
            rh, rw = (long, short) if rng.random() < 0.5 else (short, long)
            side = int(rng.integers(4))
            r = (r0, r1 - rh, int(rng.integers(r0, max(r0 + 1, r1 - rh))), int(rng.integers(r0, max(r0 + 1, r1 - rh))))
            c = (int(rng.integers(c0, max(c0 + 1, c1 - rw))), int(rng.integers(c0, max(c0 + 1, c1 - rw))), c0, c1 - rw)
            plan.place(plan.rect(r[side], c[side], rh, rw), rng)
        elif choice < 0.75:  # a table and its chairs
            th, tw = plan.cells_of(float(rng.uniform(0.6, 1.4))), plan.cells_of(float(rng.uniform(0.6, 1.4)))
            tr = int(rng.integers(r0, max(r0 + 1, r1 - th)))
            tc = int(rng.integers(c0, max(c0 + 1, c1 - tw)))
            mask = plan.rect(tr, tc, th, tw)
            chair, gap = plan.cells_of(0.4), plan.cells_of(0.15)
            for dr, dc in ((-(chair + gap), tw // 2 - chair // 2), (th + gap, tw // 2 - chair // 2),
                           (th // 2 - chair // 2, -(chair + gap)), (th // 2 - chair // 2, tw + gap)):  # fmt: skip
                if rng.random() < 0.7:
                    mask |= plan.rect(tr + dr, tc + dc, chair, chair)
            plan.place(mask, rng)
        else:  # a round table
            radius = float(rng.uniform(0.25, 0.6)) / plan.r
            plan.place(plan.disk(float(rng.uniform(r0, r1)), float(rng.uniform(c0, c1)), radius), rng)


def _rooms(plan: _Plan, rng: np.random.Generator) -> None:
    rooms: list[tuple[int, int, int, int]] = []
    t = plan.wall
    _split(rng, plan, t, t, plan.h - t, plan.w - t, rooms)
    for room in rooms:
        area = (room[2] - room[0]) * (room[3] - room[1]) * plan.r**2
        _furnish(rng, plan, room, int(rng.integers(0, 2 + int(area // 6))))


def _corridor(plan: _Plan, rng: np.random.Generator) -> None:
    """A corridor along the longer side; rooms off it on one or both sides, each with a door onto it."""
    t = plan.wall
    transpose = plan.h > plan.w  # draw along the columns, then turn the masks if the floor is tall
    if transpose:
        plan.occupied, plan.unknown, plan.doors = plan.occupied.T.copy(), plan.unknown.T.copy(), plan.doors.T.copy()
        plan.h, plan.w = plan.w, plan.h
    width = plan.cells_of(float(rng.uniform(1.2, 2.4)))
    depth = plan.h - 2 * t
    both = depth * plan.r > 5.5 and rng.random() < 0.7
    top = t + (int(rng.integers(plan.cells_of(1.8), max(plan.cells_of(1.8) + 1, depth - width - plan.cells_of(1.8))))
               if both else (0 if rng.random() < 0.5 else depth - width))  # fmt: skip
    bottom = top + width
    rooms: list[tuple[int, int, int, int]] = []
    for lo, hi, wall_at in ((t, top, top - t), (bottom, plan.h - t, bottom)):
        if hi - lo < plan.cells_of(1.2):
            continue
        c = t
        while c < plan.w - t - plan.cells_of(1.5):
            room_w = plan.cells_of(float(rng.uniform(2.0, 4.5)))
            end = min(c + room_w, plan.w - t)
            if plan.w - t - end < plan.cells_of(1.8):
                end = plan.w - t
            plan.wall_with_door(rng, True, wall_at, c, end)
            if end < plan.w - t:
                plan.occupied[lo:hi, end : end + t] = True
            rooms.append((lo, c, hi, end))
            c = end + t
    for room in rooms:
        _furnish(rng, plan, room, int(rng.integers(0, 3)))
    if transpose:
        plan.occupied, plan.unknown, plan.doors = plan.occupied.T.copy(), plan.unknown.T.copy(), plan.doors.T.copy()
        plan.h, plan.w = plan.w, plan.h


def _hall(plan: _Plan, rng: np.random.Generator) -> None:
    """Round pillars on a grid, and clusters of desks between them."""
    spacing = float(rng.uniform(2.0, 4.0)) / plan.r
    radius = float(rng.uniform(0.12, 0.35)) / plan.r
    off_r, off_c = (float(v) for v in rng.uniform(0.5, 1.0, size=2) * spacing)
    for rc in np.arange(off_r, plan.h - radius - 1, spacing):
        for cc in np.arange(off_c, plan.w - radius - 1, spacing):
            plan.place(plan.disk(float(rc), float(cc), radius), rng)
    for _ in range(int(rng.integers(1, int(2 + plan.h * plan.w * plan.r**2 // 15)))):
        dh, dw = plan.cells_of(float(rng.uniform(0.6, 0.8))), plan.cells_of(float(rng.uniform(1.0, 1.6)))
        rows, cols = int(rng.integers(1, 3)), int(rng.integers(1, 4))
        r0 = int(rng.integers(plan.wall, max(plan.wall + 1, plan.h - rows * dh)))
        c0 = int(rng.integers(plan.wall, max(plan.wall + 1, plan.w - cols * dw)))
        plan.place(plan.rect(r0, c0, rows * dh, cols * dw), rng)


def _furniture(plan: _Plan, rng: np.random.Generator) -> None:
    """One room cluttered up to a drawn share of its floor with rectangles and disks of 0.2-1.2 m."""
    density = float(rng.uniform(0.08, 0.3))
    target = density * plan.h * plan.w
    for _ in range(400):
        if plan.occupied.sum() >= target:
            break
        if rng.random() < 0.75:
            rh, rw = (plan.cells_of(float(v)) for v in rng.uniform(0.2, 1.2, size=2))
            mask = plan.rect(int(rng.integers(0, plan.h - rh + 1)), int(rng.integers(0, plan.w - rw + 1)), rh, rw)
        else:
            radius = float(rng.uniform(0.15, 0.5)) / plan.r
            mask = plan.disk(float(rng.uniform(0, plan.h)), float(rng.uniform(0, plan.w)), radius)
        plan.place(mask, rng)

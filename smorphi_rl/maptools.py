"""Map preparation for real floors: crop to the recorded area, coarsen the resolution, drop free islands.

Real occupancy maps waste most of their grid on unknown space (`tb3_world`: 94 % of 384 x 384 cells) and
carry specks of free cells that no robot can reach. These functions return a new `Map` (the input is
never changed); `smorphi-rl maps crop` and `maps resample` write the result as a map_server YAML beside its image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from smorphi_rl.errors import MapError
from smorphi_rl.maps import EDGE_TOLERANCE_CELLS, Cell, Map, check_resolution

FOUR_CONNECTED = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]])


@dataclass(frozen=True)
class Islands:
    """Free areas dropped as too small: how many and their total area."""

    count: int
    area_m2: float


def drop_islands(grid_map: Map, min_area_m2: float) -> tuple[Map, Islands]:
    """The map with every 4-connected free area smaller than `min_area_m2` marked unknown (so it is neither
    covered nor counted), and what was dropped; the largest area is always kept."""
    if not min_area_m2 >= 0:
        raise MapError(f"the smallest island to keep must be >= 0 m^2, got {min_area_m2}")
    labels, _ = ndimage.label(grid_map.cells == Cell.FREE, structure=FOUR_CONNECTED)
    sizes = np.bincount(labels.ravel())[1:]
    cell_m2 = grid_map.resolution_m**2
    small = np.flatnonzero(sizes * cell_m2 < min_area_m2) + 1
    small = small[small != 1 + int(np.argmax(sizes))]
    cells = grid_map.cells.copy()
    cells[np.isin(labels, small)] = Cell.UNKNOWN
    dropped = Islands(int(small.size), float(sizes[small - 1].sum() * cell_m2))
    return Map(cells, grid_map.resolution_m, grid_map.origin, grid_map.name), dropped


def crop_to_known(grid_map: Map, margin_m: float = 0.0) -> Map:
    """The map cut to the bounding box of its known (free or occupied) cells plus `margin_m` on each side
    (clipped to the map); the origin moves so every kept cell stays where it was in the world."""
    if not margin_m >= 0:
        raise MapError(f"the crop margin must be >= 0 m, got {margin_m}")
    side = max(grid_map.width, grid_map.height) * grid_map.resolution_m
    if margin_m > side:
        raise MapError(f"the crop margin {margin_m:g} m is beyond the map's own {side:g} m: it would crop nothing")
    k0, k1, j0, j1 = grid_map.known_box()
    pad = int(np.ceil(margin_m / grid_map.resolution_m - 1e-9))
    r0, r1 = max(k0 - pad, 0), min(k1 + pad, grid_map.height)
    c0, c1 = max(j0 - pad, 0), min(j1 + pad, grid_map.width)
    return Map(grid_map.cells[r0:r1, c0:c1], grid_map.resolution_m, _moved(grid_map, r0, c0), grid_map.name)


def _moved(grid_map: Map, row: int, col: int) -> tuple[float, float, float]:
    """The origin of a crop whose first cell is (`row`, `col`) of `grid_map`, rounded to a nanometre, so the YAML
    says -3.15 and not -3.1499999999999995."""
    x0, y0, yaw = grid_map.origin
    r = grid_map.resolution_m
    return (round(x0 + col * r, 9), round(y0 + row * r, 9), yaw)


def crop_to_rect(grid_map: Map, x0: float, y0: float, x1: float, y1: float) -> Map:
    """The cells of the map inside the rectangle [x0, x1] x [y0, y1] metres (map frame); the rectangle must
    lie on the map and hold at least one free cell."""
    rect = f"crop rectangle ({x0:g}, {y0:g}) - ({x1:g}, {y1:g}) m"
    if not (x1 > x0 and y1 > y0):
        raise MapError(f"{rect} is empty: give X0 Y0 X1 Y1 with X1 > X0 and Y1 > Y0")
    ox, oy, _ = grid_map.origin
    r = grid_map.resolution_m
    extent = (ox, oy, ox + grid_map.width * r, oy + grid_map.height * r)
    if x0 < extent[0] - 1e-9 or y0 < extent[1] - 1e-9 or x1 > extent[2] + 1e-9 or y1 > extent[3] + 1e-9:
        raise MapError(
            f"{rect} is not inside map {grid_map.name}, which spans "
            f"({extent[0]:g}, {extent[1]:g}) - ({extent[2]:g}, {extent[3]:g}) m"
        )
    tol = EDGE_TOLERANCE_CELLS
    c0, r0 = int(np.floor((x0 - ox) / r + tol)), int(np.floor((y0 - oy) / r + tol))
    c1, r1 = int(np.ceil((x1 - ox) / r - tol)), int(np.ceil((y1 - oy) / r - tol))
    cells = grid_map.cells[r0:r1, c0:c1]
    if not (cells == Cell.FREE).any():
        raise MapError(f"{rect} holds no free cell of {grid_map.name}")
    return Map(cells, r, _moved(grid_map, r0, c0), grid_map.name)


def resample(grid_map: Map, resolution_m: float) -> Map:
    """The map at `resolution_m` metres a cell, a whole multiple of its own (`coarsen`)."""
    factor = resolution_m / grid_map.resolution_m
    if not np.isfinite(factor) or factor < 1 - 1e-9:
        raise MapError(
            f"map {grid_map.name} is at {grid_map.resolution_m:g} m a cell: resample only to a coarser resolution, "
            f"not {resolution_m:g} m"
        )
    side = max(grid_map.cells.shape)
    if factor > side:
        most = side * grid_map.resolution_m
        raise MapError(f"resolution {resolution_m:g} m: a cell larger than map {grid_map.name} itself "
                       f"({side} cells of {grid_map.resolution_m:g} m); at most {most:g} m")  # fmt: skip
    if abs(factor - round(factor)) > 1e-6:
        own = grid_map.resolution_m
        near = sorted({max(2, math.floor(factor)), max(2, math.ceil(factor))})  # coarser than its own
        raise MapError(f"resolution {resolution_m:g} m is not a whole multiple of map {grid_map.name}'s {own:g} m "
                       f"(the nearest: {' or '.join(f'{round(k * own, 12):.12g}' for k in near)})")  # fmt: skip
    check_resolution(resolution_m, "--resolution")  # a map no map file may hold: refused before it is written
    return coarsen(grid_map, round(factor))


def coarsen(grid_map: Map, factor: int) -> Map:
    """The map at `factor` times its cell size. A coarse cell is occupied if any cell under it is, else
    unknown if any is, else free: conservative, so a footprint safe on the coarse map is safe on the fine one.
    The grid is padded with unknown cells to a multiple of `factor`."""
    if isinstance(factor, bool) or not isinstance(factor, int) or factor < 1:
        raise MapError(f"the coarsening factor must be a whole number >= 1, got {factor!r}")
    if factor == 1:
        return grid_map
    h, w = grid_map.cells.shape
    hp, wp = -(-h // factor) * factor, -(-w // factor) * factor
    padded = np.full((hp, wp), Cell.UNKNOWN, dtype=np.uint8)
    padded[:h, :w] = grid_map.cells
    blocks = padded.reshape(hp // factor, factor, wp // factor, factor).transpose(0, 2, 1, 3)
    occupied = (blocks == Cell.OCCUPIED).any(axis=(2, 3))
    unknown = (blocks == Cell.UNKNOWN).any(axis=(2, 3))
    cells = np.where(occupied, Cell.OCCUPIED, np.where(unknown, Cell.UNKNOWN, Cell.FREE)).astype(np.uint8)
    if not (cells == Cell.FREE).any():
        raise MapError(f"map {grid_map.name}: coarsened {factor}x no cell is wholly free; use a smaller factor")
    resolution_m = round(grid_map.resolution_m * factor, 12)  # 0.15, not 0.05 x 3 = 0.15000000000000002
    return Map(cells, resolution_m, grid_map.origin, grid_map.name)

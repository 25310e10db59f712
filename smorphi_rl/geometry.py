"""Smorphi geometry (docs/spec/fbcpp.md sections 1-2): hinge angles -> block poses -> footprint matrix F.

This is the readable, spec-literal implementation in plain Python. The compiled fast path
(`smorphi_rl._kernels`) does the same arithmetic in the same order and is tested against it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from smorphi_rl.errors import MorphologyError, SmorphiError
from smorphi_rl.inputs import is_finite_number

DEFAULT_BLOCK_SIDE_M = 0.17
"""Side of one Smorphi block, the commercial module (docs/spec/fbcpp.md section 1)."""

ANGLE_MIN_DEG = 0.0
ANGLE_MAX_DEG = 180.0
POINT_TOLERANCE_M = 1e-9
"""Closed-square tolerance when rasterising F (docs/spec/fbcpp.md section 2)."""
OVERLAP_TOLERANCE = 1e-9
"""Blocks overlap when their intersection area exceeds this many s^2 (docs/spec/fbcpp.md section 1)."""

# Hinge i sits at this corner of block i, in units of s, and folds by this sign times t_i.
HINGE_CORNERS = ((1.0, 0.0), (1.0, 1.0), (1.0, 0.0))
HINGE_SIGNS = (-1.0, 1.0, -1.0)
UNIT_SQUARE = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))

Point = tuple[float, float]


def angles_text(theta: Sequence[float]) -> str:
    """Hinge angles as every table and report shows them: (135, 56, 125)."""
    return "(" + ", ".join(f"{t:g}" for t in theta) + ")"


@dataclass(frozen=True)
class Morphology:
    """Three hinge angles in degrees, each in [0, 180]; validated on construction."""

    t1: float
    t2: float
    t3: float

    def __post_init__(self) -> None:
        for name, value in zip(("t1", "t2", "t3"), self.angles, strict=True):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise MorphologyError(f"hinge angle {name}={value!r} is not a number")
            if not math.isfinite(value) or not ANGLE_MIN_DEG <= value <= ANGLE_MAX_DEG:
                raise MorphologyError(f"hinge angle {name}={value} is outside [0, 180] degrees")

    @property
    def angles(self) -> tuple[float, float, float]:
        return (self.t1, self.t2, self.t3)

    @classmethod
    def of(cls, theta: Iterable[float]) -> Morphology:
        """Build from any sequence of three numbers (list, tuple, numpy row)."""
        values = list(theta)
        if len(values) != 3:
            raise MorphologyError(f"a morphology needs 3 hinge angles, got {len(values)}")
        return cls(*(v.item() if isinstance(v, np.generic) else v for v in values))


@dataclass(frozen=True)
class BlockPose:
    """Block origin (a corner) in metres and heading in degrees; the block is o + R(phi)[0,s]^2."""

    origin_m: Point
    heading_deg: float


def _rotate(x: float, y: float, cos_a: float, sin_a: float) -> Point:
    return (cos_a * x - sin_a * y, sin_a * x + cos_a * y)


def block_poses(morphology: Morphology, block_side_m: float = DEFAULT_BLOCK_SIDE_M) -> tuple[BlockPose, ...]:
    """Poses of blocks B1..B4: B1 at the origin, each hinge folding the rest of the chain."""
    s = block_side_m
    ox, oy, phi = 0.0, 0.0, 0.0
    poses = [BlockPose((ox, oy), phi)]
    for t, (hx, hy), sign in zip(morphology.angles, HINGE_CORNERS, HINGE_SIGNS, strict=True):
        c, sn = math.cos(math.radians(phi)), math.sin(math.radians(phi))
        nx, ny = _rotate(s, 0.0, c, sn)
        px, py = ox + nx, oy + ny  # unfolded origin of the next block
        dx, dy = _rotate(hx * s, hy * s, c, sn)
        hpx, hpy = ox + dx, oy + dy  # hinge point
        a = sign * t
        ca, sa = math.cos(math.radians(a)), math.sin(math.radians(a))
        rx, ry = _rotate(px - hpx, py - hpy, ca, sa)
        ox, oy, phi = hpx + rx, hpy + ry, phi + a
        poses.append(BlockPose((ox, oy), phi))
    return tuple(poses)


def block_corners(pose: BlockPose, block_side_m: float = DEFAULT_BLOCK_SIDE_M) -> tuple[Point, ...]:
    """The four corners of one block, counter-clockwise."""
    c, sn = math.cos(math.radians(pose.heading_deg)), math.sin(math.radians(pose.heading_deg))
    ox, oy = pose.origin_m
    corners = []
    for u, v in UNIT_SQUARE:
        dx, dy = _rotate(u * block_side_m, v * block_side_m, c, sn)
        corners.append((ox + dx, oy + dy))
    return tuple(corners)


def all_corners(morphology: Morphology, block_side_m: float = DEFAULT_BLOCK_SIDE_M) -> list[tuple[Point, ...]]:
    """Corners of every block, B1 first."""
    return [block_corners(p, block_side_m) for p in block_poses(morphology, block_side_m)]


def footprint_size(morphology: Morphology, block_side_m: float = DEFAULT_BLOCK_SIDE_M) -> tuple[float, float]:
    """(w_fp, l_fp) in metres: the extent of the 16 block corners in x and y (paper eqs. 3-4)."""
    pts = [p for block in all_corners(morphology, block_side_m) for p in block]
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    return (max(xs) - min(xs), max(ys) - min(ys))


def _clip(subject: Sequence[Point], clip: Sequence[Point]) -> list[Point]:
    """Sutherland-Hodgman: the part of convex polygon `subject` inside counter-clockwise `clip`."""
    out = list(subject)
    for k in range(len(clip)):
        if not out:
            break
        ax, ay = clip[k]
        bx, by = clip[(k + 1) % len(clip)]
        ex, ey = bx - ax, by - ay
        inp, out = out, []
        for m in range(len(inp)):
            px, py = inp[m]
            qx, qy = inp[(m + 1) % len(inp)]
            dp = ex * (py - ay) - ey * (px - ax)
            dq = ex * (qy - ay) - ey * (qx - ax)
            if dp >= 0.0:
                out.append((px, py))
            if (dp >= 0.0) != (dq >= 0.0):
                f = dp / (dp - dq)
                out.append((px + f * (qx - px), py + f * (qy - py)))
    return out


def _area(poly: Sequence[Point]) -> float:
    n = len(poly)
    twice = sum(poly[i][0] * poly[(i + 1) % n][1] - poly[(i + 1) % n][0] * poly[i][1] for i in range(n))
    return abs(twice) / 2.0


def overlap_area(a: Sequence[Point], b: Sequence[Point]) -> float:
    """Area shared by two convex counter-clockwise polygons."""
    return _area(_clip(a, b)) if a and b else 0.0


def is_feasible(morphology: Morphology, block_side_m: float = DEFAULT_BLOCK_SIDE_M) -> bool:
    """False when two blocks overlap with area above 1e-9 s^2 (a self-colliding robot)."""
    blocks = all_corners(morphology, block_side_m)
    limit = OVERLAP_TOLERANCE * block_side_m * block_side_m
    return all(overlap_area(blocks[i], blocks[j]) <= limit for i in range(4) for j in range(i + 1, 4))


def _inside(px: float, py: float, pose: BlockPose, block_side_m: float) -> bool:
    c, sn = math.cos(math.radians(pose.heading_deg)), math.sin(math.radians(pose.heading_deg))
    dx, dy = px - pose.origin_m[0], py - pose.origin_m[1]
    u, v = c * dx + sn * dy, -sn * dx + c * dy
    lo, hi = -POINT_TOLERANCE_M, block_side_m + POINT_TOLERANCE_M
    return lo <= u <= hi and lo <= v <= hi


def footprint_matrix(
    morphology: Morphology, resolution_m: float, block_side_m: float = DEFAULT_BLOCK_SIDE_M
) -> np.ndarray:
    """Trimmed footprint matrix F (rows grow with y): cells whose centre lies in some block."""
    poses = block_poses(morphology, block_side_m)
    pts = [p for pose in poses for p in block_corners(pose, block_side_m)]
    min_x, min_y = min(p[0] for p in pts), min(p[1] for p in pts)
    w_m, l_m = footprint_size(morphology, block_side_m)
    rows, cols = math.ceil(l_m / resolution_m) + 1, math.ceil(w_m / resolution_m) + 1
    grid = np.zeros((rows, cols), dtype=bool)
    for i in range(rows):
        py = min_y + (i + 0.5) * resolution_m
        for j in range(cols):
            px = min_x + (j + 0.5) * resolution_m
            grid[i, j] = any(_inside(px, py, pose, block_side_m) for pose in poses)
    return trim(grid)


def cells_along(length_m: float, resolution_m: float) -> int:
    """How many cells of F an axis-aligned side of `length_m` spans (section 2: cell centres inside, tolerance
    included): the O's and the I's F are full rectangles of these sides."""
    return math.floor((length_m + POINT_TOLERANCE_M) / resolution_m - 0.5) + 1


def trim(grid: np.ndarray) -> np.ndarray:
    """Crop a boolean grid to the bounding box of its true cells."""
    rows, cols = np.flatnonzero(grid.any(axis=1)), np.flatnonzero(grid.any(axis=0))
    if rows.size == 0:
        return grid[:0, :0]
    return grid[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]


def format_footprint(f: np.ndarray) -> str:
    """F as text, top row (highest y) first, '#' for in F: the notation of docs/spec/fbcpp.md section 8."""
    return "\n".join("".join("#" if v else "." for v in row) for row in f[::-1])


MAX_BLOCK_CELLS = 400
"""A block may span at most this many map cells (the footprint buffer grows with its square)."""


def check_block_side(block_side_m: float, resolution_m: float) -> float:
    """The block side, if a block spans at least one and at most MAX_BLOCK_CELLS cells of the map;
    MorphologyError naming both otherwise (a footprint under one cell has no tiles to plan on)."""
    if not is_finite_number(block_side_m):
        raise MorphologyError(f"block side must be a finite number of metres, got {block_side_m!r}")
    if block_side_m <= 0:
        raise MorphologyError(f"block side must be > 0 m, got {block_side_m:g}")
    cells = block_side_m / resolution_m
    if cells < 1 - 1e-9:  # a block of one cell exactly, whatever the division makes of it (0.3 / 0.30000000000000004)
        raise MorphologyError(f"a block of {block_side_m:g} m is smaller than one cell of this map "
                              f"({resolution_m:g} m): plan on a map of cells no larger than a block")  # fmt: skip
    if cells > MAX_BLOCK_CELLS:
        many = f"{cells:,.0f}" if cells < 1e9 else f"{cells:.3g}"  # not a number of 300 digits
        raise MorphologyError(f"a block of {block_side_m:g} m spans {many} cells of this map "
                              f"({resolution_m:g} m); at most {MAX_BLOCK_CELLS}: resample the map coarser")  # fmt: skip
    return float(block_side_m)


def check_step(step_deg: float) -> float:
    """A lattice step must divide 180 exactly (so 0 and 180 are both on it)."""
    if not (math.isfinite(step_deg) and 0 < step_deg <= 180):
        raise SmorphiError(f"--step must be in (0, 180], got {step_deg:g}")
    n = 180 / step_deg
    if not math.isfinite(n) or not math.isclose(n, round(n), abs_tol=1e-9):  # 5e-324: 180 / step overflows
        raise SmorphiError(f"--step {step_deg:g} does not divide 180")
    return float(step_deg)


def lattice_size(step_deg: float) -> int:
    """How many shapes the `step_deg` lattice holds: (180 / step + 1)^3, 5,929,741 at 1 degree."""
    return (round(ANGLE_MAX_DEG / step_deg) + 1) ** 3


def lattice_axis(step_deg: float) -> np.ndarray:
    """Every angle of the `step_deg` lattice of [0, 180], in order (index i: i x step), the last held at 180: 169
    steps of 180/169 make 180.00000000000003, an angle Morphology refuses. The one place an index becomes an angle."""
    return np.minimum(np.arange(round(ANGLE_MAX_DEG / step_deg) + 1) * step_deg, ANGLE_MAX_DEG)


LATTICE_TOLERANCE_DEG = 1e-3
"""How far an angle read back from a file (float32 arrays, a table's 6 significant digits) may lie from the lattice
angle it was."""


def nearest_on_lattice(thetas: np.ndarray, step_deg: float) -> np.ndarray:
    """Each angle's nearest angle of the `step_deg` lattice, as `lattice_axis` gives it (float64)."""
    axis = lattice_axis(step_deg)
    index = np.clip(np.rint(np.asarray(thetas, dtype=np.float64) / step_deg), 0, len(axis) - 1)
    return axis[index.astype(np.intp)]

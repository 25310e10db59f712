"""FBCPP (docs/spec/fbcpp.md sections 4-7, and the footprint-safe planner of docs/fbcpp-fit.md) on the compiled
fast path: value types and one full plan.

`plan_coverage` returns the path and covered mask for plots and replays; `planning.Evaluator`
is the cached, batched entry point for everything that only needs the metrics.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, NamedTuple

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import Cell, Map, free_prefix_sum


class Planner(enum.Enum):
    """Which coverage planner scores a shape."""

    PAPER = "paper"
    """docs/spec/fbcpp.md: tiles from the map's corner, traversable when any cell is free (the robot may stand over
    obstacles and unknown space, as in the paper)."""
    FIT = "fit"
    """docs/fbcpp-fit.md: F only ever over free cells, moves collision-free, a start in the largest free area."""

    @property
    def code(self) -> int:
        """The kernels' PLANNER_* code."""
        return 1 if self is Planner.FIT else 0


PLANNERS = tuple(p.value for p in Planner)


class StartKind(enum.IntEnum):
    """Where the coverage path starts (values match the kernels' START_* codes)."""

    AUTO = 0  # paper: the first traversable tile in row-major order; fit: in the largest free area
    TILE = 1  # a tile (a, b) of the resized map; must be traversable for the footprint
    CELL = 2  # paper: the tile holding this free map cell; fit: the safe placements whose F holds it


@dataclass(frozen=True)
class Start:
    """A start tile, or a free map cell whose tile is the start for every footprint."""

    kind: StartKind = StartKind.AUTO
    row: int = 0
    col: int = 0

    @classmethod
    def tile(cls, a: int, b: int) -> Start:
        if a < 0 or b < 0:
            raise SmorphiError(f"start tile ({a}, {b}) has a negative index")
        return cls(StartKind.TILE, a, b)

    @classmethod
    def point(cls, grid_map: Map, x_m: float, y_m: float) -> Start:
        """The cell under a point in metres (map frame); it must be free."""
        row, col = grid_map.cell_of(x_m, y_m)
        if grid_map.cells[row, col] != Cell.FREE:
            state = Cell(grid_map.cells[row, col]).name.lower()
            raise SmorphiError(f"start point ({x_m}, {y_m}) m is on an {state} cell of map {grid_map.name}")
        return cls(StartKind.CELL, row, col)

    def describe(self) -> str:
        return {
            StartKind.AUTO: "first traversable tile",
            StartKind.TILE: f"tile ({self.row}, {self.col})",
            StartKind.CELL: f"cell ({self.row}, {self.col})",
        }[self.kind]


AUTO_START = Start()


@dataclass(frozen=True, eq=False)
class PreparedMap:
    """A map with what every plan on it reuses: a 2-D prefix sum of free cells, the map as
    0 (free) / 1 (not free) padded below and right by `pad_cells`, so stamps need no clipping, and
    (for the fit planner) the largest free area."""

    grid_map: Map
    pad_cells: int
    planner: Planner = Planner.PAPER
    free_prefix: np.ndarray = field(init=False, repr=False)
    padded: np.ndarray = field(init=False, repr=False)
    area: np.ndarray = field(init=False, repr=False)
    """The largest 4-connected free area as a flat uint8 mask (fit planner; empty for paper)."""
    fit_bits: np.ndarray = field(init=False, repr=False)
    """What every fit plan on the map reuses (`_kernels.fit_bits`; empty for paper)."""

    def __post_init__(self) -> None:
        free = self.grid_map.cells == Cell.FREE
        prefix = free_prefix_sum(self.grid_map)
        padded = np.ones((free.shape[0] + self.pad_cells, free.shape[1] + self.pad_cells), dtype=np.uint8)
        padded[: free.shape[0], : free.shape[1]] = ~free
        object.__setattr__(self, "free_prefix", prefix)
        object.__setattr__(self, "padded", padded)
        area, bits = _NO_AREA, _NO_BITS
        if self.planner is Planner.FIT:
            from smorphi_rl import _kernels as k

            area = largest_free_area(free)
            bits = k.fit_bits(padded, area, *free.shape)
        object.__setattr__(self, "area", area)
        object.__setattr__(self, "fit_bits", bits)

    @property
    def n_area(self) -> int:
        """Free cells in the largest free area (fit), or every free cell (paper)."""
        return int(self.area.sum()) if self.planner is Planner.FIT else self.n_free

    @property
    def n_free(self) -> int:
        return self.grid_map.counts[Cell.FREE]

    @property
    def n_occupied(self) -> int:
        return self.grid_map.counts[Cell.OCCUPIED]

    def coverage_pct(self, n_covered: np.ndarray | float) -> tuple[np.ndarray | float, np.ndarray | float]:
        """(P_c, coverage_free_pct) from counts of covered free cells (docs/spec/fbcpp.md section 6; the fit planner
        never covers an obstacle, so its P_c is the share of free cells covered, docs/fbcpp-fit.md)."""
        cov_free = 100.0 * n_covered / self.n_free
        if self.planner is Planner.FIT:
            return cov_free, cov_free
        known = self.n_free + self.n_occupied
        return 100.0 * (n_covered + self.n_occupied) / known, cov_free

    def metrics(self, n_covered: Any, p_len: Any, n_ew: Any, n_ns: Any, l: Any, w: Any, n_bound: Any) -> Metrics:
        """The planner kernel's counts as docs/spec/fbcpp.md section 7's metrics: the one place they become results.
        Works on scalars (one plan) and on arrays (a batch) alike."""
        p_c, cov_free = self.coverage_pct(n_covered)
        path_cells = n_ew * w + n_ns * l
        return Metrics(p_c, cov_free, p_len, path_cells * self.grid_map.resolution_m, path_cells,
                       100.0 * n_bound / self.n_free)  # fmt: skip


_NO_AREA = np.zeros(0, dtype=np.uint8)
_NO_BITS = np.zeros((0, 0, 0), dtype=np.uint64)


def free_area_share(grid_map: Map, cell: tuple[int, int] | None = None) -> float:
    """Percent of the free cells in the 4-connected free area holding `cell` (None: the largest area): what
    share of the free space a plan starting there can reach at most."""
    from smorphi_rl import _kernels as k

    free = grid_map.cells == Cell.FREE
    labels = k.components(free.ravel(), *free.shape)
    sizes = np.bincount(labels[labels >= 0])
    if cell is None:
        return 100.0 * float(sizes.max()) / max(int(free.sum()), 1) if sizes.size else 0.0
    own = labels[cell[0] * free.shape[1] + cell[1]]
    return 100.0 * float(sizes[own]) / max(int(free.sum()), 1) if own >= 0 else 0.0


def largest_free_area(free: np.ndarray) -> np.ndarray:
    """The largest 4-connected area of free cells as a flat uint8 mask (ties: the area holding the earliest
    cell in row-major order, row 0 the lowest y)."""
    from smorphi_rl import _kernels as k

    h, w = free.shape
    labels = k.components(free.ravel(), h, w)
    if labels.max() < 0:
        return np.zeros(free.size, dtype=np.uint8)
    biggest = int(np.argmax(np.bincount(labels[labels >= 0])))  # labels follow raster order: first max wins
    return (labels == biggest).astype(np.uint8)


class Metrics(NamedTuple):
    """P_c, coverage of the free cells (%), P_len, path length in metres and in cells (scalars or arrays)."""

    P_c: Any
    coverage_free_pct: Any
    P_len: Any
    path_length_m: Any
    path_length_cells: Any
    coverable_pct: Any
    """The coverable bound as a share of the free cells (docs/fbcpp-fit.md; the paper planner: its coverage)."""


@dataclass(frozen=True, eq=False)
class Footprint:
    """The trimmed footprint matrix F (l x w cells, rows grow with y) and the footprint in metres."""

    matrix: np.ndarray
    width_m: float
    length_m: float
    feasible: bool

    @property
    def cells(self) -> tuple[int, int]:
        """(l, w): rows x columns of F, the tile size of the resized map."""
        return (int(self.matrix.shape[0]), int(self.matrix.shape[1]))


@dataclass(frozen=True, eq=False)
class CoverageResult:
    """What an evaluation returns (docs/spec/fbcpp.md section 7); path and covered mask only on request."""

    theta: tuple[float, float, float]
    feasible: bool
    P_c: float
    coverage_free_pct: float
    P_len: int
    path_length_m: float
    path_length_cells: int
    footprint_m: tuple[float, float]
    footprint_cells: tuple[int, int]
    path_tiles: np.ndarray | None = None
    """Paper planner: the tiles (a, b) visited; fit planner (which has no tiles): the same as `placements`."""
    covered: np.ndarray | None = None
    coverable_pct: float = 0.0
    planner: str = Planner.PAPER.value
    placements: np.ndarray | None = None
    """On request: the cell (row, column) of F's lowest-row, lowest-column corner at every robot position."""
    footprint: np.ndarray | None = None
    """On request: F (rows of 0/1, row 0 the lowest y)."""

    def to_dict(self) -> dict[str, object]:
        """The JSON form printed by `smorphi-rl evaluate --json`."""
        return result_dict(
            list(self.theta), self.P_c, self.coverage_free_pct, self.P_len, self.path_length_m,
            self.feasible, list(self.footprint_cells), list(self.footprint_m), self.coverable_pct, self.planner,
        )  # fmt: skip


RESULT_KEYS = (
    "theta", "P_c", "coverage_free_pct", "P_len", "path_length_m", "feasible", "footprint_cells", "footprint_m",
    "coverable_pct", "planner",
)  # fmt: skip
"""Keys of an evaluation's JSON form, in the order `result_dict` takes its values."""


def result_dict(theta: list[float], *values: object) -> dict[str, object]:
    """One evaluation as JSON-ready dict: the single definition of `evaluate --json`'s shape."""
    return dict(zip(RESULT_KEYS, ([plain_number(t) for t in theta], *values), strict=True))


def plain_number(value: float) -> float | int:
    """An angle as JSON shows it: 95 rather than 95.0, 12.5 as is."""
    return int(value) if float(value).is_integer() else float(value)


def raise_for_status(status: int, start: Start, footprint_cells: tuple[int, int], grid_map: Map) -> None:
    """Turn a kernel status into the error that names the bad start."""
    from smorphi_rl import _kernels as k

    if status == k.STATUS_OK:
        return
    l, w = footprint_cells
    tiles = f"{-(-grid_map.height // l)} x {-(-grid_map.width // w)}"
    if status == k.STATUS_PAD_TOO_SMALL:
        raise SmorphiError(f"footprint {l}x{w} is larger than the planner's buffer; raise PreparedMap.pad_cells")
    if status == k.STATUS_START_OUTSIDE:
        raise SmorphiError(f"start {start.describe()} is outside the {tiles} tiles of footprint {l}x{w}")
    if status == k.STATUS_TILE_START_FIT:
        raise SmorphiError(f"start {start.describe()}: the fit planner has no tiles; give a free point (xy:X,Y)")
    raise SmorphiError(f"start {start.describe()} is not traversable for footprint {l}x{w} on map {grid_map.name}")


def plan_coverage(
    prepared: PreparedMap, footprint: Footprint, theta: tuple[float, float, float], start: Start = AUTO_START
) -> CoverageResult:
    """Full plan with path, placements, F and covered mask; an infeasible footprint plans nothing."""
    from smorphi_rl import _kernels as k

    grid_map = prepared.grid_map
    covered = np.zeros(grid_map.cells.shape, dtype=np.uint8)
    l, w = footprint.cells
    f = np.ascontiguousarray(footprint.matrix, dtype=np.uint8)  # the kernel's one signature takes C order
    if not footprint.feasible:
        return CoverageResult(
            theta, False, 0.0, 0.0, 0, 0.0, 0, (footprint.width_m, footprint.length_m), (l, w),
            np.zeros((0, 2), np.int32), covered.astype(bool), 0.0, prepared.planner.value,
            np.zeros((0, 2), np.int32), f,
        )  # fmt: skip
    capacity = 4 * grid_map.cells.size // (l * w) + 16
    while True:
        path = np.zeros((capacity, 2), dtype=np.int32)
        status, n_cov, p_len, n_ew, n_ns, n_path, n_bound, _, _ = k.plan_any(
            prepared.planner.code, prepared.padded, prepared.free_prefix, prepared.fit_bits, f, l, w, int(start.kind),
            start.row, start.col, covered, path, k.NO_PRUNE,
        )  # fmt: skip
        raise_for_status(status, start, (l, w), grid_map)
        if n_path <= capacity:
            break
        capacity = n_path
    m = prepared.metrics(n_cov, p_len, n_ew, n_ns, l, w, n_bound)
    nodes = path[:n_path].copy()
    placements = nodes if prepared.planner is Planner.FIT else nodes * np.array([l, w], dtype=np.int32)
    return CoverageResult(
        theta=theta,
        feasible=True,
        P_c=float(m.P_c),
        coverage_free_pct=float(m.coverage_free_pct),
        P_len=int(m.P_len),
        path_length_m=float(m.path_length_m),
        path_length_cells=int(m.path_length_cells),
        footprint_m=(footprint.width_m, footprint.length_m),
        footprint_cells=(l, w),
        path_tiles=nodes,
        covered=covered.astype(bool),
        coverable_pct=float(m.coverable_pct),
        planner=prepared.planner.value,
        placements=placements,
        footprint=f,
    )


def sweep_positions(placements: Any) -> list[tuple[int, int]]:
    """Every position of F's corner along a plan: its placements and each one-cell shift of the straight
    moves between them (docs/fbcpp-fit.md section 6); what re-checking a plan from `--json --path` needs."""
    places = [(int(r), int(c)) for r, c in placements]
    out = places[:1]
    for (r0, c0), (r1, c1) in pairwise(places):
        steps = abs(r1 - r0) + abs(c1 - c0)
        if steps == 0 or (r0 != r1 and c0 != c1):
            raise SmorphiError(f"placements {(r0, c0)} -> {(r1, c1)} are not one straight lattice move")
        out += [(r0 + (r1 - r0) * k // steps, c0 + (c1 - c0) * k // steps) for k in range(1, steps + 1)]
    return out


def path_points_m(result: CoverageResult, grid_map: Map) -> np.ndarray:
    """Path as (x, y) metres in the map frame: the centre of the footprint's box at each robot position."""
    if result.placements is None:
        raise SmorphiError("this result was computed without its path")
    l, w = result.footprint_cells
    r = grid_map.resolution_m
    rows = result.placements[:, 0] + l / 2.0
    cols = result.placements[:, 1] + w / 2.0
    return np.column_stack([grid_map.origin[0] + cols * r, grid_map.origin[1] + rows * r])

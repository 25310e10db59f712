"""FBCPP (FBCPP.md sections 4-7) on the compiled fast path: value types and one full plan.

`plan_coverage` returns the path and covered mask for plots and replays; `evaluate.Evaluator`
is the cached, batched entry point for everything that only needs the metrics.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import Cell, Map


class StartKind(enum.IntEnum):
    """Where the coverage path starts (values match the kernels' START_* codes)."""

    AUTO = 0  # first traversable tile in row-major order
    TILE = 1  # a tile (a, b) of the resized map; must be traversable for the footprint
    CELL = 2  # the tile holding this free map cell, for every footprint


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
    """A map with what every plan on it reuses: a 2-D prefix sum of free cells and the map as
    0 (free) / 1 (not free) padded below and right by `pad_cells`, so stamps need no clipping."""

    grid_map: Map
    pad_cells: int
    free_prefix: np.ndarray = field(init=False, repr=False)
    padded: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        free = self.grid_map.cells == Cell.FREE
        prefix = np.zeros((free.shape[0] + 1, free.shape[1] + 1), dtype=np.int32)
        prefix[1:, 1:] = free.astype(np.int32).cumsum(axis=0).cumsum(axis=1)
        padded = np.ones((free.shape[0] + self.pad_cells, free.shape[1] + self.pad_cells), dtype=np.uint8)
        padded[: free.shape[0], : free.shape[1]] = ~free
        object.__setattr__(self, "free_prefix", prefix)
        object.__setattr__(self, "padded", padded)

    @property
    def n_free(self) -> int:
        return self.grid_map.counts[Cell.FREE]

    @property
    def n_occupied(self) -> int:
        return self.grid_map.counts[Cell.OCCUPIED]

    def coverage_pct(self, n_covered: np.ndarray | float) -> tuple[np.ndarray | float, np.ndarray | float]:
        """(P_c, coverage_free_pct) from counts of covered free cells (FBCPP.md section 6)."""
        known = self.n_free + self.n_occupied
        return 100.0 * (n_covered + self.n_occupied) / known, 100.0 * n_covered / self.n_free

    def metrics(self, n_covered: Any, p_len: Any, n_ew: Any, n_ns: Any, l: Any, w: Any) -> Metrics:
        """The planner kernel's counts as FBCPP.md section 7's metrics: the one place they become results.
        Works on scalars (one plan) and on arrays (a batch) alike."""
        p_c, cov_free = self.coverage_pct(n_covered)
        path_cells = n_ew * w + n_ns * l
        return Metrics(p_c, cov_free, p_len, path_cells * self.grid_map.resolution_m, path_cells)


class Metrics(NamedTuple):
    """P_c, coverage of the free cells (%), P_len, path length in metres and in cells (scalars or arrays)."""

    P_c: Any
    coverage_free_pct: Any
    P_len: Any
    path_length_m: Any
    path_length_cells: Any


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
    """What an evaluation returns (FBCPP.md section 7); path and covered mask only on request."""

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
    covered: np.ndarray | None = None

    def to_dict(self) -> dict[str, object]:
        """The JSON form printed by `smorphi-rl evaluate --json`."""
        return result_dict(
            list(self.theta), self.P_c, self.coverage_free_pct, self.P_len, self.path_length_m,
            self.feasible, list(self.footprint_cells), list(self.footprint_m),
        )  # fmt: skip


RESULT_KEYS = (
    "theta", "P_c", "coverage_free_pct", "P_len", "path_length_m", "feasible", "footprint_cells", "footprint_m",
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
    raise SmorphiError(f"start {start.describe()} is not traversable for footprint {l}x{w} on map {grid_map.name}")


def plan_coverage(
    prepared: PreparedMap, footprint: Footprint, theta: tuple[float, float, float], start: Start = AUTO_START
) -> CoverageResult:
    """Full plan with path tiles and covered mask; an infeasible footprint plans nothing."""
    from smorphi_rl import _kernels as k

    grid_map = prepared.grid_map
    covered = np.zeros(grid_map.cells.shape, dtype=np.uint8)
    l, w = footprint.cells
    if not footprint.feasible:
        return CoverageResult(
            theta, False, 0.0, 0.0, 0, 0.0, 0, (footprint.width_m, footprint.length_m), (l, w),
            np.zeros((0, 2), np.int32), covered.astype(bool),
        )  # fmt: skip
    f = footprint.matrix.astype(np.uint8)
    capacity = 4 * grid_map.cells.size // (l * w) + 16
    while True:
        path = np.zeros((capacity, 2), dtype=np.int32)
        status, n_cov, p_len, n_ew, n_ns, n_path = k.plan_into(
            prepared.padded, prepared.free_prefix, f, int(start.kind), start.row, start.col, covered, path
        )
        raise_for_status(status, start, (l, w), grid_map)
        if n_path <= capacity:
            break
        capacity = n_path
    m = prepared.metrics(n_cov, p_len, n_ew, n_ns, l, w)
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
        path_tiles=path[:n_path].copy(),
        covered=covered.astype(bool),
    )


def path_points_m(result: CoverageResult, grid_map: Map) -> np.ndarray:
    """Path as (x, y) metres in the map frame: the centre of the footprint's box on each tile."""
    if result.path_tiles is None:
        raise SmorphiError("this result was computed without its path")
    l, w = result.footprint_cells
    r = grid_map.resolution_m
    rows = result.path_tiles[:, 0] * l + l / 2.0
    cols = result.path_tiles[:, 1] * w + w / 2.0
    return np.column_stack([grid_map.origin[0] + cols * r, grid_map.origin[1] + rows * r])

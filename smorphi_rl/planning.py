"""Planning shapes on a map: the planner and its start (`Planning`) and cached, batched FBCPP plans
(`Evaluator`), the entry point of the env, the searches and the CLI.

The result of a morphology depends on its hinge angles only through the footprint matrix F
(docs/spec/fbcpp.md section 7), so results are cached exactly under F's bits. Batches are rasterised
in one compiled call, deduplicated by F, and only unseen footprints are planned.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smorphi_rl import _kernels as k
from smorphi_rl.coverage import (
    AUTO_START,
    PLANNERS,
    CoverageResult,
    Footprint,
    Planner,
    PreparedMap,
    Start,
    free_area_share,
    plan_coverage,
    raise_for_status,
    result_dict,
)
from smorphi_rl.errors import MorphologyError, SmorphiError
from smorphi_rl.geometry import ANGLE_MAX_DEG, ANGLE_MIN_DEG, DEFAULT_BLOCK_SIDE_M, Morphology, lattice_axis
from smorphi_rl.maps import Cell, Map, check_fits, load_map
from smorphi_rl.score import Weights

_PLAN_COLS = [k.COL_COVERED, k.COL_PLEN, k.COL_EW, k.COL_NS, k.COL_BOUND]  # what the cache holds per F


@dataclass(frozen=True, eq=False)
class BatchResult:
    """Metrics of N morphologies as arrays, in input order."""

    theta: np.ndarray  # (N, 3) degrees
    feasible: np.ndarray  # (N,) bool
    P_c: np.ndarray
    coverage_free_pct: np.ndarray
    P_len: np.ndarray  # (N,) int
    path_length_m: np.ndarray
    path_length_cells: np.ndarray  # (N,) int
    footprint_cells: np.ndarray  # (N, 2) int: l, w
    footprint_m: np.ndarray  # (N, 2): w_fp, l_fp
    coverable_pct: np.ndarray
    planner: str = Planner.PAPER.value

    def __len__(self) -> int:
        return int(self.theta.shape[0])

    def result(self, i: int) -> CoverageResult:
        """Row i as a CoverageResult (without path)."""
        l, w = (int(v) for v in self.footprint_cells[i])
        return CoverageResult(
            theta=(float(self.theta[i, 0]), float(self.theta[i, 1]), float(self.theta[i, 2])),
            feasible=bool(self.feasible[i]),
            P_c=float(self.P_c[i]),
            coverage_free_pct=float(self.coverage_free_pct[i]),
            P_len=int(self.P_len[i]),
            path_length_m=float(self.path_length_m[i]),
            path_length_cells=int(self.path_length_cells[i]),
            footprint_m=(float(self.footprint_m[i, 0]), float(self.footprint_m[i, 1])),
            footprint_cells=(l, w),
            coverable_pct=float(self.coverable_pct[i]),
            planner=self.planner,
        )

    def __iter__(self) -> Iterator[CoverageResult]:
        return (self.result(i) for i in range(len(self)))

    def records(self) -> Iterator[dict[str, object]]:
        """Rows as `CoverageResult.to_dict()` dicts, built straight from the columns (fast)."""
        return (
            result_dict(*row)
            for row in zip(
                self.theta.tolist(),
                self.P_c.tolist(),
                self.coverage_free_pct.tolist(),
                self.P_len.tolist(),
                self.path_length_m.tolist(),
                self.feasible.tolist(),
                self.footprint_cells.tolist(),
                self.footprint_m.tolist(),
                self.coverable_pct.tolist(),
                [self.planner] * len(self),
                strict=True,
            )
        )


def validate_thetas(thetas: np.ndarray) -> np.ndarray:
    """(N, 3) float64 array of finite angles in [0, 180], or a MorphologyError naming row and value. It is
    C-contiguous and writeable whatever came in (Ray hands out read-only arrays): the kernels compile once."""
    arr = np.asarray(thetas, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise MorphologyError(f"expected an (N, 3) array of hinge angles, got shape {arr.shape}")
    bad = ~np.isfinite(arr) | (arr < ANGLE_MIN_DEG) | (arr > ANGLE_MAX_DEG)
    if bad.any():
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise MorphologyError(f"row {i}: hinge angle t{j + 1}={arr[i, j]} is outside [0, 180] degrees")
    return np.require(arr, requirements=("C", "W"))


def as_planner(planner: Planner | str) -> Planner:
    """`planner` as a Planner; an unknown name is one line naming the planners."""
    try:
        return Planner(planner)
    except ValueError:
        raise SmorphiError(f"unknown planner {planner!r} (choose from {', '.join(PLANNERS)})") from None


def _shape(morphology: Morphology | Sequence[float]) -> Morphology:
    """A Morphology as it is; three hinge angles checked as one (the evaluator's public calls take either)."""
    return morphology if isinstance(morphology, Morphology) else Morphology.of(morphology)


class Evaluator:
    """FBCPP metrics of morphologies on one map, cached by footprint matrix.

    One instance per map (and block side, start, planner); the env keeps one per map for its lifetime."""

    def __init__(
        self,
        grid_map: Map | str | Path,
        block_side_m: float = DEFAULT_BLOCK_SIDE_M,
        start: Start = AUTO_START,
        cache: bool = True,
        planner: Planner | str = Planner.PAPER,
        cache_limit: int | None = None,
    ) -> None:
        """`grid_map` a Map or a map file's path; `planner` a Planner or its name."""
        if not isinstance(grid_map, Map):
            grid_map = load_map(grid_map)
        planner = as_planner(planner)
        self.block_side_m = check_fits(grid_map, block_side_m, whole_footprint=planner is Planner.FIT)
        self.start = start
        self.use_cache = cache
        self.planner = planner
        self.footprint_side = k.buffer_side(self.block_side_m, grid_map.resolution_m)
        """The side of the square buffer every F of this map fits in (cells)."""
        self.prepared = PreparedMap(grid_map, pad_cells=2 * self.footprint_side, planner=planner)
        self._buf = np.zeros((self.footprint_side, self.footprint_side), dtype=np.uint8)
        self._no_covered = np.zeros((0, 0), dtype=np.uint8)
        self._no_path = np.zeros((0, 2), dtype=np.int32)
        self._cache: dict[bytes, tuple[float, ...]] = {}
        self.cache_limit = cache_limit
        """At most this many footprints are kept (the cache is emptied when full); None: no limit."""
        self.hits = 0
        self.misses = 0

    @property
    def grid_map(self) -> Map:
        return self.prepared.grid_map

    def cache_size(self) -> int:
        return len(self._cache)

    def _remember(self, key: bytes, counts: tuple[float, ...]) -> None:
        """Keep one plan's counts under F's bits, emptying a full cache first (bounded memory on huge runs)."""
        if self.cache_limit is not None and len(self._cache) >= self.cache_limit:
            self._cache.clear()
        self._cache[key] = counts

    def footprint(self, morphology: Morphology | Sequence[float]) -> Footprint:
        """F and the footprint size of one morphology (compiled rasteriser)."""
        feasible, l, w, w_m, l_m = self._rasterise(_shape(morphology))
        return Footprint(self._buf[:l, :w].astype(bool), w_m, l_m, bool(feasible))

    def _rasterise(self, morphology: Morphology) -> tuple[bool, int, int, float, float]:
        t1, t2, t3 = (float(t) for t in morphology.angles)
        r = self.grid_map.resolution_m
        return k.footprint_into(t1, t2, t3, self.block_side_m, r, self._buf)

    def evaluate(self, morphology: Morphology | Sequence[float]) -> CoverageResult:
        """Metrics of one morphology, or three hinge angles (no path): the env's per-step call."""
        morphology = _shape(morphology)
        feasible, l, w, w_m, l_m = self._rasterise(morphology)
        if not feasible:
            return CoverageResult(morphology.angles, False, 0.0, 0.0, 0, 0.0, 0, (w_m, l_m), (l, w),
                                  planner=self.planner.value)  # fmt: skip
        key = self._buf.tobytes()
        counts = self._cache.get(key) if self.use_cache else None
        if counts is None:
            self.misses += 1
            prepared = self.prepared
            status, *plan = k.plan_any(
                self.planner.code, prepared.padded, prepared.free_prefix, prepared.fit_bits, self._buf, l, w,
                int(self.start.kind), self.start.row, self.start.col, self._no_covered, self._no_path, k.NO_PRUNE,
            )  # fmt: skip
            raise_for_status(status, self.start, (l, w), self.grid_map)
            counts = tuple(float(plan[i]) for i in (0, 1, 2, 3, 5))  # covered, P_len, E/W, N/S, bound
            if self.use_cache:
                self._remember(key, counts)
        else:
            self.hits += 1
        n_cov, p_len, n_ew, n_ns, n_bound = counts
        m = self.prepared.metrics(n_cov, p_len, n_ew, n_ns, l, w, n_bound)
        return CoverageResult(
            theta=morphology.angles,
            feasible=True,
            P_c=float(m.P_c),
            coverage_free_pct=float(m.coverage_free_pct),
            P_len=int(m.P_len),
            path_length_m=float(m.path_length_m),
            path_length_cells=int(m.path_length_cells),
            footprint_m=(w_m, l_m),
            footprint_cells=(l, w),
            coverable_pct=float(m.coverable_pct),
            planner=self.planner.value,
        )

    def plan(self, morphology: Morphology | Sequence[float]) -> CoverageResult:
        """Metrics plus path tiles and covered mask, for plots and replays (not cached)."""
        morphology = _shape(morphology)
        return plan_coverage(self.prepared, self.footprint(morphology), morphology.angles, self.start)

    def evaluate_many(self, thetas: np.ndarray) -> BatchResult:
        """Metrics of every row of an (N, 3) array of hinge angles, in order."""
        arr = validate_thetas(thetas)
        padded, prefix = self.prepared.padded, self.prepared.free_prefix
        s, r, kind, sp, sq = (
            self.block_side_m,
            self.grid_map.resolution_m,
            int(self.start.kind),
            self.start.row,
            self.start.col,
        )
        code, fit = self.planner.code, self.prepared.fit_bits
        if not self.use_cache:
            out = k.evaluate_batch(arr, s, r, padded, prefix, kind, sp, sq, self.footprint_side, code, fit, k.NO_PRUNE)
            self.misses += int(out[:, k.COL_FEASIBLE].sum())
            self._check_statuses(out)
            return self._to_batch(arr, out)
        out, bits = k.footprints_batch(arr, s, r, self.footprint_side)
        feasible = out[:, k.COL_FEASIBLE] > 0
        keys = np.ascontiguousarray(bits).view(np.dtype((np.void, bits.shape[1])))[:, 0]
        unique_keys, first, inverse = np.unique(keys[feasible], return_index=True, return_inverse=True)
        plans = np.zeros((unique_keys.shape[0], len(_PLAN_COLS)))
        missing = []
        for u, key in enumerate(unique_keys):
            cached = self._cache.get(key.tobytes())
            if cached is None:
                missing.append(u)
            else:
                plans[u] = cached
        self.hits += len(unique_keys) - len(missing)
        self.misses += len(missing)
        if missing:
            rows = np.flatnonzero(feasible)[first[missing]]
            shapes = np.ascontiguousarray(out[rows][:, [k.COL_L, k.COL_W]], dtype=np.int64)  # one kernel signature
            fresh = k.plan_batch(bits[rows], shapes, padded, prefix, kind, sp, sq, self.footprint_side, code, fit)
            fresh[:, [k.COL_L, k.COL_W]] = shapes
            self._check_statuses(fresh)
            plans[missing] = fresh[:, _PLAN_COLS]
            for u, plan in zip(missing, plans[missing], strict=True):
                self._remember(unique_keys[u].tobytes(), tuple(float(v) for v in plan))
        out[np.flatnonzero(feasible)[:, None], _PLAN_COLS] = plans[inverse.ravel()]
        return self._to_batch(arr, out)

    def prune_bound(self, weights: Weights | None, threshold: float = -np.inf) -> np.ndarray:
        """What `evaluate_bounded` prunes by: R1 under `weights` (in effect on this map) and the R1 to beat; None
        prunes nothing. Only the fit planner prunes (docs/exact-search.md); the paper planner plans everything."""
        prepared = self.prepared
        known = prepared.n_free if self.planner is Planner.FIT else prepared.n_free + prepared.n_occupied
        base = 0.0 if self.planner is Planner.FIT else 100.0 * prepared.n_occupied / known
        w1, w2 = (0.0, 0.0) if weights is None else (weights.w1, weights.w2)
        return np.array([threshold, w1, w2, base, 100.0 / known, float(prepared.n_free), float(weights is not None)])

    def evaluate_bounded(self, thetas: np.ndarray, bound: np.ndarray) -> tuple[BatchResult, np.ndarray]:
        """Uncached metrics of every row (one plan a row: give distinct footprints), and which rows were pruned:
        no plan of theirs can beat the R1 `bound` holds (`prune_bound`; its threshold rises in place to the best R1
        planned). A pruned row's metrics are zeros; no row's coverable bound is counted (0)."""
        arr = validate_thetas(thetas)
        p, start = self.prepared, self.start
        out = k.evaluate_batch(arr, self.block_side_m, self.grid_map.resolution_m, p.padded, p.free_prefix,
                               int(start.kind), start.row, start.col, self.footprint_side, self.planner.code,
                               p.fit_bits, bound)  # fmt: skip
        pruned = out[:, k.COL_STATUS] == k.STATUS_PRUNED
        out[pruned, k.COL_STATUS] = k.STATUS_OK
        self.misses += int(np.count_nonzero(out[:, k.COL_FEASIBLE]) - np.count_nonzero(pruned))
        self._check_statuses(out)
        return self._to_batch(arr, out), pruned

    def _check_statuses(self, out: np.ndarray) -> None:
        bad = np.flatnonzero(out[:, k.COL_STATUS] != k.STATUS_OK)
        if bad.size:
            i = int(bad[0])
            shape = (int(out[i, k.COL_L]), int(out[i, k.COL_W]))
            raise_for_status(int(out[i, k.COL_STATUS]), self.start, shape, self.grid_map)

    def _to_batch(self, thetas: np.ndarray, out: np.ndarray) -> BatchResult:
        feasible = out[:, k.COL_FEASIBLE] > 0
        l, w = out[:, k.COL_L], out[:, k.COL_W]
        n_cov = np.where(feasible, out[:, k.COL_COVERED], 0.0)
        n_bound = np.where(feasible, out[:, k.COL_BOUND], 0.0)
        m = self.prepared.metrics(n_cov, out[:, k.COL_PLEN], out[:, k.COL_EW], out[:, k.COL_NS], l, w, n_bound)
        return BatchResult(
            theta=thetas,
            feasible=feasible,
            P_c=np.where(feasible, m.P_c, 0.0),
            coverage_free_pct=np.where(feasible, m.coverage_free_pct, 0.0),
            P_len=m.P_len.astype(np.int64),
            path_length_m=m.path_length_m,
            path_length_cells=m.path_length_cells.astype(np.int64),
            footprint_cells=np.column_stack([l, w]).astype(np.int64),
            footprint_m=out[:, [k.COL_W_M, k.COL_L_M]],
            coverable_pct=np.asarray(m.coverable_pct, dtype=float),
            planner=self.planner.value,
        )


@dataclass(frozen=True)
class Planning:
    """How every shape on a map is planned: the block side, the planner and the start point. The one value
    handed to whatever scores shapes (the env, the searches, the exact optimum, the reward scales), so
    they all plan alike; hashable, so per-map figures can be cached under it."""

    block_side_m: float = DEFAULT_BLOCK_SIDE_M
    planner: Planner = Planner.PAPER
    start_xy: tuple[float, float] | None = None
    """A free point (metres, map frame) the plan starts from; None: the planner's default start."""

    def __post_init__(self) -> None:  # a planner's name ("fit") is the planner, as in env_config
        object.__setattr__(self, "planner", as_planner(self.planner))

    def start_on(self, grid_map: Map) -> Start:
        """The start on `grid_map` (the point must be free there)."""
        return AUTO_START if self.start_xy is None else Start.point(grid_map, *self.start_xy)

    def evaluator(self, grid_map: Map, cache: bool = True, cache_limit: int | None = None) -> Evaluator:
        """An evaluator that plans this way on `grid_map`."""
        return Evaluator(grid_map, self.block_side_m, self.start_on(grid_map), cache, self.planner, cache_limit)

    @property
    def is_paper_default(self) -> bool:
        """The paper's planner from its default start: what the paper models, and what reports leave unsaid."""
        return self.planner is Planner.PAPER and self.start_xy is None

    def describe(self, grid_map: Map) -> str:
        """One line for reports: the planner, where plans start and what share of the free space that
        start's area holds (the most any plan from there can cover)."""
        spec = "docs/fbcpp-fit.md" if self.planner is Planner.FIT else "docs/spec/fbcpp.md"
        start = self.start_on(grid_map)
        if self.start_xy is not None:
            x, y = self.start_xy
            where, cell = f"at ({x:g}, {y:g}) m", (start.row, start.col)
        elif self.planner is Planner.FIT:
            where, cell = "in the largest free area", None
        else:
            return f"planner paper ({spec}): plans start at the first traversable tile"
        share = self.reach_share(grid_map, cell)
        return f"planner {self.planner.value} ({spec}): plans start {where}, {share:.1f} % of the free cells"

    def reach_share(self, grid_map: Map, cell: tuple[int, int] | None) -> float:
        """Percent of the free cells plans from the start reach. `fit`: the free area holding `cell` (None: the
        largest), which no plan leaves. `paper`: its robot may stand over obstacles (a tile is traversable when any
        of its cells is free), so a wall thinner than a tile is crossed and the reach is the shape's: the most any of
        REACH_SHAPES covers (some other shape may reach further)."""
        if self.planner is Planner.FIT:
            return free_area_share(grid_map, cell)
        evaluator = self.evaluator(grid_map, cache=False)
        return max(evaluator.evaluate(Morphology(*theta)).coverage_free_pct for theta in REACH_SHAPES)

    def start_warning(self, grid_map: Map, covered_pct: float | None = None) -> str | None:
        """One line when plans start in a free area holding under START_AREA_MIN_PCT of the free cells (the paper's
        default start is the first free cell in row order, which on a SLAM map can be a speck of laser noise),
        naming the options that fix it; None otherwise, and None when a shape already covers `covered_pct` (a
        search's best) of at least that much."""
        if covered_pct is not None and covered_pct >= START_AREA_MIN_PCT:
            return None
        start = self.start_on(grid_map)
        if self.start_xy is not None:
            cell: tuple[int, int] | None = (start.row, start.col)
        elif self.planner is Planner.FIT:
            cell = None  # the largest free area
        else:
            free = np.argwhere(grid_map.cells == Cell.FREE)
            cell = (int(free[0, 0]), int(free[0, 1])) if len(free) else None
        share = self.reach_share(grid_map, cell)
        if share >= START_AREA_MIN_PCT:
            return None
        x, y = grid_map.world_of(*cell) if cell is not None else (0.0, 0.0)
        where = "the largest free area" if cell is None else f"around ({x:.2f}, {y:.2f}) m"
        fix = ("`maps crop --min-island M2` drops specks of free space" if share < SPECK_PCT else
               "`maps crop --rect X0 Y0 X1 Y1` cuts the map down to one of its rooms")  # fmt: skip
        return (
            f"warning: on {grid_map.name} plans start in a free area holding {share:.1f} % of the free cells "
            f"({where}): the rest is out of reach; --start-xy X Y starts them on the floor to clean, and {fix}"
        )

    def key(self) -> list[object]:
        """What a cache of results keys on (the paper planner's default start keeps its old key)."""
        key: list[object] = [self.block_side_m]
        if self.planner is not Planner.PAPER or self.start_xy is not None:
            key += [self.planner.value, None if self.start_xy is None else list(self.start_xy)]
        return key


REACH_SHAPES = ((0.0, 180.0, 0.0), (0.0, 0.0, 0.0), (180.0, 180.0, 180.0), (45.0, 90.0, 90.0), (135.0, 90.0, 90.0))
"""Shapes whose tiles bridge the most under the paper planner: the O, the I along x and along y, and the widest and
the tallest footprints (0.89 m)."""
START_AREA_MIN_PCT = 50.0
"""A start area holding less of the free floor than this is named in a warning (`Planning.start_warning`)."""
SPECK_PCT = 10.0
"""A start area under this share of the free floor is a speck (laser noise), not a room: another fix is named."""
PAPER_PLANNING = Planning()
"""The paper's planning: docs/spec/fbcpp.md with its default start and the commercial block."""


def lattice_thetas(step_deg: float) -> np.ndarray:
    """Every (t1, t2, t3) on the `step_deg` lattice of [0, 180]^3, as an (N, 3) array (`Lattice`'s rows, all: a
    meshgrid makes them five times faster than its index arithmetic, 0.11 s at 1 degree)."""
    g = lattice_axis(step_deg)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)


class Lattice:
    """The lattice's rows, (t1, t2, t3) in order with t3 the fastest, made as they are asked for, by index or slice:
    a Ray actor of a 0.5-degree search held the whole lattice, 1.1 GB, one copy per CPU."""

    def __init__(self, step_deg: float) -> None:
        self.axis = lattice_axis(step_deg)

    def __len__(self) -> int:
        return len(self.axis) ** 3

    def __getitem__(self, rows: slice | np.ndarray) -> np.ndarray:
        index = np.arange(*rows.indices(len(self))) if isinstance(rows, slice) else np.asarray(rows, dtype=np.int64)
        n = len(self.axis)
        first, rest = np.divmod(index, n * n)
        second, third = np.divmod(rest, n)
        return np.stack([self.axis[first], self.axis[second], self.axis[third]], axis=-1)

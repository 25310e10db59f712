"""FBCPP sections 4-6 in plain Python, literally as docs/spec/fbcpp.md words them.

The oracle the compiled planner is tested against, and the yardstick `scripts/bench_fbcpp.py`
measures it by. It stamps F at every one-cell step and checks targets when they are dequeued,
exactly as written; nothing here is optimised.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from smorphi_rl.coverage import CoverageResult, Planner
from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M, Morphology, footprint_matrix, footprint_size, is_feasible
from smorphi_rl.maps import Cell, Map

NEIGHBOURS = ((0, 1), (1, 0), (0, -1), (-1, 0))  # east, north, west, south as (d row, d col)
Tile = tuple[int, int]


@dataclass(frozen=True)
class ReferencePlan:
    """Counts and path of one plan; percentages are derived exactly as the fast path does."""

    n_covered: int
    path: list[Tile]
    n_ew: int
    n_ns: int

    @property
    def p_len(self) -> int:
        return len(self.path) - 1


def wavefront(start: Tile, neighbours: Callable[[Tile], list[Tile]]) -> list[Tile]:
    """docs/spec/fbcpp.md section 5, steps 2-3, on any 4-connected graph given by `neighbours` (in neighbour order)."""
    dist = {start: 0}
    queue = deque([start])
    while queue:
        t = queue.popleft()
        for u in neighbours(t):
            if u not in dist:
                dist[u] = dist[t] + 1
                queue.append(u)
    path, visited, cur = [start], {start}, start
    while len(visited) < len(dist):
        options = [u for u in neighbours(cur) if u not in visited]
        if options:
            cur = max(options, key=lambda u: dist[u])  # max keeps the first of equal D
            path.append(cur)
            visited.add(cur)
            continue
        parent: dict[Tile, Tile | None] = {cur: None}
        queue = deque([cur])
        while queue:
            t = queue.popleft()
            if t not in visited:
                break
            for u in neighbours(t):
                if u not in parent:
                    parent[u] = t
                    queue.append(u)
        route = []
        node: Tile | None = t
        while node != cur and node is not None:
            route.append(node)
            node = parent[node]
        path.extend(reversed(route))
        visited.update(route)
        cur = t
    return path


def plan_reference(cells: list[list[int]], f: list[list[bool]], start: Tile | None = None) -> ReferencePlan:
    """Wavefront coverage of the map `cells` (row 0 lowest y) with footprint `f` (l x w)."""
    h, wd = len(cells), len(cells[0])
    l, w = len(f), len(f[0])
    nr, nc = -(-h // l), -(-wd // w)

    def traversable(t: Tile) -> bool:
        a, b = t
        return any(
            cells[i][j] == Cell.FREE for i in range(a * l, min(a * l + l, h)) for j in range(b * w, min(b * w + w, wd))
        )

    trav = {(a, b) for a in range(nr) for b in range(nc) if traversable((a, b))}

    def neighbours(t: Tile) -> list[Tile]:
        return [(t[0] + da, t[1] + db) for da, db in NEIGHBOURS if (t[0] + da, t[1] + db) in trav]

    if start is None:
        start = min(trav)
    if start not in trav:
        raise ValueError(f"start tile {start} is not traversable")
    path = wavefront(start, neighbours)
    covered: set[Tile] = set()

    def stamp(y: int, x: int) -> None:
        for i in range(l):
            for j in range(w):
                if f[i][j] and 0 <= y + i < h and 0 <= x + j < wd and cells[y + i][x + j] == Cell.FREE:
                    covered.add((y + i, x + j))

    a0, b0 = path[0]
    stamp(a0 * l, b0 * w)
    n_ew = n_ns = 0
    for (pa, pb), (qa, qb) in pairwise(path):
        if pa == qa:
            n_ew += 1
            for k in range(1, w + 1):
                stamp(pa * l, pb * w + (qb - pb) * k)
        else:
            n_ns += 1
            for k in range(1, l + 1):
                stamp(pa * l + (qa - pa) * k, pb * w)
    return ReferencePlan(len(covered), path, n_ew, n_ns)


def evaluate_reference(
    grid_map: Map,
    theta: tuple[float, float, float],
    block_side_m: float = DEFAULT_BLOCK_SIDE_M,
    start: Tile | None = None,
    planner: str = "paper",
) -> dict[str, object]:
    """Geometry plus plan, all in plain Python: the metrics docs/spec/fbcpp.md section 7 names (`planner` "fit":
    docs/fbcpp-fit.md's, with `start` a start cell instead of a tile)."""
    m = Morphology.of(theta)
    w_m, l_m = footprint_size(m, block_side_m)
    f = footprint_matrix(m, grid_map.resolution_m, block_side_m)
    l, w = f.shape
    result: dict[str, object] = {"feasible": is_feasible(m, block_side_m), "footprint_cells": (l, w)}
    result["footprint_m"] = (w_m, l_m)
    if not result["feasible"]:
        return result | {"P_c": 0.0, "coverage_free_pct": 0.0, "P_len": 0, "path_length_cells": 0}
    n_free, n_occ = grid_map.counts[Cell.FREE], grid_map.counts[Cell.OCCUPIED]
    if planner == "fit":
        fit = plan_fit_reference(grid_map.cells.tolist(), f.tolist(), start)
        return result | {
            "P_c": 100.0 * fit.n_covered / n_free,
            "coverage_free_pct": 100.0 * fit.n_covered / n_free,
            "P_len": fit.p_len,
            "path_length_cells": fit.n_ew * w + fit.n_ns * l,
            "coverable_pct": 100.0 * fit.n_bound / n_free,
            "path": fit.placements,
        }
    plan = plan_reference(grid_map.cells.tolist(), f.tolist(), start)
    return result | {
        "P_c": 100.0 * (plan.n_covered + n_occ) / (n_free + n_occ),
        "coverage_free_pct": 100.0 * plan.n_covered / n_free,
        "P_len": plan.p_len,
        "path_length_cells": plan.n_ew * w + plan.n_ns * l,
        "path": plan.path,
    }


# --- planner `fit` (docs/fbcpp-fit.md), literally as written there ---------------------------------


@dataclass(frozen=True)
class FitReferencePlan:
    """Counts, start and path of one footprint-safe plan (docs/fbcpp-fit.md); placements are (row, col)."""

    n_covered: int
    n_bound: int
    start: Tile | None
    placements: list[Tile]
    n_ew: int
    n_ns: int

    @property
    def p_len(self) -> int:
        return max(len(self.placements) - 1, 0)


def free_areas(cells: list[list[int]]) -> list[set[Tile]]:
    """The 4-connected areas of free cells, largest first (ties: the one holding the earliest cell)."""
    h, wd = len(cells), len(cells[0])
    seen: set[Tile] = set()
    areas = []
    for y in range(h):
        for x in range(wd):
            if cells[y][x] != Cell.FREE or (y, x) in seen:
                continue
            area, queue = {(y, x)}, deque([(y, x)])
            seen.add((y, x))
            while queue:
                cy, cx = queue.popleft()
                for dy, dx in NEIGHBOURS:
                    n = (cy + dy, cx + dx)
                    if 0 <= n[0] < h and 0 <= n[1] < wd and cells[n[0]][n[1]] == Cell.FREE and n not in seen:
                        seen.add(n)
                        area.add(n)
                        queue.append(n)
            areas.append(area)
    return sorted(areas, key=lambda a: (-len(a), min(a)))


def plan_fit_reference(cells: list[list[int]], f: list[list[bool]], start_cell: Tile | None = None) -> FitReferencePlan:
    """The footprint-safe wavefront of docs/fbcpp-fit.md on `cells` (row 0 lowest y) with footprint `f`."""
    h, wd = len(cells), len(cells[0])
    l, w = len(f), len(f[0])
    stamp_cells = [(i, j) for i in range(l) for j in range(w) if f[i][j]]

    def safe(p: Tile) -> bool:
        return all(0 <= p[0] + i < h and 0 <= p[1] + j < wd and cells[p[0] + i][p[1] + j] == Cell.FREE
                   for i, j in stamp_cells)  # fmt: skip

    placements = sorted(p for p in ((y, x) for y in range(h) for x in range(wd)) if safe(p))
    safe_set = set(placements)

    def component(p0: Tile) -> set[Tile]:
        found, queue = {p0}, deque([p0])
        while queue:
            p = queue.popleft()
            for dy, dx in NEIGHBOURS:
                q = (p[0] + dy, p[1] + dx)
                if q in safe_set and q not in found:
                    found.add(q)
                    queue.append(q)
        return found

    if start_cell is not None:  # every safe placement whose stamp holds the start cell
        candidates = [p for p in placements if (start_cell[0] - p[0], start_cell[1] - p[1]) in stamp_cells]
    else:  # the component of placements with the most in the largest free area; its first in each lattice class
        areas = free_areas(cells)
        first_i, first_j = stamp_cells[0]
        inside = [p for p in placements if areas and (p[0] + first_i, p[1] + first_j) in areas[0]]
        best_group: tuple[int, set[Tile]] | None = None
        done: set[Tile] = set()
        for p in inside:
            if p not in done:
                group = component(p)
                done |= group
                size = sum(1 for q in inside if q in group)
                if best_group is None or size > best_group[0]:
                    best_group = (size, group)
        classes: dict[Tile, Tile] = {}
        for p in inside:
            if best_group is not None and p in best_group[1]:
                classes.setdefault((p[0] % l, p[1] % w), p)
        candidates = sorted(classes.values())
    best: tuple[int, Tile] | None = None
    for start in candidates:  # the lattice that reaches the most usable nodes; the earliest of equal ones
        s0, _, neighbours = _fit_lattice(safe, l, w, start)
        reached, queue = {s0}, deque([s0])
        while queue:
            for u in neighbours(queue.popleft()):
                if u not in reached:
                    reached.add(u)
                    queue.append(u)
        if best is None or len(reached) > best[0]:
            best = (len(reached), start)
    if best is None:
        return FitReferencePlan(0, 0, None, [], 0, 0)
    plan = _fit_walk(safe, stamp_cells, l, w, best[1])
    start = plan.placements[0]
    bound = {(p[0] + i, p[1] + j) for p in component(start) for i, j in stamp_cells}
    return FitReferencePlan(plan.n_covered, len(bound), start, plan.placements, plan.n_ew, plan.n_ns)


def _fit_lattice(
    safe: Any, l: int, w: int, start: Tile
) -> tuple[Tile, Callable[[Tile], Tile], Callable[[Tile], list[Tile]]]:
    """The lattice through `start` (docs/fbcpp-fit.md section 4): its start node, node -> placement, and the
    joined neighbours of a node in neighbour order."""
    oy, ox = start[0] % l, start[1] % w

    def node(t: Tile) -> Tile:
        return (oy + t[0] * l, ox + t[1] * w)

    def passable(t: Tile, u: Tile) -> bool:
        p, q = node(t), node(u)
        if not (u[0] >= 0 and u[1] >= 0 and safe(q)):
            return False
        steps = w if p[0] == q[0] else l
        dy, dx = (q[0] - p[0]) // steps, (q[1] - p[1]) // steps
        return all(safe((p[0] + dy * k, p[1] + dx * k)) for k in range(steps + 1))

    def neighbours(t: Tile) -> list[Tile]:
        return [u for u in ((t[0] + da, t[1] + db) for da, db in NEIGHBOURS) if passable(t, u)]

    return ((start[0] - oy) // l, (start[1] - ox) // w), node, neighbours


def _fit_walk(safe: Any, stamp_cells: list[Tile], l: int, w: int, start: Tile) -> FitReferencePlan:
    """The wavefront on the lattice of placements through `start` (docs/fbcpp-fit.md section 5); no bound."""
    s0, node, neighbours = _fit_lattice(safe, l, w, start)
    path = wavefront(s0, neighbours)
    covered: set[Tile] = set()

    def stamp(p: Tile) -> None:
        assert safe(p), f"placement {p} is not safe"  # the edge rule guarantees it
        covered.update((p[0] + i, p[1] + j) for i, j in stamp_cells)

    stamp(node(path[0]))
    n_ew = n_ns = 0
    for t, u in pairwise(path):
        p, q = node(t), node(u)
        steps = w if p[0] == q[0] else l
        n_ew, n_ns = (n_ew + 1, n_ns) if p[0] == q[0] else (n_ew, n_ns + 1)
        dy, dx = (q[0] - p[0]) // steps, (q[1] - p[1]) // steps
        for k in range(1, steps + 1):
            stamp((p[0] + dy * k, p[1] + dx * k))
    return FitReferencePlan(len(covered), 0, start, [node(t) for t in path], n_ew, n_ns)


# --- one shape, answered without the compiled kernels -----------------------------------------------

QUICK_MAX_CELLS = {Planner.PAPER: 40_000, Planner.FIT: 10_000}
"""Map sizes (cells) up to which planning one shape here beats loading the compiled kernels (about 1.3 s of
numba start-up on a 2-core machine); above them the compiled path is faster even with its start-up."""


def largest_free_area_pct(grid_map: Map) -> float:
    """Percent of the free cells in the largest 4-connected free area (where the fit planner starts)."""
    areas = free_areas(grid_map.cells.tolist())
    return 100.0 * len(areas[0]) / max(grid_map.counts[Cell.FREE], 1) if areas else 0.0


def quick_result(grid_map: Map, morphology: Morphology, block_side_m: float, planner: Planner) -> CoverageResult | None:
    """One shape from the default start, planned by this module's planners and reported exactly as
    `planning.Evaluator.evaluate` reports it (the tests hold the two equal), or None on a map too big for
    that to be quick. `smorphi-rl evaluate` of one shape uses it to answer without numba."""
    if grid_map.cells.size > QUICK_MAX_CELLS[planner]:
        return None
    fields: dict[str, Any] = evaluate_reference(grid_map, morphology.angles, block_side_m, planner=planner.value)
    w_m, l_m = fields["footprint_m"]
    l, w = fields["footprint_cells"]
    cells = int(fields["path_length_cells"])
    feasible = bool(fields["feasible"])
    if planner is Planner.PAPER:
        coverable = float(fields["coverage_free_pct"]) if feasible else 0.0
    else:
        coverable = float(fields.get("coverable_pct", 0.0))
    placements = None
    if planner is Planner.FIT and feasible:
        placements = np.asarray(fields["path"], dtype=np.int64).reshape(-1, 2)
    return CoverageResult(
        theta=morphology.angles,
        feasible=feasible,
        P_c=float(fields["P_c"]),
        coverage_free_pct=float(fields["coverage_free_pct"]),
        P_len=int(fields["P_len"]),
        path_length_m=cells * grid_map.resolution_m,
        path_length_cells=cells,
        footprint_m=(w_m, l_m),
        footprint_cells=(l, w),
        coverable_pct=coverable,
        planner=planner.value,
        placements=placements,
    )

"""FBCPP sections 4-6 in plain Python, literally as FBCPP.md words them.

The oracle the compiled planner is tested against, and the yardstick `scripts/bench_fbcpp.py`
measures it by. It stamps F at every one-cell step and checks targets when they are dequeued,
exactly as written; nothing here is optimised.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from itertools import pairwise

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
) -> dict[str, object]:
    """Geometry plus plan, all in plain Python: the metrics FBCPP.md section 7 names."""
    m = Morphology.of(theta)
    w_m, l_m = footprint_size(m, block_side_m)
    f = footprint_matrix(m, grid_map.resolution_m, block_side_m)
    l, w = f.shape
    result: dict[str, object] = {"feasible": is_feasible(m, block_side_m), "footprint_cells": (l, w)}
    result["footprint_m"] = (w_m, l_m)
    if not result["feasible"]:
        return result | {"P_c": 0.0, "coverage_free_pct": 0.0, "P_len": 0, "path_length_cells": 0}
    plan = plan_reference(grid_map.cells.tolist(), f.tolist(), start)
    n_free, n_occ = grid_map.counts[Cell.FREE], grid_map.counts[Cell.OCCUPIED]
    return result | {
        "P_c": 100.0 * (plan.n_covered + n_occ) / (n_free + n_occ),
        "coverage_free_pct": 100.0 * plan.n_covered / n_free,
        "P_len": plan.p_len,
        "path_length_cells": plan.n_ew * w + plan.n_ns * l,
        "path": plan.path,
    }

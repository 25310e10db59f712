"""Compiled fast path of FBCPP (numba): footprint rasterisation and the coverage planner.

The arithmetic follows `geometry.py` and `coverage_reference.py` step for step, so results are
identical; tests check that. Two exact shortcuts keep it fast:
- a move between neighbouring tiles stamps one precomputed *swept* mask (the union of the
  footprint shifted by 0..w or 0..l cells) instead of w or l separate stamps;
- each tile edge is swept once, however often the path crosses it.
Only this module imports numba; compiled code is cached on disk (first call compiles, ~10 s).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numba
import numpy as np
from numba import njit
from numba.core import event as numba_events
from numba.misc.appdirs import AppDirs

from smorphi_rl.rundir import own_temp_folder, writable_folder


def cache_fallback(package: Path, user_cache: Path) -> str | None:
    """Where numba should cache the kernels when it can write neither beside them (`package`, a read-only
    install) nor in the user's cache (an unwritable HOME: a shared install, a container run as another user),
    where `cache=True` fails at import in a traceback; None where it can, or NUMBA_CACHE_DIR says."""
    if os.environ.get("NUMBA_CACHE_DIR") or writable_folder(package / "__pycache__") or writable_folder(user_cache):
        return None
    return own_temp_folder("numba")


_USER_CACHE = Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)  # numba's user-wide cache
if (_fallback := cache_fallback(Path(__file__).parent, _USER_CACHE)) is not None:
    os.environ["NUMBA_CACHE_DIR"] = _fallback  # the processes this one starts
    numba.config.CACHE_DIR = _fallback  # type: ignore[attr-defined]  # (set from the environment as numba loads)

# Columns of the per-morphology result rows written by the batch kernels.
COL_FEASIBLE, COL_L, COL_W, COL_W_M, COL_L_M, COL_COVERED, COL_PLEN, COL_EW, COL_NS, COL_STATUS, COL_BOUND = range(11)
N_COLS = 11
STATUS_OK, STATUS_START_BLOCKED, STATUS_START_OUTSIDE, STATUS_PAD_TOO_SMALL, STATUS_TILE_START_FIT = 0, 1, 2, 3, 4
STATUS_PRUNED = 5
"""A bounded plan stopped early: no path from this footprint can reach the R1 it was asked to beat."""
NO_PRUNE = np.zeros(0)
PRUNE_THRESHOLD, PRUNE_W1, PRUNE_W2, PRUNE_PC0, PRUNE_PC_PER_CELL, PRUNE_CELLS, PRUNE_ACTIVE = range(7)
"""A search's `prune` array: the R1 to beat, w1, w2 (in effect), P_c = PC0 + PC_PER_CELL * covered cells, the most
cells any plan covers, and 1 to prune (0: plan everything). A search needs no coverable bound, so any non-empty
array skips it; an empty array plans as `evaluate` does."""
START_AUTO, START_TILE, START_CELL = 0, 1, 2
PLANNER_PAPER, PLANNER_FIT = 0, 1

_HINGE_X = np.array([1.0, 1.0, 1.0])
_HINGE_Y = np.array([0.0, 1.0, 0.0])
_HINGE_SIGN = np.array([-1.0, 1.0, -1.0])
_UNIT_U = np.array([0.0, 1.0, 1.0, 0.0])
_UNIT_V = np.array([0.0, 0.0, 1.0, 1.0])
_NON_ADJACENT = ((0, 2), (0, 3), (1, 3))  # hinged neighbours touch only along an edge or corner
_DR = np.array([0, 1, 0, -1])  # east, north, west, south as (d row, d col)
_DC = np.array([1, 0, -1, 0])


def buffer_side(block_side_m: float, resolution_m: float) -> int:
    """Cells per side of a buffer that holds any footprint: 4 block diagonals plus margin."""
    return math.ceil(4.0 * math.sqrt(2.0) * block_side_m / resolution_m) + 3


@njit(cache=True)
def _poses(t1: float, t2: float, t3: float, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ox, oy, phi = np.zeros(4), np.zeros(4), np.zeros(4)
    theta = (t1, t2, t3)
    for i in range(3):
        c, sn = math.cos(math.radians(phi[i])), math.sin(math.radians(phi[i]))
        px, py = ox[i] + (c * s - sn * 0.0), oy[i] + (sn * s + c * 0.0)
        hx, hy = _HINGE_X[i] * s, _HINGE_Y[i] * s
        hpx, hpy = ox[i] + (c * hx - sn * hy), oy[i] + (sn * hx + c * hy)
        a = _HINGE_SIGN[i] * theta[i]
        ca, sa = math.cos(math.radians(a)), math.sin(math.radians(a))
        dx, dy = px - hpx, py - hpy
        ox[i + 1], oy[i + 1] = hpx + (ca * dx - sa * dy), hpy + (sa * dx + ca * dy)
        phi[i + 1] = phi[i] + a
    return ox, oy, phi


@njit(cache=True)
def _clip_area(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> float:
    """Area of square a clipped by counter-clockwise square b (Sutherland-Hodgman)."""
    px, py = np.empty(16), np.empty(16)
    qx, qy = np.empty(16), np.empty(16)
    n = 4
    for m in range(4):
        px[m], py[m] = ax[m], ay[m]
    for k in range(4):
        if n == 0:
            break
        cx, cy = bx[k], by[k]
        ex, ey = bx[(k + 1) % 4] - cx, by[(k + 1) % 4] - cy
        out = 0
        for m in range(n):
            x0, y0 = px[m], py[m]
            x1, y1 = px[(m + 1) % n], py[(m + 1) % n]
            dp = ex * (y0 - cy) - ey * (x0 - cx)
            dq = ex * (y1 - cy) - ey * (x1 - cx)
            if dp >= 0.0:
                qx[out], qy[out] = x0, y0
                out += 1
            if (dp >= 0.0) != (dq >= 0.0):
                f = dp / (dp - dq)
                qx[out], qy[out] = x0 + f * (x1 - x0), y0 + f * (y1 - y0)
                out += 1
        n = out
        for m in range(n):
            px[m], py[m] = qx[m], qy[m]
    twice = 0.0
    for m in range(n):
        twice += px[m] * py[(m + 1) % n] - px[(m + 1) % n] * py[m]
    return abs(twice) / 2.0


@njit(cache=True)
def footprint_into(
    t1: float, t2: float, t3: float, s: float, r: float, buf: np.ndarray
) -> tuple[bool, int, int, float, float]:
    """Rasterise and trim F into buf[:l, :w] (buf zeroed first).

    Returns (feasible, l, w, w_fp_m, l_fp_m); l = w = 0 when buf is too small."""
    ox, oy, phi = _poses(t1, t2, t3, s)
    cs, sn = np.empty(4), np.empty(4)
    cx, cy = np.empty((4, 4)), np.empty((4, 4))
    min_x, min_y, max_x, max_y = np.inf, np.inf, -np.inf, -np.inf
    for k in range(4):
        cs[k], sn[k] = math.cos(math.radians(phi[k])), math.sin(math.radians(phi[k]))
        for m in range(4):
            u, v = _UNIT_U[m] * s, _UNIT_V[m] * s
            x, y = ox[k] + (cs[k] * u - sn[k] * v), oy[k] + (sn[k] * u + cs[k] * v)
            cx[k, m], cy[k, m] = x, y
            min_x, max_x = min(min_x, x), max(max_x, x)
            min_y, max_y = min(min_y, y), max(max_y, y)
    w_m, l_m = max_x - min_x, max_y - min_y
    feasible = True
    limit = 1e-9 * s * s
    for i, j in _NON_ADJACENT:
        if _clip_area(cx[i], cy[i], cx[j], cy[j]) > limit:
            feasible = False
    buf[:, :] = 0
    rows, cols = math.ceil(l_m / r) + 1, math.ceil(w_m / r) + 1
    if rows > buf.shape[0] or cols > buf.shape[1]:
        return feasible, 0, 0, w_m, l_m
    lo, hi = -1e-9, s + 1e-9
    r_min, r_max, c_min, c_max = rows, -1, cols, -1
    for i in range(rows):
        py = min_y + (i + 0.5) * r
        for j in range(cols):
            px = min_x + (j + 0.5) * r
            for k in range(4):
                dx, dy = px - ox[k], py - oy[k]
                u, v = cs[k] * dx + sn[k] * dy, -sn[k] * dx + cs[k] * dy
                if lo <= u <= hi and lo <= v <= hi:
                    buf[i, j] = 1
                    r_min, r_max = min(r_min, i), max(r_max, i)
                    c_min, c_max = min(c_min, j), max(c_max, j)
                    break
    if r_max < 0:
        return feasible, 0, 0, w_m, l_m
    l, w = r_max - r_min + 1, c_max - c_min + 1
    if r_min > 0 or c_min > 0:
        for i in range(l):
            for j in range(w):
                buf[i, j] = buf[i + r_min, j + c_min]
        for i in range(rows):
            for j in range(cols):
                if i >= l or j >= w:
                    buf[i, j] = 0
    return feasible, l, w, w_m, l_m


@njit(cache=True)
def _offsets(mask: np.ndarray, row_stride: int) -> np.ndarray:
    """Flat offsets of the true cells of `mask` in a grid with `row_stride` columns."""
    out = np.empty(mask.shape[0] * mask.shape[1], np.int64)
    n = 0
    for i in range(mask.shape[0]):
        for j in range(mask.shape[1]):
            if mask[i, j]:
                out[n] = i * row_stride + j
                n += 1
    return out[:n]


@njit(cache=True)
def _stamp(offsets: np.ndarray, base: int, work: np.ndarray) -> int:
    """Mark free cells (0) under the mask at flat position `base` as covered (2); count new ones."""
    new = 0
    for o in offsets:
        if work[base + o] == 0:
            work[base + o] = 2
            new += 1
    return new


@njit(cache=True)
def plan_into(
    padded: np.ndarray,
    prefix: np.ndarray,
    f: np.ndarray,
    start_kind: int,
    sp: int,
    sq: int,
    covered: np.ndarray,
    path: np.ndarray,
) -> tuple[int, int, int, int, int, int]:
    """FBCPP sections 4-6 for footprint f (l x w): the paper's planner.

    `padded` is the map as 0 (free) / 1 (not free), padded below and right with 1s by at least
    twice the footprint; `prefix` the (H+1) x (W+1) cumulative free counts of the map. Fills
    `covered` (H x W, or 0 x 0 to skip) and up to len(path) tiles of the path. Returns
    (status, covered free cells, P_len, east/west moves, north/south moves, path tiles)."""
    h, wd = prefix.shape[0] - 1, prefix.shape[1] - 1
    l, w = f.shape
    stride = padded.shape[1]
    if padded.shape[0] < h + 2 * l or stride < wd + 2 * w:
        return STATUS_PAD_TOO_SMALL, 0, 0, 0, 0, 0
    nr, nc = (h + l - 1) // l, (wd + w - 1) // w
    n = nr * nc
    trav = np.zeros(n, np.bool_)
    for a in range(nr):
        r0, r1 = a * l, min(a * l + l, h)
        for b in range(nc):
            c0, c1 = b * w, min(b * w + w, wd)
            trav[a * nc + b] = prefix[r1, c1] - prefix[r0, c1] - prefix[r1, c0] + prefix[r0, c0] > 0
    start = -1
    if start_kind == START_AUTO:
        for t in range(n):
            if trav[t]:
                start = t
                break
    else:
        sa, sb = (sp, sq) if start_kind == START_TILE else (sp // l, sq // w)
        if not (0 <= sa < nr and 0 <= sb < nc):
            return STATUS_START_OUTSIDE, 0, 0, 0, 0, 0
        start = sa * nc + sb
    if start < 0 or not trav[start]:
        return STATUS_START_BLOCKED, 0, 0, 0, 0, 0
    edge_e = np.zeros(n, np.bool_)  # tiles are joined where both are traversable (docs/spec/fbcpp.md section 5)
    edge_n = np.zeros(n, np.bool_)
    for t in range(n):
        if trav[t]:
            edge_e[t] = t % nc + 1 < nc and trav[t + 1]
            edge_n[t] = t // nc + 1 < nr and trav[t + nc]
    n_cov, p_len, n_ew, n_ns, n_path = _walk(padded, f, nr, nc, edge_e, edge_n, start, 0, 0, path, covered, h, wd,
                                             False, np.empty(0, np.int32), 0)  # fmt: skip
    return STATUS_OK, n_cov, p_len, n_ew, n_ns, n_path


@njit(cache=True)
def _joined(t: int, a: int, b: int, k: int, nr: int, nc: int, edge_e: np.ndarray, edge_n: np.ndarray) -> int:
    """The node joined to node t = a * nc + b in direction k (east, north, west, south), or -1 (the caller
    passes a and b, computed once per node: divisions are a large share of a small plan)."""
    if k == 0:
        return t + 1 if b + 1 < nc and edge_e[t] else -1
    if k == 1:
        return t + nc if a + 1 < nr and edge_n[t] else -1
    if k == 2:
        return t - 1 if b > 0 and edge_e[t - 1] else -1
    return t - nc if a > 0 and edge_n[t - nc] else -1


@njit(cache=True)
def _distances(nr: int, nc: int, edge_e: np.ndarray, edge_n: np.ndarray, start: int, dist: np.ndarray,
               queue: np.ndarray) -> int:  # fmt: skip
    """The distance transform: each node's moves from `start` into `dist` (all -1 on entry; -1 stays where not
    reached), by breadth-first search; returns how many nodes it reaches."""
    dist[start] = 0
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        t = queue[head]
        head += 1
        a = t // nc
        b = t - a * nc
        for k in range(4):
            u = _joined(t, a, b, k, nr, nc, edge_e, edge_n)
            if u >= 0 and dist[u] < 0:
                dist[u] = dist[t] + 1
                queue[tail] = u
                tail += 1
    return tail


@njit(cache=True)
def _walk(
    padded: np.ndarray,
    f: np.ndarray,
    nr: int,
    nc: int,
    edge_e: np.ndarray,
    edge_n: np.ndarray,
    start: int,
    oy: int,
    ox: int,
    path: np.ndarray,
    covered: np.ndarray,
    h: int,
    wd: int,
    all_free: bool,
    known_dist: np.ndarray,
    known_reach: int,
) -> tuple[int, int, int, int, int]:
    """docs/spec/fbcpp.md sections 5-6 on an nr x nc lattice of nodes whose node (a, b) puts F's corner at cell
    (oy + a l, ox + b w), joined where `edge_e` (to b + 1) and `edge_n` (to a + 1) say: distance transform,
    greedy walk with breadth-first escapes from dead ends, and the footprint swept along every move.
    Returns (covered free cells, P_len, east/west moves, north/south moves, path nodes). `all_free`: every
    cell the walk sweeps is free (the fit planner's moves pass safe placements only), so the sweep is ORed into
    64-cell words and counted once at the end instead of cell by cell. `known_dist` (nr * nc long, or empty) holds
    the distance transform from `start` already, and `known_reach` how many nodes it reaches (`_reach`)."""
    l, w = f.shape
    stride = padded.shape[1]
    n = nr * nc
    queue = np.empty(n, np.int32)
    if known_dist.shape[0] == n:
        dist, reachable = known_dist, known_reach
    else:
        dist = np.full(n, -1, np.int32)
        reachable = _distances(nr, nc, edge_e, edge_n, start, dist, queue)
    # swept masks: F shifted by 0..w columns (east/west moves) and by 0..l rows (north/south)
    swept_x = np.zeros((l, 2 * w), np.bool_)
    swept_y = np.zeros((2 * l, w), np.bool_)
    for i in range(l):
        for j in range(w):
            if f[i, j]:
                for k in range(w + 1):
                    swept_x[i, j + k] = True
                for k in range(l + 1):
                    swept_y[i + k, j] = True
    if all_free:  # bit rows only: the cell offsets are not needed
        off_f = off_x = off_y = np.zeros(0, np.int64)
    else:
        off_f, off_x, off_y = _offsets(f, stride), _offsets(swept_x, stride), _offsets(swept_y, stride)
    if all_free:
        pat_f, pat_x, pat_y = _patterns(f), _patterns(swept_x), _patterns(swept_y)
        nwc = (wd + 2 * w + 63) // 64 + pat_x.shape[1] + 1
        sweep = np.zeros((h + 2 * l + 1, nwc), np.uint64)
        work = np.zeros(0, np.uint8)
        _or_pattern(sweep, pat_f, oy + (start // nc) * l, ox + (start % nc) * w)
        n_cov = 0
    else:
        sweep = np.zeros((0, 0), np.uint64)
        work = padded.ravel().copy()
    origin = oy * stride + ox
    if not all_free:
        n_cov = _stamp(off_f, origin + (start // nc) * l * stride + (start % nc) * w, work)
    swept_ew = np.zeros(n, np.bool_)  # edge (a, b)-(a, b+1) stored at a*nc + b
    swept_ns = np.zeros(n, np.bool_)  # edge (a, b)-(a+1, b) stored at a*nc + b
    visited = np.zeros(n, np.bool_)
    parent = np.empty(n, np.int32)
    seen = np.zeros(n, np.int32)  # generation stamp of the dead-end searches
    route = np.empty(n, np.int32)
    visited[start] = True
    n_visited, p_len, n_ew, n_ns, n_path = 1, 0, 0, 0, 1
    if path.shape[0] > 0:
        path[0, 0], path[0, 1] = start // nc, start % nc
    cur, generation = start, 0
    while n_visited < reachable:
        best, best_d = -1, -1
        ca = cur // nc
        cb = cur - ca * nc
        for k in range(4):
            u = _joined(cur, ca, cb, k, nr, nc, edge_e, edge_n)
            if u >= 0 and not visited[u] and dist[u] > best_d:
                best, best_d = u, dist[u]
        n_route = 0
        if best >= 0:
            route[0] = best
            n_route = 1
        else:  # dead end: breadth-first to the nearest unvisited node
            generation += 1
            seen[cur] = generation
            queue[0] = cur
            head, tail, target = 0, 1, -1
            while head < tail and target < 0:
                t = queue[head]
                head += 1
                a = t // nc
                b = t - a * nc
                for k in range(4):
                    u = _joined(t, a, b, k, nr, nc, edge_e, edge_n)
                    if u >= 0 and seen[u] != generation:
                        seen[u] = generation
                        parent[u] = t
                        queue[tail] = u
                        tail += 1
                        if not visited[u]:  # first enqueued = first dequeued (FIFO)
                            target = u
                            break
            t = target
            while t != cur:
                route[n_route] = t
                n_route += 1
                t = parent[t]
            route[:n_route] = route[:n_route][::-1].copy()
        for m in range(n_route):
            nxt = route[m]
            pa, pb, qa, qb = cur // nc, cur % nc, nxt // nc, nxt % nc
            if pa == qa:
                n_ew += 1
                e = pa * nc + min(pb, qb)
                if not swept_ew[e]:
                    swept_ew[e] = True
                    if all_free:
                        _or_pattern(sweep, pat_x, oy + pa * l, ox + min(pb, qb) * w)
                    else:
                        n_cov += _stamp(off_x, origin + pa * l * stride + min(pb, qb) * w, work)
            else:
                n_ns += 1
                e = min(pa, qa) * nc + pb
                if not swept_ns[e]:
                    swept_ns[e] = True
                    if all_free:
                        _or_pattern(sweep, pat_y, oy + min(pa, qa) * l, ox + pb * w)
                    else:
                        n_cov += _stamp(off_y, origin + min(pa, qa) * l * stride + pb * w, work)
            if n_path < path.shape[0]:
                path[n_path, 0], path[n_path, 1] = qa, qb
            n_path += 1
            p_len += 1
            cur = nxt
            if not visited[cur]:
                visited[cur] = True
                n_visited += 1
    if all_free:
        for y in range(h):
            for k in range(sweep.shape[1]):
                n_cov += _popcount(sweep[y, k])
    if covered.shape[0] == h and covered.shape[1] == wd:
        for y in range(h):
            for x in range(wd):
                covered[y, x] = _bit(sweep, y, x) if all_free else work[y * stride + x] == 2
    return n_cov, p_len, n_ew, n_ns, n_path


@njit(cache=True)
def _patterns(mask: np.ndarray) -> np.ndarray:
    """The rows of a boolean mask as 64-cell words (row i, word q holds cells 64 q .. 64 q + 63)."""
    rows, cols = mask.shape
    out = np.zeros((rows, (cols + 63) // 64), np.uint64)
    for i in range(rows):
        for j in range(cols):
            if mask[i, j]:
                out[i, j >> 6] |= _ONE << np.uint64(j & 63)
    return out


@njit(cache=True)
def _or_pattern(rows: np.ndarray, pattern: np.ndarray, y: int, x: int) -> None:
    """rows |= `pattern` (`_patterns`) with its cell (0, 0) on cell (y, x) (indexed, not sliced: no view a row)."""
    q0, b = x >> 6, np.uint64(x & 63)
    nq = pattern.shape[1]
    if b == 0:
        for i in range(pattern.shape[0]):
            for q in range(nq):
                rows[y + i, q0 + q] |= pattern[i, q]
        return
    back = np.uint64(64) - b
    for i in range(pattern.shape[0]):
        carry = np.uint64(0)
        for q in range(nq):
            v = pattern[i, q]
            rows[y + i, q0 + q] |= (v << b) | carry
            carry = v >> back
        rows[y + i, q0 + nq] |= carry


_ONE = np.uint64(1)
_ALL = ~np.uint64(0)


@njit(cache=True)
def _popcount(v: np.uint64) -> int:
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True)
def _ctz(v: np.uint64) -> int:
    """Index of the lowest set bit of v (v != 0)."""
    return _popcount((v & (~v + _ONE)) - _ONE)


@njit(cache=True)
def _level(n: int) -> int:
    """The largest k with 2**k <= n (n >= 1)."""
    k = 0
    while (2 << k) <= n:
        k += 1
    return k


@njit(cache=True)
def fit_bits(padded: np.ndarray, area: np.ndarray, h: int, wd: int) -> np.ndarray:
    """What every fit plan on one map reuses, as rows of 64-cell words (docs/fbcpp-fit.md is unchanged by
    it): level k < K holds the not-free cells of `padded` dilated by 2**k (bit x of row y set where a cell in
    x .. x + 2**k - 1 is not free), so any run of F's cells in a row costs two shifted ORs; level K holds the
    largest free area `area` (H*W). Levels reach the widest F the padding allows (half of it)."""
    rows, cols = padded.shape
    nw = (cols + 63) // 64 + 2 + ((cols - wd) >> 6)  # spare words: rows are read shifted by up to cols - wd
    n_levels = _level(max(1, (cols - wd) // 2)) + 1
    out = np.zeros((n_levels + 1, rows, nw), np.uint64)
    for y in range(rows):
        for x in range(cols):
            if padded[y, x] != 0:
                out[0, y, x >> 6] |= _ONE << np.uint64(x & 63)
    for k in range(1, n_levels):
        out[k] = out[k - 1]
        _or_rows(out[k], out[k - 1], 0, 1 << (k - 1), False, rows, (cols + 63) // 64)
    for y in range(h):
        for x in range(wd):
            if area[y * wd + x]:
                out[n_levels, y, x >> 6] |= _ONE << np.uint64(x & 63)
    return out


@njit(cache=True)
def _f_runs(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F's cells as runs along its rows: (row_start (l + 1), first column, length), runs of row i at
    row_start[i] .. row_start[i + 1] - 1."""
    l, w = f.shape
    start = np.zeros(l + 1, np.int64)
    j0 = np.empty(l * ((w + 1) // 2), np.int64)
    length = np.empty(l * ((w + 1) // 2), np.int64)
    n = 0
    for i in range(l):
        start[i] = n
        j = 0
        while j < w:
            if f[i, j]:
                e = j
                while e < w and f[i, e]:
                    e += 1
                j0[n], length[n] = j, e - j
                n += 1
                j = e
            else:
                j += 1
    start[l] = n
    return start, j0[:n], length[:n]


@njit(cache=True)
def _or_rows(acc: np.ndarray, src: np.ndarray, dy: int, s: int, up: bool, n_rows: int, nw: int) -> None:
    """acc[y] |= src[y + dy] moved by s cells, for y < n_rows, over the first nw words of acc: down, bit x
    takes bit x + s (src rows must hold nw + s // 64 + 1 words); up, bit x + s takes bit x."""
    q, b = s >> 6, s & 63
    if up:
        if q >= nw:
            return
        if b == 0:
            for y in range(n_rows):
                for k in range(q, nw):
                    acc[y, k] |= src[y + dy, k - q]
        else:
            left, right = np.uint64(b), np.uint64(64 - b)
            for y in range(n_rows):
                acc[y, q] |= src[y + dy, 0] << left
                for k in range(q + 1, nw):
                    acc[y, k] |= (src[y + dy, k - q] << left) | (src[y + dy, k - q - 1] >> right)
    elif b == 0:
        for y in range(n_rows):
            for k in range(nw):
                acc[y, k] |= src[y + dy, k + q]
    else:
        right, left = np.uint64(b), np.uint64(64 - b)
        for y in range(n_rows):
            for k in range(nw):
                acc[y, k] |= (src[y + dy, k + q] >> right) | (src[y + dy, k + q + 1] << left)


@njit(cache=True)
def _safe_bits(
    bits: np.ndarray, h: int, wd: int, l: int, w: int, f_start: np.ndarray, f_j0: np.ndarray, f_len: np.ndarray,
    y_lo: int, y_hi: int,
) -> np.ndarray:  # fmt: skip
    """Bit rows of the safe placements (F with its corner on cell (y, x) overlaps only free cells): a row of
    placements is unsafe where some run of F's row i meets a not-free cell of map row y + i, 64 placements
    per operation. Only rows y_lo .. y_hi - 1 can hold a safe placement (`_placement_rows`); the others, rows past
    h and bits past wd are clear; spare words let rows be shifted by up to max(l, w) + 1 cells."""
    nw = (wd + 63) // 64
    safe = np.zeros((h + l + 1, nw + (max(l, w) + 1) // 64 + 2), np.uint64)
    if y_hi <= y_lo:
        return safe
    window = safe[y_lo:]
    for i in range(l):  # the window holds the unsafe placements until the end
        for r in range(f_start[i], f_start[i + 1]):
            k = _level(f_len[r])
            _or_rows(window, bits[k], i + y_lo, f_j0[r], False, y_hi - y_lo, nw)
            if f_len[r] > (1 << k):
                _or_rows(window, bits[k], i + y_lo, f_j0[r] + f_len[r] - (1 << k), False, y_hi - y_lo, nw)
    tail = _ALL if wd & 63 == 0 else (_ONE << np.uint64(wd & 63)) - _ONE
    for y in range(y_lo, y_hi):
        for k in range(nw):
            safe[y, k] = ~safe[y, k]
        safe[y, nw - 1] &= tail
    return safe


@njit(cache=True)
def _placement_rows(prefix: np.ndarray, l: int) -> tuple[int, int]:
    """The rows [lo, hi) that can hold a safe placement of an F of l rows (its first and last rows both hold cells,
    so both must lie on rows with a free cell): from the first free row to the last free row less l - 1. On a SLAM
    map mostly unknown, a small share of the rows."""
    h, wd = prefix.shape[0] - 1, prefix.shape[1] - 1
    lo, hi = h, -1
    for y in range(h):
        if prefix[y + 1, wd] - prefix[y, wd] > 0:
            lo = min(lo, y)
            hi = y
    return lo, max(lo, hi - l + 2)


@njit(cache=True)
def _next_bit(row: np.ndarray, x: int, one: bool, limit: int) -> int:
    """The first cell at or after x whose bit is set (one) or clear (not one), or `limit` if none before it."""
    while x < limit:
        k = x >> 6
        v = row[k] if one else ~row[k]
        v >>= np.uint64(x & 63)
        if v != 0:
            return min(x + _ctz(v), limit)
        x = (k + 1) << 6
    return limit


@njit(cache=True)
def _find(parent: np.ndarray, r: int) -> int:
    while parent[r] != r:
        parent[r] = parent[parent[r]]
        r = parent[r]
    return r


@njit(cache=True)
def _run_groups(safe: np.ndarray, h: int, wd: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """The safe placements as runs along rows, and each run's group under one-cell moves: (row_start (h + 1),
    first column, end column (exclusive), label). Labels (0, 1, ...) follow the raster order of each group's
    first placement, as `components` numbers them; two runs of adjacent rows join where their columns overlap."""
    row_start = np.zeros(h + 1, np.int64)
    cap = h * ((wd + 1) // 2)
    x0s, x1s = np.empty(cap, np.int64), np.empty(cap, np.int64)
    n = 0
    for y in range(h):
        row_start[y] = n
        row = safe[y]
        x = _next_bit(row, 0, True, wd)
        while x < wd:
            e = _next_bit(row, x, False, wd)
            x0s[n], x1s[n] = x, e
            n += 1
            x = _next_bit(row, e, True, wd)
    row_start[h] = n
    parent = np.arange(n)
    for y in range(1, h):
        a, b = row_start[y - 1], row_start[y]
        while a < row_start[y] and b < row_start[y + 1]:
            if x0s[a] < x1s[b] and x0s[b] < x1s[a]:
                ra, rb = _find(parent, a), _find(parent, b)
                if ra < rb:
                    parent[rb] = ra
                elif rb < ra:
                    parent[ra] = rb
            if x1s[a] < x1s[b]:
                a += 1
            else:
                b += 1
    label = np.empty(n, np.int64)
    n_labels = 0
    for r in range(n):
        root = _find(parent, r)
        if root == r:
            label[r] = n_labels
            n_labels += 1
        else:
            label[r] = label[root]
    return row_start, x0s[:n], x1s[:n], label, n_labels


@njit(cache=True)
def _bit(rows: np.ndarray, y: int, x: int) -> bool:
    return (rows[y, x >> 6] >> np.uint64(x & 63)) & _ONE != 0


@njit(cache=True)
def _range_bits(row: np.ndarray, x0: int, x1: int, first: bool) -> int:
    """Over cells x0 .. x1 - 1 of a bit row: how many bits are set, or (first) the first set one (-1: none)."""
    total = 0
    x = x0
    while x < x1:
        k = x >> 6
        v = row[k] >> np.uint64(x & 63)
        span = min(64 - (x & 63), x1 - x)
        if span < 64:
            v &= (_ONE << np.uint64(span)) - _ONE
        if first:
            if v != 0:
                return x + _ctz(v)
        else:
            total += _popcount(v)
        x += span
    return -1 if first else total


@njit(cache=True)
def _start_row(safe: np.ndarray, bits: np.ndarray, y: int, fi: int, fj: int, nw: int, out: np.ndarray) -> None:
    """Into out[0]: bit row y of the safe placements whose F's first cell (fi, fj) lies in the largest free
    area."""
    out[0, :nw] = 0
    _or_rows(out, bits[bits.shape[0] - 1], y + fi, fj, False, 1, nw)
    for k in range(nw):
        out[0, k] &= safe[y, k]


@njit(cache=True)
def _run_at(row_start: np.ndarray, x0s: np.ndarray, x1s: np.ndarray, y: int, x: int) -> int:
    """The run of row y that holds placement x (which must be safe)."""
    r = row_start[y]
    while x1s[r] <= x:
        r += 1
    return r


@njit(cache=True)
def _fit_candidates(
    safe: np.ndarray, bits: np.ndarray, f: np.ndarray, h: int, wd: int, start_kind: int, sp: int, sq: int,
    row_start: np.ndarray, x0s: np.ndarray, x1s: np.ndarray, label: np.ndarray, n_labels: int,
) -> np.ndarray:  # fmt: skip
    """Start placements to try (docs/fbcpp-fit.md section 3), as flat indices y * wd + x in raster order."""
    l, w = f.shape
    out = np.empty(l * w, np.int64)
    n = 0
    if start_kind == START_CELL:  # every safe placement whose stamp holds the start cell
        for y in range(max(0, sp - l + 1), min(h, sp + 1)):
            for x in range(max(0, sq - w + 1), min(wd, sq + 1)):
                if f[sp - y, sq - x] and _bit(safe, y, x):
                    out[n] = y * wd + x
                    n += 1
        return out[:n]
    fi, fj = -1, -1  # F's first cell in raster order
    for i in range(l):
        for j in range(w):
            if f[i, j] and fi < 0:
                fi, fj = i, j
    nw = (wd + 63) // 64
    start_row = np.empty((1, nw), np.uint64)
    row = start_row[0]
    count = np.zeros(max(n_labels, 1), np.int64)
    first = np.full(max(n_labels, 1), h * wd, np.int64)
    for y in range(h):
        if row_start[y] == row_start[y + 1]:
            continue
        _start_row(safe, bits, y, fi, fj, nw, start_row)
        for r in range(row_start[y], row_start[y + 1]):
            c = _range_bits(row, x0s[r], x1s[r], False)
            if c > 0:
                count[label[r]] += c
                first[label[r]] = min(first[label[r]], y * wd + _range_bits(row, x0s[r], x1s[r], True))
    best = -1
    for g in range(n_labels):
        if count[g] > 0 and (
            best < 0 or count[g] > count[best] or (count[g] == count[best] and first[g] < first[best])
        ):
            best = g
    if best < 0:
        return out[:0]
    taken = np.zeros(l * w, np.bool_)
    y = first[best] // wd  # the group's first placement in A*: none before it can be a candidate
    while y < h and n < l * w:  # every lattice class taken: no later placement can be a candidate
        cy = (y % l) * w
        _start_row(safe, bits, y, fi, fj, nw, start_row)
        for r in range(row_start[y], row_start[y + 1]):
            if label[r] != best:
                continue
            x = _range_bits(row, x0s[r], x1s[r], True)
            while x >= 0:
                if not taken[cy + x % w]:
                    taken[cy + x % w] = True
                    out[n] = y * wd + x
                    n += 1
                x = _range_bits(row, x + 1, x1s[r], True) if x + 1 < x1s[r] else -1
        y += 1
    return out[:n]


@njit(cache=True)
def _class_bounds(
    candidates: np.ndarray, cand_label: np.ndarray, row_start: np.ndarray, x0s: np.ndarray, x1s: np.ndarray,
    label: np.ndarray, n_labels: int, h: int, l: int, w: int, wd: int,
) -> np.ndarray:  # fmt: skip
    """For each candidate, the safe placements of its lattice class (row mod l, column mod w) in its group:
    the most nodes its lattice can reach (a lattice move only passes safe placements, so it stays in the group).
    Counted run by run, only for the candidates' groups."""
    slot = np.full(max(n_labels, 1), -1, np.int64)  # group -> row of `count`
    n_slots = 0
    for c in range(candidates.shape[0]):
        if slot[cand_label[c]] < 0:
            slot[cand_label[c]] = n_slots
            n_slots += 1
    count = np.zeros((n_slots, l * w), np.int64)
    for y in range(h):
        cy = (y % l) * w
        for r in range(row_start[y], row_start[y + 1]):
            g = slot[label[r]]
            if g < 0:
                continue
            length = x1s[r] - x0s[r]
            base = length // w
            if base > 0:
                for cx in range(w):
                    count[g, cy + cx] += base
            cx = x0s[r] % w
            for _ in range(length - base * w):
                count[g, cy + cx] += 1
                cx = cx + 1 if cx + 1 < w else 0
    upper = np.empty(candidates.shape[0], np.int64)
    for c in range(candidates.shape[0]):
        p = candidates[c]
        upper[c] = count[slot[cand_label[c]], (p // wd % l) * w + p % wd % w]
    return upper


@njit(cache=True)
def _moves(
    safe: np.ndarray, h: int, wd: int, l: int, w: int, y_lo: int, y_hi: int
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Bit rows of the placements a lattice move may leave from: east (every placement x .. x + w of the row
    safe) and north (every placement y .. y + l of the column safe). West and south moves are those of the
    neighbour they reach. Only rows y_lo .. y_hi - 1 hold safe placements; the others stay clear. Both are
    ANDs over spans doubled each pass (log2 of the span passes, not one a cell)."""
    nws = safe.shape[1]
    east = np.zeros((h, nws), np.uint64)
    north = np.zeros((h, nws), np.uint64)
    if y_hi <= y_lo:
        return east, north
    for y in range(y_lo, y_hi):
        east[y] = safe[y]  # east[y]: every placement x .. x + span - 1 safe
        span = 1
        while 2 * span <= w + 1:
            _and_down(east, y, span)
            span *= 2
        _and_down(east, y, w + 1 - span)  # every placement x .. x + w safe
    n_rows = y_hi - y_lo + l  # the rows y_lo .. y_hi + l - 1 a north move from rows y_lo .. y_hi - 1 passes
    run = safe[y_lo : y_lo + n_rows].copy()  # run[r]: rows y_lo + r .. y_lo + r + span - 1 all safe
    span = 1
    while 2 * span <= l + 1:
        for r in range(n_rows - span):  # upwards: run[r + span] is still the shorter span's
            for k in range(nws):
                run[r, k] &= run[r + span, k]
        span *= 2
    last = l + 1 - span
    for y in range(y_lo, y_hi):
        for k in range(nws):
            north[y, k] = run[y - y_lo, k] & run[y - y_lo + last, k]
    return east, north


@njit(cache=True)
def _and_down(rows: np.ndarray, y: int, s: int) -> None:
    """Row y of `rows` &= itself moved down by s cells (bit x keeps its value only if bit x + s is set), in place
    (indexed, not sliced: a view a call costs more than the words it ANDs)."""
    if s == 0:
        return
    q, b = s >> 6, s & 63
    n = rows.shape[1]
    for k in range(n):
        hi = rows[y, k + q] if k + q < n else np.uint64(0)
        lo = rows[y, k + q + 1] if k + q + 1 < n else np.uint64(0)
        rows[y, k] &= hi if b == 0 else (hi >> np.uint64(b)) | (lo << np.uint64(64 - b))


@njit(cache=True)
def _reach(
    east: np.ndarray, north: np.ndarray, oy: int, ox: int, l: int, w: int, nr: int, nc: int, start: int,
    dist: np.ndarray, queue: np.ndarray,
) -> int:  # fmt: skip
    """How many nodes of the lattice through (oy, ox) breadth-first search reaches from node `start`; fills
    dist[: nr * nc] with each node's moves from it (-1: not reached), the distance transform `_walk` reads (`dist`
    and `queue`: buffers at least nr * nc long)."""
    dist[: nr * nc] = -1
    dist[start] = 0
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        t = queue[head]
        head += 1
        a = t // nc
        b = t - a * nc
        y, x = oy + a * l, ox + b * w
        d = dist[t] + 1
        if b + 1 < nc and _bit(east, y, x) and dist[t + 1] < 0:
            dist[t + 1] = d
            queue[tail] = t + 1
            tail += 1
        if a + 1 < nr and _bit(north, y, x) and dist[t + nc] < 0:
            dist[t + nc] = d
            queue[tail] = t + nc
            tail += 1
        if b > 0 and _bit(east, y, x - w) and dist[t - 1] < 0:
            dist[t - 1] = d
            queue[tail] = t - 1
            tail += 1
        if a > 0 and _bit(north, y - l, x) and dist[t - nc] < 0:
            dist[t - nc] = d
            queue[tail] = t - nc
            tail += 1
    return tail


@njit(cache=True)
def _bound(
    row_start: np.ndarray, x0s: np.ndarray, x1s: np.ndarray, label: np.ndarray, group: int, h: int, wd: int,
    l: int, w: int, f_start: np.ndarray, f_j0: np.ndarray, f_len: np.ndarray,
) -> int:  # fmt: skip
    """Cells under F at some placement of `group` (all free: every placement of the group is safe), word-
    parallel: the group's placement rows dilated by 2**k cells, ORed up by every run of F's row i into row
    y + i (two shifted ORs a run)."""
    nw = (wd + w + 63) // 64 + 1
    n_levels = _level(w) + 1
    dil = np.zeros((n_levels, h, nw), np.uint64)
    for y in range(h):
        for r in range(row_start[y], row_start[y + 1]):
            if label[r] != group:
                continue
            x = x0s[r]
            while x < x1s[r]:  # set bits x0 .. x1 - 1
                span = min(64 - (x & 63), x1s[r] - x)
                mask = _ALL if span == 64 else ((_ONE << np.uint64(span)) - _ONE)
                dil[0, y, x >> 6] |= mask << np.uint64(x & 63)
                x += span
    for k in range(1, n_levels):
        dil[k] = dil[k - 1]
        _or_rows(dil[k], dil[k - 1], 0, 1 << (k - 1), True, h, nw)
    under = np.zeros((h + l, nw), np.uint64)
    for i in range(l):
        for r in range(f_start[i], f_start[i + 1]):
            k = _level(f_len[r])
            _or_rows(under[i:], dil[k], 0, f_j0[r], True, h, nw)
            if f_len[r] > (1 << k):
                _or_rows(under[i:], dil[k], 0, f_j0[r] + f_len[r] - (1 << k), True, h, nw)
    total = 0
    for y in range(h):
        for k in range(nw):
            total += _popcount(under[y, k])
    return total


@njit(cache=True)
def components(safe: np.ndarray, h: int, wd: int) -> np.ndarray:
    """Label (0, 1, ...) of each safe placement's group under one-cell moves between safe placements; -1
    where unsafe. Labels follow the raster order of each group's first placement."""
    label = np.full(h * wd, -1, np.int32)
    qy, qx = np.empty(h * wd, np.int32), np.empty(h * wd, np.int32)  # rows and columns: no divisions
    n_labels = 0
    for y0 in range(h):
        for x0 in range(wd):
            p0 = y0 * wd + x0
            if not safe[p0] or label[p0] >= 0:
                continue
            label[p0] = n_labels
            qy[0], qx[0] = y0, x0
            head, tail = 0, 1
            while head < tail:
                y, x = qy[head], qx[head]
                head += 1
                for k in range(4):
                    ny, nx = y + _DR[k], x + _DC[k]
                    if 0 <= ny < h and 0 <= nx < wd:
                        q = ny * wd + nx
                        if safe[q] and label[q] < 0:
                            label[q] = n_labels
                            qy[tail], qx[tail] = ny, nx
                            tail += 1
            n_labels += 1
    return label


@njit(cache=True)
def r1_upper(nodes: int, tile_cells: int, prune: np.ndarray) -> float:
    """The most R1 a plan can score that visits at most `nodes` lattice nodes of `tile_cells` cells each
    (docs/exact-search.md): n nodes cover at most min(cells, n * tile_cells) cells and take at least n - 1 moves,
    so R1 <= max over 1 <= n <= nodes of w1 P_c(min(cells, n * tile_cells)) - w2 (n - 1): concave and piecewise
    linear in n, so its maximum is at n = 1 or on either side of where coverage saturates."""
    w1, w2, pc0, per = prune[PRUNE_W1], prune[PRUNE_W2], prune[PRUNE_PC0], prune[PRUNE_PC_PER_CELL]
    cells = prune[PRUNE_CELLS]
    most = max(nodes, 1)
    best = -np.inf
    fill = cells / tile_cells  # nodes whose tiles could hold every coverable cell
    for n in (1, min(most, max(1, math.floor(fill))), min(most, max(1, math.ceil(fill)))):
        r1 = w1 * (pc0 + per * min(cells, float(n * tile_cells))) - w2 * (n - 1)
        best = max(best, r1)
    return best


@njit(cache=True)
def plan_fit_into(
    padded: np.ndarray,
    prefix: np.ndarray,
    bits: np.ndarray,
    f: np.ndarray,
    start_kind: int,
    sp: int,
    sq: int,
    covered: np.ndarray,
    path: np.ndarray,
    prune: np.ndarray,
) -> tuple[int, int, int, int, int, int, int, int, int]:
    """The footprint-safe planner (docs/fbcpp-fit.md) for footprint f (l x w).

    `padded` and `prefix` as for `plan_into`; `bits` is the map's `fit_bits`. Fills `covered` and up to len(path)
    placements (row, column of F's corner) as `plan_into` does. Returns (status, covered free cells, P_len,
    east/west moves, north/south moves, path length, coverable-bound cells, start row, start column); a shape
    with no safe start covers nothing (start -1, -1). Given a `prune` array, a footprint whose R1 bound
    (`r1_upper`) falls short of the R1 to beat returns STATUS_PRUNED before its lattice is walked (and no coverable
    bound is counted: 0)."""
    h, wd = prefix.shape[0] - 1, prefix.shape[1] - 1
    l, w = f.shape
    if padded.shape[0] < h + 2 * l or padded.shape[1] < wd + 2 * w:
        return STATUS_PAD_TOO_SMALL, 0, 0, 0, 0, 0, 0, -1, -1
    if start_kind == START_TILE:
        return STATUS_TILE_START_FIT, 0, 0, 0, 0, 0, 0, -1, -1
    f_start, f_j0, f_len = _f_runs(f)
    y_lo, y_hi = _placement_rows(prefix, l)
    safe = _safe_bits(bits, h, wd, l, w, f_start, f_j0, f_len, y_lo, y_hi)
    row_start, x0s, x1s, label, n_labels = _run_groups(safe, h, wd)
    candidates = _fit_candidates(safe, bits, f, h, wd, start_kind, sp, sq, row_start, x0s, x1s, label, n_labels)
    if candidates.shape[0] == 0:
        return STATUS_OK, 0, 0, 0, 0, 0, 0, -1, -1
    cand_label = np.empty(candidates.shape[0], np.int64)
    for c in range(candidates.shape[0]):
        y0, x0 = candidates[c] // wd, candidates[c] % wd
        cand_label[c] = label[_run_at(row_start, x0s, x1s, y0, x0)]
    # The lattice that reaches the most nodes, the earliest candidate of equal ones. A lattice reaches at most
    # the safe placements of its class in its candidate's group, so candidates are tried from the largest such
    # bound down, and the search stops once no bound left can match the best reach found.
    upper = _class_bounds(candidates, cand_label, row_start, x0s, x1s, label, n_labels, h, l, w, wd)
    if prune.shape[0] > 0 and prune[PRUNE_ACTIVE] > 0 and r1_upper(upper.max(), l * w, prune) < prune[PRUNE_THRESHOLD]:
        return STATUS_PRUNED, 0, 0, 0, 0, 0, 0, -1, -1
    east, north = _moves(safe, h, wd, l, w, y_lo, y_hi)
    best, best_reach = -1, -1
    n_nodes = ((h + l - 1) // l) * ((wd + w - 1) // w)  # the most nodes a lattice has
    dist, best_dist, queue = np.empty(n_nodes, np.int32), np.empty(n_nodes, np.int32), np.empty(n_nodes, np.int64)
    for c in np.argsort(-upper, kind="mergesort"):
        if upper[c] < best_reach:
            break
        if upper[c] == best_reach and c > best:
            continue
        y0, x0 = candidates[c] // wd, candidates[c] % wd
        oy, ox = y0 % l, x0 % w
        nr, nc = (h - oy + l - 1) // l, (wd - ox + w - 1) // w
        reach = _reach(east, north, oy, ox, l, w, nr, nc, (y0 // l) * nc + x0 // w, dist, queue)
        if reach > best_reach or (reach == best_reach and c < best):
            best, best_reach = c, reach
            dist, best_dist = best_dist, dist  # the best lattice's distances are kept for the walk
    y0, x0 = candidates[best] // wd, candidates[best] % wd
    oy, ox = y0 % l, x0 % w
    nr, nc = (h - oy + l - 1) // l, (wd - ox + w - 1) // w
    edge_e, edge_n = np.zeros(nr * nc, np.bool_), np.zeros(nr * nc, np.bool_)
    for a in range(nr):
        for b in range(nc):
            y, x = oy + a * l, ox + b * w
            edge_e[a * nc + b] = b + 1 < nc and _bit(east, y, x)
            edge_n[a * nc + b] = a + 1 < nr and _bit(north, y, x)
    fd = np.empty((l, w), np.bool_)  # a dense copy: the batch kernels pass a strided view
    for i in range(l):
        for j in range(w):
            fd[i, j] = f[i, j] != 0
    start = (y0 // l) * nc + x0 // w
    n_cov, p_len, n_ew, n_ns, n_path = _walk(padded, fd, nr, nc, edge_e, edge_n, start, oy, ox, path, covered, h, wd,
                                             True, best_dist[: nr * nc], best_reach)  # fmt: skip
    for m in range(min(n_path, path.shape[0])):  # lattice nodes as placements
        path[m, 0], path[m, 1] = oy + path[m, 0] * l, ox + path[m, 1] * w
    n_bound = 0 if prune.shape[0] > 0 else _bound(row_start, x0s, x1s, label, cand_label[best], h, wd, l, w, f_start,
                                                  f_j0, f_len)  # fmt: skip
    return STATUS_OK, n_cov, p_len, n_ew, n_ns, n_path, n_bound, y0, x0


@njit(cache=True)
def plan_any(
    planner: int,
    padded: np.ndarray,
    prefix: np.ndarray,
    fit: np.ndarray,
    fbuf: np.ndarray,
    l: int,
    w: int,
    start_kind: int,
    sp: int,
    sq: int,
    covered: np.ndarray,
    path: np.ndarray,
    prune: np.ndarray,
) -> tuple[int, int, int, int, int, int, int, int, int]:
    """Either planner, with the fit planner's returns (the paper's coverable bound is its own coverage, as
    it covers every reachable tile; its start placement is not reported: -1, -1). `fit` is the map's `fit_bits`
    (empty for the paper planner). `prune` bounds the fit planner only (`plan_fit_into`). F is `fbuf[:l, :w]`,
    cut here: a view cut by the caller is typed by its layout (C when whole, A when not), and each layout would
    compile this kernel again (about 25 s)."""
    f = fbuf[:l, :w]
    if planner == PLANNER_FIT:
        return plan_fit_into(padded, prefix, fit, f, start_kind, sp, sq, covered, path, prune)
    status, n_cov, p_len, n_ew, n_ns, n_path = plan_into(padded, prefix, f, start_kind, sp, sq, covered, path)
    return status, n_cov, p_len, n_ew, n_ns, n_path, n_cov, -1, -1


@njit(cache=True)
def evaluate_batch(
    thetas: np.ndarray,
    s: float,
    r: float,
    padded: np.ndarray,
    prefix: np.ndarray,
    start_kind: int,
    sp: int,
    sq: int,
    side: int,
    planner: int,
    fit: np.ndarray,
    prune: np.ndarray,
) -> np.ndarray:
    """Uncached evaluation of every row of `thetas` (N x 3): one result row each (COL_*). Given a `prune` array
    (branch and bound), a row that cannot beat prune[PRUNE_THRESHOLD] is STATUS_PRUNED, and each plan that scores
    higher raises the threshold in place, so the caller reads back the best R1 found."""
    out = np.zeros((thetas.shape[0], N_COLS))
    buf = np.zeros((side, side), np.uint8)
    no_covered = np.zeros((0, 0), np.uint8)
    no_path = np.zeros((0, 2), np.int32)
    for i in range(thetas.shape[0]):
        feasible, l, w, w_m, l_m = footprint_into(thetas[i, 0], thetas[i, 1], thetas[i, 2], s, r, buf)
        out[i, COL_FEASIBLE], out[i, COL_L], out[i, COL_W] = feasible, l, w
        out[i, COL_W_M], out[i, COL_L_M] = w_m, l_m
        if feasible and l > 0:
            res = plan_any(planner, padded, prefix, fit, buf, l, w, start_kind, sp, sq, no_covered, no_path, prune)
            out[i, COL_STATUS] = res[0]
            out[i, COL_COVERED], out[i, COL_PLEN], out[i, COL_EW], out[i, COL_NS] = res[1], res[2], res[3], res[4]
            out[i, COL_BOUND] = res[6]
            if prune.shape[0] > 0 and prune[PRUNE_ACTIVE] > 0 and res[0] == STATUS_OK:
                r1 = prune[PRUNE_W1] * (prune[PRUNE_PC0] + prune[PRUNE_PC_PER_CELL] * res[1]) - prune[PRUNE_W2] * res[2]
                prune[PRUNE_THRESHOLD] = max(prune[PRUNE_THRESHOLD], r1 - 1e-9 * (1.0 + abs(r1)))
    return out


@njit(cache=True)
def footprints_batch(thetas: np.ndarray, s: float, r: float, side: int) -> tuple[np.ndarray, np.ndarray]:
    """F of every row of `thetas`: (result rows with the geometry columns, F bits N x side*side)."""
    out = np.zeros((thetas.shape[0], N_COLS))
    bits = np.zeros((thetas.shape[0], side * side), np.uint8)
    buf = np.zeros((side, side), np.uint8)
    for i in range(thetas.shape[0]):
        feasible, l, w, w_m, l_m = footprint_into(thetas[i, 0], thetas[i, 1], thetas[i, 2], s, r, buf)
        out[i, COL_FEASIBLE], out[i, COL_L], out[i, COL_W] = feasible, l, w
        out[i, COL_W_M], out[i, COL_L_M] = w_m, l_m
        bits[i, :] = buf.ravel()
    return out, bits


@njit(cache=True)
def plan_batch(
    bits: np.ndarray,
    shapes: np.ndarray,
    padded: np.ndarray,
    prefix: np.ndarray,
    start_kind: int,
    sp: int,
    sq: int,
    side: int,
    planner: int,
    fit: np.ndarray,
) -> np.ndarray:
    """Plan every footprint (bits rows, shapes rows (l, w)); result rows with the plan columns."""
    out = np.zeros((bits.shape[0], N_COLS))
    no_covered = np.zeros((0, 0), np.uint8)
    no_path = np.zeros((0, 2), np.int32)
    no_prune = np.zeros(0)  # not the global NO_PRUNE: a global is a read-only constant here, another signature
    for i in range(bits.shape[0]):
        l, w = shapes[i, 0], shapes[i, 1]
        f = bits[i].reshape((side, side))
        res = plan_any(planner, padded, prefix, fit, f, l, w, start_kind, sp, sq, no_covered, no_path, no_prune)
        out[i, COL_STATUS] = res[0]
        out[i, COL_COVERED], out[i, COL_PLEN], out[i, COL_EW], out[i, COL_NS] = res[1], res[2], res[3], res[4]
        out[i, COL_BOUND] = res[6]
    return out


@njit(cache=True)
def _mix(h: np.uint64) -> np.uint64:
    """splitmix64's finaliser: every input bit reaches every output bit."""
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


@njit(cache=True)
def footprint_keys(thetas: np.ndarray, s: float, r: float, side: int) -> np.ndarray:
    """A 128-bit key of each row's F (N x 2 words): equal F, equal key (F's shape and bits are hashed, 64 cells a
    word, by two independent chains); (0, 0) where the shape is infeasible, (0, 1) where F has no cell."""
    keys = np.zeros((thetas.shape[0], 2), np.uint64)
    buf = np.zeros((side, side), np.uint8)
    for i in range(thetas.shape[0]):
        feasible, l, w, _, _ = footprint_into(thetas[i, 0], thetas[i, 1], thetas[i, 2], s, r, buf)
        if not feasible:
            continue
        if l == 0:  # no cell: a footprint of its own, which covers nothing
            keys[i, 1] = _ONE
            continue
        a = _mix(np.uint64(0x9E3779B97F4A7C15) ^ np.uint64(l * 4096 + w))
        b = _mix(np.uint64(0xD1B54A32D192ED03) ^ np.uint64(l * 4096 + w))
        word, n = np.uint64(0), 0
        for y in range(l):
            for x in range(w):
                if buf[y, x]:
                    word |= _ONE << np.uint64(n)
                n += 1
                if n == 64:
                    a, b = _mix(a ^ word), _mix(b + word * np.uint64(0xA24BAED4963EE407))
                    word, n = np.uint64(0), 0
        a, b = _mix(a ^ word), _mix(b + word * np.uint64(0xA24BAED4963EE407))
        keys[i, 0], keys[i, 1] = a | _ONE, b  # never (0, 0)
    return keys


COMPILE_NOTICE = "smorphi-rl: compiling the coverage planner (the first run only: up to about 40 s; then cached)"


class CompileNotice(numba_events.Listener):
    """Says COMPILE_NOTICE on a terminal as the first kernel of this file is compiled in this process (numba's
    public compile event, which a kernel loaded from the cache does not raise): a first run, or one after an upgrade,
    was silent for about 40 s."""

    said = False

    def on_start(self, event: numba_events.Event) -> None:
        kernel = getattr(event.data.get("dispatcher"), "py_func", None)
        if self.said or getattr(kernel, "__module__", None) != __name__:
            return
        self.said = True
        if getattr(sys.stderr, "isatty", lambda: False)():  # a log or a pipe need not know
            print(COMPILE_NOTICE, file=sys.stderr, flush=True)

    def on_end(self, event: numba_events.Event) -> None:
        pass


numba_events.register("numba:compile", CompileNotice())

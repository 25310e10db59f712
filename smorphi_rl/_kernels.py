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

import numpy as np
from numba import njit

# Columns of the per-morphology result rows written by the batch kernels.
COL_FEASIBLE, COL_L, COL_W, COL_W_M, COL_L_M, COL_COVERED, COL_PLEN, COL_EW, COL_NS, COL_STATUS, COL_BOUND = range(11)
N_COLS = 11
STATUS_OK, STATUS_START_BLOCKED, STATUS_START_OUTSIDE, STATUS_PAD_TOO_SMALL, STATUS_TILE_START_FIT = 0, 1, 2, 3, 4
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
    edge_e = np.zeros(n, np.bool_)  # tiles are joined where both are traversable (FBCPP.md section 5)
    edge_n = np.zeros(n, np.bool_)
    for t in range(n):
        if trav[t]:
            edge_e[t] = t % nc + 1 < nc and trav[t + 1]
            edge_n[t] = t // nc + 1 < nr and trav[t + nc]
    n_cov, p_len, n_ew, n_ns, n_path = _walk(padded, f, nr, nc, edge_e, edge_n, start, 0, 0, path, covered, h, wd)
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
) -> tuple[int, int, int, int, int]:
    """FBCPP.md sections 5-6 on an nr x nc lattice of nodes whose node (a, b) puts F's corner at cell
    (oy + a l, ox + b w), joined where `edge_e` (to b + 1) and `edge_n` (to a + 1) say: distance transform,
    greedy walk with breadth-first escapes from dead ends, and the footprint swept along every move.
    Returns (covered free cells, P_len, east/west moves, north/south moves, path nodes)."""
    l, w = f.shape
    stride = padded.shape[1]
    n = nr * nc
    dist = np.full(n, -1, np.int32)
    queue = np.empty(n, np.int32)
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
    reachable = tail
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
    off_f, off_x, off_y = _offsets(f, stride), _offsets(swept_x, stride), _offsets(swept_y, stride)
    work = padded.ravel().copy()
    origin = oy * stride + ox
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
                    n_cov += _stamp(off_x, origin + pa * l * stride + min(pb, qb) * w, work)
            else:
                n_ns += 1
                e = min(pa, qa) * nc + pb
                if not swept_ns[e]:
                    swept_ns[e] = True
                    n_cov += _stamp(off_y, origin + min(pa, qa) * l * stride + pb * w, work)
            if n_path < path.shape[0]:
                path[n_path, 0], path[n_path, 1] = qa, qb
            n_path += 1
            p_len += 1
            cur = nxt
            if not visited[cur]:
                visited[cur] = True
                n_visited += 1
    if covered.shape[0] == h and covered.shape[1] == wd:
        for y in range(h):
            for x in range(wd):
                covered[y, x] = work[y * stride + x] == 2
    return n_cov, p_len, n_ew, n_ns, n_path


_ONE = np.uint64(1)


@njit(cache=True)
def _dense(f: np.ndarray) -> np.ndarray:
    """F as a contiguous boolean array: the batch kernels pass a strided uint8 view, and every loop over F
    runs about 1.5 times faster on a dense copy."""
    out = np.empty(f.shape, np.bool_)
    for i in range(f.shape[0]):
        for j in range(f.shape[1]):
            out[i, j] = f[i, j] != 0
    return out


@njit(cache=True)
def _blocked_bits(padded: np.ndarray, n_rows: int, n_cols: int) -> np.ndarray:
    """Rows of `padded` as bit sets (bit x of row y set where the cell is not free), one spare word per row
    so a shifted read of the next word never leaves the row."""
    nw = (n_cols + 63) // 64 + 1
    out = np.zeros((n_rows, nw), np.uint64)
    cols = min(n_cols, padded.shape[1])
    for y in range(n_rows):
        for x in range(cols):
            if padded[y, x] != 0:
                out[y, x >> 6] |= _ONE << np.uint64(x & 63)
    return out


@njit(cache=True)
def _or_shifted(acc: np.ndarray, row: np.ndarray, j: int, nw: int, down: bool) -> None:
    """acc |= `row` (a bit set over cells of one row) moved by j cells, over the first nw words: down, bit x
    takes bit x + j (row must have a word past nw); up, bit x + j takes bit x."""
    if j == 0:
        for k in range(nw):
            acc[k] |= row[k]
    elif down:
        right, left = np.uint64(j), np.uint64(64 - j)
        for k in range(nw):
            acc[k] |= (row[k] >> right) | (row[k + 1] << left)
    else:
        left, right = np.uint64(j), np.uint64(64 - j)
        acc[0] |= row[0] << left
        for k in range(1, nw):
            acc[k] |= (row[k] << left) | (row[k - 1] >> right)


@njit(cache=True)
def _safe_placements(padded: np.ndarray, h: int, wd: int, f: np.ndarray) -> np.ndarray:
    """safe[y * wd + x]: F with its corner on cell (y, x) overlaps only free cells of the map. Word-parallel:
    a row of placements is unsafe where some cell (i, j) of F meets a blocked cell, i.e. the OR over F's
    cells of map row y + i shifted right by j, 64 placements per operation."""
    l, w = f.shape
    bits = _blocked_bits(padded, h + l, wd + w)
    nw = (wd + 63) // 64
    safe = np.zeros(h * wd, np.bool_)
    acc = np.empty(nw, np.uint64)
    for y in range(h):
        acc[:] = 0
        for i in range(l):
            row = bits[y + i]
            for j in range(w):
                if f[i, j]:
                    _or_shifted(acc, row, j, nw, True)
        for x in range(wd):
            safe[y * wd + x] = (acc[x >> 6] >> np.uint64(x & 63)) & _ONE == 0
    return safe


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
def _fit_candidates(
    safe: np.ndarray, label: np.ndarray, area: np.ndarray, f: np.ndarray, h: int, wd: int, start_kind: int,
    sp: int, sq: int,
) -> np.ndarray:  # fmt: skip
    """Start placements to try (docs/fbcpp-fit.md section 3), in raster order."""
    l, w = f.shape
    out = np.empty(h * wd, np.int64)
    n = 0
    if start_kind == START_CELL:  # every safe placement whose stamp holds the start cell
        for p in range(h * wd):
            y, x = p // wd, p % wd
            i, j = sp - y, sq - x
            if 0 <= i < l and 0 <= j < w and f[i, j] and safe[p]:
                out[n] = p
                n += 1
        return out[:n]
    fi, fj = -1, -1  # F's first cell in raster order
    for i in range(l):
        for j in range(w):
            if f[i, j] and fi < 0:
                fi, fj = i, j
    n_labels = label.max() + 1
    count = np.zeros(max(n_labels, 1), np.int64)
    first = np.full(max(n_labels, 1), h * wd, np.int64)
    for y in range(h):  # nested loops rather than p // wd and p % wd: divisions dominate a plan this small
        for x in range(wd):
            p = y * wd + x
            if safe[p] and area[(y + fi) * wd + x + fj]:
                count[label[p]] += 1
                first[label[p]] = min(first[label[p]], p)
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
        cx = 0
        for x in range(wd):
            p = y * wd + x
            if label[p] == best and area[(y + fi) * wd + x + fj] and not taken[cy + cx]:
                taken[cy + cx] = True
                out[n] = p
                n += 1
            cx = cx + 1 if cx + 1 < w else 0
        y += 1
    return out[:n]


@njit(cache=True)
def _safe_runs(safe: np.ndarray, h: int, wd: int) -> tuple[np.ndarray, np.ndarray]:
    """Prefix counts of safe placements along each row (h x wd+1) and each column (h+1 x wd), so that
    "every placement of a straight move is safe" is one subtraction."""
    rows = np.zeros((h, wd + 1), np.int32)
    cols = np.zeros((h + 1, wd), np.int32)
    for y in range(h):
        for x in range(wd):
            s = 1 if safe[y * wd + x] else 0
            rows[y, x + 1] = rows[y, x] + s
            cols[y + 1, x] = cols[y, x] + s
    return rows, cols


@njit(cache=True)
def _fit_lattice(
    safe: np.ndarray, rows: np.ndarray, cols: np.ndarray, h: int, wd: int, l: int, w: int, y0: int, x0: int,
    edge_e: np.ndarray, edge_n: np.ndarray,
) -> tuple[int, int, np.ndarray, np.ndarray, int]:  # fmt: skip
    """The lattice through placement (y0, x0): (rows, columns, east edges, north edges, start node), the
    edges written into the given buffers (at least H*W long; reused across candidates). Nodes are safe
    placements; an edge joins neighbours when every placement along the move is safe (`_safe_runs`)."""
    oy, ox = y0 % l, x0 % w
    nr, nc = (h - oy + l - 1) // l, (wd - ox + w - 1) // w
    n = nr * nc
    edge_e[:n] = False
    edge_n[:n] = False
    for a in range(nr):
        for b in range(nc):
            y, x = oy + a * l, ox + b * w
            if not safe[y * wd + x]:
                continue
            if b + 1 < nc:
                edge_e[a * nc + b] = rows[y, x + w + 1] - rows[y, x] == w + 1
            if a + 1 < nr:
                edge_n[a * nc + b] = cols[y + l + 1, x] - cols[y, x] == l + 1
    return nr, nc, edge_e, edge_n, ((y0 - oy) // l) * nc + (x0 - ox) // w


@njit(cache=True)
def _reach(
    nr: int, nc: int, edge_e: np.ndarray, edge_n: np.ndarray, start: int, seen: np.ndarray, queue: np.ndarray
) -> int:
    """How many nodes breadth-first search reaches from `start` over joined edges (`seen` and `queue`:
    buffers at least nr * nc long)."""
    seen[: nr * nc] = False
    seen[start] = True
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        t = queue[head]
        head += 1
        a = t // nc
        b = t - a * nc
        for k in range(4):
            u = _joined(t, a, b, k, nr, nc, edge_e, edge_n)
            if u >= 0 and not seen[u]:
                seen[u] = True
                queue[tail] = u
                tail += 1
    return tail


@njit(cache=True)
def _class_bounds(safe: np.ndarray, label: np.ndarray, candidates: np.ndarray, l: int, w: int, wd: int) -> np.ndarray:
    """For each candidate, the safe placements of its lattice class (row mod l, column mod w) in its group:
    the most nodes its lattice can reach (a lattice move only passes safe placements, so it stays in the group).
    Counted only for the candidates' groups (one, from the default start), so memory stays at l * w a group."""
    slot = np.full(label.max() + 1, -1, np.int64)  # group -> row of `count`
    n_slots = 0
    for c in range(candidates.shape[0]):
        g = label[candidates[c]]
        if slot[g] < 0:
            slot[g] = n_slots
            n_slots += 1
    count = np.zeros((n_slots, l * w), np.int64)
    h = safe.shape[0] // wd
    for y in range(h):  # nested loops: no divisions (as in `_fit_candidates`)
        cy = (y % l) * w
        cx = 0
        for x in range(wd):
            p = y * wd + x
            if safe[p] and slot[label[p]] >= 0:
                count[slot[label[p]], cy + cx] += 1
            cx = cx + 1 if cx + 1 < w else 0
    upper = np.empty(candidates.shape[0], np.int64)
    for c in range(candidates.shape[0]):
        p = candidates[c]
        upper[c] = count[slot[label[p]], (p // wd % l) * w + p % wd % w]
    return upper


@njit(cache=True)
def plan_fit_into(
    padded: np.ndarray,
    prefix: np.ndarray,
    area: np.ndarray,
    f: np.ndarray,
    start_kind: int,
    sp: int,
    sq: int,
    covered: np.ndarray,
    path: np.ndarray,
) -> tuple[int, int, int, int, int, int, int, int, int]:
    """The footprint-safe planner (docs/fbcpp-fit.md) for footprint f (l x w).

    `padded` and `prefix` as for `plan_into`; `area` (H*W, uint8) marks the largest free area. Fills `covered` and up to
    len(path) placements (row, column of F's corner) as `plan_into` does. Returns (status, covered free
    cells, P_len, east/west moves, north/south moves, path length, coverable-bound cells, start row, start
    column); a shape with no safe start covers nothing (start -1, -1)."""
    h, wd = prefix.shape[0] - 1, prefix.shape[1] - 1
    l, w = f.shape
    if padded.shape[0] < h + 2 * l or padded.shape[1] < wd + 2 * w:
        return STATUS_PAD_TOO_SMALL, 0, 0, 0, 0, 0, 0, -1, -1
    if start_kind == START_TILE:
        return STATUS_TILE_START_FIT, 0, 0, 0, 0, 0, 0, -1, -1
    f = _dense(f)
    safe = _safe_placements(padded, h, wd, f)
    rows, cols = _safe_runs(safe, h, wd)
    label = components(safe, h, wd)
    candidates = _fit_candidates(safe, label, area, f, h, wd, start_kind, sp, sq)
    if candidates.shape[0] == 0:
        return STATUS_OK, 0, 0, 0, 0, 0, 0, -1, -1
    # The lattice that reaches the most nodes, the earliest candidate of equal ones. A lattice reaches at most
    # the safe placements of its class in its candidate's group, so candidates are tried from the largest such
    # bound down, and the search stops once no bound left can match the best reach found.
    upper = _class_bounds(safe, label, candidates, l, w, wd)
    best, best_reach = -1, -1
    edge_e, edge_n = np.zeros(h * wd, np.bool_), np.zeros(h * wd, np.bool_)
    seen, queue = np.zeros(h * wd, np.bool_), np.empty(h * wd, np.int32)
    for c in np.argsort(-upper, kind="mergesort"):
        if upper[c] < best_reach:
            break
        if upper[c] == best_reach and c > best:
            continue
        y0, x0 = candidates[c] // wd, candidates[c] % wd
        nr, nc, edge_e, edge_n, s = _fit_lattice(safe, rows, cols, h, wd, l, w, y0, x0, edge_e, edge_n)
        reach = _reach(nr, nc, edge_e, edge_n, s, seen, queue)
        if reach > best_reach or (reach == best_reach and c < best):
            best, best_reach = c, reach
    y0, x0 = candidates[best] // wd, candidates[best] % wd
    oy, ox = y0 % l, x0 % w
    nr, nc, edge_e, edge_n, s = _fit_lattice(safe, rows, cols, h, wd, l, w, y0, x0, edge_e, edge_n)
    n_cov, p_len, n_ew, n_ns, n_path = _walk(padded, f, nr, nc, edge_e, edge_n, s, oy, ox, path, covered, h, wd)
    for m in range(min(n_path, path.shape[0])):  # lattice nodes as placements
        path[m, 0], path[m, 1] = oy + path[m, 0] * l, ox + path[m, 1] * w
    return STATUS_OK, n_cov, p_len, n_ew, n_ns, n_path, _bound(label, label[y0 * wd + x0], f, h, wd), y0, x0


@njit(cache=True)
def _popcount(v: np.uint64) -> int:
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True)
def _bound(label: np.ndarray, group: int, f: np.ndarray, h: int, wd: int) -> int:
    """Cells under F at some placement of `group` (all free: every placement of the group is safe), word-
    parallel: the OR over F's cells (i, j) of the group's placement rows shifted left by j into row y + i."""
    l, w = f.shape
    nw = (wd + 63) // 64 + 1  # a spare word: a shifted row never leaves the row (bits past wd stay clear)
    placed = np.zeros((h, nw), np.uint64)
    for y in range(h):
        for x in range(wd):
            if label[y * wd + x] == group:
                placed[y, x >> 6] |= _ONE << np.uint64(x & 63)
    under = np.zeros((h + l, nw), np.uint64)
    for y in range(h):
        row = placed[y]
        for i in range(l):
            out = under[y + i]
            for j in range(w):
                if f[i, j]:
                    _or_shifted(out, row, j, nw, False)
    total = 0
    for y in range(h):
        for k in range(nw):
            total += _popcount(under[y, k])
    return total


@njit(cache=True)
def plan_any(
    planner: int,
    padded: np.ndarray,
    prefix: np.ndarray,
    area: np.ndarray,
    f: np.ndarray,
    start_kind: int,
    sp: int,
    sq: int,
    covered: np.ndarray,
    path: np.ndarray,
) -> tuple[int, int, int, int, int, int, int, int, int]:
    """Either planner, with the fit planner's returns (the paper's coverable bound is its own coverage, as
    it covers every reachable tile; its start placement is not reported: -1, -1)."""
    if planner == PLANNER_FIT:
        return plan_fit_into(padded, prefix, area, f, start_kind, sp, sq, covered, path)
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
    area: np.ndarray,
) -> np.ndarray:
    """Uncached evaluation of every row of `thetas` (N x 3): one result row each (COL_*)."""
    out = np.zeros((thetas.shape[0], N_COLS))
    buf = np.zeros((side, side), np.uint8)
    no_covered = np.zeros((0, 0), np.uint8)
    no_path = np.zeros((0, 2), np.int32)
    for i in range(thetas.shape[0]):
        feasible, l, w, w_m, l_m = footprint_into(thetas[i, 0], thetas[i, 1], thetas[i, 2], s, r, buf)
        out[i, COL_FEASIBLE], out[i, COL_L], out[i, COL_W] = feasible, l, w
        out[i, COL_W_M], out[i, COL_L_M] = w_m, l_m
        if feasible and l > 0:
            res = plan_any(planner, padded, prefix, area, buf[:l, :w], start_kind, sp, sq, no_covered, no_path)
            out[i, COL_STATUS] = res[0]
            out[i, COL_COVERED], out[i, COL_PLEN], out[i, COL_EW], out[i, COL_NS] = res[1], res[2], res[3], res[4]
            out[i, COL_BOUND] = res[6]
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
    area: np.ndarray,
) -> np.ndarray:
    """Plan every footprint (bits rows, shapes rows (l, w)); result rows with the plan columns."""
    out = np.zeros((bits.shape[0], N_COLS))
    no_covered = np.zeros((0, 0), np.uint8)
    no_path = np.zeros((0, 2), np.int32)
    for i in range(bits.shape[0]):
        l, w = shapes[i, 0], shapes[i, 1]
        f = bits[i].reshape((side, side))[:l, :w]
        res = plan_any(planner, padded, prefix, area, f, start_kind, sp, sq, no_covered, no_path)
        out[i, COL_STATUS] = res[0]
        out[i, COL_COVERED], out[i, COL_PLEN], out[i, COL_EW], out[i, COL_NS] = res[1], res[2], res[3], res[4]
        out[i, COL_BOUND] = res[6]
    return out

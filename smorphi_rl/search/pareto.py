"""Pareto fronts of (maximise P_c, minimise P_len), shared by every search method and the comparison."""

from __future__ import annotations

import numpy as np


def pareto_front(p_c: np.ndarray, p_len: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated points, sorted by P_len (then P_c descending); one index per
    distinct (P_c, P_len) point. A point is dominated when another has P_c >= and P_len <= with
    at least one strict."""
    p_c = np.asarray(p_c, dtype=np.float64)
    p_len = np.asarray(p_len, dtype=np.float64)
    order = np.lexsort((-p_c, p_len))
    ranked = p_c[order]
    best_before = np.empty_like(ranked)  # the best P_c of every point earlier in that order
    best_before[:1] = -np.inf
    np.maximum.accumulate(ranked[:-1], out=best_before[1:])
    return order[ranked > best_before].astype(np.int64)

"""R1 = w1 P_c - w2 P_len: the one formula that ranks shapes everywhere (env rewards, searches, compare,
the protocol's optimum, the critic's scale). Scalars or numpy arrays alike.

P_c is a percentage, the same on any floor; P_len counts tile moves, which grow with the floor's area, so
with the paper's fixed w2 the ranking on a large floor collapses to "shortest path". The path term
`per_area` charges w2 per tile move per REFERENCE_AREA_M2 of free floor instead: the weight in effect on
a map is w2 * REFERENCE_AREA_M2 / (its free area), so the same w2 means the same trade-off on every floor
(on the shipped 5 m x 5 m maps, nearly the paper's)."""

from __future__ import annotations

from typing import Any

PATH_TERMS = ("moves", "per_area")
"""How w2 charges the path: per tile move (the paper's), or per tile move per REFERENCE_AREA_M2 of floor."""
REFERENCE_AREA_M2 = 25.0
"""The floor area `per_area` weights are stated for: the shipped maps' 5 m x 5 m."""


def effective_w2(w2: float, path_term: str, free_area_m2: float) -> float:
    """The weight of P_len in effect on a floor of `free_area_m2` free square metres."""
    if path_term == "moves":
        return w2
    if path_term == "per_area":
        return w2 * REFERENCE_AREA_M2 / free_area_m2
    raise ValueError(f"unknown path term {path_term!r} (choose from {', '.join(PATH_TERMS)})")


def r1(p_c: Any, p_len: Any, w1: float, w2: float) -> Any:
    """The env's R1 of one result (floats) or of arrays of them (float64 arrays)."""
    return w1 * p_c - w2 * p_len

"""R1 = w1 P_c - w2 P_len: the one formula that ranks shapes everywhere (env rewards, searches, compare,
the protocol's optimum, the critic's scale). Scalars or numpy arrays alike."""

from __future__ import annotations

from typing import Any


def r1(p_c: Any, p_len: Any, w1: float, w2: float) -> Any:
    """The env's R1 of one result (floats) or of arrays of them (float64 arrays)."""
    return w1 * p_c - w2 * p_len

"""R1 = w1 P_c - w2 P_len: the one formula that ranks shapes everywhere (env rewards, searches, compare,
the protocol's optimum, the critic's scale). Scalars or numpy arrays alike."""

from __future__ import annotations

from typing import TypeVar

import numpy as np

T = TypeVar("T", float, np.ndarray)


def r1(p_c: T, p_len: T | int, w1: float, w2: float) -> T:
    """The env's R1 of one result or of arrays of them."""
    if isinstance(p_c, np.ndarray) or isinstance(p_len, np.ndarray):
        return w1 * np.asarray(p_c, dtype=np.float64) - w2 * np.asarray(p_len, dtype=np.float64)  # type: ignore[return-value]
    return w1 * float(p_c) - w2 * float(p_len)  # type: ignore[return-value]

"""When a learning curve has converged: one definition, used by `transfer`, the sweeps and the benchmarks.

A run has converged at the first iteration from which the moving average of its mean episode
return (over `window` iterations) stays within `tol` (2 %) of the run's final plateau, the
mean of that moving average over the last `plateau_frac` (20 %) of the run. The convergence
step is the env-step count of that iteration. No Ray here.
"""

from __future__ import annotations

import numpy as np

WINDOW = 10
TOLERANCE = 0.02
PLATEAU_FRACTION = 0.2


def moving_average(values: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """Trailing mean over up to `window` points (shorter at the start), ignoring NaNs."""
    v = np.asarray(values, dtype=float)
    out = np.full(v.shape, np.nan)
    for i in range(len(v)):
        chunk = v[max(0, i - window + 1) : i + 1]
        if np.isfinite(chunk).any():
            out[i] = np.nanmean(chunk)
    return out


def convergence(
    env_steps: np.ndarray,
    returns: np.ndarray,
    window: int = WINDOW,
    tol: float = TOLERANCE,
    plateau_frac: float = PLATEAU_FRACTION,
) -> tuple[float | None, float]:
    """(env steps at convergence or None, the plateau). None when the curve never settles."""
    steps = np.asarray(env_steps, dtype=float)
    ma = moving_average(returns, window)
    finite = np.isfinite(ma)
    if not finite.any():
        return None, float("nan")
    tail = ma[finite][-max(1, round(plateau_frac * float(finite.sum()))) :]
    plateau = float(np.mean(tail))
    inside = np.abs(ma - plateau) <= tol * abs(plateau)
    inside[~finite] = False
    outside = np.flatnonzero(~inside)
    first = 0 if not outside.size else int(outside[-1]) + 1
    if first >= len(ma):
        return None, plateau
    return float(steps[first]), plateau

"""When a learning curve has converged: one definition, used by `transfer`, the sweeps and the benchmarks.

The curve is the final-shape R1: the R1 of the shape each episode ends on, averaged over the
last 50 episodes (`env_runners/smorphi/R1_final`), i.e. the design the policy settles on. A run
has converged at the first iteration from which that curve stays within `tol` (2 %) of the
run's plateau, the mean of its last `plateau_frac` (20 %) of iterations; the convergence step is
that iteration's env-step count. A run that enters the band only within those last 20 % has not
shown that it stays there: not converged (None). The episode return is not used: its random start and 200 steps
of walking make a random policy's return within 2 % of a trained one's. No Ray here.
"""

from __future__ import annotations

import numpy as np

CURVE_KEY = "final_R1"
"""The curve (in `Curve.as_dict()` and `sweep_report.result_curve`) that convergence is measured on."""
TOLERANCE = 0.02
PLATEAU_FRACTION = 0.2


def convergence(
    env_steps: np.ndarray, curve: np.ndarray, tol: float = TOLERANCE, plateau_frac: float = PLATEAU_FRACTION
) -> tuple[float | None, float]:
    """(env steps at convergence or None, the plateau). None when the curve is still outside the band at its end."""
    steps = np.asarray(env_steps, dtype=float)
    values = np.asarray(curve, dtype=float)
    finite = np.isfinite(values)
    if not finite.any():
        return None, float("nan")
    n_tail = max(1, round(plateau_frac * float(finite.sum())))
    plateau = float(np.mean(values[finite][-n_tail:]))
    inside = finite & (np.abs(values - plateau) <= tol * abs(plateau))
    outside = np.flatnonzero(~inside)
    first = 0 if not outside.size else int(outside[-1]) + 1
    if first >= len(values) - n_tail:  # inside only within the plateau window, if at all
        return None, plateau
    return float(steps[first]), plateau

"""When a learning curve has converged: one definition, used by `transfer`, the sweeps and the benchmarks.

The curve is the evaluation protocol's settled R1 (`eval/settled_R1_mean`): the mean R1 of the
shapes the greedy policy settles on from the fixed seeded starts, measured every few iterations.
A run has converged at the first evaluation from which that curve stays within `tol` (2 %) of the
run's plateau, the mean of its last `plateau_frac` (20 %) of evaluations; the convergence step is
that iteration's env-step count. A run that enters the band only within those last 20 % has not
shown that it stays there: not converged (None). Iterations without an evaluation are skipped.
The episode return is not used (a random policy's is within 2 % of a trained one's), nor the
stochastic final-shape R1 (exploration makes it swing by several points). No Ray here.
"""

from __future__ import annotations

import numpy as np

CURVE_KEY = "eval_R1"
"""The curve (of `sweep_report.curve_point`, which every report reads) that convergence is measured on."""
TOLERANCE = 0.02
PLATEAU_FRACTION = 0.2


def convergence(
    env_steps: np.ndarray, curve: np.ndarray, tol: float = TOLERANCE, plateau_frac: float = PLATEAU_FRACTION
) -> tuple[float | None, float]:
    """(env steps at convergence or None, the plateau). None when the curve is still outside the band at its end."""
    finite = np.isfinite(np.asarray(curve, dtype=float))  # iterations without a measurement are skipped
    steps = np.asarray(env_steps, dtype=float)[finite]
    values = np.asarray(curve, dtype=float)[finite]
    if not values.size:
        return None, float("nan")
    n_tail = max(1, round(plateau_frac * float(values.size)))
    plateau = float(np.mean(values[-n_tail:]))
    inside = np.abs(values - plateau) <= tol * abs(plateau)
    outside = np.flatnonzero(~inside)
    first = 0 if not outside.size else int(outside[-1]) + 1
    if first >= len(values) - n_tail:  # inside only within the plateau window, if at all
        return None, plateau
    return float(steps[first]), plateau

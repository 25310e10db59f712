"""When a run has converged: one definition, used by `sweep`, `transfer`, `reproduce` and the benchmarks.

Every few iterations the evaluation protocol rolls the greedy policy out from fixed seeded starts and reports the
share of starts whose settled shape is within 1 % of the exact optimum's R1. A run has converged at the first
evaluation from which that share stays at least 90 % for the rest of the run; the convergence step is that
evaluation's env-step count. A run whose last evaluation is under 90 % has not converged within its budget (None),
which reports show as such, never as a number. The shares are the trained policy's, also at the last evaluation of
a run that ends on an earlier policy (`protocol.TRAINED_KEY`): choosing a policy is not learning. Iterations
without an evaluation are skipped. The plateau reported beside it is the mean greedy settled R1 over the run's last
20 % of evaluations. No Ray here.
"""

from __future__ import annotations

import math

import numpy as np

CURVE_KEY = "eval_within"
"""The curve (of `sweep_report.curve_point`, which every report reads) that convergence is measured on."""
PLATEAU_KEY = "eval_R1"
"""The curve whose end is the run's plateau (the greedy settled R1)."""
SHARE = 0.9
"""Converged: at least this share of the protocol's starts within 1 % of the optimum, from then on."""
PLATEAU_FRACTION = 0.2


def converged_at(env_steps: np.ndarray, within: np.ndarray, share: float = SHARE) -> float | None:
    """Env steps at the first evaluation from which `within` (the share of starts within 1 %) stays >= `share`
    to the end; None when the last evaluation is below it, or there is none."""
    measured = np.isfinite(np.asarray(within, dtype=float))
    steps = np.asarray(env_steps, dtype=float)[measured]
    values = np.asarray(within, dtype=float)[measured]
    if not values.size or values[-1] < share:
        return None
    below = np.flatnonzero(values < share)
    return float(steps[int(below[-1]) + 1 if below.size else 0])


def plateau(curve: np.ndarray, fraction: float = PLATEAU_FRACTION) -> float:
    """The mean of the last `fraction` of the curve's measured points (NaN when there are none)."""
    values = np.asarray(curve, dtype=float)
    values = values[np.isfinite(values)]
    if not values.size:
        return float("nan")
    return float(np.mean(values[-max(1, round(fraction * float(values.size))) :]))


def convergence(curve: dict[str, list[float]]) -> tuple[float | None, float]:
    """(env steps at convergence or None, the settled-R1 plateau) of a run's curves (`sweep_report.result_curve`)."""
    steps = np.array(curve["env_steps"], dtype=float)
    return converged_at(steps, np.array(curve[CURVE_KEY], dtype=float)), plateau(np.array(curve[PLATEAU_KEY]))


def at_steps(curve: dict[str, list[float]], key: str, env_steps: float) -> float:
    """The run's last measured `key` (an `eval_...` curve) at or before `env_steps`; NaN when none was measured
    by then. Two runs compared at equal env steps read this."""
    steps = np.asarray(curve.get("env_steps", []), dtype=float)
    values = np.asarray(curve.get(key, []), dtype=float)
    ok = np.flatnonzero(np.isfinite(values) & (steps <= env_steps))
    return float(values[ok[-1]]) if ok.size else math.nan


def first_measured_steps(curve: dict[str, list[float]], key: str) -> float:
    """The env steps of the run's first measured `key`; inf when none was measured."""
    steps = np.asarray(curve.get("env_steps", []), dtype=float)
    ok = np.flatnonzero(np.isfinite(np.asarray(curve.get(key, []), dtype=float)))
    return float(steps[ok[0]]) if ok.size else math.inf


def measured(curve: dict[str, list[float]]) -> bool:
    """Whether any evaluation of the run measured its share within 1 % (none can on a map without an exact
    optimum: the run is "not measured", not "not converged")."""
    return bool(np.isfinite(np.asarray(curve.get(CURVE_KEY, []), dtype=float)).any())


def converged_text(converged_at: float | None, curve: dict[str, list[float]]) -> str:
    """One run's convergence as a table shows it: its env steps, "not converged" or "not measured"."""
    if converged_at is not None:
        return str(int(converged_at))
    return "not converged" if measured(curve) else "not measured"


def converged_count(converged: int, curves: list[dict[str, list[float]]]) -> str:
    """ "k of n" runs converged, n counting the runs that were measured; "not measured" when none was."""
    n = sum(measured(c) for c in curves)
    return f"{converged} of {n}" if n or not curves else "not measured"


def censored_steps(runs: list[tuple[float | None, float]]) -> tuple[list[float], list[float]]:
    """Env steps to converge of runs given as (converged at or None, env steps trained), as the bounds
    `stats.censored_median_interval` takes: (least, most), each a run's time where it converged, and its env steps
    and inf where it did not (it would converge later, if ever: right-censored, never left out)."""
    least = [float(steps) if at is None else float(at) for at, steps in runs]
    most = [math.inf if at is None else float(at) for at, _ in runs]
    return least, most

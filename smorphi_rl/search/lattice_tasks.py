"""The work of a lattice search's workers, local processes and Ray actors alike: key shapes by their footprint,
and plan one shape of each distinct footprint, pruned where it cannot beat the best R1 (docs/exact-search.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from smorphi_rl.planning import Evaluator, Lattice


def footprint_keys(evaluator: Evaluator, thetas: np.ndarray) -> np.ndarray:
    """Two 64-bit words per row: equal exactly when the rows' footprints F are (a 128-bit hash of F's shape and
    bits; both zero where the shape is infeasible)."""
    from smorphi_rl import _kernels as k

    arr = np.ascontiguousarray(thetas, dtype=np.float64)
    return k.footprint_keys(arr, evaluator.block_side_m, evaluator.grid_map.resolution_m, evaluator.footprint_side)


def run_task(evaluator: Evaluator, lattice: np.ndarray | Lattice, bound: np.ndarray,
             task: tuple[Any, ...]) -> tuple[Any, ...]:  # fmt: skip
    """One task: ("keys", lo, hi): the footprint keys of lattice rows [lo, hi); ("plan", tag, rows, threshold): the
    metrics of those rows (one distinct footprint each), pruned where they cannot beat R1 `threshold` (`bound`:
    `Evaluator.prune_bound`, raised in place), and the best R1 this worker has planned."""
    if task[0] == "keys":
        _, lo, hi = task
        return "keys", lo, hi, footprint_keys(evaluator, lattice[lo:hi])
    _, tag, rows, threshold = task
    bound[0] = max(bound[0], threshold)
    batch, pruned = evaluator.evaluate_bounded(lattice[rows], bound)
    return "plan", tag, batch.P_c, batch.P_len.astype(np.int32), batch.feasible, pruned, float(bound[0])

"""Every triple on a lattice of hinge angles, in parallel: the exact Pareto front and the best R1.

Each worker process keeps one Evaluator for the whole run, so a footprint it has planned once is
never planned again; the lattice is cut into chunks so progress can be shown.
"""

from __future__ import annotations

import hashlib
import math
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.evaluate import PAPER_PLANNING, Evaluator, Planning, lattice_thetas
from smorphi_rl.maps import load_map
from smorphi_rl.search.results import SearchResult

CHUNKS_PER_WORKER = 24
"""Enough chunks for a smooth progress display; few enough that their overhead stays small."""


def check_step(step_deg: float) -> float:
    """A lattice step must divide 180 exactly (so 0 and 180 are both on it)."""
    if not (math.isfinite(step_deg) and 0 < step_deg <= 180):
        raise SmorphiError(f"--step must be in (0, 180], got {step_deg:g}")
    n = 180 / step_deg
    if not math.isclose(n, round(n), abs_tol=1e-9):
        raise SmorphiError(f"--step {step_deg:g} does not divide 180")
    return float(step_deg)


_worker: Evaluator | None = None


WORKER_CACHE_FOOTPRINTS = 100_000
"""Footprints a worker keeps between chunks (about 70 MB at 0.05 m): memory stays flat however many distinct
footprints a large map has; a chunk's repeats are still planned once (`evaluate_many` groups them)."""


def die_with_parent(parent: int) -> None:
    """Have the kernel kill this worker when its parent dies, whatever signal ended it (Linux's
    PR_SET_PDEATHSIG; a SIGKILLed driver otherwise leaves its pool workers blocked forever)."""
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def _init(map_path: str, planning: Planning, parent: int) -> None:
    global _worker
    die_with_parent(parent)
    _worker = planning.evaluator(load_map(map_path), cache_limit=WORKER_CACHE_FOOTPRINTS)


def _chunk(thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, set[bytes]]:
    """Metrics of one chunk, and short digests of the footprints this worker planned for it (new ones only)."""
    if _worker is None:  # pragma: no cover (the pool initializer always runs first)
        raise RuntimeError("worker not initialised")
    batch = _worker.evaluate_many(thetas)
    keys = _worker.drain_planned()
    digests = {hashlib.blake2b(key, digest_size=8).digest() for key in keys}
    return batch.P_c, batch.P_len.astype(np.int32), batch.feasible, digests


def run_exhaustive(
    map_path: str,
    step_deg: float = 1.0,
    planning: Planning = PAPER_PLANNING,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SearchResult:
    """Evaluate every triple at `step_deg` on the map, planned as `planning` says, on `workers` processes
    (default: every core)."""
    step = check_step(step_deg)
    grid_map = load_map(map_path)
    thetas = lattice_thetas(step)
    n_workers = max(1, workers or os.cpu_count() or 1)
    n_chunks = max(1, min(len(thetas) // 1000, n_workers * CHUNKS_PER_WORKER))
    chunks = np.array_split(thetas, n_chunks)
    # compile (or load) the kernels before forking
    planning.evaluator(grid_map).evaluate_many(thetas[:2])
    p_c = np.zeros(len(thetas))
    p_len = np.zeros(len(thetas), dtype=np.int32)
    feasible = np.zeros(len(thetas), dtype=bool)
    digests: set[bytes] = set()
    t0 = time.perf_counter()
    context = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    with ProcessPoolExecutor(n_workers, mp_context=context, initializer=_init,
                             initargs=(str(map_path), planning, os.getpid())) as pool:  # fmt: skip
        offsets = np.cumsum([0] + [len(c) for c in chunks])
        done = 0
        for i, (c_pc, c_len, c_ok, c_digests) in enumerate(pool.map(_chunk, chunks)):
            lo, hi = offsets[i], offsets[i + 1]
            p_c[lo:hi], p_len[lo:hi], feasible[lo:hi] = c_pc, c_len, c_ok
            digests |= c_digests
            done += hi - lo
            if progress is not None:
                progress(done, len(thetas))
    params = {
        "step_deg": step,
        "workers": n_workers,
        "distinct_footprints": len(digests),
        "planner": planning.planner.value,
    }
    return SearchResult("exhaustive", grid_map.name, thetas, p_c, p_len, feasible, len(thetas),
                        time.perf_counter() - t0, params)  # fmt: skip

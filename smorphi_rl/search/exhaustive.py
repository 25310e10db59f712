"""Every triple on a lattice of hinge angles, in parallel: the exact Pareto front and the best R1.

Each worker process keeps one Evaluator for the whole run, so a footprint it has planned once is
never planned again; the lattice is cut into chunks so progress can be shown.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import multiprocessing as mp
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing import connection as mp_connection
from typing import Any

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import Map, load_map
from smorphi_rl.planning import PAPER_PLANNING, Evaluator, Planning, lattice_thetas
from smorphi_rl.search.results import SearchResult

CHUNKS_PER_WORKER = 24
"""At least this many chunks per worker, for a smooth progress display."""
IN_FLIGHT_PER_WORKER = 2
"""Chunks queued per worker at a time (one running, one ready)."""
CHUNK_SHAPES = 4096
"""At most about this many shapes a chunk: on a large floor a chunk takes seconds, so progress (and a stop) comes
within seconds too."""


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


_lattice: np.ndarray | None = None
"""The lattice being searched: set by the parent before it forks its workers, which read their chunks from it
(tasks are index ranges: a chunk of arrays in the task pipe could block it, and a stop with it)."""


def _init(map_path: str, planning: Planning, parent: int, step: float) -> None:
    global _worker, _lattice
    import signal

    if _lattice is None or len(_lattice) != (round(180 / step) + 1) ** 3:  # a spawned worker builds its own
        _lattice = lattice_thetas(step)
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the pool,
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # with SIGTERM, which must end a worker wherever it is
    _worker = planning.evaluator(load_map(map_path), cache_limit=WORKER_CACHE_FOOTPRINTS)


def _chunk(bounds: tuple[int, int]) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray, set[bytes]]:
    """Metrics of the lattice's rows [lo, hi), and short digests of the footprints this worker planned for them
    (new ones only)."""
    if _worker is None or _lattice is None:  # pragma: no cover (the initializer always runs first)
        raise RuntimeError("worker not initialised")
    batch = _worker.evaluate_many(_lattice[bounds[0] : bounds[1]])
    keys = _worker.drain_planned()
    digests = {hashlib.blake2b(key, digest_size=8).digest() for key in keys}
    return bounds[0], bounds[1], batch.P_c, batch.P_len.astype(np.int32), batch.feasible, digests


def _serve(conn: Any, map_path: str, planning: Planning, parent: int, step: float) -> None:
    """A worker: index ranges in, their metrics out, over its own pipe (no lock shared with any other process,
    so killing a worker anywhere can never block the parent), until it is sent None."""
    try:
        _init(map_path, planning, parent, step)
        while (bounds := conn.recv()) is not None:
            conn.send(_chunk(bounds))
    except Exception as exc:  # said by the parent in one line, not as a worker's traceback
        conn.send(("error", f"{type(exc).__name__}: {exc}"))


@contextmanager
def _stop_requests() -> Iterator[threading.Event]:
    """While the workers run, Ctrl-C and SIGTERM set an event instead of raising wherever the main thread happens
    to be; the search's loop checks it every 0.1 s and stops there. Outside the main thread, nothing is changed."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    import signal

    handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


CHUNK_SECONDS = 1.0
"""A chunk plans for about this long at most (every shape planned), so progress and a stop come within seconds."""
SAMPLE_PLANS = 16


def chunk_shapes(grid_map: Map, planning: Planning) -> int:
    """How many shapes a chunk holds on this map: CHUNK_SHAPES, fewer where one plan is slow (timed on a few
    random shapes, uncached), at least 64. Loads or compiles the kernels first, before any worker forks."""
    evaluator = planning.evaluator(grid_map, cache=False)
    sample = np.random.default_rng(0).integers(0, 181, size=(SAMPLE_PLANS, 3)).astype(np.float64)
    evaluator.evaluate_many(sample[:2])
    t0 = time.perf_counter()
    evaluator.evaluate_many(sample)
    per_plan = (time.perf_counter() - t0) / SAMPLE_PLANS
    return int(max(64, min(CHUNK_SHAPES, CHUNK_SECONDS / max(per_plan, 1e-9))))


def chunk_bounds(n_shapes: int, n_workers: int, most: int = CHUNK_SHAPES) -> list[tuple[int, int]]:
    """Index ranges [lo, hi) covering `n_shapes`: enough per worker for a smooth progress display, at most about
    `most` shapes each, and none under min(1,000, `most`) shapes (a chunk's overhead)."""
    least = min(1000, most)
    fewest = -(-n_shapes // most)  # no chunk over `most`
    n_chunks = max(1, fewest, min(n_shapes // least, max(n_workers * CHUNKS_PER_WORKER, fewest)))
    edges = np.linspace(0, n_shapes, n_chunks + 1).astype(np.int64)
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def run_exhaustive(
    map_path: str,
    step_deg: float = 1.0,
    planning: Planning = PAPER_PLANNING,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    address: str | None = None,
) -> SearchResult:
    """Evaluate every triple at `step_deg` on the map, planned as `planning` says, on `workers` processes
    (default: every core), or, given a Ray cluster's `address`, on `workers` actors there (default: one per CPU
    of the cluster), with the same results."""
    step = check_step(step_deg)
    grid_map = load_map(map_path)
    thetas = lattice_thetas(step)
    if address is not None:
        return _on_ray(grid_map, planning, step, thetas, workers, progress, address)
    n_workers = max(1, workers or os.cpu_count() or 1)
    chunks = chunk_bounds(len(thetas), n_workers, chunk_shapes(grid_map, planning))  # also compiles the kernels
    p_c = np.zeros(len(thetas))
    p_len = np.zeros(len(thetas), dtype=np.int32)
    feasible = np.zeros(len(thetas), dtype=bool)
    digests: set[bytes] = set()
    t0 = time.perf_counter()
    context = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
    global _lattice
    _lattice = thetas  # the forked workers read their chunks from here
    workers_: list[tuple[Any, Any]] = []
    finished = False
    try:
        for _ in range(n_workers):
            here, there = context.Pipe()
            proc = context.Process(target=_serve, args=(there, str(map_path), planning, os.getpid(), step), daemon=True)
            proc.start()
            there.close()
            workers_.append((proc, here))
        with _stop_requests() as stop:
            queued = deque(chunks)
            for (_, conn), _ in itertools.product(workers_, range(IN_FLIGHT_PER_WORKER)):  # a few ahead, not all
                if queued:
                    conn.send(queued.popleft())
            done, pending = 0, len(chunks)
            alive = {conn: proc for proc, conn in workers_}
            while pending:
                if stop.is_set():
                    raise KeyboardInterrupt
                ready: list[Any] = list(mp_connection.wait(list(alive), timeout=0.1))
                for conn in ready:
                    try:
                        answer = conn.recv()
                    except EOFError:
                        raise SmorphiError(f"a search worker died (exit code {alive[conn].exitcode})") from None
                    if answer[0] == "error":
                        raise SmorphiError(f"a search worker failed: {answer[1]}")
                    lo, hi, c_pc, c_len, c_ok, c_digests = answer
                    if queued:
                        conn.send(queued.popleft())
                    p_c[lo:hi], p_len[lo:hi], feasible[lo:hi] = c_pc, c_len, c_ok
                    digests |= c_digests
                    done, pending = done + hi - lo, pending - 1
                    if progress is not None:
                        progress(done, len(thetas))
        for _, conn in workers_:
            conn.send(None)
        finished = True
    finally:  # Ctrl-C, SIGTERM, an error or the end: every worker is gone before this returns
        for proc, conn in workers_:
            if not finished:
                proc.kill()  # at once, wherever it is: it shares no lock with anyone
            proc.join(timeout=5.0)
            if proc.is_alive():
                proc.kill()
                proc.join()
            conn.close()
        _lattice = None
    params = {
        "step_deg": step,
        "workers": n_workers,
        "distinct_footprints": len(digests),
        "planner": planning.planner.value,
    }
    return SearchResult("exhaustive", grid_map.name, thetas, p_c, p_len, feasible, len(thetas),
                        time.perf_counter() - t0, params)  # fmt: skip


def _on_ray(
    grid_map: Map,
    planning: Planning,
    step: float,
    thetas: np.ndarray,
    workers: int | None,
    progress: Callable[[int, int], None] | None,
    address: str,
) -> SearchResult:
    """`run_exhaustive` on the Ray cluster at `address` (`search/on_ray.py`)."""
    from smorphi_rl.search.on_ray import plan_chunks, ray_planners

    with ray_planners(grid_map, planning, address, workers, step) as actors, _stop_requests() as stop:
        t0 = time.perf_counter()
        chunks = chunk_bounds(len(thetas), len(actors), chunk_shapes(grid_map, planning))
        p_c, p_len, feasible, digests = plan_chunks(actors, len(thetas), chunks, stop, progress)
        wall = time.perf_counter() - t0
        n_workers = len(actors)
    params = {"step_deg": step, "workers": n_workers, "distinct_footprints": len(digests),
              "planner": planning.planner.value, "address": address}  # fmt: skip
    return SearchResult("exhaustive", grid_map.name, thetas, p_c, p_len, feasible, len(thetas), wall, params)

"""Every triple on a lattice of hinge angles, in parallel: the exact Pareto front and the best R1, or the best R1
alone by branch and bound (docs/exact-search.md).

Two passes over worker processes: the first keys every shape by its footprint F (results depend on the angles only
through F), the second plans each distinct F once, in chunks so progress can be shown and a stop comes within
seconds.
"""

from __future__ import annotations

import itertools
import math
import multiprocessing as mp
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from multiprocessing import connection as mp_connection
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl._kernels import NO_PRUNE
from smorphi_rl.cluster import usable_cpus
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.geometry import angles_text, check_step, lattice_size
from smorphi_rl.interrupts import stop_requests
from smorphi_rl.maps import Map, as_map
from smorphi_rl.planning import PAPER_PLANNING, Evaluator, Planning, lattice_thetas
from smorphi_rl.score import Weights
from smorphi_rl.search.lattice_tasks import footprint_keys, run_task
from smorphi_rl.search.results import SearchResult

CHUNKS_PER_WORKER = 24
"""At least this many chunks per worker, for a smooth progress display."""
IN_FLIGHT_PER_WORKER = 2
"""Chunks queued per worker at a time (one running, one ready)."""
CHUNK_SHAPES = 4096
"""At most about this many shapes a chunk: on a large floor a chunk takes seconds, so progress (and a stop) comes
within seconds too."""


_worker: Evaluator | None = None
_bound: np.ndarray = NO_PRUNE
"""The worker's branch-and-bound state (`Evaluator.prune_bound`: inactive when every footprint is planned)."""


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
"""The lattice being searched: set by the parent before it forks its workers, which read their tasks' shapes from
it (a task names rows of it, never carries shapes)."""


def _init(grid_map: Map, planning: Planning, parent: int, step: float, weights: Weights | None) -> None:
    global _worker, _lattice, _bound
    import signal

    if _lattice is None or len(_lattice) != lattice_size(step):  # a spawned worker builds its own
        _lattice = lattice_thetas(step)
    die_with_parent(parent)
    # Ctrl-C and SIGTERM are the parent's to handle, also when sent to the whole process group (a terminal,
    # `timeout`, a scheduler): it stops its loop and kills the workers (SIGKILL); they die with it all the same
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _worker = planning.evaluator(grid_map, cache=False)
    _bound = _worker.prune_bound(weights)


def _serve(conn: Any, grid_map: Map, planning: Planning, parent: int, step: float, weights: Weights | None) -> None:
    """A worker: tasks in, answers out, over its own pipe (no lock shared with any other process, so killing a
    worker anywhere can never block the parent), until it is sent None."""
    try:
        _init(grid_map, planning, parent, step, weights)
        while (task := conn.recv()) is not None:
            if _worker is None or _lattice is None:  # pragma: no cover (the initializer always runs first)
                raise RuntimeError("worker not initialised")
            conn.send(run_task(_worker, _lattice, _bound, task))
    except Exception as exc:  # said by the parent in one line, not as a worker's traceback
        conn.send(("error", f"{type(exc).__name__}: {exc}"))


CHUNK_SECONDS = 1.0
"""A chunk plans for about this long at most (every shape planned), so progress and a stop come within seconds."""
SAMPLE_PLANS = 16
KEY_CHUNK_SHAPES = 100_000
"""Shapes a keying task rasterises (about a quarter of a second)."""


def chunk_shapes(grid_map: Map, planning: Planning) -> int:
    """How many shapes a chunk holds on this map: CHUNK_SHAPES, fewer where one plan is slow (timed on a few
    random shapes, uncached), at least 64. Loads or compiles the kernels first, before any worker forks."""
    evaluator = planning.evaluator(grid_map, cache=False)
    sample = np.random.default_rng(0).integers(0, 181, size=(SAMPLE_PLANS, 3)).astype(np.float64)
    evaluator.evaluate_many(sample[:2])
    footprint_keys(evaluator, sample[:2])
    evaluator.evaluate_bounded(sample[:2], evaluator.prune_bound(Weights(1.0, 0.1)))
    t0 = time.perf_counter()
    evaluator.evaluate_many(sample)
    return shapes_per_chunk((time.perf_counter() - t0) / SAMPLE_PLANS)


def shapes_per_chunk(per_plan_s: float) -> int:
    """The shapes a chunk holds when one plan takes `per_plan_s`: about CHUNK_SECONDS of planning, 64 to
    CHUNK_SHAPES."""
    return int(max(64, min(CHUNK_SHAPES, CHUNK_SECONDS / max(per_plan_s, 1e-9))))


def chunk_bounds(n_shapes: int, n_workers: int, most: int = CHUNK_SHAPES) -> list[tuple[int, int]]:
    """Index ranges [lo, hi) covering `n_shapes`: enough per worker for a smooth progress display, at most about
    `most` shapes each, and none under min(1,000, `most`) shapes (a chunk's overhead)."""
    least = min(1000, most)
    fewest = -(-n_shapes // most)  # no chunk over `most`
    n_chunks = max(1, fewest, min(n_shapes // least, max(n_workers * CHUNKS_PER_WORKER, fewest)))
    edges = np.linspace(0, n_shapes, n_chunks + 1).astype(np.int64)
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def footprint_classes(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first row of each distinct key, each row's class) for an (N, 2) array of keys: sorted on the first word
    (three times faster than on both), on both where two keys share a first word."""
    _, first, inverse = np.unique(keys[:, 0], return_index=True, return_inverse=True)
    if not np.array_equal(keys[first[inverse.ravel()], 1], keys[:, 1]):
        _, first, inverse = np.unique(keys.view(np.dtype((np.void, 16))).ravel(), return_index=True,
                                      return_inverse=True)  # fmt: skip
    return first, inverse.ravel()


class _Workers:
    """Worker processes, each with its own pipe, that run tasks (`lattice_tasks.run_task`); `close` ends them all."""

    def __init__(self, n: int, grid_map: Map, planning: Planning, step: float, weights: Weights | None) -> None:
        context = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context()
        self.procs: list[tuple[Any, Any]] = []
        args = (grid_map, planning, os.getpid(), step, weights)  # forked workers inherit the Map, spawned ones copy it
        for _ in range(n):
            here, there = context.Pipe()
            proc = context.Process(target=_serve, args=(there, *args), daemon=True)
            proc.start()
            there.close()
            self.procs.append((proc, here))

    def run(self, tasks: Iterator[tuple[Any, ...]], stop: threading.Event) -> Iterator[tuple[Any, ...]]:
        """Every task's answer as it comes: a few tasks ahead per worker, not all (a task is drawn from `tasks`
        only when a worker is about to need it, so it sees every answer handled before)."""
        alive = {conn: proc for proc, conn in self.procs}
        busy = dict.fromkeys(alive, 0)

        def feed(conn: Any) -> None:
            task = next(tasks, None)
            if task is not None:
                conn.send(task)
                busy[conn] += 1

        for conn, _ in itertools.product(list(alive), range(IN_FLIGHT_PER_WORKER)):
            feed(conn)
        while any(busy.values()):
            if stop.is_set():
                raise KeyboardInterrupt
            ready: list[Any] = list(mp_connection.wait([c for c, n in busy.items() if n], timeout=0.1))
            for conn in ready:
                try:
                    answer: tuple[Any, ...] = conn.recv()
                except (EOFError, OSError):  # its end of the pipe closed or reset: the worker is gone
                    if stop.is_set():
                        raise KeyboardInterrupt from None
                    alive[conn].join(timeout=1.0)
                    raise SmorphiError(f"a search worker died (exit code {alive[conn].exitcode})") from None
                if answer[0] == "error":
                    raise SmorphiError(f"a search worker failed: {answer[1]}")
                busy[conn] -= 1
                yield answer
                feed(conn)

    def close(self, finished: bool) -> None:
        """Every worker gone: asked to end after a finished run, killed at once otherwise (it shares no lock)."""
        for proc, conn in self.procs:
            if finished:
                conn.send(None)
            else:
                proc.kill()
        for proc, conn in self.procs:
            proc.join(timeout=5.0)
            if proc.is_alive():
                proc.kill()
                proc.join()
            conn.close()


WARM_STEP_DEG = 10.0
"""Branch and bound plans the footprints of this coarser lattice first, so a good R1 to beat is known early."""


def _plan_order(thetas: np.ndarray, rows: np.ndarray, inverse: np.ndarray, n_reps: int, warm: bool) -> np.ndarray:
    """The order distinct footprints are planned in: lattice order, and for branch and bound the footprints of
    the WARM_STEP_DEG lattice first."""
    if not warm:
        return np.arange(n_reps)
    coarse = np.all(np.isclose(np.mod(thetas[rows], WARM_STEP_DEG), 0.0), axis=1)
    first = np.unique(inverse[coarse])
    rest = np.setdiff1d(np.arange(n_reps), first, assume_unique=True)
    return np.concatenate([first, rest])


class _Settled:
    """What is known of each distinct footprint as plans come back: metrics, or pruned; and the best R1 so far."""

    def __init__(self, n_reps: int, infeasible: int) -> None:
        self.p_c = np.zeros(n_reps)
        self.p_len = np.zeros(n_reps, dtype=np.int32)
        self.feasible = np.zeros(n_reps, dtype=bool)
        self.pruned = np.zeros(n_reps, dtype=bool)
        self.threshold = -math.inf
        self.settled = infeasible
        """Shapes whose result is known (infeasible shapes from the start)."""

    def record(self, ids: np.ndarray, p_c: np.ndarray, p_len: np.ndarray, ok: np.ndarray, pruned: np.ndarray,
               best: float, sizes: np.ndarray) -> None:  # fmt: skip
        self.p_c[ids], self.p_len[ids], self.feasible[ids], self.pruned[ids] = p_c, p_len, ok, pruned
        self.threshold = max(self.threshold, best)
        self.settled += int(sizes[ids].sum())


@contextmanager
def _local_pool(
    grid_map: Map, planning: Planning, step: float, weights: Weights | None, workers: int | None, thetas: np.ndarray
) -> Iterator[tuple[_Workers, int]]:
    """`workers` processes (default: every core this process may use) forked with the lattice, all gone when the
    block is left."""
    global _lattice
    n = max(1, workers or usable_cpus())
    _lattice = thetas  # the forked workers read their tasks' shapes from here
    pool = _Workers(n, grid_map, planning, step, weights)
    finished = False
    try:
        yield pool, n
        finished = True
    finally:  # Ctrl-C, SIGTERM, an error or the end: every worker is gone before this returns
        pool.close(finished)
        _lattice = None


@contextmanager
def _ray_pool(
    grid_map: Map, planning: Planning, step: float, weights: Weights | None, workers: int | None, address: str
) -> Iterator[tuple[Any, int]]:
    """`workers` planner actors (default: one per CPU) on the Ray cluster at `address` (`search/on_ray.py`)."""
    from smorphi_rl.search.on_ray import RayTasks, ray_planners

    with ray_planners(grid_map, planning, address, workers, step, weights) as planners:
        yield RayTasks(planners), len(planners.actors)


def run_exhaustive(
    map_source: str | Path | Map,
    step_deg: float = 1.0,
    planning: Planning = PAPER_PLANNING,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    address: str | None = None,
    best_for: Weights | None = None,
) -> SearchResult:
    """Evaluate every triple at `step_deg` on the map, planned as `planning` says, on `workers` processes
    (default: every core this process may use), or, given a Ray cluster's `address`, on `workers` actors there
    (default: one per CPU of the cluster), with the same results.

    Each distinct footprint is planned once (a first pass keys every shape by its footprint). Given `best_for`
    (R1's weights on the map), only the best R1 is sought, by branch and bound (docs/exact-search.md): a footprint
    whose bound cannot reach the best R1 found is not planned, and the result holds only the shapes whose
    footprint was planned (every shape of the best R1 among them). `progress(done, total)` counts shapes keyed,
    then (from 0 again) shapes settled."""
    step = check_step(step_deg)
    grid_map = as_map(map_source)
    thetas = lattice_thetas(step)
    per_chunk = chunk_shapes(grid_map, planning)  # also compiles the kernels, before any worker forks
    with ExitStack() as stack:
        if address is None:  # stops held before the workers fork: a Ctrl-C raised in the parent's at-fork hooks
            stop = stack.enter_context(stop_requests())  # (logging's) was printed as "ignored" and lost
            pool, n_workers = stack.enter_context(_local_pool(grid_map, planning, step, best_for, workers,
                                                              thetas))  # fmt: skip
        else:  # after Ray's start, which sets handlers of its own
            pool, n_workers = stack.enter_context(_ray_pool(grid_map, planning, step, best_for, workers, address))
            stop = stack.enter_context(stop_requests())
        t0 = time.perf_counter()  # start-up (workers, their kernels) is not timed
        rows, inverse, reps, state = _two_passes(pool, thetas, n_workers, per_chunk, best_for is not None, stop,
                                                 progress)  # fmt: skip
        wall = time.perf_counter() - t0
    n = len(thetas)
    params: dict[str, Any] = {"step_deg": step, "workers": n_workers, "distinct_footprints": len(reps),
                              "planner": planning.planner.value}  # fmt: skip
    if address is not None:
        params["address"] = address
    if best_for is None:
        p_c = np.zeros(n)
        p_len = np.zeros(n, dtype=np.int32)
        p_c[rows], p_len[rows] = state.p_c[inverse], state.p_len[inverse]
        ok = np.zeros(n, dtype=bool)
        ok[rows] = state.feasible[inverse]
        return SearchResult("exhaustive", grid_map.name, thetas, p_c, p_len, ok, n, wall, params, grid_map.digest)
    rep_of_row = np.full(n, -1, dtype=np.int64)
    rep_of_row[rows] = inverse
    kept = np.flatnonzero((rep_of_row >= 0) & ~state.pruned[np.maximum(rep_of_row, 0)])
    idx = rep_of_row[kept]
    params |= {"planned_footprints": int(np.count_nonzero(~state.pruned)), "pruned_footprints":
               int(np.count_nonzero(state.pruned)), "weights": {"w1": best_for.w1, "w2": best_for.w2}}  # fmt: skip
    return SearchResult("optimum", grid_map.name, thetas[kept], state.p_c[idx], state.p_len[idx],
                        state.feasible[idx], len(kept), wall, params, grid_map.digest)  # fmt: skip


def _two_passes(
    pool: Any,
    thetas: np.ndarray,
    n_workers: int,
    per_chunk: int,
    bounded: bool,
    stop: threading.Event,
    progress: Callable[[int, int], None] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, _Settled]:
    """Key every shape, then plan one shape of each distinct footprint (pruned where `bounded`), on `pool` (its
    `run(tasks, stop)` yields each task's answer). Returns (the feasible rows, each one's footprint class, one
    row of each class, what is known of each class)."""
    n = len(thetas)
    keys = np.zeros((n, 2), dtype=np.uint64)
    keyed = 0
    for _, lo, hi, chunk in pool.run((("keys", lo, hi) for lo, hi in chunk_bounds(n, n_workers, KEY_CHUNK_SHAPES)),
                                     stop):  # fmt: skip
        keys[lo:hi] = chunk
        keyed += hi - lo
        if progress is not None:
            progress(keyed, n)
    rows = np.flatnonzero(keys.any(axis=1))  # the feasible shapes
    first, inverse = footprint_classes(keys[rows])
    reps = rows[first]  # one shape per distinct footprint
    sizes = np.bincount(inverse, minlength=len(reps))
    parts = np.array_split(_plan_order(thetas, rows, inverse, len(reps), bounded), max(1, -(-len(reps) // per_chunk)))
    state = _Settled(len(reps), n - len(rows))
    if progress is not None:  # the settling pass starts below its end, so the bar shows it under its own label
        progress(state.settled, n)
    plan_tasks = (("plan", i, reps[part].astype(np.int32), state.threshold) for i, part in enumerate(parts))
    try:
        for _, i, c_pc, c_len, c_ok, c_pruned, c_best in pool.run(plan_tasks, stop):
            state.record(parts[i], c_pc, c_len, c_ok, c_pruned, c_best, sizes)
            if progress is not None:
                progress(state.settled, n)
        if stop.is_set():  # a stop as the last answers came in: the loop ended without seeing it, which then was lost
            raise KeyboardInterrupt
    except KeyboardInterrupt as exc:  # what the footprints planned so far say, for the line the stop ends in
        if isinstance(exc, Interrupted):
            raise
        ok = state.feasible & ~state.pruned
        raise SearchStopped(state.settled, n, thetas[reps[ok]], state.p_c[ok], state.p_len[ok]) from None
    return rows, inverse, reps, state


class SearchStopped(KeyboardInterrupt):
    """A stop request as the search planned its footprints: the shapes settled so far, of which `search` says the
    best (never written: the run's files are of whole searches only). A plain stop to every other caller (`train`'s
    and `design --exact`'s optimum), whose own lines say what they kept."""

    def __init__(self, settled: int, total: int, thetas: np.ndarray, p_c: np.ndarray, p_len: np.ndarray) -> None:
        super().__init__(f"stopped with {settled:,} of {total:,} shapes settled")
        self.settled, self.total, self.thetas, self.p_c, self.p_len = settled, total, thetas, p_c, p_len

    def best_so_far(self, weights: Weights) -> str:
        """One line: how far the search came and the best shape of those settled, under `weights`."""
        share = f"stopped with {100 * self.settled / self.total:.0f} % of the shapes settled"
        if not len(self.thetas):
            return f"{share}, none planned yet; nothing was written"
        r1 = weights.r1(self.p_c, self.p_len)
        i = int(np.argmax(r1))
        return (
            f"{share}; the best of them, not the optimum: {angles_text(self.thetas[i])} P_c {self.p_c[i]:.2f} %, "
            f"P_len {int(self.p_len[i])}, R1 {float(r1[i]):.2f}; nothing was written"
        )

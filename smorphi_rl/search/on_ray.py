"""The searches on a Ray cluster (`search exhaustive|random|nsga2 --address`): one actor per CPU holds the map and
its planner and plans what it is sent, so the results are the local ones, bit for bit.

The map travels as an object (the cluster's nodes need not share a file system); for the exhaustive search each
actor builds the lattice from its step and is sent index ranges, for the others it is sent the shapes."""

from __future__ import annotations

import dataclasses
import hashlib
import threading
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from smorphi_rl.maps import Map
from smorphi_rl.planning import BatchResult, Planning, lattice_thetas

IN_FLIGHT_PER_ACTOR = 2
"""Chunks sent to an actor at a time (one planning, one ready), as the local pool does."""
ACTOR_CACHE_FOOTPRINTS = 100_000
"""Footprints an actor keeps between chunks (about 70 MB at 0.05 m): memory stays flat however many distinct
footprints a large map has; a chunk's repeats are still planned once (`Evaluator.evaluate_many` groups them)."""


class ShapePlanner:
    """One Ray actor: a planner on the map, and (given a step) the lattice whose index ranges it plans."""

    def __init__(self, grid_map: Map, planning: Planning, step: float | None) -> None:
        self.evaluator = planning.evaluator(grid_map, cache_limit=ACTOR_CACHE_FOOTPRINTS)
        self.lattice = lattice_thetas(step) if step is not None else None

    def chunk(self, lo: int, hi: int) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray, set[bytes]]:
        """Lattice rows [lo, hi): P_c, P_len, feasible, and digests of the footprints newly planned for them."""
        if self.lattice is None:
            raise RuntimeError("this planner was started without a lattice step")
        batch = self.evaluator.evaluate_many(self.lattice[lo:hi])
        digests = {hashlib.blake2b(key, digest_size=8).digest() for key in self.evaluator.drain_planned()}
        return lo, hi, batch.P_c, batch.P_len.astype(np.int32), batch.feasible, digests

    def ready(self) -> bool:
        """True once the actor holds its planner (its kernels loaded): start-up is over."""
        return True

    def plan(self, thetas: np.ndarray) -> BatchResult:
        """`Evaluator.evaluate_many` of these shapes."""
        return self.evaluator.evaluate_many(thetas)


@contextmanager
def ray_planners(
    grid_map: Map, planning: Planning, address: str, workers: int | None, step: float | None = None
) -> Iterator[list[Any]]:
    """`workers` planner actors (default one per CPU of the cluster) on the Ray cluster at `address`, for the
    length of the block; the cluster is checked before anything starts, and the actors killed at the end."""
    from smorphi_rl import cluster
    from smorphi_rl.quiet import quiet

    cluster.check_reachable(address)
    quiet()
    with cluster.ray_session(address):
        import ray

        n = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        actor_class: Any = ray.remote(num_cpus=1)(ShapePlanner)
        map_ref = ray.put(grid_map)
        actors = [actor_class.remote(map_ref, planning, step) for _ in range(n)]
        try:
            ray.get([a.ready.remote() for a in actors])  # start-up (map, kernels, lattice) before any work is timed
            yield actors
        finally:
            for actor in actors:
                ray.kill(actor)


def plan_chunks(
    actors: list[Any],
    n_shapes: int,
    chunks: list[tuple[int, int]],
    stop: threading.Event,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, set[bytes]]:
    """Every lattice chunk planned by the actors, a few in flight each: (P_c, P_len, feasible, footprint digests).
    A set `stop` ends it at the next check (every 0.1 s) with KeyboardInterrupt."""
    import ray

    p_c = np.zeros(n_shapes)
    p_len = np.zeros(n_shapes, dtype=np.int32)
    feasible = np.zeros(n_shapes, dtype=bool)
    digests: set[bytes] = set()
    idle = deque(a for a in actors for _ in range(IN_FLIGHT_PER_ACTOR))
    queued = deque(chunks)
    pending: dict[Any, Any] = {}
    done = 0
    while queued or pending:
        while idle and queued:
            actor = idle.popleft()
            pending[actor.chunk.remote(*queued.popleft())] = actor
        ready, rest = ray.wait(list(pending), num_returns=1, timeout=0.1)
        if ready and rest:  # and every other chunk already done, without waiting
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        if stop.is_set():
            raise KeyboardInterrupt
        for ref in ready:
            idle.append(pending.pop(ref))
            lo, hi, c_pc, c_len, c_ok, c_digests = ray.get(ref)
            p_c[lo:hi], p_len[lo:hi], feasible[lo:hi] = c_pc, c_len, c_ok
            digests |= c_digests
            done += hi - lo
            if progress is not None:
                progress(done, n_shapes)
    return p_c, p_len, feasible, digests


class RayEvaluator:
    """`Evaluator.evaluate_many` on the actors: the rows split evenly across them, the results joined in order."""

    def __init__(self, actors: list[Any]) -> None:
        self.actors = actors

    def evaluate_many(self, thetas: np.ndarray) -> BatchResult:
        import ray

        parts = [p for p in np.array_split(np.asarray(thetas, dtype=np.float64), len(self.actors)) if len(p)]
        results: list[BatchResult] = ray.get([a.plan.remote(p) for a, p in zip(self.actors, parts, strict=False)])
        if len(results) == 1:
            return results[0]
        joined = {f.name: np.concatenate([getattr(r, f.name) for r in results])
                  for f in dataclasses.fields(BatchResult) if f.name != "planner"}  # fmt: skip
        return BatchResult(**joined, planner=results[0].planner)


@contextmanager
def evaluator_for(grid_map: Map, planning: Planning, address: str | None) -> Iterator[Any]:
    """What scores a batch of shapes: an `Evaluator` here, or one spread over the actors of the Ray cluster at
    `address` (one per CPU), for the length of the block."""
    if address is None:
        yield planning.evaluator(grid_map)
        return
    with ray_planners(grid_map, planning, address, None) as actors:
        yield RayEvaluator(actors)

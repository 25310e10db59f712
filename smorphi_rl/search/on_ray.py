"""The searches on a Ray cluster (`search exhaustive|random|nsga2 --address`): one actor per CPU holds the map and
its planner and plans what it is sent, so the results are the local ones, bit for bit.

The map travels as an object (the cluster's nodes need not share a file system); for the lattice searches each
actor builds the lattice from its step and is sent the tasks the local workers run (`lattice_tasks.run_task`: index
ranges to key, rows to plan), for the others it is sent the shapes."""

from __future__ import annotations

import dataclasses
import threading
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from smorphi_rl.maps import Map
from smorphi_rl.planning import BatchResult, Planning, lattice_thetas
from smorphi_rl.score import Weights
from smorphi_rl.search.lattice_tasks import run_task

IN_FLIGHT_PER_ACTOR = 2
"""Chunks sent to an actor at a time (one planning, one ready), as the local pool does."""
ACTOR_CACHE_FOOTPRINTS = 100_000
"""Footprints an actor keeps between chunks (about 70 MB at 0.05 m): memory stays flat however many distinct
footprints a large map has; a chunk's repeats are still planned once (`Evaluator.evaluate_many` groups them)."""


class ShapePlanner:
    """One Ray actor: a planner on the map, and (given a step) the lattice whose tasks it runs, pruned for
    `weights` (None: every footprint planned)."""

    def __init__(self, grid_map: Map, planning: Planning, step: float | None, weights: Weights | None = None) -> None:
        self.evaluator = planning.evaluator(grid_map, cache_limit=ACTOR_CACHE_FOOTPRINTS)
        self.lattice = lattice_thetas(step) if step is not None else None
        self.bound = self.evaluator.prune_bound(weights)

    def task(self, task: tuple[Any, ...]) -> tuple[Any, ...]:
        """One lattice task (`lattice_tasks.run_task`)."""
        if self.lattice is None:
            raise RuntimeError("this planner was started without a lattice step")
        return run_task(self.evaluator, self.lattice, self.bound, task)

    def ready(self) -> bool:
        """True once the actor holds its planner (its kernels loaded): start-up is over."""
        return True

    def plan(self, thetas: np.ndarray) -> BatchResult:
        """`Evaluator.evaluate_many` of these shapes."""
        return self.evaluator.evaluate_many(thetas)


@contextmanager
def ray_planners(
    grid_map: Map,
    planning: Planning,
    address: str,
    workers: int | None,
    step: float | None = None,
    weights: Weights | None = None,
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
        actors = [actor_class.remote(map_ref, planning, step, weights) for _ in range(n)]
        try:
            ray.get([a.ready.remote() for a in actors])  # start-up (map, kernels, lattice) before any work is timed
            yield actors
        finally:
            for actor in actors:
                ray.kill(actor)


@contextmanager
def cluster_lost() -> Iterator[None]:
    """A Ray call that fails because the cluster (or an actor's node) went away mid-search, said in one line: Ray's
    own error is an actor's death, or a broken pipe to its core ("error: Broken pipe"). An error raised by the work
    inside an actor (RayTaskError) is the work's, and passes."""
    import ray

    from smorphi_rl.cluster import ClusterError, ray_error_line

    lost = (ray.exceptions.RayActorError, ray.exceptions.RaySystemError, ray.exceptions.ObjectLostError,
            ray.exceptions.NodeDiedError, ConnectionError)  # fmt: skip  # not RayTaskError: an error of the work
    try:
        yield
    except lost as exc:
        raise ClusterError(f"the Ray cluster stopped answering mid-search ({type(exc).__name__}: "
                           f"{ray_error_line(exc)[:160]}); nothing of the search is kept: run it again once the "
                           "cluster is up") from None  # fmt: skip


class RayTasks:
    """Lattice tasks run by the actors, a few in flight each, as the local workers run them."""

    def __init__(self, actors: list[Any]) -> None:
        self.actors = actors

    def run(self, tasks: Iterator[tuple[Any, ...]], stop: threading.Event) -> Iterator[tuple[Any, ...]]:
        """Every task's answer as it comes (a task is drawn only when an actor is about to need it, so it sees every
        answer handled before). A set `stop` ends it at the next check (every 0.1 s) with KeyboardInterrupt."""
        import ray

        idle = deque(a for a in self.actors for _ in range(IN_FLIGHT_PER_ACTOR))
        pending: dict[Any, Any] = {}

        def feed() -> None:
            while idle and (task := next(tasks, None)) is not None:
                actor = idle.popleft()
                pending[actor.task.remote(task)] = actor

        feed()
        while pending:
            with cluster_lost():
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.1)
            if stop.is_set():
                raise KeyboardInterrupt
            for ref in ready:
                idle.append(pending.pop(ref))
                with cluster_lost():
                    answer = ray.get(ref)
                yield answer
                with cluster_lost():
                    feed()


class RayEvaluator:
    """`Evaluator.evaluate_many` on the actors: the rows split evenly across them, the results joined in order."""

    def __init__(self, actors: list[Any]) -> None:
        self.actors = actors

    def evaluate_many(self, thetas: np.ndarray) -> BatchResult:
        import ray

        parts = [p for p in np.array_split(np.asarray(thetas, dtype=np.float64), len(self.actors)) if len(p)]
        with cluster_lost():
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

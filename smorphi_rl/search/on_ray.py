"""The searches on a Ray cluster (`search exhaustive|random|nsga2 --address`): one actor per CPU holds the map and
its planner and plans what it is sent, so the results are the local ones, bit for bit.

The map travels as an object (the cluster's nodes need not share a file system; they need smorphi-rl, the same
version, which start-up checks); for the lattice searches each actor makes the lattice rows it is sent from their
indices (`planning.Lattice`) and runs the tasks the local workers run (`lattice_tasks.run_task`: index ranges to key,
rows to plan), for the others it is sent the shapes. An actor lost (its node gone, Ray's memory monitor) is dropped
and its work sent to another, each task being a pure function of its input (`Planners`): a preempted node no longer
ends an hour's search."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import threading
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from typing import Any

import numpy as np

from smorphi_rl.cluster import ClusterError, ray_error_line
from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import Map
from smorphi_rl.planning import BatchResult, Lattice, Planning
from smorphi_rl.score import Weights
from smorphi_rl.search.lattice_tasks import run_task

IN_FLIGHT_PER_ACTOR = 2
"""Chunks sent to an actor at a time (one planning, one ready), as the local pool does."""
ACTOR_CACHE_FOOTPRINTS = 100_000
"""Footprints an actor keeps between chunks (about 70 MB at 0.05 m): memory stays flat however many distinct
footprints a large map has; a chunk's repeats are still planned once (`Evaluator.evaluate_many` groups them)."""
START_TIMEOUT_S = 600.0
"""How long the actors may take to start (placed, map received, kernels compiled: about 40 s on a node without
numba's cache) before the search says which did not."""
PLANNER_MODULES = ("smorphi_rl._kernels", "smorphi_rl.coverage", "smorphi_rl.geometry", "smorphi_rl.maps",
                   "smorphi_rl.planning", "smorphi_rl.score", "smorphi_rl.search.lattice_tasks")  # fmt: skip
"""The modules whose code decides a plan: the driver and every actor must hold the same (`planner_digest`)."""


def planner_digest() -> str:
    """A digest of PLANNER_MODULES' source as installed here: equal on two machines when they plan alike."""
    digest = hashlib.sha256()
    for name in PLANNER_MODULES:
        spec = importlib.util.find_spec(name)
        loader: Any = spec.loader if spec is not None else None
        try:  # the source, as a wheel, an editable install or a zip holds it (None where only bytecode is)
            source = loader.get_source(name) if loader is not None else None
        except (ImportError, OSError):
            source = None
        digest.update(name.encode() + b"\0" + (source or "").encode() + b"\0")
    return digest.hexdigest()[:16]


class ShapePlanner:
    """One Ray actor: a planner on the map, and (given a step) the lattice whose tasks it runs, pruned for
    `weights` (None: every footprint planned)."""

    def __init__(self, grid_map: Map, planning: Planning, step: float | None, weights: Weights | None = None) -> None:
        self.evaluator = planning.evaluator(grid_map, cache_limit=ACTOR_CACHE_FOOTPRINTS)
        self.lattice = Lattice(step) if step is not None else None
        self.bound = self.evaluator.prune_bound(weights)

    def task(self, task: tuple[Any, ...]) -> tuple[Any, ...]:
        """One lattice task (`lattice_tasks.run_task`)."""
        if self.lattice is None:
            raise RuntimeError("this planner was started without a lattice step")
        return run_task(self.evaluator, self.lattice, self.bound, task)

    def ready(self) -> str:
        """`planner_digest()` once the actor holds its planner and has run one shape through the kernels its work
        runs (compiled or loaded from the cache): start-up is over before the search is timed."""
        if self.lattice is not None:
            run_task(self.evaluator, self.lattice, self.bound.copy(), ("keys", 0, 1))
            run_task(self.evaluator, self.lattice, self.bound.copy(), ("plan", -1, np.zeros(1, np.int64), -np.inf))
        else:
            self.evaluator.evaluate_many(np.full((1, 3), 90.0))
        return planner_digest()

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
) -> Iterator[Planners]:
    """`workers` planner actors (default one per CPU free on the cluster) on the Ray cluster at `address`, for the
    length of the block; the cluster is checked before anything starts, and the actors killed at the end."""
    from smorphi_rl import cluster
    from smorphi_rl.quiet import quiet

    cluster.check_reachable(address)
    quiet()
    with cluster.ray_session(address):
        import ray

        free, total = (int(r.get("CPU", 0)) for r in (ray.available_resources(), ray.cluster_resources()))
        n = workers or max(1, free)  # the CPUs free: an actor asking for a busy one would wait unseen
        actor_class: Any = ray.remote(num_cpus=1)(ShapePlanner)
        map_ref = ray.put(grid_map)
        planners = Planners(lambda: actor_class.remote(map_ref, planning, step, weights), n)
        try:
            _start(planners.actors, free, total)  # start-up (map, kernels) before any work is timed
            yield planners
        finally:
            for actor in list(planners.actors):
                with suppress(Exception):  # a cluster gone: the error that ended the search is the one said
                    ray.kill(actor)


class Planners:
    """A search's planner actors (`new()` starts one). One lost (its node gone, Ray's memory monitor) is dropped and
    its work sent to another (each task is a pure function of its input): a search ends only when none is left, as
    the CPUs of the others are theirs and a new actor would find none free."""

    def __init__(self, new: Callable[[], Any], n: int) -> None:
        self.actors = [new() for _ in range(n)]
        self._turn = 0

    def drop(self, lost: Any, why: ClusterError) -> Any:
        """Drop `lost` (once; killed, should it be unreachable rather than gone) and give the actor its work goes to
        next, in turn; `why` raised when none is left."""
        import ray

        if lost in self.actors:
            self.actors.remove(lost)
            with suppress(Exception):
                ray.kill(lost)
        if not self.actors:
            raise why
        self._turn += 1
        return self.actors[self._turn % len(self.actors)]


def _start(actors: list[Any], free: int, total: int) -> None:
    """Wait for every actor's start-up; one line where one fails (smorphi-rl missing on a node), where some do not
    start within START_TIMEOUT_S (the cluster's CPUs taken), or where a node plans with other code than this one."""
    import ray

    try:
        done, waiting = ray.wait([a.ready.remote() for a in actors], num_returns=len(actors), timeout=START_TIMEOUT_S)
        digests = ray.get(done)
    except ray.exceptions.RayError as exc:
        raise ClusterError(f"the planners could not start on the Ray cluster ({ray_error_line(exc)[:200]}): every "
                           "node needs smorphi-rl, the same version as here") from None  # fmt: skip
    if waiting:
        raise ClusterError(f"{len(waiting)} of {len(actors)} planners did not start within {START_TIMEOUT_S:.0f} s "
                           f"(the cluster had {free} of its {total} CPUs free): other work holds its CPUs")  # fmt: skip
    if any(d != planner_digest() for d in digests):
        raise ClusterError("the Ray cluster's smorphi-rl plans with other code than this one's (its planner's source "
                           "differs): install the same version on every node")  # fmt: skip


class ActorLost(ClusterError):
    """An actor died mid-search (its node gone, Ray's memory monitor): its work can be sent to another."""


@contextmanager
def cluster_lost() -> Iterator[None]:
    """A Ray call that fails because the cluster (or an actor's node) went away mid-search, said in one line: Ray's
    own error is an actor's death, or a broken pipe to its core ("error: Broken pipe"). An error raised by the work
    inside an actor (RayTaskError) is the work's: ours as it was raised, another in one line, as a local worker's."""
    import ray

    lost = (ray.exceptions.RaySystemError, ray.exceptions.ObjectLostError, ray.exceptions.NodeDiedError,
            ConnectionError)  # fmt: skip  # not RayTaskError: an error of the work
    try:
        yield
    except (ray.exceptions.RayActorError, ray.exceptions.OutOfMemoryError) as exc:  # Ray's memory monitor's kill
        raise ActorLost(_lost_line(exc)) from None
    except ray.exceptions.RayTaskError as exc:
        cause = exc.cause if isinstance(getattr(exc, "cause", None), BaseException) else exc
        if isinstance(cause, SmorphiError):
            raise cause from None
        raise SmorphiError(f"a search worker on the cluster failed: {type(cause).__name__}: "
                           f"{ray_error_line(cause)[:200]}") from None  # fmt: skip
    except lost as exc:
        raise ClusterError(_lost_line(exc)) from None


def _lost_line(exc: BaseException) -> str:
    """What a search says of the cluster (or an actor) lost mid-search."""
    return (
        f"the Ray cluster stopped answering mid-search ({type(exc).__name__}: {ray_error_line(exc)[:160]}); "
        "nothing of the search is kept: run it again once the cluster is up"
    )


class RayTasks:
    """Lattice tasks run by the actors, a few in flight each, as the local workers run them; a task of an actor
    lost is sent to another."""

    def __init__(self, planners: Planners) -> None:
        self.planners = planners

    def run(self, tasks: Iterator[tuple[Any, ...]], stop: threading.Event) -> Iterator[tuple[Any, ...]]:
        """Every task's answer as it comes (a task is drawn only when an actor is about to need it, so it sees every
        answer handled before). A set `stop` ends it at the next check (every 0.1 s) with KeyboardInterrupt."""
        import ray

        idle = deque(a for a in self.planners.actors for _ in range(IN_FLIGHT_PER_ACTOR))
        pending: dict[Any, tuple[Any, tuple[Any, ...]]] = {}

        def feed() -> None:
            while idle:
                actor = idle.popleft()
                if actor not in self.planners.actors:  # dropped since: its places go with it
                    continue
                task = next(tasks, None)
                if task is None:
                    idle.appendleft(actor)
                    return
                pending[actor.task.remote(task)] = (actor, task)

        feed()
        while pending:
            with cluster_lost():
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.1)
            if stop.is_set():
                raise KeyboardInterrupt
            for ref in ready:
                actor, task = pending.pop(ref)
                try:
                    with cluster_lost():
                        answer = ray.get(ref)
                except ActorLost as lost:  # its task to another, which holds one more in flight until it is done
                    other = self.planners.drop(actor, lost)
                    with cluster_lost():
                        pending[other.task.remote(task)] = (other, task)
                    continue
                idle.append(actor)  # (one dropped as unreachable, yet answering, is skipped by `feed`)
                yield answer
                with cluster_lost():
                    feed()


class RayEvaluator:
    """`Evaluator.evaluate_many` on the actors: the rows split evenly across them, the results joined in order; the
    part of an actor lost is planned by another."""

    def __init__(self, planners: Planners) -> None:
        self.planners = planners

    def evaluate_many(self, thetas: np.ndarray) -> BatchResult:
        import ray

        actors = self.planners.actors
        parts = [p for p in np.array_split(np.asarray(thetas, dtype=np.float64), len(actors)) if len(p)]
        sent = [(a, p, a.plan.remote(p)) for a, p in zip(actors, parts, strict=False)]
        results: list[BatchResult] = []
        for actor, part, ref in sent:
            while True:
                try:
                    with cluster_lost():
                        results.append(ray.get(ref))
                    break
                except ActorLost as lost:
                    actor = self.planners.drop(actor, lost)
                    with cluster_lost():
                        ref = actor.plan.remote(part)
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
    with ray_planners(grid_map, planning, address, None) as planners:
        yield RayEvaluator(planners)

"""NSGA-II over integer hinge angles with pymoo (the paper's Table 6, Figure 7): maximise P_c, minimise P_len.

The only module that imports pymoo. Seeded and deterministic; every evaluation is kept, so the
result is the whole search, not only its last population.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.core.callback import Callback
from pymoo.core.problem import Problem
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.pm import PM
from pymoo.operators.repair.rounding import RoundingRepair
from pymoo.operators.sampling.rnd import IntegerRandomSampling
from pymoo.optimize import minimize

from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import Map, as_map
from smorphi_rl.planning import PAPER_PLANNING, Evaluator, Planning
from smorphi_rl.search.on_ray import evaluator_for
from smorphi_rl.search.results import SearchResult


class _MorphologyProblem(Problem):
    """Three integer angles in [0, 180]; objectives (-P_c, P_len); infeasible shapes score worst."""

    def __init__(self, evaluator: Evaluator | Any) -> None:
        super().__init__(n_var=3, n_obj=2, xl=0, xu=180, vtype=int)
        self.evaluator = evaluator
        self.seen: list[np.ndarray] = []

    def _evaluate(self, x: np.ndarray, out: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        thetas = np.rint(np.asarray(x, dtype=np.float64))
        batch = self.evaluator.evaluate_many(thetas)
        self.seen.append(np.column_stack([thetas, batch.P_c, batch.P_len, batch.feasible]))
        out["F"] = np.column_stack([-batch.P_c, np.where(batch.feasible, batch.P_len, np.inf)])


class _Generations(Callback):
    """pymoo's per-generation hook: tells `progress` how many generations are done."""

    def __init__(self, generations: int, progress: Callable[[int, int], None] | None) -> None:
        super().__init__()
        self.generations, self.progress = generations, progress

    def notify(self, algorithm: Any) -> None:
        if self.progress is not None:
            self.progress(min(int(algorithm.n_gen), self.generations), self.generations)


def run_nsga2(
    map_source: str | Path | Map,
    pop: int,
    generations: int,
    seed: int,
    planning: Planning = PAPER_PLANNING,
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SearchResult:
    """NSGA-II with `pop` individuals for `generations` generations; each generation scored here, or spread over
    the Ray cluster at `address` (the same search, shape for shape); `progress(done, total)` hears of each
    generation."""
    if pop < 2:
        raise SmorphiError(f"--pop must be >= 2, got {pop}")
    if generations < 1:
        raise SmorphiError(f"--generations must be >= 1, got {generations}")
    grid_map = as_map(map_source)
    algorithm = NSGA2(
        pop_size=pop,
        sampling=IntegerRandomSampling(),
        crossover=SBX(prob=0.9, eta=15, vtype=float, repair=RoundingRepair()),
        mutation=PM(eta=20, vtype=float, repair=RoundingRepair()),
        eliminate_duplicates=True,
    )
    with evaluator_for(grid_map, planning, address) as evaluator:
        problem = _MorphologyProblem(evaluator)
        t0 = time.perf_counter()
        minimize(problem, algorithm, ("n_gen", generations), seed=seed, verbose=False,
                 callback=_Generations(generations, progress))  # fmt: skip
        wall = time.perf_counter() - t0
    seen = np.vstack(problem.seen)
    params: dict[str, object] = {"pop": pop, "generations": generations, "seed": seed,
                                 "planner": planning.planner.value}  # fmt: skip
    if address is not None:
        params["address"] = address
    return SearchResult("nsga2", grid_map.name, seen[:, :3], seen[:, 3], seen[:, 4].astype(np.int64),
                        seen[:, 5] > 0, len(seen), wall, params, grid_map.digest)  # fmt: skip

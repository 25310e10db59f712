"""`search METHOD`: one run's configuration (the only home of every method's defaults, validated once) and
`run_search`, which runs it. The command line parses into a SearchConfig and formats what comes back."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from smorphi_rl.coverage import Planner
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import check_step, lattice_size
from smorphi_rl.planning import PAPER_PLANNING, Planning
from smorphi_rl.protocol import EVAL_STARTS
from smorphi_rl.search.results import MAX_EVALUATIONS, SearchResult

METHODS = {
    "random": "uniformly random integer shapes (paper Table 4)",
    "nsga2": "NSGA-II over integer angles (paper Table 6, Figure 7)",
    "exhaustive": "every triple on the lattice: the exact front and best R1",
    "optimum": "the exact best R1 on the lattice alone; under --planner fit, by branch and bound (fewer plans)",
    "hillclimb": "steepest ascent over the 26 one-step moves from the protocol's fixed starts",
    "anneal": "simulated annealing over the same moves from the same starts",
}
LOCAL_METHODS = ("hillclimb", "anneal")
LATTICE_METHODS = ("exhaustive", "optimum")
"""The methods that go over every triple of a lattice (`--step`)."""
METHOD_FIELDS = {
    "random": ("samples", "seed"),
    "nsga2": ("pop", "generations", "seed"),
    "exhaustive": ("step",),
    "optimum": ("step",),
    "hillclimb": ("seed", "budget", "starts"),
    "anneal": ("seed", "budget", "starts"),
}
"""The SearchConfig fields each method reads (its command-line options)."""
RAY_METHODS = ("exhaustive", "optimum", "random", "nsga2")
"""The methods that also run on a Ray cluster (`--address`): those that score many shapes at once."""


CUTS = {
    "exhaustive": "a coarser --step",
    "optimum": "a coarser --step",
    "random": "fewer --samples",
    "nsga2": "a smaller --pop or fewer --generations",
    "hillclimb": "a smaller --budget or fewer --starts",
    "anneal": "a smaller --budget or fewer --starts",
}
"""What cuts each method's work: named when a budget is refused and when a run will take over a minute."""


class SearchConfigError(SmorphiError):
    """A search option out of range, named as the command line spells it."""


@dataclass(frozen=True)
class SearchConfig:
    """One `search` run on one map."""

    method: str
    map_path: str
    planning: Planning = PAPER_PLANNING
    w1: float = EnvConfig.w1
    """R1's weights (the local methods and `optimum` rank by R1 while they search; the others keep every front
    point)."""
    w2: float = EnvConfig.w2
    path_term: str = EnvConfig.path_term
    seed: int = 0
    """random, nsga2, hillclimb, anneal: the seed of the method's generator."""
    samples: int = 1000
    """random: shapes to draw."""
    pop: int = 40
    """nsga2: population size."""
    generations: int = 50
    """nsga2: generations."""
    budget: int = 200
    """hillclimb, anneal: FBCPP evaluations per start."""
    starts: int = EVAL_STARTS
    """hillclimb, anneal: the protocol's fixed seeded starts."""
    step: float = 1.0
    """exhaustive, optimum: lattice step in degrees; must divide 180."""
    address: str | None = None
    """exhaustive, optimum, random, nsga2: a Ray cluster (HOST:PORT or auto) to plan on; None: the cores this
    process may use."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise SearchConfigError(f"unknown search method '{self.method}' (choose from {', '.join(METHODS)})")
        if self.method in LATTICE_METHODS:
            try:
                check_step(self.step)
            except SmorphiError as exc:
                raise SearchConfigError(str(exc)) from None
        elif self.method == "random" and self.samples < 1:
            raise SearchConfigError(f"--samples must be >= 1, got {self.samples}")
        elif self.method in LOCAL_METHODS and (self.budget < 1 or self.starts < 1):
            raise SearchConfigError(f"--budget and --starts must be >= 1, got {self.budget} and {self.starts}")
        elif self.method == "nsga2" and (self.pop < 2 or self.generations < 1):
            raise SearchConfigError(f"--pop must be >= 2 and --generations >= 1, got {self.pop} and {self.generations}")
        total = self.evaluations
        if total > MAX_EVALUATIONS:
            digits = int((total.bit_length() - 1) * math.log10(2))  # str() of a 5,000-digit count raises
            shown = f"{total:,}" if total < 10**15 else f"over 10^{digits}"  # a step of 1e-300
            raise SearchConfigError(f"{self.method} would score {shown} shapes; at most {MAX_EVALUATIONS:,} "
                                    f"({CUTS[self.method]})")  # fmt: skip

    @property
    def evaluations(self) -> int:
        """The shapes the run scores at most."""
        if self.method in LATTICE_METHODS:
            return lattice_size(self.step)
        if self.method == "random":
            return self.samples
        if self.method in LOCAL_METHODS:
            return self.budget * self.starts
        return self.pop * self.generations

    @property
    def run_name(self) -> str:
        """The default run folder: method, map, the planner where it is not the paper's (a run of each on one map
        takes no --name) and the step (exhaustive, optimum) or the seed."""
        from smorphi_rl.rundir import safe_name

        suffix = f"step{self.step:g}" if self.method in LATTICE_METHODS else f"seed{self.seed}"
        planner = "" if self.planning.planner is Planner.PAPER else f"-{self.planning.planner.value}"
        return safe_name(f"{self.method}-{Path(self.map_path).stem}{planner}-{suffix}")


def run_search(cfg: SearchConfig, progress: Callable[[int, int], None] | None = None) -> SearchResult:
    """Run the configured method on its map (`progress(done, total)`: shapes of the lattice methods, keyed and
    then, from 0 again, settled; starts of the local searches; generations of NSGA-II; random search is one
    batch)."""
    if cfg.method in LATTICE_METHODS:
        from smorphi_rl.search.exhaustive import run_exhaustive

        best_for = None
        if cfg.method == "optimum":
            from smorphi_rl.maps import load_map

            best_for = EnvConfig.from_dict({"w1": cfg.w1, "w2": cfg.w2, "path_term": cfg.path_term}).weights_on(
                load_map(cfg.map_path)
            )
        return run_exhaustive(cfg.map_path, cfg.step, cfg.planning, progress=progress, address=cfg.address,
                              best_for=best_for)  # fmt: skip
    if cfg.method == "random":
        from smorphi_rl.search.random import run_random

        return run_random(cfg.map_path, cfg.samples, cfg.seed, cfg.planning, cfg.address)
    if cfg.method in LOCAL_METHODS:
        from smorphi_rl.search.local import run_local_search

        env = {"w1": cfg.w1, "w2": cfg.w2, "path_term": cfg.path_term, "planner": cfg.planning.planner.value,
               "start_xy": cfg.planning.start_xy}  # fmt: skip
        return run_local_search(cfg.method, cfg.map_path, cfg.budget, cfg.seed, cfg.starts, env, progress)
    from smorphi_rl.search.nsga2 import run_nsga2

    return run_nsga2(cfg.map_path, cfg.pop, cfg.generations, cfg.seed, cfg.planning, cfg.address, progress)

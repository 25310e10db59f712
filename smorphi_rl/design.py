"""A trained policy as a designer: roll-outs on one floor within a budget of planner evaluations.

The policy walks from a fixed, seeded list of start shapes, one roll-out after another; every new shape it
reaches is scored by FBCPP, and the answer is the best shape scored. The first `greedy` roll-outs take the
most likely move of each hinge: such a roll-out is deterministic and its observation depends on the floor and
the shape alone, so it stops at its first revisit (from there it would repeat a walk already scored) or at
the env's `max_steps`. Then roll-outs sample each move from the policy's own distribution (seeded), which
explore around the regions the greedy walks lead to. The policy spends 60 % of the budget; the last 40 % goes
to compass search from the best shape it found (`search/local.py`: +-32 down to +-1 degree per
hinge), which climbs the peak the policy's walks came near, then restarts from the best shape scored far from
every earlier climb. The answer is the best shape scored within
`budget` distinct shapes. The same procedure runs with the torch module (training's evaluation, the
benchmarks) and with the NumPy copy of its policy net (`smorphi-rl design`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import lattice_size
from smorphi_rl.score import Scored

DESIGN_STARTS = 64
"""Start shapes of the design's roll-outs (used in turn, again from the first when they run out)."""
DESIGN_SEED = 7
"""Seeds the designer's starts and its sampled moves: another stream than the protocol's starts."""
DEFAULT_BUDGET = 200
"""Planner evaluations (distinct shapes) a design may use by default."""
PROGRESS_EVERY = 256
"""Shapes scored between two reports to a design's `progress`."""
PROGRESS_FROM = 2_000
"""Budgets from which `design` shows a progress bar (100,000 took 45 s in silence; 200 takes 0.3 s)."""
GREEDY_ROLLOUTS = 16
"""Greedy roll-outs before the sampled ones."""
REFINE_SHARE = 0.4
"""The share of the budget left to compass search from the policy's best shape. Chosen on 40 validation floors
(seeds 900,100-900,139, neither training's nor the held-out set's) at 200 evaluations, median gap against
NSGA-II's: 0.15: 0.192 %, 0.25: 0.145 %, 0.4: 0.107 %, 0.5: 0.127 % (NSGA-II 0.446 %; docs/decisions.md)."""
MAX_STEPS_PER_EVALUATION = 50
"""A design stops after this many env steps per budgeted evaluation even if budget is left (a policy that only
revisits shapes it has scored)."""

Logits = Callable[[Sequence[dict[str, np.ndarray]]], np.ndarray]
"""The policy's action logits (n, sum of the action sizes) for a batch of observations."""


@dataclass(frozen=True)
class Design:
    """What a design run found and what it cost."""

    best: Scored
    evaluations: int
    """Distinct shapes scored (the budget counts these)."""
    planner_calls: int
    """Distinct footprints planned: shapes with the same rasterised footprint share one plan."""
    rollouts: int
    wall_s: float
    refined: int = 0
    """Shapes the compass search scored after the policy's roll-outs."""
    walks: list[list[tuple[float, float, float]]] = field(default_factory=list)
    """Every roll-out's shapes, in order (for plots)."""
    budget: int = 0
    """The budget it ran with: the one asked for, or the lattice's size where that is smaller."""


def design_starts(n: int = DESIGN_STARTS, step_deg: float = 1.0) -> np.ndarray:
    """The designer's fixed start shapes (n x 3), seeded, on the `step_deg` lattice."""
    from smorphi_rl.protocol import eval_starts

    return eval_starts(n, step_deg, DESIGN_SEED)


def design_rng(seed: int = DESIGN_SEED) -> np.random.Generator:
    """The stream a design draws its sampled moves and compass restarts from: a child of the seed's sequence, so
    not the numbers `design_starts` drew the starts from (`default_rng(DESIGN_SEED)` was that very stream)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,)))


MAX_BUDGET = 100_000
"""A design's budget is at most this: the designer is for a few hundred evaluations; beyond this, the exhaustive
search (5.9 million shapes, seconds to minutes) answers exactly."""


def check_budget(budget: Any) -> int:
    """A budget is a whole number of planner evaluations, at least 1."""
    if isinstance(budget, bool) or not isinstance(budget, int | np.integer) or not 1 <= budget <= MAX_BUDGET:
        raise SmorphiError(f"--budget must be a whole number of planner evaluations in 1..{MAX_BUDGET:,}, got "
                           f"{budget!r} (`search exhaustive` evaluates every shape)")  # fmt: skip
    return int(budget)


def moves(logits: np.ndarray, nvec: Sequence[int], rng: np.random.Generator | None) -> np.ndarray:
    """One move per hinge from a row of logits: the most likely (rng None) or one drawn from the softmax."""
    out = np.empty(len(nvec), dtype=np.int64)
    lo = 0
    for h, n in enumerate(nvec):
        part = logits[lo : lo + n].astype(np.float64)
        lo += n
        if rng is None:
            out[h] = int(np.argmax(part))
        else:
            p = np.exp(part - part.max())
            out[h] = int(rng.choice(n, p=p / p.sum()))
    return out


def run_design(
    env: Any, logits: Logits, budget: int = DEFAULT_BUDGET, greedy: int = GREEDY_ROLLOUTS,
    starts: np.ndarray | None = None, seed: int = DESIGN_SEED, progress: Callable[[int, int], None] | None = None,
) -> Design:  # fmt: skip
    """Roll-outs of the policy on `env` (a MorphologyEnv of one map) until `budget` distinct shapes are scored
    (module docstring); the best shape scored is the design. `progress(done, budget)` hears of every
    PROGRESS_EVERY shapes scored."""
    budget = min(check_budget(budget), lattice_size(env.config.angle_step_deg))  # past it, roll-outs would spin
    policy_budget = max(1, budget - int(REFINE_SHARE * budget))
    starts = design_starts(step_deg=env.config.angle_step_deg) if starts is None else starts
    nvec = [int(n) for n in env.action_space.nvec]
    rng = design_rng(seed)
    t0 = time.perf_counter()
    calls0 = env.planner_calls
    scored: dict[tuple[float, float, float], Scored] = {}
    walks: list[list[tuple[float, float, float]]] = []
    steps, max_steps = 0, MAX_STEPS_PER_EVALUATION * budget
    reported = 0  # PROGRESS_EVERYs of shapes told to `progress`
    while len(scored) < policy_budget and steps < max_steps:
        sampled = len(walks) >= greedy
        start = starts[len(walks) % len(starts)]
        obs, info = env.reset(seed=0, options={"theta": tuple(float(t) for t in start)})
        theta = tuple(info["theta"])
        walk = [theta]
        walks.append(walk)
        if theta in scored and not sampled:  # a start an earlier walk passed through: its greedy walk is known
            continue
        scored.setdefault(theta, env.current)
        for _ in range(env.config.max_steps):
            if len(scored) >= policy_budget:
                break
            obs, _, terminated, truncated, info = env.step(moves(logits([obs])[0], nvec, rng if sampled else None))
            steps += 1
            theta = tuple(info["theta"])
            walk.append(theta)
            if theta in scored and not sampled:  # a greedy revisit: from here the walk repeats one already scored
                break
            if theta not in scored:
                scored[theta] = env.current
                if progress is not None and len(scored) // PROGRESS_EVERY > reported:
                    reported = len(scored) // PROGRESS_EVERY
                    progress(len(scored), budget)
            if terminated or truncated:
                break
    rollouts = len(walks)
    refined: list[tuple[float, float, float]] = []
    if budget > len(scored):
        from smorphi_rl.search.local import compass_refine

        start = max(scored.values(), key=lambda s: s.R1).theta
        told = None if progress is None else (lambda n: progress(n, budget) if n % PROGRESS_EVERY == 0 else None)
        refined = compass_refine(env, {t: s.R1 for t, s in scored.items()}, start, budget, rng, told)
        scored |= {t: env.score(t) for t in refined}
        walks.append(refined)
    best = max(scored.values(), key=lambda s: s.R1)
    if progress is not None:
        progress(budget, budget)
    return Design(best, len(scored), env.planner_calls - calls0, rollouts, time.perf_counter() - t0,
                  refined=len(refined), walks=walks, budget=budget)  # fmt: skip

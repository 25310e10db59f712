"""Local baselines under the evaluation protocol: what a user would try before reinforcement learning.

Each starts from the protocol's fixed starts, moves on the same lattice with the same moves as the
policy (each hinge -1, 0 or +1 step: the 26 non-zero moves), and stops at a budget of FBCPP
evaluations (distinct shapes scored), so every method is compared at equal cost:

- `hill_climb`: steepest ascent over the 26 neighbours; at a local maximum it restarts from a
  uniformly random shape (seeded) while budget remains, and ends on the best shape found;
- `anneal`: simulated annealing over the same neighbours (a random neighbour, accepted with
  probability exp(dR1 / T), T falling geometrically from 1 to 0.01 R1-spreads as the budget is
  spent; at most 20 proposed moves per evaluation), ending on the best;
- `random_walk`: uniformly random moves from the start (an untrained policy's episode of `max_steps`, cut short
  at the budget of distinct shapes), ending on the shape the protocol says it settled on;
- `random_search`: uniformly random shapes, ending on the best;
- `pattern`: compass search with shrinking steps: from the start, each hinge tries +-32 lattice steps, taking
  every move that improves R1 until none does, then +-16, ... down to +-1 (sizes only shrink); when the +-1 pass
  improves nothing, it restarts from a uniformly random shape (seeded), ending on the best. Unlike the one-step
  moves, it jumps the plateaus and ripples of the R1 landscape at a few degrees. A design's compass search
  (`compass_refine`) restarts instead from the best shape already scored far from its earlier climbs.

No method scores past the lattice: a budget past it counts as the lattice, and the methods that restart stop once
every shape is scored (annealing and the walk stop as they would; revisiting a scored shape costs nothing). Moves
land on the lattice (`i * step`), so each shape has one key whatever the step.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
from collections.abc import Callable

import numpy as np

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import RewardMode
from smorphi_rl.geometry import lattice_axis, lattice_size
from smorphi_rl.protocol import EVAL_STARTS, Outcome, eval_starts, settled_theta
from smorphi_rl.search.results import SearchResult

Theta = tuple[float, float, float]
MOVES = [m for m in itertools.product((-1, 0, 1), repeat=3) if any(m)]
"""The 26 non-zero moves of one step per hinge."""
METHODS = ("hillclimb", "anneal", "random_walk", "random_search", "pattern")
PATTERN_STEPS = (32, 16, 8, 4, 2, 1)
"""Compass search's step sizes, in lattice steps, largest first."""
ANNEAL_MOVES_PER_EVALUATION = 20
"""Annealing stops after this many proposed moves per budgeted evaluation even if some budget is left."""


class _Budgeted:
    """R1 of shapes on one env's map, counting distinct shapes scored; stops answering past the budget."""

    def __init__(self, env: MorphologyEnv, budget: int, on_score: Callable[[int], None] | None = None) -> None:
        self.on_score = on_score
        """Told the count of shapes scored after each new one (a design's progress)."""
        self.step = env.config.angle_step_deg
        self.angles: tuple[float, ...] = tuple(lattice_axis(self.step).tolist())
        self.n = len(self.angles) - 1
        self.lattice = lattice_size(self.step)
        self.env, self.budget = env, min(budget, self.lattice)  # a budget past the lattice counts as the lattice
        self.seen: dict[Theta, float] = {}
        self.metrics: dict[Theta, tuple[float, int, bool]] = {}

    @property
    def scored_all(self) -> bool:
        """Every shape of the lattice is scored: a search that restarts would spin for ever."""
        return len(self.seen) >= self.lattice

    def snap(self, angle: float) -> float:
        """The lattice angle nearest `angle`, held in [0, 180]: one key per shape, whatever the step."""
        return self.angles[min(max(round(angle / self.step), 0), self.n)]

    def r1(self, theta: Theta) -> float | None:
        if theta in self.seen:
            return self.seen[theta]
        if len(self.seen) >= self.budget:
            return None
        scored = self.env.score(theta)
        self.metrics[theta] = (float(scored.P_c), int(scored.P_len), bool(scored.feasible))
        value = self.seen[theta] = float(scored.R1)
        if self.on_score is not None:
            self.on_score(len(self.seen))
        return value

    def moved(self, theta: Theta, move: tuple[int, ...]) -> Theta:
        """`theta` moved by one lattice step per hinge as `move` says, held in [0, 180]."""
        a, b, c = (self.snap(t + d * self.step) for t, d in zip(theta, move, strict=True))
        return (a, b, c)

    def neighbours(self, theta: Theta) -> list[Theta]:
        return [t for t in (self.moved(theta, m) for m in MOVES) if t != theta]

    def random_theta(self, rng: np.random.Generator) -> Theta:
        i, j, k = (int(v) for v in rng.integers(0, self.n + 1, size=3))
        return (self.angles[i], self.angles[j], self.angles[k])

    def best(self) -> Theta:
        return max(self.seen, key=lambda t: self.seen[t])


def hill_climb(space: _Budgeted, start: Theta, rng: np.random.Generator) -> Theta:
    """Steepest ascent over the 26 one-step neighbours, restarting from a random shape at a local maximum; the
    best shape scored within the budget."""
    current: Theta | None = start
    while current is not None:
        value = space.r1(current)
        if value is None:
            break
        best, best_value = current, value
        for t in space.neighbours(current):
            v = space.r1(t)
            if v is None:
                return space.best()
            if v > best_value:
                best, best_value = t, v
        if best == current and space.scored_all:
            break
        current = best if best != current else space.random_theta(rng)  # a local maximum: restart
    return space.best()


def anneal(space: _Budgeted, start: Theta, rng: np.random.Generator) -> Theta:
    """Simulated annealing over the one-step neighbours, the temperature falling geometrically as the budget is
    spent; the best shape scored."""
    current, value = start, space.r1(start)
    scale = space.env.sigma_map if space.env.config.reward != RewardMode.PAPER else 1.0
    t_hi, t_lo = 1.0 * scale, 0.01 * scale
    moves = 0
    while value is not None and len(space.seen) < space.budget and moves < ANNEAL_MOVES_PER_EVALUATION * space.budget:
        moves += 1  # at a low temperature every neighbour may already be scored: bound the moves too
        frac = len(space.seen) / space.budget
        temperature = t_hi * (t_lo / t_hi) ** frac
        options = space.neighbours(current)
        candidate = options[int(rng.integers(len(options)))]
        v = space.r1(candidate)
        if v is None:
            break
        if v >= value or rng.random() < math.exp((v - value) / temperature):
            current, value = candidate, v
    return space.best()


def random_walk(space: _Budgeted, start: Theta, rng: np.random.Generator) -> Theta:
    """Uniformly random moves for an episode (an untrained policy); the shape the protocol says it settled on."""
    history = [start]
    space.r1(start)
    for _ in range(space.env.config.max_steps):
        m = MOVES[int(rng.integers(len(MOVES)))] if rng.random() > 1 / 27 else (0, 0, 0)
        theta = space.moved(history[-1], m)
        if space.r1(theta) is None:
            break  # the budget of distinct shapes is spent: the walk ends where it stands
        history.append(theta)
    return settled_theta(history)


def random_search(space: _Budgeted, start: Theta, rng: np.random.Generator) -> Theta:
    """Uniformly random shapes until the budget is spent; the best."""
    space.r1(start)
    while len(space.seen) < space.budget:
        space.r1(space.random_theta(rng))
    return space.best()


Restart = Callable[[list[Theta], np.random.Generator], Theta]
"""Where compass search climbs next once a climb ends (given that climb's path: its start, each shape it moved to)."""
RESTART_SEPARATION_DEG = 16.0
"""A design's compass search restarts from the best shape scored more than this many degrees (on some hinge) from
every shape an earlier climb started from or moved to: the next region the policy's walks rated well, where the
search baseline draws a random shape. Measured on 40 validation floors (docs/decisions.md)."""


def pattern(space: _Budgeted, start: Theta, rng: np.random.Generator, restart: Restart | None = None) -> Theta:
    """Compass search with shrinking steps (+-32 lattice steps down to +-1), restarting where `restart` says (a
    random shape by default) once the +-1 pass improves nothing; the best shape scored."""
    current: Theta = start
    path = [current]
    while True:
        value = space.r1(current)
        if value is None:
            break
        for size in PATTERN_STEPS:
            improved = True
            while improved:
                improved = False
                for hinge, sign in itertools.product(range(3), (-1, 1)):
                    moved = list(current)
                    moved[hinge] = space.snap(moved[hinge] + sign * size * space.step)
                    candidate: Theta = (moved[0], moved[1], moved[2])
                    v = space.r1(candidate)
                    if v is None:
                        return space.best()
                    if v > value:
                        current, value, improved = candidate, v, True
                        path.append(current)
        if space.scored_all:
            break
        # the +-1 pass improves nothing: restart
        current = space.random_theta(rng) if restart is None else restart(path, rng)
        path = [current]
    return space.best()


class _Regions:
    """`compass_refine`'s restarts: the best shape scored more than `RESTART_SEPARATION_DEG` on some hinge from every
    mark (each shape a climb started from or moved to), the earliest scored among equals; a random shape when none
    is left. Shapes wait in a heap by R1; one found near a mark stays near it (marks only grow) and leaves the heap,
    so each shape is checked once however large the budget."""

    def __init__(self, space: _Budgeted) -> None:
        self.space = space
        self.heap: list[tuple[float, int, Theta]] = []
        self.known = 0
        self.marks: list[Theta] = []

    def __call__(self, path: list[Theta], rng: np.random.Generator) -> Theta:
        fresh = len(self.space.seen) - self.known  # scored since the last call: the newest entries of `seen`
        for theta, value in reversed(list(itertools.islice(reversed(self.space.seen.items()), fresh))):
            heapq.heappush(self.heap, (-value, self.known, theta))
            self.known += 1
        self.marks.extend(path)
        marks = np.asarray(self.marks, dtype=float)
        choice: Theta | None = None
        while self.heap and choice is None:
            _, _, theta = heapq.heappop(self.heap)
            if bool((np.abs(marks - np.asarray(theta)).max(axis=1) > RESTART_SEPARATION_DEG).all()):
                choice = theta
        choice = self.space.random_theta(rng) if choice is None else choice
        self.marks.append(choice)
        return choice


def compass_refine(
    env: MorphologyEnv, seen: dict[Theta, float], start: Theta, budget: int, rng: np.random.Generator,
    on_score: Callable[[int], None] | None = None,
) -> list[Theta]:  # fmt: skip
    """Compass search (`pattern`) on `env` from `start`, the shapes of `seen` (with their R1) counted as scored,
    until `budget` shapes are scored in all; the shapes it scored, in order (what a design spends its last
    evaluations on). A climb that ends restarts from the best shape scored far from every shape a climb started
    from or moved to (`_Regions`): where the policy's walks rated the floor well, not a random shape."""
    space = _Budgeted(env, budget, on_score)
    space.seen.update(seen)
    pattern(space, start, rng, _Regions(space))
    return [t for t in space.seen if t not in seen]


SEARCHERS: dict[str, Callable[[_Budgeted, Theta, np.random.Generator], Theta]] = {
    "hillclimb": hill_climb, "anneal": anneal, "random_walk": random_walk, "random_search": random_search,
    "pattern": pattern,
}  # fmt: skip


def run_local(
    method: str,
    env: MorphologyEnv,
    starts: np.ndarray,
    budget: int,
    seed: int,
    visited: list[_Budgeted] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Outcome]:
    """`method` from every start on `env`'s (single) map, each with `budget` evaluations and its own stream
    (SeedSequence(seed) spawned per start). `visited`, if given, receives each start's scored shapes;
    `progress(done, total)` hears of each start finished."""
    if method not in SEARCHERS:
        raise ValueError(f"unknown local method '{method}' (choose from {', '.join(METHODS)})")
    if budget < 1:
        raise ValueError(f"budget must be >= 1 evaluation, got {budget}")
    env.reset(seed=0)
    streams = np.random.SeedSequence(seed).spawn(len(starts))
    outcomes = []
    for start, stream in zip(starts, streams, strict=True):
        theta0: Theta = (float(start[0]), float(start[1]), float(start[2]))
        space = _Budgeted(env, budget)
        end = SEARCHERS[method](space, theta0, np.random.default_rng(stream))
        if visited is not None:
            visited.append(space)
        scored = env.score(end)
        outcomes.append(Outcome(theta0, end, float(scored.R1), float(scored.P_c), int(scored.P_len),
                                len(space.seen)))  # fmt: skip
        if progress is not None:
            progress(len(outcomes), len(starts))
    return outcomes


def run_local_search(
    method: str,
    map_path: str,
    budget: int,
    seed: int,
    starts: int = EVAL_STARTS,
    env_config: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SearchResult:
    """`search hillclimb|anneal`: the method from the protocol's fixed starts, every shape it scored pooled into
    one SearchResult (for `compare`), with the protocol's outcome per start in `params`."""
    env = MorphologyEnv({**(env_config or {}), "maps": [map_path]})
    spaces: list[_Budgeted] = []
    t0 = time.perf_counter()
    outcomes = run_local(method, env, eval_starts(starts, env.config.angle_step_deg), budget, seed, spaces, progress)
    wall = time.perf_counter() - t0
    shapes = {t: m for space in spaces for t, m in space.metrics.items()}
    thetas = np.array(list(shapes), dtype=np.float64).reshape(-1, 3)
    p_c = np.array([m[0] for m in shapes.values()])
    p_len = np.array([m[1] for m in shapes.values()], dtype=np.int64)
    feasible = np.array([m[2] for m in shapes.values()], dtype=bool)
    evaluations = sum(len(space.seen) for space in spaces)
    ran = spaces[0].budget if spaces else budget  # a budget past the lattice ran as the lattice
    params = {"budget_per_start": ran, "starts": starts, "seed": seed, "planner": env.config.planner,
              "settled_R1": [o.R1 for o in outcomes], "settled": [list(o.settled) for o in outcomes]}  # fmt: skip
    return SearchResult(method, env.grid_map.name, thetas, p_c, p_len, feasible, evaluations, wall, params,
                        env.grid_map.digest)  # fmt: skip

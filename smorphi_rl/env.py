"""The morphology MDP (ENV.md) as a gymnasium environment, registered as `smorphi_rl/Morphology-v0`.

## Description
The agent reshapes a Smorphi robot one hinge step at a time; every new shape is scored by
FBCPP on the episode's map (cached by footprint, so revisits cost nothing).

## Action Space
`MultiDiscrete([3, 3, 3])`: per hinge 0, 1, 2 means -1, 0, +1 `angle_step_deg`, clipped to [0, 180].

## Observation Space
`Dict`, the same shape for every map so one policy transfers between maps:
- `map`: `Box(0, 255, (2, S, S), uint8)`, the fraction of occupied (channel 0) and unknown
  (channel 1) cells of the map's known area (the bounding box of its free and occupied cells)
  resampled to S x S (`obs_size`, default 64), times 255 and rounded
  (a quarter of float32's bytes through every connector; the policy divides by 255);
- `angles`: `Box(0, 1, (3,))`, theta / 180;
- `metrics`: `Box(0, 1, (2,))`, P_c / 100 and P_len / (P_len + 100) of the current shape.

## Rewards
`R1 = w1 P_c - w2 P_len` of a shape (infeasible shapes score P_c = P_len = 0). By `reward` mode:
- `paper`: `R = R1 + R2` of the new shape, `R2 = -beta` when the action leaves all three angles
  unchanged (the paper's eqs. 8-10, for reproduction).
- `level`: `R = (R1(s') - mu_map) / sigma_map`, no `R2`: the return is the discounted sum of the
  standardised R1 of every shape visited, so the best behaviour is to walk to the best shape fast
  and stay there; each step's reward says directly how good the shape reached is.
- `peak`: `R = softplus(PEAK_SHARPNESS (R1(s') - q90_map) / sigma_map)`: `level` with the top of the
  landscape stretched. Most random shapes score within a few tenths of sigma_map of the best, so under
  `level` a near-best plateau pays almost what the best does; here a shape pays about nothing below the
  map's 90th percentile and PEAK_SHARPNESS units per sigma_map above it. A monotone transform of R1, so
  the best shape to settle on is the same.
- In `level` and `peak`, a step that changes the shape also pays `-move_cost` (default 0, off): where no
  move gains anything, standing still then pays more than drifting, so the policy settles on a shape.
- `improvement`: `R = (R1(s') - R1(s)) / sigma_map`; the return telescopes to the final shape's R1
  minus the start's, so standing still at the optimum costs nothing.
- `commit`: the all-zero action ends the episode and pays `R1(s) / sigma_map`; any other step pays
  `-step_cost`, and truncation pays the final shape's `R1 / sigma_map` as well.
`mu_map`, `sigma_map` and `q90_map` are the mean, standard deviation and 90th percentile of R1 over a
fixed seeded sample of random shapes on the map.

## Starting State
A map drawn from `maps`, and theta uniform on the `angle_step_deg` lattice (or `start_theta`, or
`reset(options={"theta": ...})`, rounded to the lattice), both from the env's seeded generator.

## Episode End
Terminated when P_c >= `coverage_threshold` (off unless set), or in `commit` mode on the all-zero
action; truncated after `max_steps`.

## Version History
- v0: first version; the map channels became uint8 and the `improvement` and `commit` reward modes
  were added without a version bump (no policy had been published); likewise the map channels now
  cover the known cells' bounding box (identical on maps with no unknown border, such as the shipped
  ones) and the config took `planner`, `start_xy` and `path_term` (defaults: the old behaviour), and
  `move_cost` (default 0: the old behaviour).
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, fields, replace
from enum import Enum
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from smorphi_rl.coverage import PLANNERS, CoverageResult, Planner
from smorphi_rl.errors import SmorphiError
from smorphi_rl.evaluate import Evaluator, Planning
from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M, Morphology, check_block_side
from smorphi_rl.maps import SHIPPED_DEFAULT_MAP, Cell, Map, load_map
from smorphi_rl.score import PATH_TERMS, Scored, Weights, effective_w2

ENV_ID = "smorphi_rl/Morphology-v0"
DEFAULT_MAPS = (str(SHIPPED_DEFAULT_MAP),)


class RewardMode(str, Enum):
    """What an episode pays (ENV.md, "Reward modes")."""

    PAPER = "paper"
    LEVEL = "level"
    PEAK = "peak"
    IMPROVEMENT = "improvement"
    COMMIT = "commit"


REWARD_MODES = tuple(m.value for m in RewardMode)
PEAK_SHARPNESS = 10.0
"""`peak` mode: reward units per sigma_map of R1 above the map's 90th percentile (20 did worse on map-1)."""
DEFAULT_MOVE_COST = 0.0
"""`level`/`peak` move cost, off by default: 0.03 took PPO on map-1 from 30 to 47 % of the protocol's starts within
1 % but map-2 from 40 to 32 % with twice the median gap, and IMPALA's gaps grew on both (README, Learning)."""
SIGMA_SAMPLES = 256
"""Random shapes whose R1 spread scales the design rewards (seeded, so every process agrees)."""
MAP_LEVELS = 255
"""The map channels are fractions times this, rounded to uint8."""
SCORE_CACHE_SIZE = 1 << 17
"""Scored lattice points kept per env (a few hundred bytes each) before the memo starts again."""
PLAN_CACHE_SIZE = 4096
"""Full plans (path and covered mask, a few KB each) kept per env before the cache starts again."""


UNSCORED = Scored((0.0, 0.0, 0.0), 0.0, 0.0, 0, 0.0, False, 0.0, "")
"""What an env holds as its current and best shape before its first reset."""


class EnvConfigError(SmorphiError):
    """An `env_config` key that is unknown or has a bad value."""


@dataclass(frozen=True)
class EnvConfig:
    """Everything the env takes, validated once; the only place its defaults live."""

    maps: tuple[str, ...] = DEFAULT_MAPS
    """map_server YAML paths; one is drawn per episode."""
    angle_step_deg: float = 1.0
    """Hinge step per action (the paper's 1-degree design space); must divide 180."""
    w1: float = 1.0
    """Weight of P_c (percent) in R1."""
    w2: float = 0.1
    """Weight of P_len (tile moves) in R1: 10 moves cost as much as 1 % of coverage."""
    path_term: str = "moves"
    """How w2 charges the path: `moves` (per tile move, the paper's) or `per_area` (per tile move per 25 m^2
    of free floor, so a weight means the same on every floor size; `score.py`)."""
    beta: float = 1.0
    """Penalty R2 for an action that leaves the shape unchanged."""
    coverage_threshold: float | None = None
    """End the episode once P_c reaches this percentage (off by default)."""
    max_steps: int = 200
    """Episode length (truncation)."""
    obs_size: int = 64
    """Side of the resampled map in the observation."""
    start_theta: tuple[float, float, float] | None = None
    """Fixed start morphology; random on the lattice when None."""
    block_side_m: float = DEFAULT_BLOCK_SIDE_M
    """Side of one block in metres."""
    reward: str = RewardMode.PEAK.value
    """Reward mode: peak (level with the top stretched: learns best, see the README), level (standardised R1 of
    each shape reached), paper (R1 + R2, for reproduction), improvement (R1 gained, scaled) or commit (R1 of the
    committed shape)."""
    step_cost: float = 0.0
    """`commit` mode: what every step that does not commit costs (in units of sigma_map)."""
    move_cost: float = DEFAULT_MOVE_COST
    """`level` and `peak` modes: what a step that changes the shape costs (in reward units). With nothing to
    gain, standing still then pays more than drifting over a plateau, so the policy settles (0: off)."""
    planner: str = Planner.PAPER.value
    """Coverage planner: paper (FBCPP.md; the robot may stand over obstacles) or fit (docs/fbcpp-fit.md)."""
    start_xy: tuple[float, float] | None = None
    """Where every coverage plan starts: a free point (x, y) in metres, map frame; None: the planner's default
    (paper: the first traversable tile; fit: in the largest free area)."""

    def __post_init__(self) -> None:
        if self.reward not in REWARD_MODES:
            raise EnvConfigError(
                f"env_config 'reward': unknown mode '{self.reward}' (choose from {', '.join(REWARD_MODES)})"
            )
        if self.path_term not in PATH_TERMS:
            raise EnvConfigError(
                f"env_config 'path_term': unknown path term '{self.path_term}' (choose from {', '.join(PATH_TERMS)})"
            )
        if self.planner not in PLANNERS:
            raise EnvConfigError(
                f"env_config 'planner': unknown planner '{self.planner}' (choose from {', '.join(PLANNERS)})"
            )
        for name in ("step_cost", "move_cost"):
            if getattr(self, name) < 0:
                raise EnvConfigError(f"env_config '{name}' must be >= 0, got {getattr(self, name)}")
        if not self.maps:
            raise EnvConfigError("env_config 'maps': give at least one map")
        step = self.angle_step_deg
        if not (0 < step <= 180 and math.isclose(180 / step, round(180 / step), abs_tol=1e-9)):
            raise EnvConfigError(f"env_config 'angle_step_deg' must divide 180, got {step}")
        if self.max_steps < 1:
            raise EnvConfigError(f"env_config 'max_steps' must be >= 1, got {self.max_steps}")
        if self.obs_size < 4:
            raise EnvConfigError(f"env_config 'obs_size' must be >= 4, got {self.obs_size}")
        if self.coverage_threshold is not None and not 0 < self.coverage_threshold <= 100:
            raise EnvConfigError(f"env_config 'coverage_threshold' must be in (0, 100], got {self.coverage_threshold}")
        if self.block_side_m <= 0:
            raise EnvConfigError(f"env_config 'block_side_m' must be > 0, got {self.block_side_m}")
        if self.start_theta is not None:
            try:
                Morphology.of(self.start_theta)
            except SmorphiError as exc:
                raise EnvConfigError(f"env_config 'start_theta': {exc}") from None

    @classmethod
    def from_dict(cls, raw: dict[str, Any] | None) -> EnvConfig:
        """From the plain dict RLlib passes (extra RLlib attributes such as worker_index ignored)."""
        raw = dict(raw or {})
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(raw) - set(known))
        if unknown:
            raise EnvConfigError(f"env_config: unknown key '{unknown[0]}' (known: {', '.join(known)})")
        values: dict[str, Any] = {}
        for name, value in raw.items():
            values[name] = _coerce(name, value)
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def weights_on(self, grid_map: Map) -> Weights:
        """R1's weights in effect on `grid_map` (w2 after `path_term`)."""
        free_m2 = grid_map.counts[Cell.FREE] * grid_map.resolution_m**2
        return Weights(self.w1, effective_w2(self.w2, self.path_term, free_m2))

    @property
    def planning(self) -> Planning:
        """How this env plans every shape (block side, planner, start)."""
        return Planning(self.block_side_m, Planner(self.planner), self.start_xy)


def _coerce(name: str, value: Any) -> Any:
    """Check one env_config value's type; lists become tuples, numbers floats or ints."""
    try:
        if name == "maps":
            items = [value] if isinstance(value, str | Path) else list(value)
            return tuple(str(Path(v).resolve()) for v in items)
        if name == "start_theta":
            return None if value is None else tuple(float(v) for v in value)
        if name == "start_xy":
            if value is None:
                return None
            point = tuple(_real(v) for v in value)
            if len(point) != 2:
                raise TypeError
            return point
        if name == "coverage_threshold":
            return None if value is None else _real(value)
        if name == "reward":
            if not isinstance(value, str | RewardMode):
                raise TypeError
            return RewardMode(value).value if value in REWARD_MODES else str(value)
        if name == "path_term":
            if not isinstance(value, str):
                raise TypeError
            return value
        if name == "planner":
            if not isinstance(value, str | Planner):
                raise TypeError
            return Planner(value).value if value in PLANNERS else str(value)
        if name in ("max_steps", "obs_size"):
            if isinstance(value, bool) or int(value) != value:
                raise TypeError
            return int(value)
        return _real(value)
    except (TypeError, ValueError):
        raise EnvConfigError(f"env_config '{name}': bad value {value!r}") from None


def _real(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise TypeError
    return float(value)


def resample(mask: np.ndarray, size: int) -> np.ndarray:
    """Fraction of true cells of `mask` under each cell of a size x size grid (area average;
    each output cell covers at least one input cell, so small maps are upsampled by nearest)."""
    h, w = mask.shape
    prefix = np.zeros((h + 1, w + 1))
    prefix[1:, 1:] = mask.astype(np.float64).cumsum(0).cumsum(1)

    def bounds(n: int) -> tuple[np.ndarray, np.ndarray]:
        lo = np.minimum((np.arange(size) * n) // size, n - 1)
        hi = np.maximum(lo + 1, ((np.arange(size) + 1) * n) // size)
        return lo, hi

    r0, r1 = bounds(h)
    c0, c1 = bounds(w)
    total = prefix[r1][:, c1] - prefix[r0][:, c1] - prefix[r1][:, c0] + prefix[r0][:, c0]
    area = (r1 - r0)[:, None] * (c1 - c0)[None, :]
    return (total / area).astype(np.float32)


def peak_reward(value: Any, q90: float, sigma: float) -> Any:
    """The `peak` reward of R1 = value (a number or an array): softplus of PEAK_SHARPNESS sigmas above q90."""
    return np.logaddexp(0.0, PEAK_SHARPNESS * (np.asarray(value, dtype=np.float64) - q90) / sigma)


class R1Stats(NamedTuple):
    """R1 over a fixed seeded sample of random shapes on one map: what scales the design rewards."""

    mu: float
    sigma: float
    q90: float

    def peak(self, value: float) -> float:
        """The `peak` reward of a shape scoring R1 = value."""
        return float(peak_reward(value, self.q90, self.sigma))


@lru_cache(maxsize=64)
def r1_stats(map_path: str, weights: Weights, planning: Planning) -> R1Stats:
    """Mean, standard deviation and 90th percentile of R1 over SIGMA_SAMPLES seeded random integer shapes on
    the map (computed once per map and weights in each process; sigma at least 1e-6 so a flat map scales)."""
    rng = np.random.default_rng(20231)
    thetas = rng.integers(0, 181, size=(SIGMA_SAMPLES, 3)).astype(np.float64)
    batch = planning.evaluator(load_map(map_path)).evaluate_many(thetas)
    values = weights.r1(batch.P_c, batch.P_len)
    return R1Stats(float(np.mean(values)), max(float(np.std(values)), 1e-6), float(np.quantile(values, 0.9)))


class MorphologyEnv(gym.Env[dict[str, np.ndarray], np.ndarray]):
    """Smorphi morphology design as an MDP (module docstring has the full spec)."""

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 (gymnasium's convention)

    def __init__(self, env_config: dict[str, Any] | None = None, **kwargs: Any) -> None:
        self.config = EnvConfig.from_dict({**(env_config or {}), **kwargs})
        self._maps: list[Map] = [load_map(p) for p in self.config.maps]
        for grid_map in self._maps:  # a footprint under one cell, or absurdly many, fails here and names the map
            try:
                check_block_side(self.config.block_side_m, grid_map.resolution_m)
            except SmorphiError as exc:
                raise EnvConfigError(f"env_config 'block_side_m' on {grid_map.name}: {exc}") from None
            try:
                self.config.planning.start_on(grid_map)
            except SmorphiError as exc:
                raise EnvConfigError(f"env_config 'start_xy': {exc}") from None
        self._evaluators: dict[int, Evaluator] = {}
        self._plans: dict[tuple[int, bool, tuple[int, ...], bytes], CoverageResult] = {}
        self._scores: dict[tuple[int, int, int, int], Scored] = {}
        self._map_obs = [self._map_channels(m) for m in self._maps]
        self._mode = RewardMode(self.config.reward)
        self._weights = [self.config.weights_on(m) for m in self._maps]
        cfg = self.config
        self._stats = [
            r1_stats(p, w, cfg.planning) if self._mode is not RewardMode.PAPER else R1Stats(0.0, 1.0, 0.0)
            for p, w in zip(cfg.maps, self._weights, strict=True)
        ]  # fmt: skip
        self._lattice_max = round(180 / self.config.angle_step_deg)
        size = self.config.obs_size
        self.action_space = spaces.MultiDiscrete([3, 3, 3])
        self.observation_space = spaces.Dict(
            {
                "map": spaces.Box(0, MAP_LEVELS, (2, size, size), np.uint8),
                "angles": spaces.Box(0.0, 1.0, (3,), np.float32),
                "metrics": spaces.Box(0.0, 1.0, (2,), np.float32),
            }
        )
        self._map_index = 0
        self._idx: tuple[int, int, int] = (0, 0, 0)  # theta = idx * angle_step_deg
        self._steps = 0
        self._last = self._best = UNSCORED  # until the first reset

    def sibling(self) -> MorphologyEnv:
        """A fresh env of the same configuration that shares this one's maps, observations and caches
        (an env runner's sub-envs share them, so a shape scored by one is free for all); unseeded."""
        twin = copy.copy(self)
        twin._idx, twin._steps, twin._last, twin._best = (0, 0, 0), 0, UNSCORED, UNSCORED
        twin._np_random, twin._np_random_seed = None, None
        return twin

    # -- helpers ---------------------------------------------------------------------------
    def _map_channels(self, grid_map: Map) -> np.ndarray:
        """The observation's map: occupied and unknown fractions over the known cells' bounding box (a
        recorded map is mostly unknown space around the floor; the policy sees the floor, not the frame)."""
        size = self.config.obs_size
        rows, cols = np.nonzero(grid_map.cells != Cell.UNKNOWN)
        cells = grid_map.cells[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]
        fractions = np.stack([resample(cells == c, size) for c in (Cell.OCCUPIED, Cell.UNKNOWN)])
        channels = np.rint(fractions * MAP_LEVELS).astype(np.uint8)
        channels.setflags(write=False)  # shared by every observation of this map
        return channels

    def _evaluator(self) -> Evaluator:
        if self._map_index not in self._evaluators:
            self._evaluators[self._map_index] = self.config.planning.evaluator(self._maps[self._map_index])
        return self._evaluators[self._map_index]

    @property
    def theta(self) -> tuple[float, float, float]:
        step = self.config.angle_step_deg
        i, j, k = self._idx
        return (i * step, j * step, k * step)

    @property
    def grid_map(self) -> Map:
        """The current episode's map."""
        return self._maps[self._map_index]

    def plan(self, theta: tuple[float, float, float]) -> CoverageResult:
        """The full FBCPP plan (path and covered cells) of `theta` on the current map, for figures and
        recordings; cached by footprint matrix like the metrics, so replanning a visited shape is free."""
        evaluator = self._evaluator()
        morphology = Morphology.of(theta)
        f = evaluator.footprint(morphology)
        key = (self._map_index, f.feasible, f.matrix.shape, f.matrix.tobytes())
        plan = self._plans.get(key)
        if plan is None:
            if len(self._plans) >= PLAN_CACHE_SIZE:
                self._plans.clear()
            plan = self._plans[key] = evaluator.plan(morphology)
        return replace(plan, theta=morphology.angles, footprint_m=(f.width_m, f.length_m))

    def score(self, theta: tuple[float, float, float]) -> Scored:
        """FBCPP metrics and R1 of `theta` on the current episode's map (the fields `info` reports)."""
        result = self._evaluator().evaluate(Morphology.of(theta))
        t1, t2, t3 = (float(t) for t in theta)
        return Scored(
            theta=(t1, t2, t3),
            P_c=result.P_c,
            coverage_free_pct=result.coverage_free_pct,
            P_len=result.P_len,
            path_length_m=result.path_length_m,
            feasible=result.feasible,
            R1=self._weights[self._map_index].r1(result.P_c, result.P_len),
            map=self._maps[self._map_index].name,
        )

    def _score_current(self) -> Scored:
        """`score` of the current lattice point, memoised by (map, lattice index): the env's hot path."""
        key = (self._map_index, *self._idx)
        scored = self._scores.get(key)
        if scored is None:
            if len(self._scores) >= SCORE_CACHE_SIZE:
                self._scores.clear()
            scored = self._scores[key] = self.score(self.theta)
        return scored

    @property
    def sigma_map(self) -> float:
        """The R1 spread that scales the design rewards on the current map (1 in `paper` mode)."""
        return self._stats[self._map_index].sigma

    def _observe(self) -> dict[str, np.ndarray]:
        p_c, p_len = self._last.P_c, self._last.P_len
        return {
            "map": self._map_obs[self._map_index],
            "angles": np.asarray(self.theta, dtype=np.float32) / np.float32(180.0),
            "metrics": np.array([p_c / 100.0, p_len / (p_len + 100.0)], dtype=np.float32),
        }

    def _info(self) -> dict[str, Any]:
        return self._last.info | self._best.best_info

    def _record(self, scored: Scored, first: bool = False) -> None:
        self._last = scored
        if first or scored.R1 > self._best.R1:
            self._best = scored

    # -- gymnasium API ---------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self._map_index = int(self.np_random.integers(len(self._maps)))
        start = (options or {}).get("theta", self.config.start_theta)
        if start is not None:  # options={"theta": ...}: the evaluation protocol's fixed starts
            try:
                Morphology.of(start)
            except (SmorphiError, TypeError, ValueError) as exc:
                raise EnvConfigError(f"reset option 'theta': {exc}") from None
            i, j, k = (min(round(t / self.config.angle_step_deg), self._lattice_max) for t in start)
        else:
            i, j, k = (int(v) for v in self.np_random.integers(0, self._lattice_max + 1, size=3))
        self._idx = (i, j, k)
        self._steps = 0
        self._record(self._score_current(), first=True)
        return self._observe(), self._info()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        moves = action.tolist() if isinstance(action, np.ndarray) else list(action)
        if len(moves) != 3 or any(m not in (0, 1, 2) for m in moves):
            raise SmorphiError(f"action must be three values in {{0, 1, 2}}, got {action!r}")
        self._steps += 1
        before = self._last
        truncated = self._steps >= self.config.max_steps
        if self._mode is RewardMode.COMMIT and moves == [1, 1, 1]:
            # committing keeps the shape and ends the episode, paid the value of that one design
            return self._observe(), float(before.R1 / self.sigma_map), True, False, self._info()
        top = self._lattice_max
        i, j, k = (min(max(v + m - 1, 0), top) for v, m in zip(self._idx, moves, strict=True))
        unchanged = (i, j, k) == self._idx
        self._idx = (i, j, k)
        scored = self._score_current()
        self._record(scored)
        if self._mode is RewardMode.PAPER:
            reward = scored.R1 - (self.config.beta if unchanged else 0.0)
        elif self._mode is RewardMode.LEVEL:
            stats = self._stats[self._map_index]
            reward = (scored.R1 - stats.mu) / stats.sigma - (0.0 if unchanged else self.config.move_cost)
        elif self._mode is RewardMode.PEAK:
            reward = self._stats[self._map_index].peak(scored.R1) - (0.0 if unchanged else self.config.move_cost)
        elif self._mode is RewardMode.IMPROVEMENT:
            reward = (scored.R1 - before.R1) / self.sigma_map
        else:
            reward = -self.config.step_cost + (scored.R1 / self.sigma_map if truncated else 0.0)
        threshold = self.config.coverage_threshold
        terminated = threshold is not None and scored.P_c >= threshold
        return self._observe(), float(reward), bool(terminated), bool(truncated), self._info()


def register() -> None:
    """Register with gymnasium under ENV_ID (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="smorphi_rl.env:MorphologyEnv")


register()

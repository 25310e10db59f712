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
from dataclasses import replace
from functools import lru_cache
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from smorphi_rl.coverage import CoverageResult
from smorphi_rl.env_config import EnvConfig, EnvConfigError, RewardMode
from smorphi_rl.errors import SmorphiError
from smorphi_rl.evaluate import Evaluator, Planning
from smorphi_rl.geometry import Morphology, check_block_side
from smorphi_rl.maps import Cell, Map, load_map
from smorphi_rl.score import Scored, Weights

ENV_ID = "smorphi_rl/Morphology-v0"


PEAK_SHARPNESS = 10.0
"""`peak` mode: reward units per sigma_map of R1 above the map's 90th percentile (20 did worse on map-1)."""
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

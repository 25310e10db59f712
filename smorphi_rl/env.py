"""The morphology MDP (docs/spec/env.md) as a gymnasium environment, registered as `smorphi_rl/Morphology-v0`.

## Description
The agent reshapes a Smorphi robot one hinge step at a time; every new shape is scored by
FBCPP on the episode's map (cached by footprint, so revisits cost nothing).

## Action Space
`MultiDiscrete([2K + 1] * 3)` for `moves` (K step sizes, default (1,)): per hinge, index K keeps the angle and
the others move it by -m_K .. -m_1, +m_1 .. +m_K lattice steps of `angle_step_deg`, clipped to [0, 180]; with
the default, 0, 1, 2 mean -1, 0, +1.

## Observation Space
`Dict`, the same shape for every map so one policy transfers between maps:
- `map`: `Box(0, 255, (2, S, S), uint8)`, the fraction of occupied (channel 0) and unknown
  (channel 1) cells of the map's known area (the bounding box of its free and occupied cells)
  resampled to S x S (`obs_size`, default 64), times 255 and rounded
  (a quarter of float32's bytes through every connector; the policy divides by 255);
- `angles`: `Box(0, 1, (3,))`, theta / 180;
- `metrics`: `Box(0, 1, (2,))`, P_c / 100 and P_len / (P_len + 100) of the current shape.
That is the `picture` layout (the default). The `floor` layout (`observation: floor`) pads the known box to a
square before resampling (the picture keeps the floor's aspect), takes metrics that mean the same on any floor
size (P_c, free coverage, the path against the free area, R1 / 100: `Box(0, 1, (4,))`) and adds `scale`,
`Box(0, 1, (9,))`: the floor's size and resolution against the block and its clearance shares
(`floor_scale`; docs/spec/env.md section 4).
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
- `commit`: the stay action (index K, no move, on every hinge) ends the episode and pays `R1(s) / sigma_map`;
  any other step pays `-step_cost`, and truncation pays the final shape's `R1 / sigma_map` as well.
`mu_map`, `sigma_map` and `q90_map` are the mean, standard deviation and 90th percentile of R1 over a
fixed seeded sample of random shapes on the map.

## Starting State
A map drawn from `maps` (files, or a `generate:KIND[:LO-HI]` entry that draws a fresh floor's seed), and theta
uniform on the `angle_step_deg` lattice (or `start_theta`, or `reset(options={"theta": ...})`, rounded to the
lattice), both from the env's seeded generator.

## Episode End
Terminated when P_c >= `coverage_threshold` (off unless set), or in `commit` mode on the stay
action; truncated after `max_steps`.

## Version History
- v0: first version; the map channels became uint8 and the `improvement` and `commit` reward modes
  were added without a version bump (no policy had been published); likewise the map channels now
  cover the known cells' bounding box (identical on maps with no unknown border, such as the shipped
  ones) and the config took `planner`, `start_xy` and `path_term` (defaults: the old behaviour), and
  `move_cost` (default 0: the old behaviour); then `observation` and `moves` (defaults: the old layout and
  actions, so checkpoints written before them load as they were).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from smorphi_rl.coverage import CoverageResult, Planner
from smorphi_rl.env_config import EnvConfig, EnvConfigError, ObservationLayout, RewardMode
from smorphi_rl.errors import MapError, MorphologyError, SmorphiError
from smorphi_rl.floorplans import generate_floor
from smorphi_rl.geometry import Morphology, lattice_axis
from smorphi_rl.map_sources import generators
from smorphi_rl.maps import CELL_COLOURS, PATH_COLOUR, Cell, Map, check_fits, load_map
from smorphi_rl.planning import Evaluator, Planning
from smorphi_rl.score import Scored, Weights

ENV_ID = "smorphi_rl/Morphology-v0"
"""The id `import smorphi_rl` registers this env under with gymnasium (`smorphi_rl.ENV_ID`, checked equal by the
tests: the package's own import stays light)."""


PEAK_SHARPNESS = 10.0
"""`peak` mode: reward units per sigma_map of R1 above the map's 90th percentile (20 did worse on map-1)."""
SIGMA_SAMPLES = 256
"""Random shapes whose R1 spread scales the design rewards (seeded, so every process agrees)."""
MAP_LEVELS = 255
"""The map channels are fractions times this, rounded to uint8."""
GENERATED_SIGMA_SAMPLES = 128
"""Random shapes that scale the rewards on a generated floor (its build is most of an episode's cost)."""
SCORE_CACHE_SIZE = 1 << 17
"""Scored lattice points kept per floor (a few hundred bytes each) before the memo starts again; the floor's planner
keeps as many footprints (a fine map has up to 954,707 distinct ones, docs/spec/fbcpp.md)."""
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


_R1_STATS: OrderedDict[tuple[Any, ...], R1Stats] = OrderedDict()
"""`r1_stats` of the 64 maps used last in this process."""


def r1_stats(grid_map: Map, weights: Weights, planning: Planning) -> R1Stats:
    """`map_r1_stats` of a map file's map, computed once per map, weights and planning in each process: keyed by
    the map's cells, not its path, so a file changed on disk is scaled anew."""
    digest = hashlib.blake2b(grid_map.cells.tobytes(), digest_size=16).digest()
    key = (digest, grid_map.cells.shape, grid_map.resolution_m, tuple(grid_map.origin), weights, planning)
    stats = _R1_STATS.get(key)
    if stats is None:
        if len(_R1_STATS) >= 64:
            _R1_STATS.popitem(last=False)
        stats = _R1_STATS[key] = map_r1_stats(grid_map, weights, planning)
    _R1_STATS.move_to_end(key)
    return stats


def map_r1_stats(grid_map: Map, weights: Weights, planning: Planning, samples: int = SIGMA_SAMPLES) -> R1Stats:
    """Mean, standard deviation and 90th percentile of R1 over `samples` seeded random integer shapes on the map
    (sigma at least 1e-6 so a flat map scales)."""
    rng = np.random.default_rng(20231)
    thetas = rng.integers(0, 181, size=(samples, 3)).astype(np.float64)
    batch = planning.evaluator(grid_map).evaluate_many(thetas)
    values = weights.r1(batch.P_c, batch.P_len)
    return R1Stats(float(np.mean(values)), max(float(np.std(values)), 1e-6), float(np.quantile(values, 0.9)))


SCALE_KEY = "scale"
"""The `floor` layout's entry for the floor's scale and clearance against the block."""
EXTRA_KEYS = ("metrics", SCALE_KEY)
"""The observation's entries a policy reads as they are (beside the map and the angles), in this order."""
CLEARANCE_BLOCKS = (0.5, 1.0, 2.0, 4.0)
"""`scale`: the shares of free cells at least this many block sides from anything not free."""
FLOOR_CACHE_SIZE = 256
"""Generated floors an env process keeps built (map, planner, scores); shared by sibling sub-envs."""


@dataclass
class Floor:
    """One map as the env plays it: the map, its weights, reward scales and observation entries, and the scores
    of the shapes visited on it (an env's floors are built once and shared by its sibling sub-envs)."""

    grid_map: Map
    weights: Weights
    stats: R1Stats
    picture: np.ndarray
    scale: np.ndarray
    evaluator: Evaluator | None = None
    scores: dict[tuple[int, int, int], Scored] = field(default_factory=dict)
    plans: dict[tuple[bool, tuple[int, ...], bytes], CoverageResult] = field(default_factory=dict)
    free_m2: float = 1.0
    o_tile_m2: float = 0.0
    """The O-shape's tile (2 x 2 blocks): P_len times it over the free area is about 1 for a full O-shape path."""


def map_picture(grid_map: Map, size: int, square: bool) -> np.ndarray:
    """Occupied and unknown fractions over the known cells' bounding box (a recorded map is mostly unknown space
    around the floor: the policy sees the floor, not the frame), resampled to size x size, times 255 (uint8).
    `square`: the box is first padded with unknown cells to a square, so the picture keeps the floor's aspect."""
    r0, r1, c0, c1 = grid_map.known_box()
    cells = grid_map.cells[r0:r1, c0:c1]
    if square:
        side = max(cells.shape)
        canvas = np.full((side, side), Cell.UNKNOWN, dtype=np.uint8)
        r0, c0 = (side - cells.shape[0]) // 2, (side - cells.shape[1]) // 2
        canvas[r0 : r0 + cells.shape[0], c0 : c0 + cells.shape[1]] = cells
        cells = canvas
    fractions = np.stack([resample(cells == c, size) for c in (Cell.OCCUPIED, Cell.UNKNOWN)])
    channels = np.rint(fractions * MAP_LEVELS).astype(np.uint8)
    channels.setflags(write=False)  # shared by every observation of this map
    return channels


def floor_scale(grid_map: Map, block_side_m: float) -> np.ndarray:
    """The `floor` layout's `scale` entry, each in [0, 1]: a block's side in cells / 4, the known box's width and
    height in metres / 20, the free area in m^2 / 200, the free share of the known cells, and the shares of free
    cells at least 0.5, 1, 2 and 4 block sides from anything not free (how cluttered the floor is for this robot)."""
    from scipy import ndimage

    r = grid_map.resolution_m
    height_m, width_m = grid_map.known_sides_m()
    free = grid_map.cells == Cell.FREE
    n_free = max(int(free.sum()), 1)
    clearance_m = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1] * r
    shares = [float((clearance_m[free] >= k * block_side_m).sum()) / n_free for k in CLEARANCE_BLOCKS]
    known = max(int((grid_map.cells != Cell.UNKNOWN).sum()), 1)
    values = [block_side_m / r / 4, width_m / 20, height_m / 20, n_free * r * r / 200, n_free / known, *shares]
    scale = np.clip(np.asarray(values, dtype=np.float32), 0.0, 1.0)
    scale.setflags(write=False)
    return scale


def squash(x: float) -> float:
    """x / (1 + x) for x >= 0: a count or ratio of any size into [0, 1)."""
    return x / (1.0 + x)


class MorphologyEnv(gym.Env[dict[str, np.ndarray], np.ndarray]):
    """Smorphi morphology design as an MDP (module docstring has the full spec)."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012 (gymnasium's)

    def __init__(self, env_config: dict[str, Any] | None = None, render_mode: str | None = None, **kwargs: Any) -> None:
        """`env_config` (and keyword arguments, which win) as `docs/commands.md` lists; `render_mode` None or
        "rgb_array" (`render` returns the floor with the current shape's covered area and path)."""
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise EnvConfigError(f"render_mode {render_mode!r} is not one of None, 'rgb_array'")
        self.render_mode = render_mode
        if env_config is not None and not isinstance(env_config, Mapping):
            raise EnvConfigError(f"env_config must be a dict of the keys docs/commands.md lists, not a "
                                 f"{type(env_config).__name__} (a map: {{'maps': [path]}})")  # fmt: skip
        self.config = EnvConfig.from_dict({**(env_config or {}), **kwargs})
        cfg = self.config
        self._mode = RewardMode(cfg.reward)
        self._layout = ObservationLayout(cfg.observation)
        self._files: list[Floor] = [self._build(load_map(p), generated=False) for p in cfg.map_files]
        self._sources = generators(cfg.maps)
        self._generated: OrderedDict[tuple[int, int], Floor] = OrderedDict()
        self._floor: Floor | None = None
        self._angles: tuple[float, ...] = tuple(lattice_axis(cfg.angle_step_deg).tolist())
        """Each lattice index's angle (`geometry.lattice_axis`): the step's hot path reads theta through it."""
        self._lattice_max = len(self._angles) - 1
        k = len(cfg.moves)
        self._offsets = (*(-m for m in reversed(cfg.moves)), 0, *cfg.moves)
        """Lattice steps of each action index of a hinge (a tuple: the step's hot path indexes it)."""
        self._indices = frozenset(range(2 * k + 1))
        self._stay = k
        """The action index that leaves a hinge where it is."""
        size = cfg.obs_size
        self.action_space = spaces.MultiDiscrete([2 * k + 1] * 3)
        entries: dict[str, spaces.Space[Any]] = {
            "map": spaces.Box(0, MAP_LEVELS, (2, size, size), np.uint8),
            "angles": spaces.Box(0.0, 1.0, (3,), np.float32),
            "metrics": spaces.Box(0.0, 1.0, (4 if self._layout is ObservationLayout.FLOOR else 2,), np.float32),
        }
        if self._layout is ObservationLayout.FLOOR:
            entries[SCALE_KEY] = spaces.Box(0.0, 1.0, (5 + len(CLEARANCE_BLOCKS),), np.float32)
        self.observation_space = spaces.Dict(entries)
        self._idx: tuple[int, int, int] = (0, 0, 0)  # theta = idx * angle_step_deg
        self._steps = 0
        self._last = self._best = UNSCORED  # until the first reset
        self._started = False  # reset at least once: step and render refuse before (ResetNeeded)

    def _build(self, grid_map: Map, generated: bool) -> Floor:
        """A map's Floor; a block under one cell, a floor smaller than the robot or a start off the floor fails here
        and names the map."""
        cfg = self.config
        try:  # and a floor smaller than the robot, here rather than at its first plan (`paper` plans none to build)
            check_fits(grid_map, cfg.block_side_m, whole_footprint=cfg.planner == Planner.FIT.value)
        except MorphologyError as exc:
            raise EnvConfigError(f"env_config 'block_side_m' on {grid_map.name}: {exc}") from None
        except MapError as exc:
            raise EnvConfigError(f"env_config 'maps': {exc}") from None
        try:
            cfg.planning.start_on(grid_map)
        except SmorphiError as exc:
            raise EnvConfigError(f"env_config 'start_xy': {exc}") from None
        weights = cfg.weights_on(grid_map)
        if self._mode is RewardMode.PAPER:
            stats = R1Stats(0.0, 1.0, 0.0)
        elif not generated:
            stats = r1_stats(grid_map, weights, cfg.planning)
        else:  # a generated floor, seen for an episode or a few: half the sample, half the cost of its build
            stats = map_r1_stats(grid_map, weights, cfg.planning, GENERATED_SIGMA_SAMPLES)
        floor = self._layout is ObservationLayout.FLOOR
        scale = floor_scale(grid_map, cfg.block_side_m) if floor else np.zeros(0, dtype=np.float32)
        free_m2 = grid_map.counts[Cell.FREE] * grid_map.resolution_m**2
        picture = map_picture(grid_map, cfg.obs_size, floor)
        return Floor(grid_map, weights, stats, picture, scale, free_m2=free_m2, o_tile_m2=4 * cfg.block_side_m**2)

    def sibling(self) -> MorphologyEnv:
        """A fresh env of the same configuration that shares this one's maps, observations and caches
        (an env runner's sub-envs share them, so a shape scored by one is free for all); its random stream its own,
        from fresh entropy, as an env never seeded draws it."""
        twin = copy.copy(self)
        twin._idx, twin._steps, twin._last, twin._best = (0, 0, 0), 0, UNSCORED, UNSCORED
        twin._started = False
        twin.np_random = np.random.default_rng()  # its own stream (a copy shared this env's), until seeded by reset
        return twin

    # -- helpers ---------------------------------------------------------------------------
    def _draw_floor(self) -> Floor:
        """The next episode's floor: one of the map files or a generated floor, drawn with the env's generator."""
        n_files, n_sources = len(self._files), len(self._sources)
        pick = int(self.np_random.integers(n_files + n_sources))
        if pick < n_files:
            return self._files[pick]
        source = self._sources[pick - n_files]
        seed = int(self.np_random.integers(source.lo, source.hi))
        key = (pick - n_files, seed)
        floor = self._generated.get(key)
        if floor is None:
            if len(self._generated) >= FLOOR_CACHE_SIZE:
                self._generated.popitem(last=False)
            floor = self._generated[key] = self._build(generate_floor(source.kind, seed), generated=True)
        else:
            self._generated.move_to_end(key)
        return floor

    @property
    def floor(self) -> Floor:
        """The current episode's floor (the first map before the first reset)."""
        if self._floor is None:
            self._floor = self._files[0] if self._files else self._draw_floor()
        return self._floor

    def _evaluator(self) -> Evaluator:
        floor = self.floor
        if floor.evaluator is None:
            floor.evaluator = self.config.planning.evaluator(floor.grid_map, cache_limit=SCORE_CACHE_SIZE)
        return floor.evaluator

    @property
    def theta(self) -> tuple[float, float, float]:
        i, j, k = self._idx
        return (self._angles[i], self._angles[j], self._angles[k])

    @property
    def grid_map(self) -> Map:
        """The current episode's map."""
        return self.floor.grid_map

    def plan(self, theta: tuple[float, float, float]) -> CoverageResult:
        """The full FBCPP plan (path and covered cells) of `theta` on the current map, for figures and
        recordings; cached by footprint matrix like the metrics, so replanning a visited shape is free."""
        evaluator = self._evaluator()
        morphology = Morphology.of(theta)
        f = evaluator.footprint(morphology)
        plans = self.floor.plans
        key = (f.feasible, f.matrix.shape, f.matrix.tobytes())
        plan = plans.get(key)
        if plan is None:
            if len(plans) >= PLAN_CACHE_SIZE:
                plans.clear()
            plan = plans[key] = evaluator.plan(morphology)
        return replace(plan, theta=morphology.angles, footprint_m=(f.width_m, f.length_m))

    def score(self, theta: tuple[float, float, float]) -> Scored:
        """FBCPP metrics and R1 of `theta` on the current episode's map (the fields `info` reports)."""
        result = self._evaluator().evaluate(Morphology.of(theta))
        t1, t2, t3 = (float(t) for t in theta)
        floor = self.floor
        return Scored(
            theta=(t1, t2, t3),
            P_c=result.P_c,
            coverage_free_pct=result.coverage_free_pct,
            P_len=result.P_len,
            path_length_m=result.path_length_m,
            feasible=result.feasible,
            R1=floor.weights.r1(result.P_c, result.P_len),
            map=floor.grid_map.name,
        )

    def _score_current(self) -> Scored:
        """`score` of the current lattice point, memoised by lattice index on the floor: the env's hot path."""
        scores = (self._floor or self.floor).scores
        scored = scores.get(self._idx)
        if scored is None:
            if len(scores) >= SCORE_CACHE_SIZE:
                scores.clear()
            scored = scores[self._idx] = self.score(self.theta)
        return scored

    @property
    def current(self) -> Scored:
        """The current shape's score (after a reset or a step)."""
        return self._last

    @property
    def planner_calls(self) -> int:
        """Footprints this env has planned on the current floor (its cache of plans answers the rest)."""
        return self._evaluator().misses

    @property
    def sigma_map(self) -> float:
        """The R1 spread that scales the design rewards on the current map (1 in `paper` mode)."""
        return self.floor.stats.sigma

    def _observe(self) -> dict[str, np.ndarray]:
        last, floor = self._last, self._floor or self.floor
        angles = np.asarray(self.theta, dtype=np.float32) / np.float32(180.0)
        if self._layout is ObservationLayout.PICTURE:
            metrics = np.array([last.P_c / 100.0, last.P_len / (last.P_len + 100.0)], dtype=np.float32)
            return {"map": floor.picture, "angles": angles, "metrics": metrics}
        path = squash(last.P_len * floor.o_tile_m2 / floor.free_m2)
        r1 = min(max(last.R1 / 100.0, 0.0), 1.0)
        metrics = np.array([last.P_c / 100.0, last.coverage_free_pct / 100.0, path, r1], dtype=np.float32)
        return {"map": floor.picture, "angles": angles, "metrics": metrics, SCALE_KEY: floor.scale}

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
        self._floor = self._draw_floor()
        self._started = True
        start = (options or {}).get("theta", self.config.start_theta)
        if start is not None:  # options={"theta": ...}: the evaluation protocol's fixed starts
            try:
                Morphology.of(start)
            except (SmorphiError, TypeError, ValueError) as exc:
                raise EnvConfigError(f"reset option 'theta': {exc}") from None
            step = self.config.angle_step_deg  # a tie to 9 places is a tie: 0.35 / 0.1 is 3.4999999999999996
            i, j, k = (min(round(round(t / step, 9)), self._lattice_max) for t in start)
        else:
            i, j, k = (int(v) for v in self.np_random.integers(0, self._lattice_max + 1, size=3))
        self._idx = (i, j, k)
        self._steps = 0
        self._record(self._score_current(), first=True)
        return self._observe(), self._info()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if not self._started:  # gymnasium.make's wrapper refuses it too; a raw env played an episode of no reset
            raise gym.error.ResetNeeded("call reset() before step()")
        moves = action.tolist() if isinstance(action, np.ndarray) else list(action)
        if len(moves) != 3 or any(isinstance(m, bool | np.bool_) or m not in self._indices for m in moves):  # True == 1
            raise SmorphiError(f"action must be three values in 0..{2 * self._stay}, got {action!r}")
        moves = [int(m) for m in moves]  # 1.0 is the index 1
        self._steps += 1
        before = self._last
        truncated = self._steps >= self.config.max_steps
        if self._mode is RewardMode.COMMIT and all(m == self._stay for m in moves):
            # committing keeps the shape and ends the episode, paid the value of that one design
            return self._observe(), float(before.R1 / self.sigma_map), True, False, self._info()
        top, offsets = self._lattice_max, self._offsets
        i, j, k = (min(max(v + offsets[m], 0), top) for v, m in zip(self._idx, moves, strict=True))
        unchanged = (i, j, k) == self._idx
        self._idx = (i, j, k)
        scored = self._score_current()
        self._record(scored)
        stats = self._floor.stats  # type: ignore[union-attr]  # set by reset
        threshold = self.config.coverage_threshold
        terminated = threshold is not None and scored.P_c >= threshold
        if self._mode is RewardMode.PAPER:
            reward = scored.R1 - (self.config.beta if unchanged else 0.0)
        elif self._mode is RewardMode.LEVEL:
            reward = (scored.R1 - stats.mu) / stats.sigma - (0.0 if unchanged else self.config.move_cost)
        elif self._mode is RewardMode.PEAK:
            reward = stats.peak(scored.R1) - (0.0 if unchanged else self.config.move_cost)
        elif self._mode is RewardMode.IMPROVEMENT:
            reward = (scored.R1 - before.R1) / stats.sigma
        else:  # `commit`: an episode that ends without a commit is paid the design it ends on, as one that commits
            reward = -self.config.step_cost + (scored.R1 / stats.sigma if truncated or terminated else 0.0)
        return self._observe(), float(reward), bool(terminated), bool(truncated), self._info()

    def render(self) -> np.ndarray | None:  # type: ignore[override]  # gymnasium types it as any RenderFrame
        """`render_mode="rgb_array"`: the current floor as an RGB image, north up, at least RENDER_MIN_PX on its
        longer side: free white, occupied black, unknown grey, what the current shape covers green, its coverage
        path red (the colours of the figures). None, with gymnasium's warning, without a render mode."""
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: make the env with render_mode='rgb_array'")
            return None
        if not self._started:
            raise gym.error.ResetNeeded("call reset() before render()")
        return floor_image(self.grid_map, self.plan(self.theta))


RENDER_MIN_PX = 256
"""`render`'s image is scaled by whole cells to at least this many pixels on its longer side."""


def _rgb(colour: str) -> list[int]:
    return [int(colour[i : i + 2], 16) for i in (1, 3, 5)]


RENDER_COLOURS = np.array([_rgb(c) for c in CELL_COLOURS], dtype=np.uint8)
"""Free, occupied, unknown and covered cells (Cell's values, then covered): the figures' `maps.CELL_COLOURS`."""
RENDER_PATH = np.array(_rgb(PATH_COLOUR), dtype=np.uint8)


def floor_image(grid_map: Map, plan: CoverageResult) -> np.ndarray:
    """`grid_map` as an RGB image (rows north first) with `plan`'s covered free cells and its path between the
    footprint's centres; the path's points past the map's edge (the paper's planner may stand there) are left out."""
    codes = grid_map.cells.astype(np.intp)
    if plan.covered is not None:
        codes = np.where(plan.covered & (grid_map.cells == Cell.FREE), len(RENDER_COLOURS) - 1, codes)
    scale = max(1, -(-RENDER_MIN_PX // max(codes.shape)))
    image = np.repeat(np.repeat(RENDER_COLOURS[codes], scale, axis=0), scale, axis=1)
    if plan.placements is not None and len(plan.placements):
        l, w = plan.footprint_cells
        centres = (plan.placements + np.array([l / 2, w / 2])) * scale  # (row, col) in pixels, as path_points_m
        for a, b in itertools.pairwise(centres):
            n = int(np.abs(b - a).max()) + 1
            rows, cols = (np.rint(np.linspace(a[i], b[i], n)).astype(np.intp) for i in (0, 1))
            for dr, dc in ((0, 0), (1, 0), (0, 1), (1, 1))[: 4 if scale > 2 else 1]:  # 2 px wide where cells are
                r, c = rows + dr, cols + dc
                keep = (r >= 0) & (r < image.shape[0]) & (c >= 0) & (c < image.shape[1])
                image[r[keep], c[keep]] = RENDER_PATH
    return np.ascontiguousarray(image[::-1])  # row 0 of a map is its lowest y: north up

"""The env's configuration (`env_config`), validated once: the only home of the env's defaults. Kept apart from
the env itself so that the command line and the searches read its fields without importing gymnasium."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smorphi_rl.coverage import PLANNERS, Planner
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M, Morphology
from smorphi_rl.inputs import is_finite_number
from smorphi_rl.maps import SHIPPED_DEFAULT_MAP, Cell, Map
from smorphi_rl.score import PATH_TERMS, Weights, effective_w2

if TYPE_CHECKING:
    from smorphi_rl.planning import Planning  # loads the compiled kernels: imported where planning starts

DEFAULT_MAPS = (str(SHIPPED_DEFAULT_MAP),)
PLANNING_KEYS = ("block_side_m", "planner", "start_xy")
"""The keys `EnvConfig.planning` reads: a `planning.Planning`'s fields (a test holds them equal)."""


class RewardMode(str, Enum):
    """What an episode pays (docs/spec/env.md section 3, "Score and rewards")."""

    PAPER = "paper"
    LEVEL = "level"
    PEAK = "peak"
    IMPROVEMENT = "improvement"
    COMMIT = "commit"


REWARD_MODES = tuple(m.value for m in RewardMode)
DEFAULT_MOVE_COST = 0.0
"""`level`/`peak` move cost, off by default: 0.03 took PPO on map-1 from 30 to 47 % of the protocol's starts within
1 % but map-2 from 40 to 32 % with twice the median gap, and IMPALA's gaps grew on both (docs/decisions.md)."""


class ObservationLayout(str, Enum):
    """What the observation holds (docs/spec/env.md section 4)."""

    PICTURE = "picture"
    """The map as a picture of the known cells, the angles, P_c and P_len: the paper's, for one map or a few."""
    FLOOR = "floor"
    """The picture at its true aspect, the floor's scale against the block, its clearance at the block's scale,
    and metrics that mean the same on any floor size: for a policy that designs for floors it has not seen."""


LAYOUTS = tuple(m.value for m in ObservationLayout)
MAX_MOVE_SIZES = 4
"""At most this many step sizes per hinge (an action picks one of 2 K + 1 moves per hinge)."""
MIN_ANGLE_STEP = 0.1
"""Finer than a hobby servo resolves; the lattice is then 1,801^3 = 5.8 billion shapes."""


class EnvConfigError(SmorphiError):
    """An `env_config` key that is unknown or has a bad value."""


MAX_OBS_SIZE = 512
"""The map picture is at most 512 x 512 (the default 64): larger ones are a typo, and 10^7 asked for 728 TiB."""
MAX_EPISODE_STEPS = 100_000
"""An episode is at most this many steps (the paper's are 200): longer ones are a typo, and one roll-out of them
would run for minutes."""
MAX_WEIGHT = 1e6
"""R1's weights are at most this: far beyond any ranking, and R1 stays a number a table can print."""
MAX_RECORDED_MAPS = 1000
"""Map entries a policy or checkpoint may record: more than any run is trained on (a generator is one entry)."""


@dataclass(frozen=True)
class EnvConfig:
    """Everything the env takes, validated once; the only place its defaults live."""

    maps: tuple[str, ...] = DEFAULT_MAPS
    """Map files, folders, globs or `generate:KIND[:LO-HI]` floor generators (`map_sources.py`); one map is drawn
    per episode."""
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
    """Reward mode: peak (level with the top stretched: learns best, see docs/decisions.md), level (standardised R1 of
    each shape reached), paper (R1 + R2, for reproduction), improvement (R1 gained, scaled) or commit (R1 of the
    committed shape)."""
    step_cost: float = 0.0
    """`commit` mode: what every step that does not commit costs (in units of sigma_map)."""
    move_cost: float = DEFAULT_MOVE_COST
    """`level` and `peak` modes: what a step that changes the shape costs (in reward units). With nothing to
    gain, standing still then pays more than drifting over a plateau, so the policy settles (0: off)."""
    planner: str = Planner.PAPER.value
    """Coverage planner: paper (docs/spec/fbcpp.md; the robot may stand over obstacles) or fit (docs/fbcpp-fit.md)."""
    start_xy: tuple[float, float] | None = None
    """Where every coverage plan starts: a free point (x, y) in metres, map frame; None: the planner's default
    (paper: the first traversable tile; fit: in the largest free area)."""
    observation: str = ObservationLayout.PICTURE.value
    """Observation layout: picture (the map's picture, angles, P_c and P_len) or floor (adds the floor's scale and
    clearance against the block, for a policy that designs for unseen floors)."""
    moves: tuple[int, ...] = (1,)
    """Step sizes of a hinge move, in lattice steps: (1,) is the paper's -1/0/+1; (1, 4, 16) lets a policy cross
    the angle range in a few steps and still refine by one."""

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
        why = "(R1 rewards coverage and charges the path)"  # each weight named alone: the flag the user gave
        if not 0 < self.w1 <= MAX_WEIGHT:
            raise EnvConfigError(f"env_config 'w1' must be in (0, {MAX_WEIGHT:g}] {why}, got {self.w1:g}")
        if not 0 <= self.w2 <= MAX_WEIGHT:
            raise EnvConfigError(f"env_config 'w2' must be in [0, {MAX_WEIGHT:g}] {why}, got {self.w2:g}")
        for name in ("step_cost", "move_cost", "beta"):
            if not 0 <= getattr(self, name) <= MAX_WEIGHT:
                raise EnvConfigError(f"env_config '{name}' must be in [0, {MAX_WEIGHT:g}], got {getattr(self, name)}")
        if not self.maps:
            raise EnvConfigError("env_config 'maps': give at least one map")
        if self.observation not in LAYOUTS:
            raise EnvConfigError(f"env_config 'observation': unknown layout '{self.observation}' (choose from "
                                 f"{', '.join(LAYOUTS)})")  # fmt: skip
        step = self.angle_step_deg
        if not (MIN_ANGLE_STEP <= step <= 180 and math.isclose(180 / step, round(180 / step), abs_tol=1e-9)):
            raise EnvConfigError(f"env_config 'angle_step_deg' must divide 180 and be at least {MIN_ANGLE_STEP}, got "
                                 f"{step}")  # fmt: skip
        lattice = round(180 / step)  # the moves are checked against the step: a bad step is named first
        if not (
            1 <= len(self.moves) <= MAX_MOVE_SIZES
            and all(1 <= m <= lattice for m in self.moves)
            and list(self.moves) == sorted(set(self.moves))
        ):
            raise EnvConfigError(f"env_config 'moves' must be 1 to {MAX_MOVE_SIZES} increasing step sizes in "
                                 f"[1, {lattice}] lattice steps, got {list(self.moves)}")  # fmt: skip
        if not 1 <= self.max_steps <= MAX_EPISODE_STEPS:
            raise EnvConfigError(f"env_config 'max_steps' must be in 1..{MAX_EPISODE_STEPS:,}, got {self.max_steps}")
        if not 4 <= self.obs_size <= MAX_OBS_SIZE:
            raise EnvConfigError(f"env_config 'obs_size' must be in 4..{MAX_OBS_SIZE}, got {self.obs_size}")
        if self.coverage_threshold is not None and not 0 < self.coverage_threshold <= 100:
            raise EnvConfigError(f"env_config 'coverage_threshold' must be in (0, 100], got {self.coverage_threshold}")
        if self.block_side_m <= 0:
            raise EnvConfigError(f"env_config 'block_side_m' must be > 0, got {self.block_side_m}")
        self._check_generated()
        if self.start_theta is not None:
            try:
                Morphology.of(self.start_theta)
            except SmorphiError as exc:
                raise EnvConfigError(f"env_config 'start_theta': {exc}") from None

    def _check_generated(self) -> None:
        """What every `generate:` floor must allow, checked now: such a floor is first built when it is drawn, in an
        env runner mid-run, where a block too small for its cells or a start off its floor would stop training."""
        from smorphi_rl.map_sources import is_generator

        if not any(is_generator(m) for m in self.maps):
            return
        if self.start_xy is not None:
            raise EnvConfigError("env_config 'start_xy' cannot be used with generate: floors (a fixed point is free "
                                 "on some and not on others); leave it unset")  # fmt: skip
        from smorphi_rl.floorplans import DEFAULT_RANGE, MAX_BLOCK_SIDE_M

        fine, coarse = DEFAULT_RANGE.min_resolution_m, DEFAULT_RANGE.max_resolution_m
        if not coarse <= self.block_side_m <= MAX_BLOCK_SIDE_M:
            raise EnvConfigError(f"env_config 'block_side_m' must be in [{coarse:g}, {MAX_BLOCK_SIDE_M:g}] m with "
                                 f"generate: floors (a cell or more of every such floor, whose cells are {fine:g}-"
                                 f"{coarse:g} m, and a robot that every such floor holds), got "
                                 f"{self.block_side_m:g}")  # fmt: skip

    @classmethod
    def from_dict(cls, raw: dict[str, Any] | None) -> EnvConfig:
        """From the plain dict RLlib passes (its EnvContext's worker_index and the like are attributes, not keys); an
        unknown key is refused in one line naming the known ones."""
        raw = dict(raw or {})
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(raw) - set(known))
        if unknown:
            raise EnvConfigError(f"env_config: unknown key '{unknown[0]}' (known: {', '.join(known)})")
        values: dict[str, Any] = {}
        for name, value in raw.items():
            values[name] = _coerce(name, value)
        return cls(**values)

    @classmethod
    def recorded(cls, raw: dict[str, Any]) -> EnvConfig:
        """An env configuration a policy or checkpoint recorded: its maps are the files and floors its training
        resolved, named one by one, never a glob or folder to expand again (a file's list of globs read the whole
        disk each time it was loaded), and at most MAX_RECORDED_MAPS of them."""
        maps = raw.get("maps")
        entries = [maps] if isinstance(maps, str) else list(maps) if isinstance(maps, list | tuple) else []
        if len(entries) > MAX_RECORDED_MAPS:
            raise EnvConfigError(f"env_config 'maps' names {len(entries):,} maps, more than any run is trained on "
                                 f"({MAX_RECORDED_MAPS:,})")  # fmt: skip
        from smorphi_rl.map_sources import is_generator

        for entry in entries:
            text = str(entry)
            if not is_generator(text) and (any(ch in text for ch in "*?[") or Path(text).is_dir()):
                raise EnvConfigError(f"env_config 'maps' entry {text[:80]!r} is a glob or folder, which a policy "
                                     "never records (its maps are resolved when it is trained)")  # fmt: skip
        return cls.from_dict(raw)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def map_files(self) -> tuple[str, ...]:
        """The maps that are files (not floor generators)."""
        from smorphi_rl.map_sources import map_files

        return map_files(self.maps)

    def weights_on(self, grid_map: Map) -> Weights:
        """R1's weights in effect on `grid_map` (w2 after `path_term`)."""
        free_m2 = grid_map.counts[Cell.FREE] * grid_map.resolution_m**2
        return Weights(self.w1, effective_w2(self.w2, self.path_term, free_m2))

    @property
    def planning(self) -> Planning:
        """How this env plans every shape (block side, planner, start: PLANNING_KEYS)."""
        from smorphi_rl.planning import Planning

        return Planning(self.block_side_m, Planner(self.planner), self.start_xy)


def _coerce(name: str, value: Any) -> Any:
    """Check one env_config value's type; lists become tuples, numbers floats or ints (numpy's, and its arrays,
    as Python's: a value a user's code or a sampler computed)."""
    try:
        value = _pythons(value)
        if name == "maps":
            from smorphi_rl.map_sources import MapSourceError, resolve

            items = [value] if isinstance(value, str | Path) else list(value)
            try:
                return resolve([str(v) for v in items])
            except MapSourceError as exc:
                raise EnvConfigError(f"env_config 'maps': {exc}") from None
        if name == "moves":
            sizes: list[Any] = [value] if isinstance(value, int) else list(value)
            if any(isinstance(v, bool) or not isinstance(v, int | float) or int(v) != v for v in sizes):
                raise TypeError
            return tuple(int(v) for v in sizes)
        if name == "observation":
            if not isinstance(value, str | ObservationLayout):
                raise TypeError
            return ObservationLayout(value).value if value in LAYOUTS else str(value)
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
    except EnvConfigError:
        raise  # already names the problem (a ValueError too)
    except RecursionError:  # a crafted file's lists 900 deep: their repr would recurse too
        raise EnvConfigError(f"env_config '{name}': bad value (lists nested too deep)") from None
    except (TypeError, ValueError, OverflowError):  # OverflowError: int(inf), float of a 400-digit integer
        raise EnvConfigError(f"env_config '{name}': bad value {value!r}") from None


def _pythons(value: Any) -> Any:
    """`value` with numpy's scalars and arrays, at any depth of a list or tuple, as Python's."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    if isinstance(value, list | tuple):
        return [_pythons(v) for v in value]
    return value


def _real(value: Any) -> float:
    if not is_finite_number(value):
        raise TypeError
    return float(value)

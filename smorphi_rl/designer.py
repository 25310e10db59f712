"""The generalist designer as a user runs it: an exported policy, the floors it accepts, and its env on a map.

A designer was trained on a distribution of floors (`floorplans.py`) with the `floor` observation; it
accepts a floor whose scale features it can represent (the `accepts` limits in its policy.json: the known
area's sides, the resolution against the block) and refuses others in one line. Its policy.json also records the
sides of the floors it was trained on (`trained_sides_m`, written at export), so a floor outside them is warned of.
"""

from __future__ import annotations

import math
import shlex
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.design import DEFAULT_BUDGET, DESIGN_SEED, Design, run_design
from smorphi_rl.env_config import EnvConfig, EnvConfigError, ObservationLayout
from smorphi_rl.errors import MapError, SmorphiError
from smorphi_rl.floorplans import DEFAULT_RANGE
from smorphi_rl.inputs import is_finite_number
from smorphi_rl.map_sources import is_generator
from smorphi_rl.maps import Cell, Map, check_fits, load_map
from smorphi_rl.numpy_policy import NumpyPolicy
from smorphi_rl.policy_file import SHIPPED_DESIGNER, PolicyFile, layout_problem, read_policy
from smorphi_rl.score import Scored, degenerate_warning

ACCEPTS = {"max_side_m": 20.0, "min_cells_per_block": 1.0, "max_cells_per_block": 4.0, "max_free_m2": 200.0}
"""What the `floor` observation's scale features represent without saturating (`env.floor_scale`): a known area
up to 20 m a side and 200 m^2 free, a block of 1 to 4 cells."""
TRAINED_SIDES_KEY = "trained_sides_m"
"""policy.json's [least, greatest] side in metres of the known area of the floors the policy was trained on."""


@dataclass(frozen=True)
class Designer:
    """A policy read for designing: its files, its NumPy net and the env configuration it was trained for."""

    policy: PolicyFile
    net: NumpyPolicy
    env_config: EnvConfig
    trained_sides: tuple[float, float] | None = None
    """The least and greatest side of the floors it was trained on (`sides_trained_on`); None: not known."""

    @property
    def path(self) -> Path:
        return self.policy.path

    @property
    def summary(self) -> str:
        """One line for reports: the algorithm and what it was trained on."""
        model = self.policy.model_config
        trained = self.policy.meta.get("trained")  # what its shipping recorded, if anything: read, never required
        steps = trained.get("env_steps") if isinstance(trained, dict) else None
        start = trained.get("pretrained") if isinstance(trained, dict) else None
        text = f"{str(model.get('algorithm', 'policy')).upper()}"
        if isinstance(steps, int):
            text += f", {steps:,} env steps"
        maps = self.env_config.maps
        text += f" on {', '.join(maps[:2])}{' ...' if len(maps) > 2 else ''}"
        return text + (f", fine-tuned from {Path(start).name}" if isinstance(start, str) and start else "")

    def logits(self, observations: Any) -> np.ndarray:
        """The policy's action logits for a batch of observations (what `design.run_design` takes)."""
        return np.stack([self.net.logits(o) for o in observations])


def load_designer(path: Path) -> Designer:
    """The policy in `path` (an exported folder) ready to design; refused in one line if it is not one."""
    policy = read_policy(path)
    raw = policy.env_config
    if not raw:
        raise SmorphiError(f"{path}: the policy carries no env configuration")
    try:
        env_config = EnvConfig.recorded(raw)
    except EnvConfigError as exc:
        raise SmorphiError(f"{path}: the policy's {exc}") from None
    frequencies = int(policy.model_config.get("policy_angle_frequencies", 8))
    try:
        net = NumpyPolicy(policy.weights, policy.action_nvec, frequencies, policy.observation_shapes)
    except SmorphiError as exc:  # its layers: the folder named, as for its description
        raise SmorphiError(f"{path}: {exc}") from None
    return Designer(policy, net, env_config, _recorded_sides(policy, env_config))


def _recorded_sides(policy: PolicyFile, env_config: EnvConfig) -> tuple[float, float] | None:
    """The training floors' sides policy.json records; for a policy exported before it recorded them, its generated
    floors' range (their sides are drawn from `floorplans.DEFAULT_RANGE`; map files are not read again)."""
    given = policy.meta.get(TRAINED_SIDES_KEY)
    if given is None:
        generated = bool(env_config.maps) and all(is_generator(m) for m in env_config.maps)
        return sides_trained_on(env_config.maps) if generated else None
    if not (isinstance(given, list) and len(given) == 2 and all(is_finite_number(v) and v > 0 for v in given)
            and given[0] <= given[1]):  # fmt: skip
        raise SmorphiError(f"{policy.path}: its policy.json's '{TRAINED_SIDES_KEY}' must be [least, greatest] side "
                           "in metres, two positive numbers")  # fmt: skip
    return float(given[0]), float(given[1])


def sides_trained_on(maps: Iterable[str]) -> tuple[float, float] | None:
    """The least and greatest side of the known area of the floors `maps` names (a generator's drawn range, a map
    file's measured), recorded at export; None when a map file cannot be read, so the range is not known."""
    lows, highs = [], []
    for entry in maps:
        if is_generator(entry):
            lows.append(DEFAULT_RANGE.min_side_m)
            highs.append(DEFAULT_RANGE.max_side_m)
            continue
        try:
            sides = load_map(entry).known_sides_m()
        except (MapError, OSError):
            return None
        lows.append(min(sides))
        highs.append(max(sides))
    return (round(min(lows), 3), round(max(highs), 3)) if lows else None


def accepts(designer: Designer, grid_map: Map, map_path: str | Path | None = None) -> None:
    """Refuse, naming the limit, a floor the designer's observation cannot represent; given the map's file, with the
    `maps resample` or `maps crop` command that makes one it can (a crop holding as much free floor as fits)."""
    given = designer.policy.meta.get("accepts") or {}
    if not isinstance(given, dict) or not all(k in ACCEPTS and is_finite_number(v) and v > 0 for k, v in given.items()):
        raise SmorphiError(f"{designer.path}: its policy.json's 'accepts' must map {', '.join(ACCEPTS)} to positive "
                           "numbers")  # fmt: skip
    limits = {**ACCEPTS, **given}
    least, most = limits["min_cells_per_block"], limits["max_cells_per_block"]
    if least > most:
        raise SmorphiError(f"{designer.path}: its policy.json's 'accepts' has min_cells_per_block {least:g} over "
                           f"max_cells_per_block {most:g}")  # fmt: skip
    r = grid_map.resolution_m
    sides = grid_map.known_sides_m()
    cells_per_block = designer.env_config.block_side_m / r
    free_m2 = grid_map.counts[Cell.FREE] * r * r
    name = grid_map.name
    if not limits["min_cells_per_block"] <= cells_per_block <= limits["max_cells_per_block"]:
        lo = designer.env_config.block_side_m / limits["max_cells_per_block"]
        hi = designer.env_config.block_side_m / limits["min_cells_per_block"]
        k = math.ceil(lo / r - 1e-9)  # the finest whole multiple of the map's cell the designer represents
        if r < lo and k * r <= hi:
            fix = f" (`{_command('resample', map_path, f'--resolution {round(k * r, 12):.12g}')}` coarsens it)"
        elif r < lo:
            fix = " (`maps resample` coarsens a finer map, to a whole multiple of its cell)"
        else:
            fix = f" (a map cannot be made finer: record or save the floor at {hi:.4g} m a cell or finer)"
        raise SmorphiError(f"{name}: resolution {r:g} m; this designer represents {lo:.4g}-{hi:.4g} m a cell{fix}")
    wide, large = max(sides) > limits["max_side_m"], free_m2 > limits["max_free_m2"]
    if wide or large:  # both limits named at once: a crop that meets one may still break the other
        over = " and ".join(
            text for text, past in ((f"its known area is {max(sides):.1f} m across", wide),
                                    (f"it holds {free_m2:.0f} m^2 of free floor", large)) if past
        )  # fmt: skip
        x0, y0, x1, y1 = fitting_rect(grid_map, limits["max_side_m"], limits["max_free_m2"])
        rect = " ".join(f"{v + 0.0:.6f}".rstrip("0").rstrip(".") for v in (x0, y0, x1, y1))  # + 0.0: no "-0"
        crop = _command("crop", map_path, f"--rect {rect}")
        raise SmorphiError(f"{name}: {over}; this designer takes floors up to {limits['max_side_m']:g} m across "
                           f"holding up to {limits['max_free_m2']:g} m^2 of free floor (cut a part of it: `{crop}` "
                           "keeps a part that fits; --rect is X0 Y0 X1 Y1, metres in the map "
                           "frame)")  # fmt: skip


def _command(tool: str, map_path: str | Path | None, option: str) -> str:
    """`smorphi-rl maps TOOL MAP OPTION --out NEW`, the map named by its file (MAP where none is known), quoted for a
    shell."""
    where = "MAP" if map_path is None else shlex.quote(str(map_path))
    out = "NEW.yaml" if map_path is None else f"{Path(map_path).stem}-{'crop' if tool == 'crop' else 'coarse'}.yaml"
    return f"smorphi-rl maps {tool} {where} {option} --out {shlex.quote(out)}"


def fitting_rect(grid_map: Map, max_side_m: float, max_free_m2: float) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1), metres in the map frame on cell edges, of a rectangle inside the known area at most
    `max_side_m` a side and holding at most `max_free_m2` of free floor: of those tried (12 heights by 12 widths,
    each at places a quarter of it apart), the one holding the most free floor."""
    r = grid_map.resolution_m
    r0, r1, c0, c1 = grid_map.known_box()
    side = max(1, math.floor(max_side_m / r + 1e-9))
    most = max(1, math.floor(max_free_m2 / (r * r) + 1e-9))  # free cells
    total = np.pad(np.cumsum(np.cumsum(grid_map.cells == Cell.FREE, axis=0), axis=1), ((1, 0), (1, 0)))
    best = (-1, r0, c0, 1, 1)
    heights = np.unique(np.linspace(1, min(r1 - r0, side), 12).round().astype(int))
    widths = np.unique(np.linspace(1, min(c1 - c0, side), 12).round().astype(int))
    for h in heights[::-1]:
        for w in widths[::-1]:
            if h * w <= best[0]:  # holds no more free cells than the best found
                continue
            rows = np.unique(np.append(np.arange(r0, r1 - h + 1, max(1, h // 4)), r1 - h))
            cols = np.unique(np.append(np.arange(c0, c1 - w + 1, max(1, w // 4)), c1 - w))
            free = (total[np.ix_(rows + h, cols + w)] - total[np.ix_(rows, cols + w)] - total[np.ix_(rows + h, cols)]
                    + total[np.ix_(rows, cols)])  # fmt: skip
            free = np.where(free <= most, free, -1)
            at = np.unravel_index(int(np.argmax(free)), free.shape)
            if free[at] > best[0]:
                best = (int(free[at]), int(rows[at[0]]), int(cols[at[1]]), int(h), int(w))
    _, i, j, h, w = best
    ox, oy = grid_map.origin[0], grid_map.origin[1]
    return (_edge(ox, j, r, True), _edge(oy, i, r, True), _edge(ox, j + w, r, False), _edge(oy, i + h, r, False))


def _edge(origin: float, cells: int, r: float, low: bool) -> float:
    """The map-frame coordinate of a cell edge, to 6 decimals at most, that `maps crop --rect` reads as that edge: the
    plain rounded value where it does, else one rounded inward (`crop_to_rect` rounds outward)."""
    exact = origin + cells * r
    clean = round(exact, 6)
    at = (clean - origin) / r
    if (math.floor(at + 1e-9) if low else math.ceil(at - 1e-9)) == cells:
        return clean
    return (math.ceil if low else math.floor)(exact * 1e6) / 1e6


def unfamiliar_warning(designer: Designer, grid_map: Map) -> str | None:
    """A warning when the floor's known area is smaller or larger than every floor the designer was trained on: it
    accepts such a floor, but nothing measured says how near the best its design lies there."""
    trained = designer.trained_sides
    if trained is None:
        return None
    lo, hi = trained
    sides = grid_map.known_sides_m()
    r = grid_map.resolution_m  # a side counts whole cells: a 15 m floor at 0.08 m spans 188 of them, 15.04 m
    if lo - r <= min(sides) and max(sides) <= hi + r:
        return None
    return (f"warning: {grid_map.name}: its known area is {sides[1]:.1f} x {sides[0]:.1f} m; this designer was "
            f"trained on floors {lo:g}-{hi:g} m a side, so its design may lie further from the best than on "
            "those")  # fmt: skip


def designer_env(designer: Designer, map_path: str, start_xy: tuple[float, float] | None = None) -> Any:
    """The designer's env on one map (its planner, weights, moves and episode length), checked to fit it; plans start
    at `start_xy` (metres, map frame) where given, else where the designer's configuration says."""
    from smorphi_rl.env import MorphologyEnv

    if designer.env_config.observation != ObservationLayout.FLOOR.value:
        raise SmorphiError(f"{designer.path}: a designer sees the 'floor' observation; this policy was trained on "
                           f"'{designer.env_config.observation}' (evaluate it with evaluate-policy)")  # fmt: skip
    grid_map = load_map(map_path)
    whole = designer.env_config.planner == "fit"
    accepts(designer, grid_map, map_path)  # first: a cell coarser than a block is said with the designer's range
    check_fits(grid_map, designer.env_config.block_side_m, whole_footprint=whole)  # said of the map, not the env
    config = replace(designer.env_config, maps=EnvConfig.from_dict({"maps": [map_path]}).maps, reward="paper")
    config = config if start_xy is None else replace(config, start_xy=start_xy)
    env = MorphologyEnv(config.to_dict())  # `paper`: no reward scales to compute, so no planner calls for them
    have = {k: tuple(s.shape) for k, s in env.observation_space.spaces.items()}  # type: ignore[attr-defined]
    env_moves = [int(n) for n in env.action_space.nvec]  # type: ignore[attr-defined]
    problem = layout_problem(designer.policy.observation_shapes, have, list(designer.policy.action_nvec), env_moves)
    if problem:
        raise SmorphiError(f"{designer.path}: {problem}")
    return env


def design_map(
    map_path: str | Path,
    budget: int = DEFAULT_BUDGET,
    policy: str | Path | None = None,
    start_xy: tuple[float, float] | None = None,
    seed: int = DESIGN_SEED,
) -> Design:
    """A designer's shape for one map file, as `smorphi-rl design` finds it: the shipped designer (or the exported
    policy at `policy`) walked for `budget` planner evaluations, then compass search (`design.run_design`). Its
    `best` holds the shape and its scores under the designer's own weights (`path_term: per_area`)."""
    designer = load_designer(Path(policy) if policy is not None else SHIPPED_DESIGNER)
    env = designer_env(designer, str(map_path), start_xy)
    for text in env.grid_map.warnings():  # before the design, which costs the whole frame: as the command says it
        warnings.warn(text, UserWarning, stacklevel=2)
    design = run_design(env, designer.logits, budget, seed=seed)
    for text in filter(None, design_warnings(designer, env, design.best)):
        warnings.warn(text, UserWarning, stacklevel=2)  # what the command prints on stderr
    return design


def design_warnings(designer: Designer, env: Any, best: Scored) -> tuple[str | None, str | None]:
    """What a design's figures do not say: a floor unlike those the designer was trained on, and a start that cannot
    reach most of the floor or weights under which the best shape is degenerate (None where there is nothing)."""
    planning, grid_map = env.config.planning, env.grid_map
    return unfamiliar_warning(designer, grid_map), planning.start_warning(grid_map, best.coverage_free_pct) or (
        degenerate_warning(env.floor.weights, best.P_c, best.P_len, env.config.path_term, grid_map.name)
    )

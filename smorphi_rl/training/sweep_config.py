"""Sweep files (`tune_configs/*.yaml`): our small schema, validated before Ray starts. No Ray here.

A sweep is the grid algorithms x map sets x seeds x the grid parts of `search`, each grid point
sampled `num_samples` times for the random parts (choice, uniform, loguniform). Every problem
names the file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from smorphi_rl.env import EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.presets import ALGORITHMS, PRESETS

SPACE_KINDS = ("grid", "choice", "uniform", "loguniform")
ALIASES = {"lambda": "lambda_"}
"""YAML names that differ from the Preset field (RLlib's `lambda_`)."""
KEYS = {
    "name": "the experiment's name: its folder under --log-dir (default: the file's name)",
    "algorithms": "list of ppo, impala, appo",
    "maps": "list; each item a map file, or a list of map files that one policy trains on together",
    "seeds": "list of non-negative integers",
    "timesteps": "env steps each trial trains for",
    "preset": "fast or paper: the hyperparameters the search space starts from",
    "stop": "extra stop criteria, {metric: value} as Ray Tune takes them, e.g. time_total_s: 600",
    "checkpoint": "{every: iterations between checkpoints, keep: how many to keep (0: all)}",
    "env": "env_config overrides (max_steps, w1, w2, ...), the same for every trial",
    "search": "{hyperparameter: value or {grid|choice|uniform|loguniform: ...}}",
    "num_samples": "samples of the random search parts per grid point",
    "pretrained": "a checkpoint every trial fine-tunes from",
    "max_iterations": "also stop each trial after this many iterations (smoke runs)",
    "record_every": "record every Nth episode of each env to MCAP in the trial's episodes/ (0: off)",
}


class SweepConfigError(SmorphiError):
    """A sweep file that cannot be used, with the file and key named."""


@dataclass(frozen=True)
class Space:
    """One hyperparameter's values: a constant, or a grid / choice list, or a uniform / loguniform range."""

    kind: str
    values: tuple[Any, ...]

    def to_tune(self) -> Any:
        """The Ray Tune search-space object (imported here only, when the sweep runs)."""
        from ray import tune

        if self.kind == "constant":
            return self.values[0]
        if self.kind == "grid":
            return tune.grid_search(list(self.values))
        if self.kind == "choice":
            return tune.choice(list(self.values))
        return getattr(tune, self.kind)(*self.values)

    def examples(self) -> list[Any]:
        """Values to validate against the algorithms (ranges: both ends)."""
        return list(self.values)


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep file."""

    path: Path
    name: str
    algorithms: tuple[str, ...]
    map_sets: tuple[tuple[str, ...], ...]
    seeds: tuple[int, ...]
    timesteps: int = TrainConfig.timesteps
    preset: str = TrainConfig.preset
    stop: dict[str, float] = field(default_factory=dict)
    checkpoint_every: int = TrainConfig.checkpoint_every
    checkpoint_keep: int = 0
    env: dict[str, Any] = field(default_factory=dict)
    search: dict[str, Space] = field(default_factory=dict)
    num_samples: int = 1
    pretrained: str | None = None
    max_iterations: int | None = None
    record_every: int = TrainConfig.record_every

    @property
    def num_grid_trials(self) -> int:
        """Trials before random sampling: algorithms x map sets x seeds x grid points, times num_samples."""
        grid = math.prod(len(s.values) for s in self.search.values() if s.kind == "grid")
        return len(self.algorithms) * len(self.map_sets) * len(self.seeds) * grid * self.num_samples

    def base_config(self, algo: str, maps: tuple[str, ...], seed: int, overrides: dict[str, Any]) -> TrainConfig:
        """The TrainConfig of one trial."""
        env = EnvConfig.from_dict({**self.env, "maps": list(maps)})
        return TrainConfig(algo=algo, env=env, timesteps=self.timesteps, seed=seed, preset=self.preset,
                           checkpoint_every=self.checkpoint_every, pretrained=self.pretrained,
                           max_iterations=self.max_iterations, overrides=overrides,
                           record_every=self.record_every)  # fmt: skip


STOP_METRICS = (keys.TIME_TOTAL, keys.ITERATION, keys.STEPS, keys.TIMESTEPS_TOTAL)
"""Stop criteria a sweep may give (Ray Tune ignores an unknown metric silently: a typo would never stop)."""
MAX_TRIALS = 10_000
"""More trials than any machine or cluster of ours runs; a larger grid is a typo (it would create the folders)."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (the second would silently win)."""


def _no_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and validate a sweep file; SweepConfigError names the file and the key."""
    file = Path(path)
    where = str(path)
    try:
        raw = yaml.load(file.read_text(), Loader=_UniqueKeyLoader)
    except FileNotFoundError:
        raise SweepConfigError(f"{where}: no such sweep file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SweepConfigError(f"{where}: cannot read ({exc.__class__.__name__})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", "") or ""
        detail = f" ({problem})" if problem.startswith("duplicate key") else ""
        raise SweepConfigError(f"{where}: not valid YAML{at}{detail}") from None
    if not isinstance(raw, dict):
        raise SweepConfigError(f"{where}: expected a mapping of keys ({', '.join(KEYS)})")

    def fail(key: str, message: str) -> SweepConfigError:
        return SweepConfigError(f"{where}: key '{key}': {message}")

    for key in raw:
        if key not in KEYS:
            raise fail(str(key), f"unknown key (known: {', '.join(KEYS)})")
    for key in ("algorithms", "maps", "seeds"):
        if key not in raw:
            raise fail(key, f"missing ({KEYS[key]})")

    algorithms = tuple(_list(raw["algorithms"], "algorithms", fail, str))
    for a in algorithms:
        if a not in ALGORITHMS:
            raise fail("algorithms", f"unknown algorithm '{a}' (choose from {', '.join(ALGORITHMS)})")
    items = _list(raw["maps"], "maps", fail)
    map_sets = tuple(_map_set(item, f"maps[{i}]", file, fail) for i, item in enumerate(items))
    seeds = tuple(_list(raw["seeds"], "seeds", fail, int))
    if any(s < 0 for s in seeds):
        raise fail("seeds", "seeds must be non-negative")
    preset = raw.get("preset", TrainConfig.preset)
    if preset not in PRESETS:
        raise fail("preset", f"unknown preset {preset!r} (choose from {', '.join(PRESETS)})")
    checkpoint = raw.get("checkpoint") or {}
    if not isinstance(checkpoint, dict) or set(checkpoint) - {"every", "keep"}:
        raise fail("checkpoint", KEYS["checkpoint"])
    stop = raw.get("stop") or {}
    if not isinstance(stop, dict) or not all(_is_number(v) for v in stop.values()):
        raise fail("stop", KEYS["stop"])
    unknown_stop = sorted(str(k) for k in stop if k not in STOP_METRICS)
    if unknown_stop:
        raise fail("stop", f"unknown metric '{unknown_stop[0]}' (known: {', '.join(STOP_METRICS)})")
    env = raw.get("env") or {}
    if not isinstance(env, dict):
        raise fail("env", KEYS["env"])
    if "maps" in env:
        raise fail("env.maps", "give maps at the top level ('maps')")
    try:
        EnvConfig.from_dict({**env, "maps": list(map_sets[0])})
    except SmorphiError as exc:
        raise fail("env", str(exc)) from None
    search = raw.get("search") or {}
    if not isinstance(search, dict):
        raise fail("search", KEYS["search"])
    spaces = {ALIASES.get(str(k), str(k)): _space(v, f"search.{k}", fail) for k, v in search.items()}
    pretrained = raw.get("pretrained")
    if pretrained is not None and not isinstance(pretrained, str):
        raise fail("pretrained", "a checkpoint path")
    cfg = SweepConfig(
        path=file,
        name=_name(raw.get("name", file.stem), fail),
        algorithms=algorithms,
        map_sets=map_sets,
        seeds=seeds,
        timesteps=_positive(raw.get("timesteps", TrainConfig.timesteps), "timesteps", fail),
        preset=preset,
        stop={str(k): float(v) for k, v in stop.items()},
        checkpoint_every=_positive(checkpoint.get("every", TrainConfig.checkpoint_every), "checkpoint.every", fail),
        checkpoint_keep=_positive(checkpoint.get("keep", 0), "checkpoint.keep", fail, zero=True),
        env=env,
        search=spaces,
        num_samples=_positive(raw.get("num_samples", 1), "num_samples", fail),
        pretrained=pretrained,
        max_iterations=None if raw.get("max_iterations") is None else _positive(raw["max_iterations"],
                                                                               "max_iterations", fail),
        record_every=_positive(raw.get("record_every", TrainConfig.record_every), "record_every", fail, zero=True),
    )  # fmt: skip
    if cfg.num_grid_trials > MAX_TRIALS:
        raise fail("num_samples", f"{cfg.num_grid_trials:,} trials; at most {MAX_TRIALS:,} (a typo?)")
    for algo in algorithms:  # every value of every space must suit every algorithm
        for key, space in spaces.items():
            for value in space.examples():
                try:
                    cfg.base_config(algo, map_sets[0], seeds[0], {key: value})
                except SmorphiError as exc:
                    raise fail(f"search.{key}", str(exc)) from None
    return cfg


def _list(value: Any, key: str, fail: Any, kind: type | None = None) -> list[Any]:
    if not isinstance(value, list) or not value:
        raise fail(key, "expected a non-empty list")
    if kind is not None:
        for v in value:
            if isinstance(v, bool) or not isinstance(v, kind):
                raise fail(key, f"expected {kind.__name__} items, got {v!r}")
    return value


def _map_set(item: Any, key: str, file: Path, fail: Any) -> tuple[str, ...]:
    """One trial's maps: a path or a list of paths, resolved against the working directory, then the file's."""
    items = _list(item, key, fail, str) if isinstance(item, list) else [item]
    out = []
    for p in items:
        if not isinstance(p, str):
            raise fail(key, f"expected a map path, got {p!r}")
        candidates = [Path(p), file.parent / p]
        found = next((c for c in candidates if c.is_file()), None)
        if found is None:
            raise fail(key, f"map file '{p}' not found (looked in the working directory and next to the sweep file)")
        out.append(str(found.resolve()))
    return tuple(out)


def _space(value: Any, key: str, fail: Any) -> Space:
    if _is_number(value):
        return Space("constant", (value,))
    if not isinstance(value, dict) or len(value) != 1 or next(iter(value)) not in SPACE_KINDS:
        raise fail(key, f"expected a number or one of {{{' | '.join(SPACE_KINDS)}: ...}}, got {value!r}")
    ((kind, args),) = value.items()
    if not isinstance(args, list) or not args or not all(_is_number(a) for a in args):
        raise fail(key, f"{kind} takes a list of numbers, got {args!r}")
    if kind in ("uniform", "loguniform"):
        if len(args) != 2 or not args[0] < args[1] or (kind == "loguniform" and args[0] <= 0):
            raise fail(key, f"{kind} takes [low, high] with low < high{' and low > 0' if kind == 'loguniform' else ''}")
        args = [float(a) for a in args]
    return Space(kind, tuple(args))


def _is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)


def _positive(value: Any, key: str, fail: Any, zero: bool = False) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < (0 if zero else 1):
        raise fail(key, f"expected a {'non-negative' if zero else 'positive'} integer, got {value!r}")
    return value


def _name(value: Any, fail: Any) -> str:
    from smorphi_rl.rundir import RUN_NAME

    if not isinstance(value, str) or not RUN_NAME.fullmatch(value):
        raise fail("name", f"expected a plain folder name (letters, digits and _ . + -, not first; no / or ..), "
                           f"got {value!r}")  # fmt: skip
    return value

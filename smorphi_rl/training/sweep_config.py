"""Sweep files (`tune_configs/*.yaml`): our small schema, validated before Ray starts. No Ray here.

A sweep is the grid algorithms x map sets x seeds x the grid parts of `search`, each grid point
sampled `num_samples` times for the random parts (choice, uniform, loguniform). Every problem
names the file and the key.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, get_args, get_origin

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from smorphi_rl.config_fields import field_docs
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.inputs import (
    MAX_SEED,
    MAX_YAML_BYTES,
    check_not_special,
    first_repeat,
    is_finite_number,
    strict_yaml,
)
from smorphi_rl.map_sources import is_generator, map_set_label, name_clash
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.config import INTEGER_HYPERPARAMETERS, TrainConfig
from smorphi_rl.training.presets import ALGORITHMS, PRESETS

SPACE_KINDS = ("grid", "choice", "uniform", "loguniform")
_DOCS = field_docs(TrainConfig)
ALIASES = {"lambda": "lambda_"}
"""YAML names that differ from the Preset field (RLlib's `lambda_`)."""


class _Checkpoint(BaseModel):
    """The sweep file's `checkpoint` mapping."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)
    every: int = Field(TrainConfig.checkpoint_every, ge=1, description=_DOCS["checkpoint_every"])
    keep: int = Field(0, ge=0, description="how many to keep (0: all)")


class _Evaluation(BaseModel):
    """The sweep file's `evaluation` mapping: the protocol every trial runs, as `train` runs it."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)
    every: int = Field(TrainConfig.eval_every, ge=1, description="iterations between evaluations (every trial is "
                       "evaluated: at least 1)")  # fmt: skip
    starts: int = Field(TrainConfig.eval_starts, ge=1, description=_DOCS["eval_starts"])
    select_starts: int = Field(TrainConfig.select_starts, ge=0, description=_DOCS["select_starts"])
    maps: list[str] = Field(default_factory=list, description=_DOCS["eval_maps"])
    design_budget: int = Field(TrainConfig.design_budget, ge=0, description=_DOCS["design_budget"])


DEFAULT_EVALUATION = _Evaluation(
    every=TrainConfig.eval_every,
    starts=TrainConfig.eval_starts,
    select_starts=TrainConfig.select_starts,
    design_budget=TrainConfig.design_budget,
)


class SweepFile(BaseModel):
    """The sweep file's keys, types and ranges (unknown keys refused). The checks that need more than a type (map
    files, stop metrics, env values, search spaces against the algorithms) follow in `load_sweep`."""

    model_config = ConfigDict(extra="forbid", strict=True)
    name: str | None = Field(None, description="the experiment's name: its folder under --log-dir (default: the "
                                               "file's name)")  # fmt: skip
    algorithms: list[str] = Field(min_length=1, description=f"list of {', '.join(ALGORITHMS)}")
    maps: list[Any] = Field(min_length=1, description="list; each item a map file, or a list of map files that "
                                                      "one policy trains on together")  # fmt: skip
    seeds: list[Annotated[int, Field(ge=0, le=MAX_SEED)]] = Field(min_length=1, description="list of whole numbers "
                                                                  "in [0, 2^32-1]")  # fmt: skip
    timesteps: int = Field(TrainConfig.timesteps, ge=1, description=_DOCS["timesteps"])
    preset: str = Field(TrainConfig.preset, description=f"{_DOCS['preset']} The search space starts from it.")
    stop: dict[str, Annotated[float, Field(allow_inf_nan=False)]] = Field(
        default_factory=dict,
        description="extra stop criteria, {metric: value} as Ray Tune takes them, e.g. time_total_s: 600",
    )
    checkpoint: _Checkpoint = Field(
        _Checkpoint(every=TrainConfig.checkpoint_every, keep=0),
        description="{every: iterations between checkpoints, keep: how many to keep (0: all)}",
    )
    env: dict[str, Any] = Field(default_factory=dict, description="env_config overrides (max_steps, w1, w2, "
                                                                  "...), the same for every trial")  # fmt: skip
    search: dict[str, Any] = Field(default_factory=dict, description="{hyperparameter: value or "
                                   "{grid|choice|uniform|loguniform: ...}}")  # fmt: skip
    num_samples: int = Field(1, ge=1, description="samples of the random search parts per grid point")
    pretrained: str | None = Field(None, description="a checkpoint every trial fine-tunes from")
    max_iterations: int | None = Field(TrainConfig.max_iterations, ge=1, description=_DOCS["max_iterations"])
    record_every: int = Field(TrainConfig.record_every, ge=0, description=_DOCS["record_every"])
    evaluation: _Evaluation = Field(DEFAULT_EVALUATION, description="{every, starts, select_starts, maps, "
                                    "design_budget}: every trial's evaluation protocol, as train runs it")  # fmt: skip
    env_runners: int | None = Field(None, ge=0, description=_DOCS["num_env_runners"])
    envs_per_runner: int = Field(TrainConfig.envs_per_runner, ge=1, description=_DOCS["envs_per_runner"])


KEYS = {name: field.description or "" for name, field in SweepFile.model_fields.items()}
"""Every key a sweep file may give, with what it means (the schema's own descriptions)."""


class SweepConfigError(SmorphiError):
    """A sweep file that cannot be used, with the file and key named."""


@dataclass(frozen=True)
class Space:
    """One hyperparameter's values: a constant, or a grid / choice list, or a uniform / loguniform range."""

    kind: str
    values: tuple[Any, ...]

    def draw(self, rng: np.random.Generator) -> Any:
        """One value of a constant, choice, uniform or loguniform space (a grid is expanded by `trials`)."""
        if self.kind == "constant":
            return self.values[0]
        if self.kind == "choice":
            return self.values[int(rng.integers(len(self.values)))]
        lo, hi = self.values
        if self.kind == "uniform":
            return float(rng.uniform(lo, hi))
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))

    def examples(self) -> list[Any]:
        """Values to validate against the algorithms (ranges: both ends)."""
        return list(self.values)


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep file, resolved (map paths found, search spaces parsed); its defaults are SweepFile's."""

    path: Path
    name: str
    algorithms: tuple[str, ...]
    map_sets: tuple[tuple[str, ...], ...]
    seeds: tuple[int, ...]
    timesteps: int
    preset: str
    stop: dict[str, float]
    checkpoint_every: int
    checkpoint_keep: int
    env: dict[str, Any]
    search: dict[str, Space]
    num_samples: int
    pretrained: str | None
    max_iterations: int | None
    record_every: int
    evaluation: _Evaluation = DEFAULT_EVALUATION
    env_runners: int | None = None
    envs_per_runner: int = TrainConfig.envs_per_runner

    @property
    def step_budget(self) -> int:
        """The env steps a trial runs for: `timesteps`, or a `stop` on env steps below it (what the progress line
        counts to, and what a run that never converged is reported past)."""
        caps = [math.ceil(v) for k, v in self.stop.items() if k in (keys.STEPS, keys.TIMESTEPS_TOTAL)]
        return min([self.timesteps, *caps])

    @property
    def num_grid_trials(self) -> int:
        """Trials before random sampling: algorithms x map sets x seeds x grid points, times num_samples."""
        grid = math.prod(len(s.values) for s in self.search.values() if s.kind == "grid")
        return len(self.algorithms) * len(self.map_sets) * len(self.seeds) * grid * self.num_samples

    def trials(self) -> list[dict[str, Any]]:
        """Every trial of the sweep, in order: {index, algo, maps, seed, hp}, the random parts drawn here from
        `SAMPLE_SEED` (not by Tune), so a resumed sweep finds the same trials under the same indices. A sample's draw
        depends on its grid point and number alone: every seed, algorithm and map set gets the same values, so its
        seeds form one group over which the tables give intervals."""
        names = sorted(self.search)
        grids = [self.search[k].values if self.search[k].kind == "grid" else (None,) for k in names]
        points = list(enumerate(itertools.product(*grids)))
        out: list[dict[str, Any]] = []
        for algo, maps, seed, (p, point) in itertools.product(self.algorithms, self.map_sets, self.seeds,
                                                              points):  # fmt: skip
            for sample in range(self.num_samples):
                rng = np.random.default_rng([SAMPLE_SEED, p, sample])
                hp = {k: v if self.search[k].kind == "grid" else self.search[k].draw(rng)
                      for k, v in zip(names, point, strict=True)}  # fmt: skip
                out.append({"index": len(out), "algo": algo, "maps": list(maps), "seed": seed, "hp": hp})
        return out

    def base_config(self, algo: str, maps: tuple[str, ...], seed: int, overrides: dict[str, Any]) -> TrainConfig:
        """The TrainConfig of one trial."""
        env = EnvConfig.from_dict({**self.env, "maps": list(maps)})
        ev = self.evaluation
        return TrainConfig(algo=algo, env=env, timesteps=self.timesteps, seed=seed, preset=self.preset,
                           checkpoint_every=self.checkpoint_every, pretrained=self.pretrained,
                           max_iterations=self.max_iterations, overrides=overrides, record_every=self.record_every,
                           eval_every=ev.every, eval_starts=ev.starts, select_starts=ev.select_starts,
                           eval_maps=tuple(ev.maps), design_budget=ev.design_budget,
                           num_env_runners=self.env_runners, envs_per_runner=self.envs_per_runner)  # fmt: skip


SAMPLE_SEED = 20_240_917
"""Seeds the draws of a sweep's random search parts (each trial its own stream, by index)."""
STOP_METRICS = (keys.TIME_TOTAL, keys.ITERATION, keys.STEPS, keys.TIMESTEPS_TOTAL)
"""Stop criteria a sweep may give (Ray Tune ignores an unknown metric silently: a typo would never stop)."""
MAX_TRIAL_NAME = 200
"""Bytes of a trial folder's name: the file system takes 255, and Ray names files after it too."""
MAX_TRIALS = 10_000
"""More trials than any machine or cluster of ours runs; a larger grid is a typo (it would create the folders)."""


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and validate a sweep file; SweepConfigError names the file and the key."""
    file = Path(path)
    where = str(path)
    check_not_special(file, "sweep file", SweepConfigError)
    try:
        size = file.stat().st_size
        if size > MAX_YAML_BYTES:
            raise SweepConfigError(f"{where}: {size:,} bytes; a sweep file is at most {MAX_YAML_BYTES:,}")
        raw = strict_yaml(file.read_text())
    except FileNotFoundError:
        raise SweepConfigError(f"{where}: no such sweep file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SweepConfigError(f"{where}: cannot read ({exc.__class__.__name__})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", "") or ""
        detail = f" ({problem})" if problem.startswith(("duplicate key", "aliases", "nested", "an integer")) else ""
        raise SweepConfigError(f"{where}: not valid YAML{at}{detail}") from None
    if not isinstance(raw, dict):
        raise SweepConfigError(f"{where}: expected a mapping of keys ({', '.join(KEYS)})")

    def fail(key: str, message: str) -> SweepConfigError:
        return SweepConfigError(f"{where}: key '{key}': {message}")

    empty = (
        "stop",
        "checkpoint",
        "env",
        "search",
        "evaluation",
    )  # `key:` with nothing after it: the default, as before
    try:
        doc = SweepFile.model_validate(_whole_numbers({k: v for k, v in raw.items() if v is not None or k not in empty},
                                                      SweepFile))  # fmt: skip
    except ValidationError as exc:
        raise _first_problem(exc, fail) from None
    for a in doc.algorithms:
        if a not in ALGORITHMS:
            raise fail("algorithms", f"unknown algorithm '{a}' (choose from {', '.join(ALGORITHMS)})")
    map_sets = tuple(_map_set(item, f"maps[{i}]", file, fail) for i, item in enumerate(doc.maps))
    sets = [tuple(sorted(s)) for s in map_sets]  # one set of maps in another order trains the same policies
    for key, items, given in (("algorithms", doc.algorithms, doc.algorithms), ("seeds", doc.seeds, doc.seeds),
                              ("maps", sets, doc.maps)):  # fmt: skip
        twice = first_repeat(items)
        if twice is not None:
            shown = repr(given[twice])
            shown = shown if len(shown) <= 80 else shown[:77] + "..."
            raise fail(f"{key}[{twice}]", f"{shown} is given twice: its trials would run twice")
    if doc.preset not in PRESETS:
        raise fail("preset", f"unknown preset {doc.preset!r} (choose from {', '.join(PRESETS)})")
    unknown_stop = sorted(k for k in doc.stop if k not in STOP_METRICS)
    if unknown_stop:
        raise fail("stop", f"unknown metric '{unknown_stop[0]}' (known: {', '.join(STOP_METRICS)})")
    spent = next((k for k, v in sorted(doc.stop.items()) if not v > 0), None)
    if spent is not None:  # every metric starts at 0: a trial would stop before it trained
        raise fail(f"stop.{spent}", f"must be above 0 (a trial would stop before it trained), got {doc.stop[spent]}")
    if "maps" in doc.env:
        raise fail("env.maps", "give maps at the top level ('maps')")
    for i, maps in enumerate(map_sets):
        try:
            EnvConfig.from_dict({**doc.env, "maps": list(maps)})
        except SmorphiError as exc:
            said = str(exc)
            if said.startswith("env_config 'maps'"):  # an entry of this set, not an env override
                raise fail(f"maps[{i}]", said.removeprefix("env_config 'maps'").lstrip(": ")) from None
            raise fail(sweep_key(said, doc.env, "env"), said) from None
    spelt: dict[str, str] = {}
    for k in map(str, doc.search):  # lambda and lambda_ are one setting: both given, one would vanish unsaid
        other = spelt.setdefault(ALIASES.get(k, k), k)
        if other != k:
            raise fail(f"search.{k}", f"{other} and {k} are one setting: give one")
    spaces = {ALIASES.get(str(k), str(k)): _space(v, f"search.{k}", fail) for k, v in doc.search.items()}
    for k, space in spaces.items():  # num_epochs: {grid: [1e1, 2e1]}, whole numbers YAML read as floats
        if k in INTEGER_HYPERPARAMETERS and space.kind in ("constant", "grid", "choice"):
            spaces[k] = Space(space.kind, tuple(map(whole, space.values)))
    cfg = SweepConfig(
        path=file,
        name=_name(file.stem, fail, from_file=True) if doc.name is None else _name(doc.name, fail),
        algorithms=tuple(doc.algorithms),
        map_sets=map_sets,
        seeds=tuple(doc.seeds),
        timesteps=doc.timesteps,
        preset=doc.preset,
        stop=dict(doc.stop),
        checkpoint_every=doc.checkpoint.every,
        checkpoint_keep=doc.checkpoint.keep,
        env=dict(doc.env),
        search=spaces,
        num_samples=doc.num_samples,
        pretrained=None if doc.pretrained is None else _resolve_checkpoint(doc.pretrained, file, fail),
        max_iterations=doc.max_iterations,
        record_every=doc.record_every,
        evaluation=doc.evaluation.model_copy(
            update={"maps": [_resolve(m, file, "evaluation.maps", fail) for m in doc.evaluation.maps]}
        ),
        env_runners=doc.env_runners,
        envs_per_runner=doc.envs_per_runner,
    )
    layout = spaces.get("policy_angle_frequencies")
    if cfg.pretrained is not None and layout is not None and len(set(layout.examples())) > 1:
        raise fail("search.policy_angle_frequencies", "a pretrained policy is fine-tuned in the layout it was "
                   "trained with: its trials would be one trial under several labels")  # fmt: skip
    if cfg.num_samples > 1 and all(s.kind in ("grid", "constant") for s in spaces.values()):
        raise fail("num_samples", f"{cfg.num_samples} samples of a search with no random part would repeat the same "
                   "trials: give more seeds, or a choice, uniform or loguniform part")  # fmt: skip
    if cfg.num_grid_trials > MAX_TRIALS:
        raise fail("num_samples", f"{cfg.num_grid_trials:,} trials; at most {MAX_TRIALS:,} (a typo?)")
    first = (cfg.algorithms[0], list(cfg.map_sets[0]), cfg.seeds[0])
    drawn: set[tuple[tuple[str, Any], ...]] = set()
    for t in (t for t in cfg.trials() if (t["algo"], t["maps"], t["seed"]) == first):
        values = tuple(sorted(t["hp"].items()))
        if values in drawn:  # a choice drawn alike: the same trials twice, and one group's seeds counted twice
            shown = ", ".join(f"{k}={v:g}" for k, v in values)
            raise fail("num_samples", f"two of the {cfg.num_samples} samples draw the same values ({shown}), so their "
                       "trials would run twice: fewer samples, a choice of more values, or a uniform part")  # fmt: skip
        drawn.add(values)
    for i, maps in enumerate(map_sets):  # a trial's folder is named for its maps: one the file system takes
        named = {"maps": maps, "seed": max(cfg.seeds), "index": 0}
        longest = max(len(trial_dirname(named | {"algo": a}).encode()) for a in cfg.algorithms)
        if longest > MAX_TRIAL_NAME:
            raise fail(f"maps[{i}]", f"its trials' folders would be named {longest} bytes long (algorithm, map names, "
                       f"seed); at most {MAX_TRIAL_NAME}: give the map files shorter names")  # fmt: skip
    files: list[str] = []
    for i, maps in enumerate(map_sets):  # every trial is measured against its evaluated maps' exact optima
        try:
            trial = cfg.base_config(cfg.algorithms[0], maps, cfg.seeds[0], {})
        except SmorphiError as exc:
            raise fail(*complaint(str(exc), cfg.env, f"maps[{i}]")) from None
        _check_evaluable(trial, f"maps[{i}]", fail)
        files += [*trial.env.map_files, *trial.evaluation_maps]
    clash = name_clash(tuple(files))
    if clash is not None:  # groups, tables, optima and the resume's digests are keyed by a map's name
        raise fail("maps", f"{clash[0]} and {clash[1]} share the name {Path(clash[1]).stem!r}, which names the "
                   "trials, the groups of the tables and the optima: rename one")  # fmt: skip
    firsts = {k: space.examples()[0] for k, space in spaces.items()}
    for algo in cfg.algorithms:  # every value of every space must suit every algorithm
        for key, space in spaces.items():
            for value in space.examples():
                try:
                    cfg.base_config(algo, map_sets[0], cfg.seeds[0], {key: value})
                except SmorphiError as exc:
                    try:  # one that needs another beside it (lr_knee_at, the lr_knee it places) is not refused
                        cfg.base_config(algo, map_sets[0], cfg.seeds[0], firsts | {key: value})
                    except SmorphiError:
                        raise fail(f"search.{key}", str(exc)) from None
    _check_combinations(cfg, map_sets[0], fail)
    return cfg


def _check_combinations(cfg: SweepConfig, maps: tuple[str, ...], fail: Any) -> None:
    """Each trial's values together, before Ray starts: a minibatch_size and a train_batch_size that each suit the
    algorithm alone may not suit each other, and the trial would fail hours in."""
    if len(cfg.search) < 2:
        return
    checked: set[tuple[str, tuple[tuple[str, Any], ...]]] = set()
    for trial in cfg.trials():
        key = (trial["algo"], tuple(sorted(trial["hp"].items())))
        if key in checked:  # the same values under another seed or map set
            continue
        checked.add(key)
        try:
            cfg.base_config(trial["algo"], maps, cfg.seeds[0], trial["hp"])
        except SmorphiError as exc:
            shown = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in key[1])
            raise fail("search", f"trial {trial['index']} ({trial['algo']}, {shown}): {exc}") from None


def trial_dirname(trial: dict[str, Any]) -> str:
    """A trial's folder, from its fields and sweep index (the same folder when a resumed sweep runs it again;
    Tune's own config still holds placeholders for the fields when it names the folder)."""
    maps = map_set_label(trial["maps"])
    return f"{trial['algo']}-{maps}-seed{trial['seed']}_{trial['index']:05d}"


def _whole_numbers(raw: dict[str, Any], model: type[BaseModel]) -> dict[str, Any]:
    """`raw` with a whole number written with an exponent (`timesteps: 3e5`, which YAML reads as 300000.0) as the
    integer it is, where `model`'s field, or its nested mapping's, takes an integer."""
    out = dict(raw)
    for key, value in raw.items():
        field = model.model_fields.get(key)
        if field is None:
            continue
        kind = field.annotation
        if int in (kind, *get_args(kind)):
            out[key] = whole(value)
        elif get_origin(kind) is list:  # seeds: [1e3]
            out[key] = [whole(v) for v in value] if isinstance(value, list) else value
        elif isinstance(value, dict) and kind in (_Checkpoint, _Evaluation):
            out[key] = _whole_numbers(value, kind)
    return out


def whole(value: Any) -> Any:
    """A float that is a whole number (YAML's 3e5) as the integer it is; anything else as it is."""
    return int(value) if isinstance(value, float) and value.is_integer() and abs(value) <= 2**53 else value


TRIAL_KEYS = {
    "timesteps": "timesteps", "envs_per_runner": "envs_per_runner", "num_env_runners": "env_runners",
    "env_runners": "env_runners", "eval_every": "evaluation.every", "eval_starts": "evaluation.starts",
    "select_starts": "evaluation.select_starts", "design_budget": "evaluation.design_budget",
    "max_iterations": "max_iterations", "record_every": "record_every", "checkpoint_every": "checkpoint.every",
    "eval_maps": "evaluation.maps",
}  # fmt: skip
"""A trial's configuration field, as its complaints begin, and the sweep file's key that sets it."""


def sweep_key(message: str, env: dict[str, Any], default: str) -> str:
    """The sweep file's key a trial's complaint is about: the field it begins with (`timesteps ...`), or the `env`
    key it names (`env_config 'start_xy' ...`); `default` (the map set being built) otherwise."""
    named = re.match(r"env_config '(\w+)'", message)
    if named:
        return f"env.{named[1]}" if named[1] in env else default
    return TRIAL_KEYS.get(re.split(r"[\s:]", message, maxsplit=1)[0], default)


def complaint(message: str, env: dict[str, Any], default: str) -> tuple[str, str]:
    """A trial's complaint as the sweep file's key it is about (`sweep_key`) and in the file's words (`said_as`)."""
    key = sweep_key(message, env, default)
    return key, said_as(message, key)


def said_as(message: str, key: str) -> str:
    """A trial's complaint in the sweep file's words: the configuration field it begins with (`eval_starts must
    be ...`) said as the file's key (`evaluation.starts must be ...`), and no key twice (`eval_maps: ...`)."""
    field = re.split(r"[\s:]", message, maxsplit=1)[0]
    if TRIAL_KEYS.get(field) != key:
        return message
    return message.removeprefix(f"{field}: ") if message.startswith(f"{field}: ") else key + message[len(field) :]


def _check_evaluable(trial: TrainConfig, key: str, fail: Any) -> None:
    """One line when a trial could not be evaluated against an exact optimum: it trains on generated floors with no
    `evaluation.maps`, or a map it is evaluated on is over the cells an optimum is computed on."""
    from smorphi_rl.maps import load_map
    from smorphi_rl.protocol import OPTIMUM_MAX_CELLS

    if not trial.evaluation_maps:
        raise fail("evaluation.maps", f"the maps of {key} are generated ({', '.join(trial.env.maps)}), so its trials "
                   "have no exact optimum to be measured against: name fixed floors under evaluation.maps")  # fmt: skip
    where = "evaluation.maps" if trial.eval_maps else key
    for path in trial.evaluation_maps:
        try:
            cells = load_map(path).cells.size
        except SmorphiError as exc:
            raise fail(where, str(exc)) from None
        if cells > OPTIMUM_MAX_CELLS:
            raise fail(where, f"{path}: {cells:,} cells, over the {OPTIMUM_MAX_CELLS:,} an exact optimum is "
                       "computed on, so its trials could not be evaluated: cut it down (smorphi-rl maps crop or "
                       "resample)")  # fmt: skip


def _first_problem(exc: ValidationError, fail: Any) -> SweepConfigError:
    """The schema's first complaint as one line naming the key (a list item as key[i], a nested key as a.b)."""
    error = exc.errors()[0]
    key = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in error["loc"]).lstrip(".")
    top = str(error["loc"][0]) if error["loc"] else ""
    if error["type"] == "extra_forbidden":
        nested = {"checkpoint": _Checkpoint.model_fields, "evaluation": _Evaluation.model_fields}
        known = KEYS if len(error["loc"]) == 1 else nested.get(top, {})
        return fail(key, f"unknown key (known: {', '.join(known)})")
    if error["type"] == "missing":
        return fail(key, f"missing ({KEYS.get(top, '')})")
    message = error["msg"][0].lower() + error["msg"][1:]
    return fail(key, f"{message}, got {error['input']!r}")


def _map_set(item: Any, key: str, file: Path, fail: Any) -> tuple[str, ...]:
    """One trial's maps: a map entry or a list of them (`map_sources.py`: files, folders and globs resolved
    against the working directory, then the file's; floor generators as they are)."""
    items = item if isinstance(item, list) else [item]
    if not items:
        raise fail(key, "expected a map path or a non-empty list of them")
    out: list[str] = []
    for p in items:
        if not isinstance(p, str):
            raise fail(key, f"expected a map path, got {p!r}")
        out.append(_resolve(p, file, key, fail))
        if out[-1] in out[:-1] and not is_generator(out[-1]):  # a floor generator given twice weighs it
            raise fail(key, f"{p} is given twice in one set: each of its evaluation starts would count twice")
    return tuple(out)


def _resolve_checkpoint(entry: str, file: Path, fail: Any) -> str:
    """`pretrained` as a path found in the working directory or next to the sweep file (made absolute), as map
    entries are: a shipped sweep file runs from anywhere."""
    for base in (Path(entry), file.parent / entry):
        if base.exists():
            return str(base.resolve())
    raise fail("pretrained", f"checkpoint '{entry}' not found (looked in the working directory and next to the sweep "
                             "file)")  # fmt: skip


def _resolve(entry: str, file: Path, key: str, fail: Any) -> str:
    """A map entry as the env takes it: a generator spec, or a file, folder or glob found in the working
    directory or next to the sweep file (made absolute)."""
    from smorphi_rl.map_sources import MapSourceError, absolute_map, is_generator, parse_generator

    if is_generator(entry):
        try:
            return parse_generator(entry).spec
        except MapSourceError as exc:
            raise fail(key, str(exc)) from None
    for base in (Path(entry), file.parent / entry):
        if base.is_file():  # a linked map keeps its own name, as every command reads it (`absolute_map`)
            try:
                return absolute_map(base)
            except MapSourceError as exc:
                raise fail(key, str(exc)) from None
        if base.is_dir() or (any(ch in entry for ch in "*?[") and base.parent.is_dir()):
            return str(base.resolve()) if not any(ch in entry for ch in "*?[") else str(base.parent.resolve() /
                                                                                        base.name)  # fmt: skip
    raise fail(key, f"map file '{entry}' not found (looked in the working directory and next to the sweep file)")


def _space(value: Any, key: str, fail: Any) -> Space:
    if is_finite_number(value):
        return Space("constant", (value,))
    if not isinstance(value, dict) or len(value) != 1 or next(iter(value)) not in SPACE_KINDS:
        raise fail(key, f"expected a number or one of {{{' | '.join(SPACE_KINDS)}: ...}}, got {value!r}")
    ((kind, args),) = value.items()
    if not isinstance(args, list) or not args or not all(is_finite_number(a) for a in args):
        raise fail(key, f"{kind} takes a list of numbers, got {args!r}")
    if kind == "grid" and len(set(args)) < len(args):  # a choice may repeat a value to weight it
        raise fail(key, f"grid {args!r} gives a value twice: its trials would run twice")
    if kind in ("uniform", "loguniform"):
        if len(args) != 2 or not args[0] < args[1] or (kind == "loguniform" and args[0] <= 0):
            raise fail(key, f"{kind} takes [low, high] with low < high{' and low > 0' if kind == 'loguniform' else ''}")
        args = [float(a) for a in args]
    return Space(kind, tuple(args))


def _name(value: Any, fail: Any, from_file: bool = False) -> str:
    """The experiment's folder name: the `name` key's, else (`from_file`) the file's name without its suffix."""
    from smorphi_rl.rundir import RUN_NAME

    if not isinstance(value, str) or not RUN_NAME.fullmatch(value):
        rule = "letters, digits and _ . + -, not first; at most 128 characters; no / or .."
        if from_file:  # no `name` key: the file's own name is the one refused
            raise fail("name", f"missing, and the file's name {value!r}, the default, is not a plain folder name "
                       f"({rule}): add a name")  # fmt: skip
        raise fail("name", f"expected a plain folder name ({rule}), got {value!r}")
    return value

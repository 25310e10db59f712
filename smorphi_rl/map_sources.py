"""Where an env's maps come from: map files, folders and globs of them, or a floor generator drawn per episode.

An entry of `env_config['maps']` is one of:
- a map_server YAML file;
- a folder: every `*.yaml` and `*.yml` in it, sorted;
- a glob (`floors/rooms-*.yaml`): every YAML it matches, sorted;
- `generate:KIND` or `generate:KIND:LO-HI`: a fresh floor of `floorplans.generate_floor(KIND, seed)` each episode,
  the seed drawn from [LO, HI) by the env's seeded generator (default: the training seeds, TRAINING_SEEDS).
Files are resolved once, to absolute paths; a folder or glob that holds no map is refused.

Seed ranges keep training, validation and held-out floors apart: they never share a floor.
"""

from __future__ import annotations

import glob
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from smorphi_rl.errors import SmorphiError
from smorphi_rl.floorplans import HELD_OUT_SEED, FloorKind
from smorphi_rl.inputs import MAX_SEED, InputError, resolved
from smorphi_rl.maps import shipped_hint

GENERATE_PREFIX = "generate:"
VALIDATION_SEED = 900_000
"""Validation floors (the designer's learning curve) have seeds in [VALIDATION_SEED, HELD_OUT_SEED)."""
TRAINING_SEEDS = (0, VALIDATION_SEED)
"""Training floors are drawn from [0, VALIDATION_SEED) unless a range is given."""
VALIDATION_SEEDS = (VALIDATION_SEED, HELD_OUT_SEED)
HELD_OUT_SEEDS = (HELD_OUT_SEED, MAX_SEED)


class MapSourceError(SmorphiError):
    """A map entry that names no map."""


@dataclass(frozen=True)
class FloorSource:
    """`generate:KIND:LO-HI`: floors of one kind with seeds in [lo, hi)."""

    kind: FloorKind
    lo: int
    hi: int

    @property
    def spec(self) -> str:
        return f"{GENERATE_PREFIX}{self.kind.value}:{self.lo}-{self.hi}"

    def split(self) -> str:
        """Which of the seed ranges the floors come from (training, validation, held-out, or mixed)."""
        for name, (lo, hi) in (("training", TRAINING_SEEDS), ("validation", VALIDATION_SEEDS),
                               ("held-out", HELD_OUT_SEEDS)):  # fmt: skip
            if lo <= self.lo and self.hi <= hi:
                return name
        return "mixed"


def is_generator(entry: str) -> bool:
    """Whether a map entry names generated floors (`generate:KIND[:LO-HI]`) rather than files."""
    return entry.startswith(GENERATE_PREFIX)


def parse_generator(entry: str) -> FloorSource:
    """The floor source of a `generate:KIND[:LO-HI]` entry."""
    body = entry[len(GENERATE_PREFIX) :]
    kind_text, _, seeds = body.partition(":")
    try:
        kind = FloorKind(kind_text)
    except ValueError:
        kinds = ", ".join(k.value for k in FloorKind)
        raise MapSourceError(f"map entry {entry!r}: unknown floor kind {kind_text!r} (choose from {kinds})") from None
    lo, hi = TRAINING_SEEDS
    if seeds:
        a, sep, b = seeds.partition("-")
        if not (sep and a.isdigit() and b.isdigit()):
            raise MapSourceError(f"map entry {entry!r}: the seed range must be LO-HI, two integers")
        lo, hi = int(a), int(b)
        if not 0 <= lo < hi <= MAX_SEED:
            raise MapSourceError(f"map entry {entry!r}: need 0 <= LO < HI <= 2^32-1")
    return FloorSource(kind, lo, hi)


def resolve(entries: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Every entry as absolute map files (folders and globs expanded, sorted) or a normalised generator spec."""
    out: list[str] = []
    for entry in entries:
        text = str(entry)
        if is_generator(text):
            out.append(parse_generator(text).spec)
        elif any(ch in text for ch in "*?["):
            found = sorted(p for p in glob.glob(text) if p.endswith((".yaml", ".yml")))
            if not found:
                raise MapSourceError(f"map glob {text!r} matches no map YAML")
            out.extend(absolute_map(p) for p in found)
        elif Path(text).is_dir():
            found = sorted(absolute_map(p) for p in Path(text).iterdir() if p.suffix in (".yaml", ".yml"))
            if not found:
                raise MapSourceError(f"map folder {text} holds no map YAML")
            out.extend(found)
        else:
            hint = shipped_hint(Path(text)) if not Path(text).exists() else ""
            if hint:  # `maps/...` away from the clone: said here, before the path is made absolute
                raise MapSourceError(f"map file not found: {text}{hint}")
            out.append(absolute_map(text))
    return tuple(out)


def absolute_map(path: str | Path) -> str:
    """A map file's absolute path: its folder's links resolved, its own name kept (a linked YAML's image is looked
    for beside the link, as nav2 and every other command look); one line where it cannot be (a symlink loop)."""
    try:
        resolved(Path(path), "map")  # a loop is named here
        return str(resolved(Path(path).parent, "map") / Path(path).name)
    except InputError as exc:
        raise MapSourceError(str(exc)) from None


def map_label(entry: str) -> str:
    """A short name of a map entry for folder names and tables: a file's stem, a generator's kind."""
    return parse_generator(entry).kind.value if is_generator(entry) else Path(entry).stem


def map_set_label(entries: Iterable[str]) -> str:
    """A set of maps as sweep folders, tables and records name it: their labels joined by `+`."""
    return "+".join(map_label(e) for e in entries)


def map_files(entries: tuple[str, ...]) -> tuple[str, ...]:
    """The entries that are map files (not generators)."""
    return tuple(e for e in entries if not is_generator(e))


def generators(entries: tuple[str, ...]) -> tuple[FloorSource, ...]:
    """The generated-floor sources among map entries."""
    return tuple(parse_generator(e) for e in entries if is_generator(e))


def name_clash(files: tuple[str, ...], key: Callable[[str], str] | None = None) -> tuple[str, str] | None:
    """The first two different map files of one name (their stem, or `key` of the path), or None: results, runs and
    optima are named by a map's name, so one would take the other's place."""
    named: dict[str, str] = {}
    for file in files:
        name = key(file) if key is not None else Path(file).stem
        other = named.setdefault(name, file)
        if absolute_map(other) != absolute_map(file):
            return other, file
    return None

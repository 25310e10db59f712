"""Inputs checked at the edge, one place per kind: YAML documents, images, numbers and seeds, output files.

Every check raises a SmorphiError naming the input and the problem, before any work starts.
"""

from __future__ import annotations

import math
import re
import stat
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from smorphi_rl.errors import MapError, SmorphiError

MAX_YAML_BYTES = 1 << 20
"""A map YAML or a sweep file is a few hundred bytes; anything over 1 MiB is not one."""
MAX_IMAGE_PIXELS = 25_000_000
"""Map images larger than this (5,000 x 5,000) are refused before they are decoded."""
MAP_IMAGE_FORMATS = ("PNG", "PPM")
"""What Pillow may decode a map image as, whatever its name says: PNG, and PGM (Pillow's PPM plugin). Any other
(an EPS named map.png would run Ghostscript) reads as not a map image."""
MAX_SEED = 2**32 - 1
"""The largest seed every consumer takes (numpy, torch, RLlib and Tune's trial seeds)."""


class InputError(SmorphiError):
    """An input that cannot be used."""


MAX_YAML_DEPTH = 64
"""Nesting of a map YAML or a sweep file (ours need 4 levels)."""
MAX_YAML_INT_DIGITS = 3_000
"""The longest integer a YAML file may spell, in characters (Python shows one of up to 4,300 decimal digits): a
hexadecimal one of 5,000 digits read, as Python limits only decimal ones, and every message that then showed it
raised ValueError; a sexagesimal one (`1:0:0:...`) of 320 KB took 2 s to build."""


class _StrictLoader(yaml.SafeLoader):
    """YAML's safe loader that refuses aliases (a few lines of them expand to billions of nodes), a key given
    twice in one mapping (the second would silently win) and nesting past MAX_YAML_DEPTH (a RecursionError)."""

    depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.events.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, "aliases (*name) are not allowed", event.start_mark)
        if self.depth >= MAX_YAML_DEPTH:  # before Python's recursion limit (about 330 levels of the composer)
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, f"nested more than {MAX_YAML_DEPTH} levels deep", mark)
        self.depth += 1
        try:
            return super().compose_node(parent, index)  # type: ignore[no-untyped-call]
        finally:
            self.depth -= 1


def _no_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


def _bounded_int(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int:
    if len(node.value) > MAX_YAML_INT_DIGITS:  # before it is built
        raise yaml.constructor.ConstructorError(None, None, f"an integer of over {MAX_YAML_INT_DIGITS:,} digits",
                                                node.start_mark)  # fmt: skip
    value: int = loader.construct_yaml_int(node)  # type: ignore[no-untyped-call]
    return value


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)
_StrictLoader.add_constructor("tag:yaml.org,2002:int", _bounded_int)
_StrictLoader.add_implicit_resolver(  # YAML 1.2's 1e-4 (1.1, PyYAML's, reads it as a string: 'lr: 1e-4' failed)
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def strict_yaml(text: str) -> Any:
    """A YAML document read strictly (no aliases, no duplicate keys, at most MAX_YAML_DEPTH levels); yaml.YAMLError
    otherwise, also for what PyYAML itself raises as Python's errors (a mapping as a key, an integer of more digits
    than Python converts)."""
    try:
        return yaml.load(text, Loader=_StrictLoader)  # a SafeLoader: no Python objects
    except TypeError:  # PyYAML hashes every key
        raise yaml.YAMLError("a mapping or a list used as a key") from None
    except ValueError as exc:
        raise yaml.YAMLError(str(exc).split(":")[0] or type(exc).__name__) from None


def is_finite_number(value: Any) -> bool:
    """A real number (not a bool) that is finite as a float: an integer too large for one (JSON and YAML read 10^400
    as an int) is not, where `math.isfinite` would raise OverflowError."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


MAX_TREE_NODES = 100_000
"""More values than any configuration of ours holds (a policy's model_config has a few dozen)."""


def first_repeat(items: Sequence[Any]) -> int | None:
    """The index of the first item equal to an earlier one (a seed, a map, a value given twice), or None."""
    return next((i for i, v in enumerate(items) if v in items[:i]), None)


def is_plain_tree(value: Any, max_nodes: int = MAX_TREE_NODES) -> bool:
    """Whether `value` is JSON-like data (dicts with string keys, lists, tuples, strings, finite numbers, bools,
    None) of at most `max_nodes` values. Walked without recursion and counted, so a cycle or a 'billion laughs'
    of shared references ends the walk at the limit instead of hanging it."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > max_nodes:
            return False
        if isinstance(item, dict):
            if not all(isinstance(k, str) for k in item):
                return False
            stack.extend(item.values())
        elif isinstance(item, list | tuple):
            stack.extend(item)
        elif not (item is None or isinstance(item, str | bool) or is_finite_number(item)):
            return False
    return True


def check_not_special(path: Path, what: str, error: type[SmorphiError] = InputError) -> None:
    """Refuse, before it is opened, an input that is a FIFO, a socket or a device: reading one blocks or never
    ends. A missing file or a folder is left to the reader, which names it."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return
    except ValueError:  # a NUL byte, which no file name holds
        raise error(f"{what} {path} holds a NUL byte, which no file name can") from None
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise error(f"{what} {path} is not a regular file (a FIFO, socket or device is never read)")


def check_image_size(path: Path) -> None:
    """Refuse, before decoding, an image whose declared size exceeds MAX_IMAGE_PIXELS."""
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():  # Pillow's own warning: ours is the one line
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path, formats=MAP_IMAGE_FORMATS) as img:
                width, height = img.size
    except Image.DecompressionBombError:  # Pillow's own refusal, at twice its limit: far beyond ours
        raise MapError(f"{path}: an image of far more than {MAX_IMAGE_PIXELS:,} pixels, the most that are read "
                       "(cut it down with an image editor: no command here reads it)") from None  # fmt: skip
    except Exception:  # a missing or unreadable image: the decoder says so, with the file's name
        return
    if width * height > MAX_IMAGE_PIXELS:
        raise MapError(f"{path}: a {width:,} x {height:,} image; at most {MAX_IMAGE_PIXELS:,} pixels are read "
                         "(cut it down with an image editor: no command here reads it)")  # fmt: skip


def check_seed(seed: Any, what: str = "seed", error: type[SmorphiError] | None = None) -> int:
    """A seed is a whole number in [0, MAX_SEED], what numpy, torch, RLlib and Tune all take; `error` (default
    InputError) is the exception the caller's input raises."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= seed <= MAX_SEED:
        raise (error or InputError)(f"{what} must be a whole number in [0, 2^32-1], got {seed!r}")
    return int(seed)


def resolved(path: Path, what: str) -> Path:
    """`path.resolve()`, or one line naming it when it cannot be (a symlink loop, an unreadable folder)."""
    try:
        return path.resolve()
    except (RuntimeError, OSError, ValueError) as exc:  # ValueError: a NUL byte
        raise InputError(f"{what} {path}: cannot be resolved ({exc})") from None


def output_file(value: str, flag: str, suffixes: tuple[str, ...], inputs: tuple[Path | str, ...] = (),
                force: bool = False) -> Path:  # fmt: skip
    """An output path used exactly as given: it ends in one of `suffixes`, is not a folder, its folder exists or
    can be made (the nearest existing one is a writable folder; nothing is created here), it is none of the
    command's inputs (a plot never replaces the map it draws), and an existing file is replaced only when `force`
    (another map's image, another run's plot)."""
    if not value:
        raise InputError(f"{flag}: give a file name ending in {' or '.join(suffixes)}")
    path = Path(value)
    if path.suffix.lower() not in suffixes:
        raise InputError(f"{flag} {value!r}: give a file name ending in {' or '.join(suffixes)}")
    if path.is_dir():
        raise InputError(f"{flag} {value}: is a folder; give a file name ending in {' or '.join(suffixes)}")
    import os

    target = resolved(path, flag)
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{flag} {value}: {folder} is not a folder this process can write into")
    for item in inputs:
        if resolved(Path(item), "input") == target:
            raise InputError(f"{flag} {value} is one of this command's inputs: write it somewhere else")
    if path.exists() and not force:
        from smorphi_rl.rundir import FORCE_HINT

        raise InputError(f"{flag} {value} exists; {FORCE_HINT}")
    return path


FORCE_HELP = "replace an output file that exists (never one of the command's inputs)"


def read_json_object(path: Path, what: str) -> dict[str, Any]:
    """A JSON file that must hold an object (a run's summary or configuration), or one line naming it."""
    import json

    check_not_special(path, what)
    try:
        doc = json.loads(path.read_text()) if path.stat().st_size <= MAX_YAML_BYTES * 16 else None
    except FileNotFoundError:
        from smorphi_rl.rundir import cut_short

        why = "the run stopped before it finished and wrote it" if cut_short(path.parent) else "no such file"
        raise InputError(f"{path}: no {what}: {why}") from None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:  # RecursionError: nested far too deep
        raise InputError(f"{path}: not a readable {what} ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not a {what} (expected a JSON object)")
    return doc

"""Command-line options made from configuration fields: the flag, type, default and help text all come from
the field (its default and the docstring under it), so a default or its explanation is written once, in the
configuration type, and the `--help` of every command that exposes it says the same."""

from __future__ import annotations

import argparse
import inspect
import math
from collections.abc import Callable
from typing import Any

from smorphi_rl.config_fields import field_default, field_docs

FIELD_FLAGS: dict[str, str] = {}
"""Each configuration field an option sets, and its flag: an error that names the field names the flag too."""

UNSET: Any = None
"""What an option holds when the user did not give it and the field's default is applied later (by the
configuration, a checkpoint's configuration or a preset), rather than by argparse."""


def finite_arg(text: str) -> float:
    """argparse type of every real-valued option: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def param_default(func: Callable[..., Any], name: str) -> Any:
    """The default of parameter `name` of `func`: for options whose home is a job function's signature."""
    return inspect.signature(func).parameters[name].default


def shown(value: Any) -> str:
    """A default as help texts print it: 0.1 not 0.10000, none for None, a sequence space-separated."""
    if value is None:
        return "none"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple | list):
        return " ".join(shown(v) for v in value)
    return str(value)


def option(parser: argparse.ArgumentParser, cls: type, name: str, *flags: str, unset: bool = False,
           default_text: str | None = None, **kwargs: Any) -> argparse.Action:  # fmt: skip
    """Add the option of field `name` of `cls` (flag `--the-name` unless `flags` are given).

    Its help is the field's docstring and its default; its type that of the default unless `type` is given
    (None: that of the default).
    `unset`: the option holds UNSET when not given, and the field's default (or `default_text`) is only shown,
    for options whose default is applied downstream (a checkpoint's env, the preset's layout)."""
    default = field_default(cls, name)
    if kwargs.get("type") is None and "action" not in kwargs:
        kwargs["type"] = type(default) if isinstance(default, int | float | str) else None
    if kwargs.get("type") is float:  # no NaN or infinity reaches a configuration
        kwargs["type"] = finite_arg
    doc = field_docs(cls).get(name, "").replace("%", "%%")  # argparse formats help with %
    doc = doc.replace("; None: ", "; not given: ")  # a field's unset value, which no flag spells
    said = default_text if default_text is not None else shown(default)
    kwargs["help"] = f"{doc} (default: {said})".strip() if doc else f"default: {said}"
    kwargs["default"] = UNSET if unset else default
    flags = flags or (f"--{name.replace('_', '-')}",)
    field_flag(name, flags[0])
    return parser.add_argument(*flags, **kwargs)


def field_flag(name: str, flag: str) -> None:
    """Record that `flag` sets configuration field `name`, for an option not made by `option` (`train --map` sets the
    env's `maps`), so a complaint about the field names the flag (`flag_named`)."""
    FIELD_FLAGS[name] = flag


def flag_named(message: str, argv: list[str]) -> str:
    """`message` naming the flag the user gave for the configuration field it names: `timesteps must be ...` reads
    `--timesteps must be ...`, `env_config 'w1' must be ...` reads `--w1 must be ...`, `env_config 'maps': ...` reads
    `--map: ...`, and one that names the field inside reads `--w1: ...` before it; as it was when it names no field,
    or one given by no flag."""
    for name, flag in FIELD_FLAGS.items():
        given = any(a == flag or a.startswith(f"{flag}=") for a in argv)
        if not given or message.startswith(flag):
            continue
        for said, join in ((f"{name} ", " "), (f"{name}: ", ": "), (f"env_config '{name}' ", " "),
                           (f"env_config '{name}': ", ": ")):  # fmt: skip
            if message.startswith(said):
                return flag + join + message[len(said) :]
        if f"'{name}'" in message:
            return f"{flag}: {message}"
    return message

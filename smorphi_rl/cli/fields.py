"""Command-line options made from configuration fields: the flag, type, default and help text all come from
the field (its default and the docstring under it), so a default or its explanation is written once, in the
configuration type, and the `--help` of every command that exposes it says the same."""

from __future__ import annotations

import argparse
import ast
import inspect
import textwrap
from collections.abc import Callable
from dataclasses import MISSING, Field, fields
from functools import cache
from typing import Any

UNSET: Any = None
"""What an option holds when the user did not give it and the field's default is applied later (by the
configuration, a checkpoint's configuration or a preset), rather than by argparse."""


@cache
def field_docs(cls: type) -> dict[str, str]:
    """Each field's docstring (the string literal under the field in the class body), whitespace folded."""
    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0]
    assert isinstance(body, ast.ClassDef)
    docs = {}
    for node, after in zip(body.body, body.body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def field_default(cls: type, name: str) -> Any:
    """The default of field `name` of dataclass `cls`."""
    f: Field[Any] = {f.name: f for f in fields(cls)}[name]
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    raise KeyError(f"{cls.__name__}.{name} has no default")


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
    doc = field_docs(cls).get(name, "").replace("%", "%%")  # argparse formats help with %
    said = default_text if default_text is not None else shown(default)
    kwargs["help"] = f"{doc} (default: {said})".strip() if doc else f"default: {said}"
    kwargs["default"] = UNSET if unset else default
    return parser.add_argument(*(flags or (f"--{name.replace('_', '-')}",)), **kwargs)

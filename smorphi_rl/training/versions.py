"""The Ray and torch versions the RLlib layer is tested with, and one warning line when others are installed.

RLlib marks its env runner and learner APIs alpha: they change between releases, and `sampling.py`,
`learners.py` and `module.py` build on them. A cluster may run its own Ray, so another version is a warning,
not a refusal.
"""

from __future__ import annotations

import sys
from importlib import metadata
from typing import Any

TESTED = {"ray": "2.60.0", "torch": "2.13.0"}
"""Exact versions the suite passes with (the pins of pyproject.toml and the Makefile)."""
_warned: list[bool] = []


def installed(package: str) -> str:
    """The installed version of `package`, or "not installed"."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def version_warning() -> str | None:
    """The warning line when Ray or torch is not the tested version (torch's local build tag ignored)."""
    found = {name: installed(name) for name in TESTED}
    off = [f"{name} {found[name]}" for name, want in TESTED.items() if found[name].split("+")[0] != want]
    if not off:
        return None
    tested = ", ".join(f"{name} {want}" for name, want in TESTED.items())
    return (
        f"warning: smorphi-rl's RLlib layer is tested with {tested}; this is {', '.join(off)}: RLlib's env "
        "runner and learner APIs change between releases, so training may fail or sample differently"
    )


def warn_once(out: Any = None) -> None:
    """Print the version warning (if any) once per process, on stderr."""
    if _warned:
        return
    _warned.append(True)
    line = version_warning()
    if line:
        print(line, file=out or sys.stderr)

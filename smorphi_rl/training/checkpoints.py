"""The one place that knows where RLlib puts things in a checkpoint, and how to load our module back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from smorphi_rl.errors import SmorphiError

MODULE_SUBDIR = Path("learner_group") / "learner" / "rl_module" / "default_policy"
"""Where a (new API stack) Algorithm checkpoint keeps the RLModule's state."""
MODULE_COMPONENT = "learner_group/learner/rl_module/default_policy"
"""The same path as an RLlib component name (for `Algorithm.restore_from_path`)."""


class CheckpointError(SmorphiError):
    """A path that holds no checkpoint of ours."""


def is_checkpoint(path: Path) -> bool:
    return (path / MODULE_SUBDIR).is_dir()


def checkpoints_under(path: Path) -> list[Path]:
    """Every checkpoint directory at or below `path`, oldest first (by modification time, then name)."""
    if is_checkpoint(path):
        return [path]
    found = [p for p in path.rglob("checkpoint_*") if p.is_dir() and is_checkpoint(p)]
    return sorted(found, key=lambda p: (p.stat().st_mtime, str(p)))


def find_checkpoint(path: str | Path) -> Path:
    """A checkpoint directory itself, or the newest one under a trial or run directory."""
    root = Path(path)
    if not root.exists():
        raise CheckpointError(f"checkpoint not found: {root}")
    if not root.is_dir():
        raise CheckpointError(f"{root}: not a directory (give a checkpoint, trial or run directory)")
    found = checkpoints_under(root)
    if not found:
        raise CheckpointError(f"{root}: holds no RLlib checkpoint of ours (no {MODULE_SUBDIR.as_posix()} below it)")
    return found[-1]


SAFE_MODULES = ("smorphi_rl.", "numpy", "collections", "gymnasium.spaces", "torch", "builtins", "copyreg", "_codecs")
"""What the pickles of one of our module checkpoints may import (module-name prefixes); anything else is refused."""
OUR_CLASS = ("smorphi_rl.training.module", "MorphologyModule")
_STRING_OPS = {"SHORT_BINUNICODE", "BINUNICODE", "UNICODE", "BINUNICODE8", "SHORT_BINSTRING", "BINSTRING", "STRING"}
_GET_OPS = {"GET", "BINGET", "LONG_BINGET"}
_PUT_OPS = {"PUT", "BINPUT", "LONG_BINPUT"}


def pickle_globals(path: Path) -> set[tuple[str, str]]:
    """Every (module, name) a pickle would import, read from its opcodes without running it."""
    import pickletools

    found: set[tuple[str, str]] = set()
    memo: dict[int, Any] = {}
    pushed: list[Any] = []  # the last values pushed (strings, or None for anything else)
    with open(path, "rb") as fh:
        for op, arg, _ in pickletools.genops(fh):
            name = op.name
            if name in _STRING_OPS:
                pushed.append(arg)
            elif name in _GET_OPS:
                pushed.append(memo.get(int(arg)))  # type: ignore[arg-type]
            elif name == "MEMOIZE":
                memo[len(memo)] = pushed[-1] if pushed else None
            elif name in _PUT_OPS:
                memo[int(arg)] = pushed[-1] if pushed else None  # type: ignore[arg-type]
            elif name == "STACK_GLOBAL":
                module, attr = (pushed[-2], pushed[-1]) if len(pushed) >= 2 else (None, None)
                found.add((str(module), str(attr)))
                pushed.append(None)
            elif name in ("GLOBAL", "INST"):
                module, _, attr = str(arg).partition(" ")
                found.add((module, attr))
                pushed.append(None)
            elif op.stack_after:
                pushed.append(None)
    return found


def check_ours(checkpoint: Path) -> None:
    """Refuse, before anything is unpickled, a checkpoint that is not one of our policies or whose pickles
    would import anything beyond numpy, torch, gymnasium spaces and our own module (checkpoints are pickles:
    a crafted one runs code when loaded)."""
    folder = checkpoint / MODULE_SUBDIR
    pickles = sorted(folder.glob("*.pkl"))
    if not pickles:
        raise CheckpointError(f"{checkpoint}: holds no module state of ours")
    for pkl in pickles:
        try:
            names = pickle_globals(pkl)
        except Exception as exc:  # not a pickle at all
            raise CheckpointError(f"{pkl}: not a readable checkpoint file ({type(exc).__name__})") from None
        foreign = sorted(f"{m}.{n}" for m, n in names if not m.startswith(SAFE_MODULES))
        if foreign:
            raise CheckpointError(f"{pkl}: refused, it would import {', '.join(foreign[:3])} (not a smorphi-rl "
                                  "checkpoint; load only checkpoints you trust)")  # fmt: skip
        if pkl.name == "class_and_ctor_args.pkl" and OUR_CLASS not in names:
            raise CheckpointError(f"{checkpoint}: not a smorphi-rl policy (its module class is not MorphologyModule)")


def load_module(checkpoint: Path) -> Any:
    """The trained MorphologyModule of a checkpoint, on the CPU, ready for `forward_inference`."""
    from ray.rllib.core.rl_module.rl_module import RLModule

    from smorphi_rl.training.module import MorphologyModule
    from smorphi_rl.training.quiet import quiet

    quiet()
    check_ours(checkpoint)
    try:
        module = RLModule.from_checkpoint(str((checkpoint / MODULE_SUBDIR).resolve()))
    except Exception as exc:  # a damaged or foreign checkpoint: say which, in one line
        raise CheckpointError(f"{checkpoint}: cannot load the policy ({type(exc).__name__}: {exc})") from None
    if not isinstance(module, MorphologyModule):
        raise CheckpointError(f"{checkpoint}: holds a {type(module).__name__}, not a smorphi-rl policy")
    return module

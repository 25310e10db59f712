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


def load_module(checkpoint: Path) -> Any:
    """The trained MorphologyModule of a checkpoint, on the CPU, ready for `forward_inference`."""
    from ray.rllib.core.rl_module.rl_module import RLModule

    from smorphi_rl.training.module import MorphologyModule
    from smorphi_rl.training.quiet import quiet

    quiet()
    try:
        module = RLModule.from_checkpoint(str((checkpoint / MODULE_SUBDIR).resolve()))
    except Exception as exc:  # a damaged or foreign checkpoint: say which, in one line
        raise CheckpointError(f"{checkpoint}: cannot load the policy ({type(exc).__name__}: {exc})") from None
    if not isinstance(module, MorphologyModule):
        raise CheckpointError(f"{checkpoint}: holds a {type(module).__name__}, not a smorphi-rl policy")
    return module

"""Run directories under logs/: created and proven writable up front; an existing run is never overwritten."""

from __future__ import annotations

from pathlib import Path

from smorphi_rl.errors import SmorphiError


class RunDirError(SmorphiError):
    """The run directory cannot be used."""


def prepare_run_dir(log_dir: str | Path, name: str) -> Path:
    """`log_dir/name`, made and write-tested; refused if it already holds anything."""
    root = Path(log_dir).resolve()
    run_dir = root / name
    if run_dir.exists() and any(run_dir.iterdir()):
        raise RunDirError(f"run directory {run_dir} already exists: choose another --name")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        raise RunDirError(f"log directory {root} is not writable ({exc.strerror or exc})") from None
    return run_dir

"""What a failed Tune experiment says in one line, and what a full disk leaves behind.

Tune records a trial's error in a pickle beside its results; on a full disk that file is cut short and
reading it raises, so the error is read defensively. A checkpoint Tune was copying when the disk filled
is cut short too: it is removed, so `--pretrained` and `evaluate-policy` on the run folder find the last
whole one.
"""

from __future__ import annotations

import errno
import re
import shutil
from pathlib import Path
from typing import Any, NamedTuple

from smorphi_rl.training.checkpoints import STAGING_PREFIX, CheckpointError, checkpoints_under, read_module_files
from smorphi_rl.words import counted

FULL_MARKERS = ("No space left on device", "Disk quota exceeded", f"[Errno {errno.ENOSPC}]", f"errno {errno.ENOSPC}")
"""How ENOSPC and EDQUOT read in an error's text (Python's OSError and pyarrow's status alike)."""
LOW_FREE_BYTES = 1 << 20
"""A disk with less than this free is taken as full when a trial's own error cannot be read."""


def trial_errors(results: Any) -> list[str] | None:
    """Each failed trial's error text, or None when Tune's record of them cannot be read (cut short)."""
    try:
        return [str(e) for e in results.errors]
    except Exception:  # EOFError, UnpicklingError, OSError: error.pkl written onto a full disk
        return None


def _free_bytes(folder: Path) -> int | None:
    try:
        return shutil.disk_usage(folder).free
    except OSError:
        return None


def disk_full(folder: Path, errors: list[str] | None) -> bool:
    """Whether the run failed because the disk holding `folder` filled up."""
    texts = list(errors or [])
    for txt in folder.rglob("error.txt"):
        try:
            texts.append(txt.read_text(errors="replace"))
        except OSError:
            continue
    if any(marker in t for t in texts for marker in FULL_MARKERS):
        return True
    free = _free_bytes(folder)
    return errors is None and free is not None and free < LOW_FREE_BYTES


def drop_staging(folder: Path) -> None:
    """Remove the staging folders under `folder` that trials left (a trial Tune stops as it reports its last
    checkpoint never leaves its `with`): they were never checkpoints, only their copies are."""
    for staging in folder.rglob(f"{STAGING_PREFIX}*"):
        shutil.rmtree(staging, ignore_errors=True)


def drop_incomplete_checkpoints(folder: Path) -> list[Path]:
    """Remove every checkpoint under `folder` whose module cannot be read back (cut short); return them."""
    dropped = []
    for checkpoint in checkpoints_under(folder):
        try:
            read_module_files(checkpoint)
        except CheckpointError:
            shutil.rmtree(checkpoint, ignore_errors=True)
            dropped.append(checkpoint)
    return dropped


class Failure(NamedTuple):
    """A failed run, in one line; `disk_full` when a full disk stopped it (then nothing more can be written)."""

    line: str
    disk_full: bool


def _disk_full_failure(folder: Path, what: str) -> Failure:
    dropped = drop_incomplete_checkpoints(folder)
    kept = checkpoints_under(folder)
    free = _free_bytes(folder)
    left = f", {free / 2**20:.1f} MiB free" if free is not None else ""
    cut = f"; removed {counted(len(dropped), 'checkpoint')} cut short" if dropped else ""
    whole = f"the last whole checkpoint is {kept[-1]}" if kept else "no checkpoint was written whole"
    return Failure(f"{what} stopped: the disk holding {folder} is full{left}{cut}; {whole}", True)


def failure(results: Any, folder: Path, what: str = "training") -> Failure | None:
    """None when no trial failed; otherwise a full disk named with the run folder and the checkpoints that
    survive, or the first error's last line and where the full errors are."""
    errors = trial_errors(results)
    if errors == []:
        return None
    if disk_full(folder, errors):
        return _disk_full_failure(folder, what)
    if errors is None:
        return Failure(f"{what} failed and its error could not be read back (see the trial folders under {folder})",
                       False)  # fmt: skip
    first = errors[0].strip().splitlines()
    line = re.sub(r"^smorphi_rl(\.\w+)+: ", "", first[-1]) if first else "unknown error"  # ours says what it is
    where = f" in {len(errors)} trials" if len(errors) > 1 else ""
    return Failure(f"{what} failed{where}: {line} (full errors under {folder})", False)


def fit(tuner: Any, folder: Path, what: str = "training") -> tuple[Any, Failure | None]:
    """`tuner.fit()` and how it failed, if it did; Tune's results are None when Tune could not even read its own
    record of the run back (a trial's error file cut short by a full disk)."""
    try:
        results = tuner.fit()
    except Exception as exc:  # KeyboardInterrupt passes: the caller keeps what finished
        if disk_full(folder, [str(exc)]) or disk_full(folder, None):
            return None, _disk_full_failure(folder, what)
        said = (str(exc).strip().splitlines() or [""])[0]
        return None, Failure(f"{what} failed: {type(exc).__name__}{': ' + said if said else ''} (see the trial "
                             f"folders under {folder})", False)  # fmt: skip
    finally:  # every trial has ended, however: a staging folder left now is one Tune stopped mid-report or killed
        drop_staging(folder)
    return results, failure(results, folder, what)

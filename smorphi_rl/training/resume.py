"""Resuming a sweep from files that cannot run code: our own state file beside each checkpoint, and the trials'
JSON records.

Tune's own resume (`Tuner.restore`) unpickles `tuner.pkl` and the experiment state, and RLlib's
`restore_from_path` unpickles every state file of a checkpoint; those pickles hold classes and functions by
value, so no allowlist can tell a genuine folder from a crafted one. So a sweep's trial writes, beside RLlib's
checkpoint, the algorithm's state (weights, optimiser moments, metrics and counters: numbers and arrays only) to
`smorphi_state.pkl`, which is read back by the checkpoint loader's `SafeUnpickler`; `sweep --resume` starts a
fresh Tune experiment of the unfinished trials, each continuing from that file in its own folder. Nothing else
in the folder is unpickled.
"""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.checkpoints import CheckpointError, checkpoints_under, safe_unpickle
from smorphi_rl.training.sweep_report import SET_ASIDE, result_files, result_rows

STATE_FILE = "smorphi_state.pkl"
"""Our resumable state in a checkpoint folder (numbers and arrays: `SafeUnpickler` reads it)."""
STATE_KEYS = ("learner_group", "metrics_logger", "training_iteration")
"""RLlib's names (COMPONENT_LEARNER_GROUP, COMPONENT_METRICS_LOGGER, TRAINING_ITERATION) of the parts kept; the
env runners' state is left out (our connectors hold none) and rebuilt from the config."""
LEFT_OUT = ("env_runner", "eval_env_runner")
"""RLlib's names (COMPONENT_ENV_RUNNER, COMPONENT_EVAL_ENV_RUNNER) of the parts not kept."""
ELAPSED = "smorphi_time_total_s"
"""Training seconds before this checkpoint (a sweep's `time_total_s` stop counts across resumes)."""


def _plain(obj: Any) -> Any:
    """`obj` with numpy scalars as Python numbers, so its pickle names no class but arrays."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_plain(v) for v in obj)
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def save_state(algo: Any, folder: Path, elapsed_s: float) -> None:
    """Write the algorithm's resumable state (module docstring) into checkpoint `folder`."""
    state = algo.get_state(not_components=list(LEFT_OUT))
    kept = {k: _plain(state[k]) for k in STATE_KEYS}
    kept[ELAPSED] = float(elapsed_s)
    with (folder / STATE_FILE).open("wb") as fh:
        pickle.dump(kept, fh, protocol=pickle.HIGHEST_PROTOCOL)


def load_state(checkpoint: Path) -> dict[str, Any]:
    """The resumable state of `checkpoint`, read by `SafeUnpickler` and checked for its parts; CheckpointError
    otherwise."""
    state = safe_unpickle(checkpoint / STATE_FILE)
    if not isinstance(state, dict) or set(state) != {*STATE_KEYS, ELAPSED}:
        raise CheckpointError(f"{checkpoint / STATE_FILE}: not the state a smorphi-rl sweep writes")
    it, elapsed = state["training_iteration"], state[ELAPSED]
    if not (isinstance(it, int) and it >= 1 and isinstance(elapsed, float) and 0 <= elapsed < 1e9):
        raise CheckpointError(f"{checkpoint / STATE_FILE}: its iteration or elapsed time is out of range")
    if not all(isinstance(state[k], dict) for k in ("learner_group", "metrics_logger")):
        raise CheckpointError(f"{checkpoint / STATE_FILE}: not the state a smorphi-rl sweep writes")
    return state


def resume_point(trial_dir: Path) -> Path | None:
    """The newest checkpoint under `trial_dir` holding our state file of an iteration the trial's results record
    (an interrupt can land between a checkpoint and its row; the state is read and checked, `load_state`); None:
    start the trial afresh."""
    files = result_files(trial_dir)
    logged = max((int(r.get(keys.ALGO_ITERATION) or 0) for r in result_rows(*files)), default=0) if files else 0
    for checkpoint in reversed(checkpoints_under(trial_dir)):
        if (checkpoint / STATE_FILE).is_file() and load_state(checkpoint)["training_iteration"] <= logged:
            return checkpoint
    return None


SET_ASIDE_FILES = ("result.json", "progress.csv")


def set_aside(trial_dir: Path) -> Path | None:
    """Move the trial's own checkpoints and results into a new `before-resume-N/` folder: a resumed trial numbers
    its checkpoints from 0 again and Tune starts its result files anew, so nothing written earlier is
    overwritten (the reports read the set-aside results first, `sweep_report.result_files`). Returns the folder
    (None when there was nothing to move)."""
    own = sorted(p for p in trial_dir.glob("checkpoint_*") if p.is_dir())
    own += [trial_dir / name for name in SET_ASIDE_FILES if (trial_dir / name).is_file()]
    if not own:
        return None
    n = 1 + sum(1 for p in trial_dir.glob(f"{SET_ASIDE}-*") if p.is_dir())
    aside = trial_dir / f"{SET_ASIDE}-{n}"
    aside.mkdir()
    for p in own:
        shutil.move(str(p), str(aside / p.name))
    return aside


def trial_spec(trial_dir: Path) -> dict[str, Any] | None:
    """The trial's fields (`SweepConfig.trials`) as Tune's params.json in `trial_dir` records them; None for a
    folder that holds no trial of a sweep."""
    try:
        spec = json.loads((trial_dir / "params.json").read_text())
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    index = spec.get("index") if isinstance(spec, dict) else None
    return spec if isinstance(index, int) and not isinstance(index, bool) else None


def finished(trial_dir: Path) -> bool:
    """Whether the trial's last recorded result says it reached its budget or its stop criteria."""
    files = result_files(trial_dir)
    rows = result_rows(*files) if files else []
    return bool(rows and rows[-1].get(keys.TRIAL_DONE))

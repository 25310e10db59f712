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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.inputs import InputError, is_finite_number
from smorphi_rl.rundir import write_atomic
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.checkpoints import checkpoints_under
from smorphi_rl.training.safe_pickle import CheckpointError, UnreadableCheckpoint, safe_unpickle, shown
from smorphi_rl.training.sweep_report import (
    MAX_PARAMS_BYTES,
    SET_ASIDE,
    aside_number,
    result_files,
    result_rows,
    trial_done,
)

STATE_FILE = "smorphi_state.pkl"
"""Our resumable state in a checkpoint folder (numbers and arrays: `SafeUnpickler` reads it)."""
STATE_KEYS = ("learner_group", "metrics_logger", "training_iteration")
"""RLlib's names (COMPONENT_LEARNER_GROUP, COMPONENT_METRICS_LOGGER, TRAINING_ITERATION) of the parts kept; the
env runners' state is left out (our connectors hold none) and rebuilt from the config."""
LEFT_OUT = ("env_runner", "eval_env_runner")
"""RLlib's names (COMPONENT_ENV_RUNNER, COMPONENT_EVAL_ENV_RUNNER) of the parts not kept."""
ELAPSED = "smorphi_time_total_s"
"""Training seconds before this checkpoint (a sweep's `time_total_s` stop counts across resumes)."""
KEPT = "smorphi_kept_policy"
"""The policy the run would end on if no later one beats it (`MorphologyCallbacks.kept_policy`: its selection
score, env steps and weights); absent when the run keeps none."""


def _plain(obj: Any) -> Any:
    """`obj` with numpy scalars as Python numbers, so its pickle names no class but arrays."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_plain(v) for v in obj)
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def save_state(
    algo: Any, folder: Path, elapsed_s: float, kept_policy: dict[str, Any] | None = None,
    trained: dict[str, Any] | None = None,
) -> None:  # fmt: skip
    """Write the algorithm's resumable state (module docstring), and the run's kept policy if it has one, into
    checkpoint `folder`. `trained`: the weights the learner trained to, where the run's end put the kept policy in
    their place; the file holds them as the learner's, so a run stopped early goes on from them (and from the
    optimiser moments that go with them), as a killed one does."""
    state = algo.get_state(not_components=list(LEFT_OUT))
    kept = {k: _plain(state[k]) for k in STATE_KEYS}
    if trained is not None:
        kept["learner_group"]["learner"]["rl_module"]["default_policy"] = _plain(trained)
    kept[ELAPSED] = float(elapsed_s)
    if kept_policy is not None:
        kept[KEPT] = _plain(kept_policy)
    write_atomic(folder / STATE_FILE, pickle.dumps(kept, protocol=pickle.HIGHEST_PROTOCOL))


MAX_ITERATION = 10**9
"""More training iterations than any run of ours (a day at 10,000 a second)."""


def _numbers_only(obj: Any) -> bool:
    """Whether `obj` is a tree of dicts, lists and tuples whose leaves are numbers, strings, None or numeric
    arrays: what RLlib's state of our algorithm is made of."""
    if isinstance(obj, dict):
        return all(isinstance(k, str | int) and _numbers_only(v) for k, v in obj.items())
    if isinstance(obj, list | tuple):
        return all(_numbers_only(v) for v in obj)
    if isinstance(obj, np.ndarray):
        return obj.dtype.kind in "biuf"
    return obj is None or isinstance(obj, bool | int | float | str)


def _shape_problem(state: dict[str, Any]) -> str | None:
    """What in `state` is not of the shape `save_state` writes (None: nothing)."""
    it, elapsed = state["training_iteration"], state[ELAPSED]
    if isinstance(it, bool) or not isinstance(it, int) or not 1 <= it <= MAX_ITERATION:
        return f"its iteration {shown(it)} is not a whole number in 1..{MAX_ITERATION:,}"
    if not isinstance(elapsed, float) or not 0 <= elapsed < 1e9:
        return f"its elapsed time {shown(elapsed)} is out of range"
    learner = state["learner_group"].get("learner") if isinstance(state["learner_group"], dict) else None
    if not isinstance(learner, dict) or not all(isinstance(learner.get(k), dict) for k in ("rl_module", "optimizer")):
        return "its learner state is not a learner's (module weights and optimiser)"
    weights = learner["rl_module"].get("default_policy")
    if not isinstance(weights, dict) or not weights or not all(_weight(v) for v in weights.values()):
        return "its module weights are not a table of finite float32 arrays"
    stats = state["metrics_logger"].get("stats") if isinstance(state["metrics_logger"], dict) else None
    if not isinstance(stats, dict) or not all(isinstance(v, dict) for v in stats.values()):
        return "its metrics are not RLlib's"
    if KEPT in state and (problem := _kept_problem(state[KEPT], weights)) is not None:
        return problem
    if not _numbers_only(state):
        return "it holds something other than numbers, strings and numeric arrays"
    return None


def _weight(value: Any) -> bool:
    """Whether `value` is a weight as our modules hold them: a finite float32 array in the machine's byte order."""
    return isinstance(value, np.ndarray) and value.dtype == np.dtype(np.float32) and bool(np.all(np.isfinite(value)))


def _kept_problem(kept: Any, weights: dict[str, Any]) -> str | None:
    """What in the kept policy's record is not of the shape `save_state` writes: a score (starts within 1 %, a
    finite number), env steps and the module's weights, name for name and shape for shape."""
    if not isinstance(kept, dict) or set(kept) != {"score", "env_steps", "weights"}:
        return "its kept policy is not a score, env steps and weights"
    score, steps, kept_weights = kept["score"], kept["env_steps"], kept["weights"]
    if (not isinstance(score, list) or len(score) != 2 or isinstance(score[0], bool) or not isinstance(score[0], int)
            or score[0] < 0 or not isinstance(score[1], float) or not np.isfinite(score[1])):  # fmt: skip
        return f"its kept policy's score {shown(score)} is not a count and a finite number"
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        return f"its kept policy's env steps {shown(steps)} are not a whole number"
    if (
        not isinstance(kept_weights, dict)
        or set(kept_weights) != set(weights)
        or not all(_weight(v) and v.shape == weights[k].shape for k, v in kept_weights.items())
    ):
        return "its kept policy's weights are not the module's (the same names and shapes, finite float32)"
    return None


def check_fits(state: dict[str, Any], module: dict[str, Any], checkpoint: Path) -> None:
    """CheckpointError unless the weights of `state` (`load_state`'s, whose kept policy matches them) are
    `module`'s (the trial's own weights, by name) name for name and shape for shape: RLlib restores weights
    leniently, and a name missing from the file would leave that weight as initialised."""
    weights = state["learner_group"]["learner"]["rl_module"]["default_policy"]
    ours = {k: np.shape(v) for k, v in module.items()}
    if {k: v.shape for k, v in weights.items()} != ours:
        missing, extra = sorted(set(ours) - set(weights)), sorted(set(weights) - set(ours))
        raise CheckpointError(f"{checkpoint / STATE_FILE}: its weights are not this trial's module's (missing "
                              f"{missing[:2]}, extra {extra[:2]}, or shapes differ); not the state this run "
                              "writes")  # fmt: skip


def load_state(checkpoint: Path) -> dict[str, Any]:
    """The resumable state of `checkpoint`, read by `SafeUnpickler` and checked for the shape `save_state`
    writes; CheckpointError otherwise."""
    path = checkpoint / STATE_FILE
    state = safe_unpickle(path)
    if not isinstance(state, dict) or set(state) - {KEPT} != {*STATE_KEYS, ELAPSED}:
        raise CheckpointError(f"{path}: not the state a smorphi-rl run writes")
    try:
        problem = _shape_problem(state)
    except RecursionError:
        problem = "it is nested too deeply"
    if problem is not None:
        raise CheckpointError(f"{path}: {problem}; not the state a smorphi-rl run writes")
    return state


def resume_point(trial_dir: Path, said: list[str] | None = None) -> Path | None:
    """The newest checkpoint under `trial_dir` holding our state file of an iteration the trial's results record
    (an interrupt can land between a checkpoint and its row; the state is read and checked, `load_state`); None:
    start the trial afresh. A state file that does not read as a pickle (a kill as Tune copied the checkpoint) is
    passed over for an older one, a line saying so added to `said`; CheckpointError names it when no older one reads.
    One read and refused for what it holds stops the resume, named."""
    files = result_files(trial_dir)
    logged = max((int(r.get(keys.ALGO_ITERATION) or 0) for r in result_rows(*files)), default=0) if files else 0
    unread: list[tuple[Path, UnreadableCheckpoint]] = []
    for checkpoint in reversed(checkpoints_under(trial_dir)):
        here = checkpoint / STATE_FILE
        if not (here.exists() or here.is_symlink()):
            continue
        try:
            iteration = load_state(checkpoint)["training_iteration"]
        except UnreadableCheckpoint as exc:
            unread.append((here, exc))
            continue
        if iteration <= logged:
            if said is not None:
                said.extend(_passed_over(trial_dir, path.parent, checkpoint) for path, _ in unread)
            return checkpoint
    if unread:
        raise unread[0][1]
    return None


def _passed_over(trial_dir: Path, skipped: Path, point: Path) -> str:
    """What a resume says of a checkpoint whose state file it passed over (by the checkpoints' names, which stay
    true when they are set aside)."""
    from smorphi_rl.rundir import rel

    return (f"{rel(trial_dir)}: the state file of {skipped.name} does not read (cut short by a kill?): it resumes "
            f"from {point.name}")  # fmt: skip


SET_ASIDE_FILES = ("result.json", "progress.csv", "summary.json")
"""A trial's files a resume moves with its checkpoints (summary.json names a checkpoint; it is written again)."""


def set_aside(trial_dir: Path) -> Path | None:
    """Move the trial's own checkpoints and results into a new `before-resume-N/` folder: a resumed trial numbers
    its checkpoints from 0 again and Tune starts its result files anew, so nothing written earlier is
    overwritten (the reports read the set-aside results first, `sweep_report.result_files`). Returns the folder
    (None when there was nothing to move)."""
    own = sorted(p for p in trial_dir.glob("checkpoint_*") if p.is_dir())
    own += [trial_dir / name for name in SET_ASIDE_FILES if (trial_dir / name).is_file()]
    if not own:
        return None
    n = 1 + max((aside_number(p) or 0 for p in trial_dir.glob(f"{SET_ASIDE}-*")), default=0)
    aside = trial_dir / f"{SET_ASIDE}-{n}"
    aside.mkdir()
    for p in own:
        shutil.move(str(p), str(aside / p.name))
    return aside


def set_aside_from(trial_dir: Path, point: Path | None) -> Path | None:
    """`set_aside` of a trial about to continue from checkpoint `point`: where that checkpoint lies once moved (None
    for none); one line when the files cannot be moved."""
    from smorphi_rl.rundir import RunDirError

    try:
        aside = set_aside(trial_dir)
    except OSError as exc:
        raise RunDirError(f"{trial_dir}: its checkpoints cannot be set aside ({exc.strerror or exc})") from None
    if point is None:
        return None
    return aside / point.name if aside is not None and point.parent == trial_dir else point


def trial_spec(trial_dir: Path) -> dict[str, Any] | None:
    """The trial's fields (`SweepConfig.trials`) as Tune's params.json in `trial_dir` records them; None for a
    folder that holds no trial of a sweep."""
    try:
        params = trial_dir / "params.json"
        spec = json.loads(params.read_text()) if params.stat().st_size <= MAX_PARAMS_BYTES else None
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    index = spec.get("index") if isinstance(spec, dict) else None
    return spec if isinstance(index, int) and not isinstance(index, bool) else None


def finished(trial_dir: Path) -> bool:
    """Whether the trial's last recorded result says it reached its budget or its stop criteria."""
    files = result_files(trial_dir)
    return trial_done(result_rows(*files) if files else [])


@dataclass(frozen=True)
class ResumedTrial:
    """A `train` run continued (`train --resume`): its trial's folder, the checkpoint it continues from (set aside
    with the trial's earlier files) and the results it recorded up to that checkpoint, which the run reports too."""

    trial_dir: Path
    checkpoint: Path
    rows: list[dict[str, Any]]
    elapsed_s: float = 0.0
    """Training seconds before the checkpoint (its state file's), which the run's wall time adds."""
    done: bool = False
    """The run trained its whole budget before it was killed (as it wrote its tables): nothing to train again."""
    said: tuple[str, ...] = ()
    """What `resume_point` said of newer state files that did not read, printed as the run resumes."""

    @property
    def env_steps(self) -> int:
        return int(self.rows[-1].get(keys.STEPS) or 0) if self.rows else 0


def continue_train_run(
    run_dir: Path, wanted: dict[str, Any], algo: str, digests: dict[str, str] | None = None
) -> ResumedTrial:
    """Claim the `train` run in `run_dir` again to continue it with the settings `wanted` (`TrainConfig.to_dict`) on
    maps of `digests` (`run.map_digests`): refused in one line when it is not a run of `train`, finished, in use,
    trained with other settings or on a map file changed since, or holds no checkpoint with our state; its later
    checkpoints and results are set aside, never deleted."""
    from smorphi_rl.inputs import read_json_object
    from smorphi_rl.rundir import claim_again, refuse_links, rel
    from smorphi_rl.training.config import TrainConfigError
    from smorphi_rl.training.settings_diff import setting_differs

    if run_dir.is_symlink() or not run_dir.is_dir():
        raise TrainConfigError(f"--resume: there is no run {rel(run_dir)} to continue")
    refuse_links(run_dir)  # Tune and RLlib would write wherever a link points
    if not (run_dir / "config.json").is_file():
        raise TrainConfigError(f"--resume: {rel(run_dir)} holds no run of `train` (no config.json): give the --name "
                               "(and --log-dir) of the run to continue")  # fmt: skip
    if (run_dir / "summary.json").is_file() and not _stopped_early(run_dir / "summary.json"):
        raise TrainConfigError(f"--resume: {rel(run_dir)} finished (its summary.json): nothing to continue; "
                               "`train --pretrained` starts a new run from its checkpoint")  # fmt: skip
    claim_again(run_dir)  # refused while the process that ran it still runs
    stored = read_json_object(run_dir / "config.json", "run configuration")
    differ = setting_differs(stored, wanted)
    if differ is not None:
        raise TrainConfigError(f"--resume: {rel(run_dir)} was trained with other settings ({differ}): give the "
                               "options it ran with (its config.json)")  # fmt: skip
    recorded = stored.get("map_digests")  # a run of an earlier version recorded none: its settings alone
    changed = sorted(m for m, d in (digests or {}).items() if isinstance(recorded, dict) and recorded.get(m, d) != d)
    if changed:
        raise TrainConfigError(f"--resume: {rel(run_dir)} was trained on another floor named {changed[0]!r} (the "
                               "map file changed since); restore it, or train again under another --name")  # fmt: skip
    trials = sorted(d for d in run_dir.glob(f"{algo}-*") if d.is_dir() and not d.is_symlink())
    if not trials:
        raise TrainConfigError(f"--resume: {rel(run_dir)} holds no trial folder of {algo}: nothing to continue from")
    if len(trials) != 1:
        raise TrainConfigError(f"--resume: {rel(run_dir)} holds {len(trials)} trial folders of {algo}, where a run "
                               "of `train` makes one")  # fmt: skip
    trial = trials[0]
    said: list[str] = []
    point = resume_point(trial, said)
    if point is None:
        raise TrainConfigError(f"--resume: {rel(trial)} holds no checkpoint to continue from (one is written every "
                               "--checkpoint-every iterations); start it again with another --name")  # fmt: skip
    state = load_state(point)
    iteration, elapsed = state["training_iteration"], float(state[ELAPSED])
    rows = [r for r in result_rows(*result_files(trial)) if int(r.get(keys.ALGO_ITERATION) or 0) <= iteration]
    for r in rows:  # the resumed run counts on from them, and its report reads each (Infinity: an OverflowError)
        if not _whole_steps(r.get(keys.STEPS, 0)):
            raise TrainConfigError(f"--resume: {rel(trial)}: its results' env steps at iteration "
                                   f"{r.get(keys.ALGO_ITERATION)} read {shown(r.get(keys.STEPS))}, not what "
                                   "smorphi-rl writes; start it again with another --name")  # fmt: skip
    steps = int(rows[-1].get(keys.STEPS) or 0) if rows else 0
    cap = wanted.get("max_iterations")
    budget_spent = steps >= int(wanted["timesteps"]) or (isinstance(cap, int) and iteration >= cap)
    # killed as it wrote its tables: they are written again, nothing trained (a stop's last row is done too, but its
    # budget is not spent: it trains on)
    if trial_done(rows) and budget_spent:
        return ResumedTrial(trial, point, rows, elapsed, done=True, said=tuple(said))
    checkpoint = set_aside_from(trial, point)
    assert checkpoint is not None
    return ResumedTrial(trial, checkpoint, rows, elapsed, said=tuple(said))


def _whole_steps(value: Any) -> bool:
    """Whether `value` is an env-step count as a result row holds it: a whole, non-negative, finite number."""
    return is_finite_number(value) and value >= 0 and float(value).is_integer()


def can_continue(run_dir: Path, algo: str) -> bool:
    """Whether the `train` run of `algo` in `run_dir`, cut short, holds what `continue_train_run` continues from (its
    configuration, one trial folder and a checkpoint with our state that its results record): a transfer job's cut
    run continues rather than trains again from nothing. A state file that does not read is not continued from."""
    trials = [d for d in run_dir.glob(f"{algo}-*") if d.is_dir() and not d.is_symlink()]
    if run_dir.is_symlink() or not (run_dir / "config.json").is_file() or len(trials) != 1:
        return False
    try:
        summary = run_dir / "summary.json"  # one that does not say the run stopped early is not continued
        return (not summary.exists() or _stopped_early(summary)) and resume_point(trials[0]) is not None
    except (UnreadableCheckpoint, InputError):  # no state or summary that reads: trained again (one read and
        return False  # refused for what it holds stops the job, named)


def _stopped_early(summary: Path) -> bool:
    """Whether a run's summary.json says it stopped before its budget (a Ctrl-C or SIGTERM: a scheduler's time limit
    sends one before its kill), so that `--resume` may continue it."""
    from smorphi_rl.inputs import read_json_object

    return read_json_object(summary, "run summary").get("interrupted") is True

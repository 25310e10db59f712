"""A run that fails: one line, the full disk named with the run folder, the whole checkpoints kept.

The real runs fill a small tmpfs (mounting one needs root; skipped otherwise)."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_runs import cli

from smorphi_rl.training.checkpoints import MODULE_SUBDIR, checkpoints_under, find_checkpoint, load_module
from smorphi_rl.training.failures import failure, fit

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
# `small_disk` (conftest): 4 MB, where two of the main job's checkpoints (1.5 MB each) fit and the third does not


class _Results:
    def __init__(self, errors: list[Exception] | Exception) -> None:
        self._errors = errors

    @property
    def errors(self) -> list[Exception]:
        if isinstance(self._errors, Exception):
            raise self._errors
        return self._errors


class _Tuner:
    def __init__(self, exc: Exception) -> None:
        self.exc = exc

    def fit(self) -> None:
        raise self.exc


def _cut_short_checkpoint(trial: Path, index: int) -> Path:
    checkpoint = trial / f"checkpoint_{index:06d}"
    (checkpoint / MODULE_SUBDIR).mkdir(parents=True)
    (checkpoint / MODULE_SUBDIR / "module_state.pkl").write_bytes(b"\x80\x04")  # a pickle cut off after 2 bytes
    return checkpoint


def test_no_failure_is_none(tmp_path):
    assert failure(_Results([]), tmp_path) is None


def test_an_ordinary_error_names_its_last_line_and_where_the_rest_is(tmp_path):
    failed = failure(_Results([RuntimeError("Traceback ...\n  File x\nValueError: bad lr")]), tmp_path)
    assert failed is not None and not failed.disk_full
    assert failed.line == f"training failed: ValueError: bad lr (full errors under {tmp_path})"


def test_a_trials_error_as_ray_raises_it_names_its_last_line(tmp_path):
    """The error a failed trial holds is Ray's RayTaskError (as the error of its cause), whose text opens with the
    worker's coloured name: the line is the cause's, not that first line."""
    import traceback

    from ray.exceptions import RayTaskError

    try:
        raise ValueError("bad lr")
    except ValueError as exc:
        error = RayTaskError("train", traceback.format_exc(), exc).as_instanceof_cause()
    assert isinstance(error, ValueError) and "\x1b[" in str(error)  # what Tune hands over, as Ray builds it
    failed = failure(_Results([error]), tmp_path)
    assert failed is not None and failed.line == f"training failed: ValueError: bad lr (full errors under {tmp_path})"


def test_an_error_of_ours_is_said_without_its_module_path(tmp_path):
    """Ours name the problem themselves; another package's keep their class name (`ValueError: bad lr` above)."""
    text = "Traceback ...\nsmorphi_rl.training.callbacks.DivergedError: the policy diverged after 2,000 env steps"
    failed = failure(_Results([RuntimeError(text)]), tmp_path)
    assert failed is not None
    assert failed.line == f"training failed: the policy diverged after 2,000 env steps (full errors under {tmp_path})"


def test_a_full_disk_removes_the_checkpoint_cut_short_and_names_the_folder(tmp_path):
    cut = _cut_short_checkpoint(tmp_path / "ppo-0", 1)
    failed = failure(_Results([OSError(28, "No space left on device")]), tmp_path, "the sweep")
    assert failed is not None and failed.disk_full
    assert failed.line.startswith(f"the sweep stopped: the disk holding {tmp_path} is full")
    assert "removed 1 checkpoint cut short; no checkpoint was written whole" in failed.line
    assert not cut.exists()


def test_an_unreadable_record_of_errors_is_one_line_too(tmp_path):
    failed = failure(_Results(EOFError("Ran out of input")), tmp_path)
    assert failed is not None and "could not be read back" in failed.line and "\n" not in failed.line
    results, failed = fit(_Tuner(EOFError("Ran out of input")), tmp_path)
    assert results is None and failed is not None and "EOFError" in failed.line and "\n" not in failed.line


def _one_error_line(err: str) -> str:
    assert "Traceback" not in err, err[-3000:]
    errors = [line for line in err.splitlines() if "error" in line.lower()]
    assert len(errors) == 1, err[-3000:]
    return errors[0]


@pytest.mark.slow
def test_train_onto_a_full_disk_ends_in_one_line_and_keeps_whole_checkpoints(small_disk, tmp_path):
    run = cli("train", "--map", MAP_1, "--timesteps", "40000", "--checkpoint-every", "1", "--record-every", "0",
              "--log-dir", str(small_disk), "--name", "full", cwd=tmp_path)  # fmt: skip
    assert run.returncode == 1
    line = _one_error_line(run.stderr)
    run_dir = small_disk / "full"
    assert line.startswith(f"smorphi-rl: error: training stopped: the disk holding {run_dir} is full")
    kept = checkpoints_under(run_dir)
    assert kept and f"the last whole checkpoint is {kept[-1]}" in line
    for checkpoint in kept:
        load_module(checkpoint)
    assert find_checkpoint(run_dir) == kept[-1]


@pytest.mark.slow
def test_sweep_onto_a_full_disk_ends_in_one_line(small_disk, tmp_path):
    config = tmp_path / "full.yaml"
    config.write_text(f"name: full\nalgorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\ntimesteps: 40000\n"
                      "checkpoint: {every: 1}\n")  # fmt: skip
    run = cli("sweep", str(config), "--log-dir", str(small_disk), cwd=tmp_path)
    assert run.returncode == 1
    line = _one_error_line(run.stderr)
    assert line.startswith(f"smorphi-rl: error: the sweep stopped: the disk holding {small_disk / 'full'} is full")
    for checkpoint in checkpoints_under(small_disk / "full"):
        load_module(checkpoint)


def test_a_staging_folder_a_stopped_trial_left_is_removed_when_the_run_ends(tmp_path):
    """Tune stops a trial as it reports its last checkpoint, before the trial leaves its `with`: the staged copy
    (1.5 MB a checkpoint) stayed in the trial's folder of a finished sweep."""
    from smorphi_rl.training.checkpoints import STAGING_PREFIX

    class Tuner:
        def fit(self) -> _Results:
            (tmp_path / "ppo-1" / f"{STAGING_PREFIX}abc" / "learner_group").mkdir(parents=True)
            (tmp_path / "ppo-1" / "checkpoint_000000").mkdir()
            return _Results([])

    _, failed = fit(Tuner(), tmp_path)
    assert failed is None and not list(tmp_path.rglob(f"{STAGING_PREFIX}*"))
    assert (tmp_path / "ppo-1" / "checkpoint_000000").is_dir()  # the checkpoint itself stays


def test_rllibs_error_when_no_env_runner_started_is_told_apart():
    """A runner that fails as it builds its env dies in its worker's log; RLlib then reads the spaces from the first
    of no runners, and the trial's line read "IndexError: list index out of range"."""
    import inspect

    from ray.rllib.env.env_runner_group import EnvRunnerGroup

    from smorphi_rl.training.trial import no_runner_started

    source = inspect.getsource(EnvRunnerGroup.get_spaces)  # RLlib indexes the runners' answers there
    assert ")[0]" in source, "RLlib reads the spaces otherwise now: check `trial.no_runner_started`"

    def get_spaces() -> None:
        [][0]

    def elsewhere() -> None:
        [][0]

    for fn, expected in ((get_spaces, True), (elsewhere, False)):
        try:
            fn()
        except IndexError as exc:
            assert no_runner_started(exc) is expected

"""Resuming a sweep from our own files: the trial list is fixed in advance, stop criteria count across resumes,
a finished trial is never touched, and a state file that names anything but numbers and arrays is refused."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.rundir import RunDirError
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.checkpoints import MODULE_SUBDIR, CheckpointError
from smorphi_rl.training.resume import ELAPSED, KEPT, STATE_FILE, finished, load_state, resume_point, set_aside
from smorphi_rl.training.sweep import drop_unstarted, read_resume, set_aside_started, trial_dirname
from smorphi_rl.training.sweep_config import STOP_METRICS, load_sweep
from smorphi_rl.training.sweep_report import result_files, result_rows
from smorphi_rl.training.trial import stop_reached

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
SWEEP = f"""algorithms: [ppo, appo]
maps: [{MAP_1}]
seeds: [0, 1]
num_samples: 2
search:
  lr: {{loguniform: [0.0001, 0.01]}}
  entropy_coeff: {{grid: [0.0, 0.01]}}
  gamma: {{choice: [0.99, 0.995]}}
"""


def plan_resume(exp, trials):
    """What `sweep --resume` does with a folder: read it back (refusing before anything moves), then set aside."""
    pending, started, unrecorded = read_resume(exp, trials)
    assert not unrecorded
    return pending, set_aside_started(started)


@pytest.fixture
def sweep(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(SWEEP)
    return load_sweep(path)


def test_trials_are_the_grid_with_random_parts_drawn_reproducibly(sweep):
    trials = sweep.trials()
    assert len(trials) == sweep.num_grid_trials == 2 * 2 * 2 * 2
    assert [t["index"] for t in trials] == list(range(16))
    assert trials == load_sweep(sweep.path).trials()  # a resumed sweep finds the same trials
    lrs = [t["hp"]["lr"] for t in trials]
    assert all(1e-4 <= lr <= 1e-2 for lr in lrs) and len(set(lrs)) == 4  # each grid point and sample its own draw
    by_run = {}
    for t in trials:
        by_run.setdefault((t["algo"], t["seed"]), []).append(
            (t["hp"]["entropy_coeff"], t["hp"]["lr"], t["hp"]["gamma"])
        )
    assert len({tuple(v) for v in by_run.values()}) == 1  # shared by every seed and algorithm: a group over seeds
    assert {t["hp"]["entropy_coeff"] for t in trials} == {0.0, 0.01} and {t["hp"]["gamma"] for t in trials} <= {
        0.99, 0.995}  # fmt: skip
    assert json.loads(json.dumps(trials)) == trials  # what params.json records compares equal


def test_every_stop_metric_stops_a_trial():
    for metric in STOP_METRICS:
        assert stop_reached({metric: 5}, iteration=5, steps=5, elapsed_s=5.0)
        assert not stop_reached({metric: 6}, iteration=5, steps=5, elapsed_s=5.0)
    assert not stop_reached({}, iteration=10**6, steps=10**9, elapsed_s=1e6)


def write_trial(exp: Path, trial: dict, rows: list[dict], checkpoints: dict[str, object] | None = None) -> Path:
    """A trial folder as Tune and `run_trial` leave it: params.json, result.json and checkpoints with our state."""
    d = exp / trial_dirname(trial)
    d.mkdir(parents=True)
    (d / "params.json").write_text(json.dumps(trial))
    (d / "result.json").write_text("".join(json.dumps(r) + "\n" for r in rows))
    for name, state in (checkpoints or {}).items():
        c = d / name
        (c / MODULE_SUBDIR).mkdir(parents=True)
        (c / STATE_FILE).write_bytes(pickle.dumps(state))
    return d


def state(iteration: int) -> dict:
    """The shape `save_state` writes (RLlib's learner group and metrics), with one weight."""
    learner = {"rl_module": {"default_policy": {"w": np.zeros(3, np.float32)}}, "optimizer": {"adam": {"lr": 1e-3}},
               "metrics_logger": {"stats": {}}, "weights_seq_no": 3}  # fmt: skip
    return {"learner_group": {"learner": learner}, "metrics_logger": {"stats": {"x": {"stats_cls_identifier": "ema"}}},
            "training_iteration": iteration, "smorphi_time_total_s": 1.5}  # fmt: skip


def row(iteration: int, done: bool = False) -> dict:
    return {keys.ALGO_ITERATION: iteration, keys.TRIAL_DONE: done}


def test_resume_skips_finished_trials_and_continues_started_ones(sweep, tmp_path):
    trials = sweep.trials()
    exp = tmp_path / "exp"
    done = write_trial(exp, trials[0], [row(1), row(2, done=True)], {"checkpoint_000000": state(2)})
    started = write_trial(exp, trials[1], [row(1), row(2), row(3)],
                          {"checkpoint_000000": state(2), "checkpoint_000001": state(4)})  # fmt: skip
    done_before = sorted(done.rglob("*"))
    pending, points = plan_resume(exp, trials)
    assert [t["index"] for t in pending] == list(range(1, 16))  # the never-started ones too
    assert sorted(done.rglob("*")) == done_before and finished(done) and not finished(started)
    # iteration 4's checkpoint has no row (the interrupt landed between them): iteration 2's is the point
    assert points == {1: started / "before-resume-1" / "checkpoint_000000"}
    assert not list(started.glob("checkpoint_*")) and not (started / "result.json").exists()
    assert result_files(started) == [started / "before-resume-1" / "result.json"]
    (started / "result.json").write_text(json.dumps(row(3)) + "\n" + json.dumps(row(4, done=True)) + "\n")
    assert [r[keys.ALGO_ITERATION] for r in result_rows(*result_files(started))] == [1, 2, 3, 4]
    assert finished(started)
    assert set_aside(started) is not None and result_files(started)[-1].parent.name == "before-resume-2"


def test_resume_refuses_a_trial_of_another_sweep_and_moves_nothing(sweep, tmp_path):
    trials = sweep.trials()
    exp = tmp_path / "exp"
    other = dict(trials[1], hp={**trials[1]["hp"], "lr": 0.5})
    d = write_trial(exp, other, [row(1)], {"checkpoint_000000": state(1)})
    with pytest.raises(RunDirError, match="not a trial of this sweep"):
        plan_resume(exp, trials)
    assert (d / "checkpoint_000000").is_dir()


class Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('ran')",))


def test_a_crafted_state_file_is_refused_before_anything_moves(sweep, tmp_path):
    trials = sweep.trials()
    marker = tmp_path / "ran"
    d = write_trial(tmp_path / "exp", trials[0], [row(1)], {"checkpoint_000000": Payload(marker)})
    with pytest.raises(CheckpointError, match=f"{STATE_FILE}: refused, it names builtins.exec"):
        plan_resume(tmp_path / "exp", trials)
    assert not marker.exists() and (d / "checkpoint_000000").is_dir() and (d / "result.json").is_file()


def kept(**changed: object) -> dict:
    """A kept policy's record as `save_state` writes it, for `state`'s module (one weight `w` of 3)."""
    return {"score": [18, -0.25], "env_steps": 4000, "weights": {"w": np.ones(3, np.float32)}} | changed


def test_a_state_file_with_the_run_s_kept_policy_loads(tmp_path):
    (tmp_path / STATE_FILE).write_bytes(pickle.dumps({**state(2), KEPT: kept()}))
    assert load_state(tmp_path)[KEPT]["env_steps"] == 4000


def test_a_run_ended_on_its_kept_policy_resumes_from_the_weights_it_trained(tmp_path):
    """The run's end puts the kept policy in the learner (its checkpoint's policy), but a run stopped early (Ctrl-C,
    a scheduler's SIGTERM) went on from that policy when resumed, with the trained weights' optimiser moments: the
    state file now holds the trained weights as the learner's, and the kept policy beside them."""
    from types import SimpleNamespace

    from smorphi_rl.training.resume import save_state

    ending = state(2)  # the learner holds the kept policy (ones) after the run's end
    ending["learner_group"]["learner"]["rl_module"]["default_policy"] = {"w": np.ones(3, np.float32)}
    algo = SimpleNamespace(get_state=lambda not_components: {**ending, "env_runner": {}})
    trained = {"w": np.full(3, 2.0, np.float32)}
    save_state(algo, tmp_path, 1.5, kept(), trained)
    loaded = load_state(tmp_path)
    assert loaded["learner_group"]["learner"]["rl_module"]["default_policy"]["w"].tolist() == [2.0] * 3
    assert loaded[KEPT]["weights"]["w"].tolist() == [1.0] * 3 and loaded["learner_group"]["learner"]["optimizer"]
    assert ending["learner_group"]["learner"]["rl_module"]["default_policy"]["w"].tolist() == [1.0] * 3  # untouched
    save_state(algo, tmp_path, 1.5, kept())  # no trained weights set aside: the learner's own
    assert load_state(tmp_path)["learner_group"]["learner"]["rl_module"]["default_policy"]["w"].tolist() == [1.0] * 3


@pytest.mark.parametrize("bad", [[1, 2], {**state(1), "extra": 1}, {**state(1), "training_iteration": 0},
                                 {**state(1), "learner_group": [1]}, {**state(1), KEPT: [1]},
                                 {**state(1), KEPT: kept(score=[True, 0.0])},
                                 {**state(1), KEPT: kept(score=[3, float("nan")])},
                                 {**state(1), KEPT: kept(env_steps=-1)},
                                 {**state(1), KEPT: kept(weights={"w": np.ones(4, np.float32)})},
                                 {**state(1), KEPT: kept(weights={"v": np.ones(3, np.float32)})},
                                 {**state(1), KEPT: kept(weights={"w": np.full(3, np.inf, np.float32)})},
                                 {**state(1), KEPT: kept(weights={"w": np.ones(3, np.float64)})},
                                 {**state(1), KEPT: kept(score=[-1, 0.0])}])  # fmt: skip
def test_a_state_file_of_another_shape_is_refused(tmp_path, bad):
    (tmp_path / STATE_FILE).write_bytes(pickle.dumps(bad))
    with pytest.raises(CheckpointError, match=STATE_FILE):
        load_state(tmp_path)


@pytest.mark.parametrize("field", ["training_iteration", "elapsed", "score", "env_steps"])
def test_a_state_file_s_refused_value_is_named_in_a_short_line(tmp_path, field):
    """A string of 100 KB shared 200 times (100 KB of pickle) made a refusal of 20 million characters."""
    shared = ["x" * 100_000] * 200
    bad = {
        "training_iteration": {**state(1), "training_iteration": shared},
        "score": {**state(1), KEPT: kept(score=shared)},
        "env_steps": {**state(1), KEPT: kept(env_steps=shared)},
    }
    bad["elapsed"] = {**state(1), ELAPSED: shared}
    (tmp_path / STATE_FILE).write_bytes(pickle.dumps(bad[field]))
    with pytest.raises(CheckpointError, match="a list of 200 items") as refused:
        load_state(tmp_path)
    assert len(str(refused.value)) < len(str(tmp_path)) + 300


def test_a_trial_without_a_state_file_starts_afresh(sweep, tmp_path):
    d = write_trial(tmp_path, sweep.trials()[0], [row(1)])
    assert resume_point(d) is None


def test_rows_past_the_checkpoint_a_resume_continued_from_are_dropped_even_where_not_reached_again(tmp_path):
    """A resumed run stopped again before it re-reached the iterations the kill had discarded: those rows stayed in
    its curves (a transfer run's convergence), where its own report left them out."""
    aside, own = tmp_path / "aside.json", tmp_path / "result.json"
    aside.write_text("".join(json.dumps(row(i) | {"n": "old"}) + "\n" for i in range(1, 6)))
    own.write_text(json.dumps(row(4) | {"n": "new"}) + "\n")  # continued from iteration 3's checkpoint
    assert [(r[keys.ALGO_ITERATION], r["n"]) for r in result_rows(aside, own)] == [
        (1, "old"), (2, "old"), (3, "old"), (4, "new")]  # fmt: skip


def test_a_transfer_run_is_continued_only_where_train_resume_would_continue_it(sweep, tmp_path):
    """`transfer --resume` continues a cut run when `can_continue` says so: one whose summary does not say it stopped
    early would then be refused by `continue_train_run` as finished, on every resume of the job."""
    from smorphi_rl.training.resume import can_continue

    trial = sweep.trials()[0]
    write_trial(tmp_path, trial, [row(1), row(2)], {"checkpoint_000000": state(2)})
    assert not can_continue(tmp_path, trial["algo"])  # no config.json: no run of `train`
    (tmp_path / "config.json").write_text("{}")
    assert can_continue(tmp_path, trial["algo"])  # killed: no summary
    for interrupted, expected in ((True, True), (None, False), (False, False)):
        (tmp_path / "summary.json").write_text(json.dumps({"interrupted": interrupted}))
        assert can_continue(tmp_path, trial["algo"]) is expected
    (tmp_path / "summary.json").write_text("{not json")
    assert not can_continue(tmp_path, trial["algo"])
    (tmp_path / "summary.json").unlink()
    (tmp_path / trial_dirname(trial) / "checkpoint_000000" / STATE_FILE).write_bytes(b"\x80\x04")
    assert not can_continue(tmp_path, trial["algo"])  # no state that reads: trained again
    (tmp_path / trial_dirname(trial) / "checkpoint_000000" / STATE_FILE).write_bytes(pickle.dumps({"x": print}))
    with pytest.raises(CheckpointError, match="refused"):  # one read and refused for what it holds stops the job
        can_continue(tmp_path, trial["algo"])


def test_a_newest_state_file_cut_short_is_passed_over_for_the_one_before(sweep, tmp_path):
    """Killed as Tune copied its newest checkpoint: that state file is cut short, and the resume was refused where
    the checkpoint before it reads. With none before it that reads, the error names the file."""
    checkpoints = {f"checkpoint_{i:06d}": state(i + 1) for i in range(3)}
    d = write_trial(tmp_path, sweep.trials()[0], [row(1), row(2), row(3)], checkpoints)
    newest = d / "checkpoint_000002" / STATE_FILE
    whole = newest.read_bytes()
    newest.write_bytes(whole[: len(whole) // 2])
    said: list[str] = []
    assert resume_point(d, said) == d / "checkpoint_000001"
    assert said == [f"{d}: the state file of checkpoint_000002 does not read (cut short by a kill?): it resumes from "
                    "checkpoint_000001"]  # fmt: skip
    newest.write_bytes(pickle.dumps({"training_iteration": print}))  # read, and refused for what it holds: named
    with pytest.raises(CheckpointError, match="refused"):
        resume_point(d)
    newest.write_bytes(whole[: len(whole) // 2])
    for name in ("checkpoint_000000", "checkpoint_000001"):
        (d / name / STATE_FILE).write_bytes(b"\x80\x04")
    with pytest.raises(CheckpointError, match=f"checkpoint_000002/{STATE_FILE}"):
        resume_point(d)


def test_result_lines_that_are_no_rows_of_ours_are_skipped(tmp_path):
    """Among them a row of empty lists (3 bytes of text each, some 60 in memory: a 67 MB file took 2.1 GB)."""
    path = tmp_path / "result.json"
    path.write_text("\n".join([json.dumps(row(1)), "garbage", "{not json", "[1, 2, 3]", '"str"',
                               json.dumps({keys.ALGO_ITERATION: "2"}), "[" * 20000 + "]" * 20000,
                               json.dumps(row(4) | {"x": [[]] * 10_000}),
                               json.dumps(row(2) | {keys.STEPS: 4000})]) + "\n")  # fmt: skip
    assert [r[keys.ALGO_ITERATION] for r in result_rows(path)] == [1, 2]


@pytest.mark.parametrize(
    "damage", ["same index twice", "folder of another trial", "params not json", "params gone", "a link"]
)
def test_resume_refuses_a_folder_whose_trial_records_do_not_add_up(sweep, tmp_path, damage):
    trials = sweep.trials()
    exp = tmp_path / "exp"
    write_trial(exp, trials[0], [row(1)], {"checkpoint_000000": state(1)})
    second = write_trial(exp, trials[1], [row(1)], {"checkpoint_000000": state(1)})
    if damage == "same index twice":
        (exp / "extra").mkdir()
        (exp / "extra" / "params.json").write_text(json.dumps(trials[1]))
    elif damage == "folder of another trial":
        (second / "params.json").write_text(json.dumps(trials[0]))
    elif damage == "params not json":
        (second / "params.json").write_text("{not json")
    elif damage == "params gone":  # a finished trial whose record is gone was trained again over its checkpoints
        (second / "params.json").unlink()
    else:  # the resume wrote the trial's tables into the folder a link pointed to
        elsewhere = tmp_path / "elsewhere"
        second.rename(elsewhere)
        second.symlink_to(elsewhere, target_is_directory=True)
    listing = sorted(exp.rglob("*"))
    with pytest.raises(RunDirError, match=r"resume only sweeps you ran|without its params\.json"):
        plan_resume(exp, trials)
    assert sorted(exp.rglob("*")) == listing


@pytest.mark.parametrize("bad", ["fifo", "dir", {**state(1), "training_iteration": 10**30},
                                 {**state(1), "training_iteration": True},
                                 {**state(1), "learner_group": {"learner": "hello"}},
                                 {**state(1), "learner_group": {"learner": {"rl_module": {"default_policy": {
                                     "w": [1, 2, "x"]}}, "optimizer": {}}}},
                                 {**state(1), "metrics_logger": {"stats": {"x": {
                                     "v": np.array(["a"], dtype=object)}}}}],
                         ids=["fifo", "dir", "huge-iteration", "bool-iteration", "learner-str", "weights-list",
                              "object-array"])  # fmt: skip
def test_a_damaged_state_file_is_refused_before_anything_moves(sweep, tmp_path, bad):
    import os

    exp = tmp_path / "exp"
    d = write_trial(exp, sweep.trials()[0], [row(1)], {"checkpoint_000000": state(1)})
    target = d / "checkpoint_000000" / STATE_FILE
    target.unlink()
    if bad == "fifo":
        os.mkfifo(target)
    elif bad == "dir":
        target.mkdir()
    else:
        target.write_bytes(pickle.dumps(bad))
    listing = sorted(exp.rglob("*"))
    with pytest.raises(CheckpointError, match=STATE_FILE):
        plan_resume(exp, sweep.trials())
    assert sorted(exp.rglob("*")) == listing


def test_set_aside_numbers_after_the_highest_folder(sweep, tmp_path):
    d = write_trial(tmp_path, sweep.trials()[0], [row(1)], {"checkpoint_000000": state(1)})
    (d / "before-resume-2").mkdir()
    assert set_aside(d) == d / "before-resume-3"


@pytest.mark.parametrize("copy", [b"[" * 20000 + b"]" * 20000, b"\xff\xfe", b"a: *x", b"", b"- 1\n"])
def test_a_damaged_copy_of_the_sweep_file_is_one_line(sweep, tmp_path, copy):
    """An emptied copy was reported as "the sweep file has changed: restore it from" that empty copy."""
    from smorphi_rl.training.sweep import SWEEP_COPY, prepare_experiment

    exp = tmp_path / "logs" / sweep.name
    exp.mkdir(parents=True)
    (exp / SWEEP_COPY).write_bytes(copy)
    with pytest.raises(RunDirError, match="not the sweep file smorphi-rl copied there"):
        prepare_experiment(sweep, tmp_path / "logs", resume=True)


def test_a_sweep_folder_that_lost_its_copy_of_the_sweep_file_says_so(sweep, tmp_path):
    """It said the folder held no sweep at all, beside the trials and records of one."""
    from smorphi_rl.training.sweep import MAPS_RECORD, prepare_experiment

    exp = tmp_path / "logs" / sweep.name
    exp.mkdir(parents=True)
    (exp / MAPS_RECORD).write_text("{}")
    with pytest.raises(RunDirError, match=r"has lost sweep\.yaml, the copy of the sweep file it ran"):
        prepare_experiment(sweep, tmp_path / "logs", resume=True)


def test_a_sweep_folder_holding_a_link_is_refused_before_the_resume_claims_it(sweep, tmp_path):
    """Tune wrote its tuner.pkl through a planted link, outside the folder the user named."""
    from smorphi_rl.rundir import MARKER
    from smorphi_rl.training.sweep import SWEEP_COPY, prepare_experiment

    exp = tmp_path / "logs" / sweep.name
    exp.mkdir(parents=True)
    (exp / SWEEP_COPY).write_bytes(sweep.path.read_bytes())
    (tmp_path / "victim").write_text("keep")
    (exp / "tuner.pkl").symlink_to(tmp_path / "victim")
    with pytest.raises(RunDirError, match=r"tuner\.pkl: a link inside"):
        prepare_experiment(sweep, tmp_path / "logs", resume=True)
    assert (tmp_path / "victim").read_text() == "keep" and not (exp / MARKER).exists()


def test_a_kept_policy_of_a_real_module_round_trips_and_names_must_be_the_trial_s(tmp_path):
    """What `kept_policy` writes of a real module loads back (`load_state`), fits that module and is put back into
    it; a file whose two weight tables both lack or add a name, which RLlib's lenient restore would take, does not
    fit the trial's module and is refused in one line."""
    import torch

    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.callbacks import MorphologyCallbacks
    from smorphi_rl.training.checkpoints import build_module
    from smorphi_rl.training.resume import check_fits

    env_config = EnvConfig().to_dict()
    env = MorphologyEnv(env_config)
    module = build_module(env.observation_space, env.action_space, {"value_offset": 0.0, "value_scale": 1.0,
                          "policy_angle_frequencies": 0, "env_config": env_config, "algorithm": "ppo"})  # fmt: skip
    ours = {k: v.detach().numpy() for k, v in module.state_dict().items()}
    hooks = MorphologyCallbacks()
    hooks._kept = ((18, -0.25), 4000, {k: v + 1 for k, v in module.state_dict().items()}, None, [])
    written = state(2)
    written["learner_group"]["learner"]["rl_module"]["default_policy"] = ours
    (tmp_path / STATE_FILE).write_bytes(pickle.dumps({**written, KEPT: hooks.kept_policy()}))
    loaded = load_state(tmp_path)
    check_fits(loaded, ours, tmp_path)
    again = MorphologyCallbacks()
    again.restore_kept(loaded[KEPT])
    module.load_state_dict(again._kept[2])  # strict: every name, every shape
    assert again._kept[:2] == ((18, -0.25), 4000)
    first = next(iter(ours))
    assert torch.equal(module.state_dict()[first], torch.from_numpy(ours[first] + 1))
    for table in (loaded["learner_group"]["learner"]["rl_module"]["default_policy"], loaded[KEPT]["weights"]):
        table["extra"] = np.zeros(2, np.float32)
    with pytest.raises(CheckpointError, match=r"not this trial's module's \(missing \[\], extra \['extra'\]"):
        check_fits(loaded, ours, tmp_path)


def test_a_resume_is_refused_while_the_sweep_still_runs(sweep, tmp_path):
    """`sweep --resume` claimed nothing: a resume while the sweep (or another resume) ran would set aside the
    checkpoints and results the other process was still writing."""
    import os
    import subprocess
    import sys

    from smorphi_rl.rundir import MARKER
    from smorphi_rl.training.sweep import SWEEP_COPY, prepare_experiment

    exp = tmp_path / "logs" / sweep.name
    exp.mkdir(parents=True)
    (exp / SWEEP_COPY).write_bytes(sweep.path.read_bytes())
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        (exp / MARKER).write_text(f"pid {live.pid} at 2026-01-01T00:00:00\n")
        with pytest.raises(RunDirError, match=f"is in use by process {live.pid}"):
            prepare_experiment(sweep, tmp_path / "logs", resume=True)
    finally:
        live.kill()
        live.wait()
    assert prepare_experiment(sweep, tmp_path / "logs", resume=True) == exp.resolve()  # the process gone: claimed
    assert f"pid {os.getpid()}" in (exp / MARKER).read_text()


@pytest.mark.parametrize("damage", [{keys.STEPS: "abc"}, {keys.STEPS: float("inf")}, {keys.ENV_RUNNERS: []}],
                         ids=["steps a string", "steps infinite", "env_runners a list"])  # fmt: skip
def test_a_finished_trial_whose_records_are_damaged_is_named_in_one_line(sweep, tmp_path, damage):
    """Each of these ended `sweep --resume` in a traceback, after the pending trials had trained."""
    from smorphi_rl.training.sweep_report import SweepReadError, read_sweep

    exp = tmp_path / "exp"
    write_trial(exp, sweep.trials()[0], [row(1), row(2, done=True) | damage])
    with pytest.raises(SweepReadError, match="its records are not what smorphi-rl writes"):
        read_sweep(exp)


def test_a_resume_on_maps_edited_since_the_sweep_started_is_refused(tmp_path):
    """A map file replaced between the start and the resume once had the finished trials' summaries report the new
    floor's digest and optimum for shapes found on the old one (`compare` then read a gap of -0.40)."""
    from smorphi_rl.training.sweep import MAPS_RECORD, check_maps_unchanged

    exp = tmp_path / "exp"
    exp.mkdir()
    check_maps_unchanged(exp, {"m1": {"m1": "aaa"}})  # a sweep started before the record: nothing to compare
    (exp / MAPS_RECORD).write_text(json.dumps({"m1": {"m1": "aaa"}}))
    check_maps_unchanged(exp, {"m1": {"m1": "aaa"}})
    with pytest.raises(RunDirError, match="map m1 is not the floor sweep exp started on"):
        check_maps_unchanged(exp, {"m1": {"m1": "bbb"}})


def test_an_empty_folder_tune_made_before_a_stop_is_a_trial_that_never_started(sweep, tmp_path):
    """Stopped between two trials, a sweep left the second's folder empty, and its own resume command refused it."""
    trials = sweep.trials()
    exp = tmp_path / "exp"
    (exp / trial_dirname(trials[1])).mkdir(parents=True)
    pending, started, unrecorded = read_resume(exp, trials)
    assert trials[1] in pending and not started and not unrecorded
    assert (exp / trial_dirname(trials[1])).is_dir()  # nothing moved yet
    drop_unstarted(exp, pending)
    assert not (exp / trial_dirname(trials[1])).exists()


def test_a_trial_killed_as_it_wrote_its_first_checkpoint_is_kept_aside_and_trains_again(sweep, tmp_path):
    """SIGKILLed there, the trial's folder held its checkpoint while its params.json and results were still in Ray's
    staging folder: every `--resume` was refused until the folder was moved by hand."""
    import io

    from smorphi_rl.training.sweep import set_aside_unrecorded

    trials = sweep.trials()
    exp = tmp_path / "exp"
    cut = exp / trial_dirname(trials[2]) / "checkpoint_000000"
    cut.mkdir(parents=True)
    (cut / "rllib_checkpoint.json").write_text("{}")
    pending, started, unrecorded = read_resume(exp, trials)
    assert trials[2] in pending and not started and unrecorded == [cut.parent]
    out = io.StringIO()
    set_aside_unrecorded(unrecorded, out)
    kept = cut.parent.with_name(cut.parent.name + ".cut-1")
    assert (kept / "checkpoint_000000" / "rllib_checkpoint.json").is_file() and not cut.parent.exists()
    assert f"kept as {kept.name}, and the trial trains again" in out.getvalue()
    assert read_resume(exp, trials)[2] == []  # the kept folder is no trial's: the next resume passes it by


def test_train_resume_refuses_what_it_cannot_continue_in_one_line(tmp_path):
    """No run, a finished one, one trained otherwise, one without a checkpoint to continue from, one in use."""
    import json
    import subprocess
    import sys

    from smorphi_rl.rundir import MARKER
    from smorphi_rl.training.config import TrainConfig, TrainConfigError
    from smorphi_rl.training.resume import continue_train_run
    from smorphi_rl.training.run import train

    cfg = TrainConfig(timesteps=4000)
    with pytest.raises(TrainConfigError, match="--resume continues a run: give its --name"):
        train(cfg, log_dir=tmp_path, resume=True)
    run = tmp_path / "run"
    with pytest.raises(TrainConfigError, match=r"there is no run .*run to continue"):
        continue_train_run(run, cfg.to_dict(), "ppo")
    run.mkdir()
    with pytest.raises(TrainConfigError, match=r"holds no run of `train` \(no config\.json\)"):
        continue_train_run(run, cfg.to_dict(), "ppo")
    (run / "config.json").write_text(json.dumps(cfg.to_dict() | {"timesteps": 8000, "name": "run"}))
    with pytest.raises(TrainConfigError, match=r"trained with other settings \(timesteps.*give the options it ran"):
        continue_train_run(run, cfg.to_dict(), "ppo")
    (run / "config.json").write_text(json.dumps(cfg.to_dict() | {"name": "run", "address": None}))
    (run / "ppo-1").mkdir()
    with pytest.raises(TrainConfigError, match="holds no checkpoint to continue from"):
        continue_train_run(run, cfg.to_dict(), "ppo")
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        (run / MARKER).write_text(f"pid {live.pid} at 2026-01-01T00:00:00\n")
        with pytest.raises(RunDirError, match=f"in use by process {live.pid}"):
            continue_train_run(run, cfg.to_dict(), "ppo")
    finally:
        live.kill()
        live.wait()
    (run / "summary.json").write_text('{"interrupted": true}')  # Ctrl-C, or a scheduler's SIGTERM before its kill
    with pytest.raises(TrainConfigError, match="holds no checkpoint to continue from"):  # resumable, but not this one
        continue_train_run(run, cfg.to_dict(), "ppo")
    (run / "summary.json").write_text('{"interrupted": false}')
    with pytest.raises(TrainConfigError, match=r"finished \(its summary\.json\): nothing to continue"):
        continue_train_run(run, cfg.to_dict(), "ppo")
    (run / "ppo-1").rmdir()
    with pytest.raises(TrainConfigError, match="holds no trial folder of ppo: nothing to continue from"):
        (run / "summary.json").unlink()
        continue_train_run(run, cfg.to_dict(), "ppo")
    # a row whose env steps read Infinity: the resume ended in an OverflowError
    trial = run / "ppo-1"
    (trial / "checkpoint_000000" / MODULE_SUBDIR).mkdir(parents=True)
    (trial / "checkpoint_000000" / STATE_FILE).write_bytes(pickle.dumps(state(2)))
    rows = [row(1) | {keys.STEPS: 2000}, row(2) | {keys.STEPS: float("inf")}]
    (trial / "result.json").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(TrainConfigError, match=r"env steps at iteration 2 read inf, not what smorphi-rl writes"):
        continue_train_run(run, cfg.to_dict(), "ppo")


def test_a_run_is_not_continued_on_a_map_file_changed_since(tmp_path):
    """A killed run resumed on a map edited since trained on a floor its checkpoints never saw: its config.json now
    records the maps' digests, as a finished run's summary does."""
    from smorphi_rl.training.config import TrainConfig, TrainConfigError
    from smorphi_rl.training.resume import continue_train_run

    cfg, run = TrainConfig(), tmp_path / "run"
    run.mkdir()
    recorded = {"name": "run", "address": None, "map_digests": {"map-1": "a" * 24}}
    (run / "config.json").write_text(json.dumps(cfg.to_dict() | recorded))
    with pytest.raises(TrainConfigError, match="trained on another floor named 'map-1' \\(the map file changed since"):
        continue_train_run(run, cfg.to_dict(), cfg.algo, {"map-1": "b" * 24})
    with pytest.raises(TrainConfigError, match="holds no trial folder"):  # the same floor: on to the next check
        continue_train_run(run, cfg.to_dict(), cfg.algo, {"map-1": "a" * 24})

"""The transfer job's Table 5, from synthetic runs (no Ray): intervals over seeds, non-converged runs named."""

from dataclasses import replace
from pathlib import Path

import pytest

from smorphi_rl.training.transfer import TransferRun, write_transfer_report


def _run(mode: str, seed: int, converged_at: float | None, plateau: float) -> TransferRun:
    curve = {
        "env_steps": [0.0, 10_000.0],
        "eval_R1": [80.0, plateau],
        "episode_return_mean": [1.0, 2.0],
        "best_R1": [85.0, 89.0],
        "final_R1": [80.0, 85.0],
        "eval_gap": [5.0, 1.0],
        "eval_within": [0.0, 0.5],
    }
    return TransferRun("val-1", seed, mode, 20_000, converged_at, plateau, 89.0, True, Path("."), curve)


def test_table_5_has_intervals_and_counts_runs_that_never_converged(tmp_path):
    runs = [
        _run("fine-tune", 0, 2_000, 88.0),
        _run("fine-tune", 1, 4_000, 88.4),
        _run("fine-tune", 2, None, 87.0),
        _run("scratch", 0, 6_000, 87.5),
        _run("scratch", 1, 8_000, 87.9),
        _run("scratch", 2, 16_000, 88.1),  # median 8,000, mean 10,000
    ]
    files = write_transfer_report(tmp_path, runs)
    row = next(line for line in files["md"].read_text().splitlines() if line.startswith("| val-1"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # the run that never converged is not a number, and not left out (2,000 and 4,000 alone would give 3,000):
    # it counts as past the 20,000-step budget, above every run that converged
    assert cells[1] == "4,000 [2,000, inf]" and cells[2] == "2 of 3"
    assert cells[3].startswith("8,000 [") and cells[4] == "3 of 3"
    assert cells[5] == "2.00 [0.00, 8.00]"  # the medians: 8,000 / 4,000, exact; a resample may lose fine-tuning's
    assert files["png"].is_file()
    runs[1] = _run("fine-tune", 1, None, 87.0)  # most fine-tuned runs never converged: their median is past 20,000
    row = next(line for line in write_transfer_report(tmp_path, runs)["md"].read_text().splitlines()
               if line.startswith("| val-1"))  # fmt: skip
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1].startswith("> 20,000 [") and cells[2] == "1 of 3"
    assert cells[5].startswith("< 0.40 [")  # at most 8,000 / 20,000: a bound, never a number it cannot be
    runs[1:3] = [_run("fine-tune", 1, 4_000, 88.4), _run("fine-tune", 2, 3_000, 87.0)]  # every run converged
    row = next(line for line in write_transfer_report(tmp_path, runs)["md"].read_text().splitlines()
               if line.startswith("| val-1"))  # fmt: skip
    assert [c.strip() for c in row.strip("|").split("|")][5].startswith("2.67 [")  # 8,000 / 3,000


def test_table_5_compares_the_modes_at_equal_env_steps(tmp_path):
    """A head start shows before either mode converges: each run's greedy gap at a tenth of the budget."""
    runs = [_run("fine-tune", s, None, 88.0) for s in range(3)] + [_run("scratch", s, None, 88.0) for s in range(3)]

    def curve(r: TransferRun, gap: float) -> dict[str, list[float]]:
        by_key = {k: v + v for k, v in r.curve.items()}  # four evaluations
        by_key["env_steps"] = [1_000.0, 2_000.0, 3_000.0, 20_000.0]
        by_key["eval_gap"] = [gap, 0.5 * gap, 0.1, 0.1] if r.mode == "fine-tune" else [4.0, 3.0 + r.seed, 0.1, 0.1]
        return by_key

    runs = [replace(r, curve=curve(r, gap)) for r, gap in zip(runs, (2.0, 1.0, 3.0, 0, 0, 0), strict=True)]
    files = write_transfer_report(tmp_path, runs)
    text = files["md"].read_text()
    assert "| Gap at 2,000 env steps fine-tuned | scratch |" in text  # a tenth of the 20,000-step budget
    cells = [c.strip() for c in next(line for line in text.splitlines() if line.startswith("| val-1")).split("|")]
    assert cells[7].startswith("1.00 [") and cells[8].startswith("4.00 [")  # medians of (1, 0.5, 1.5), (3, 4, 5)
    assert files["csv"].read_text().splitlines()[1].split(",")[7:9] == ["2000", "1.000"]
    from smorphi_rl.training.transfer import equal_steps

    short = [replace(r, env_steps=4_000) for r in runs]  # a tenth, 400, comes before any evaluation: the first
    assert equal_steps(short) == 1_000


def test_a_job_stopped_before_a_maps_scratch_runs_still_writes_its_table(tmp_path):

    from smorphi_rl.training.transfer import by_map

    cut = replace(_run("scratch", 0, None, 80.0), interrupted=True)  # its shorter budget is no scratch figure
    runs = [_run("fine-tune", 0, 2_000, 88.0), cut]
    files = write_transfer_report(tmp_path, runs)
    row = next(line for line in files["md"].read_text().splitlines() if line.startswith("| val-1"))
    assert row.rstrip().endswith("| 89.00 / - |")  # no scratch run finished: no best, not "nan"
    unfinished = [replace(r, best_R1=float("nan")) for r in runs]  # no episode ended within the budget
    row = next(line for line in write_transfer_report(tmp_path, unfinished)["md"].read_text().splitlines()
               if line.startswith("| val-1"))  # fmt: skip
    assert row.rstrip().endswith("| - / - |")
    assert "nan" not in files["csv"].read_text()  # the CSV leaves a cell empty, as the table says "-"
    assert by_map(runs)[0].ratio.n == 0  # no scratch run finished its budget: no ratio
    assert by_map(runs)[0].scratch == [] and "Runs cut short (1; transfer.csv) are left out" in files["md"].read_text()
    assert files["csv"].read_text().splitlines()[-1].endswith(",True")


def test_a_transfer_job_is_checked_when_made():
    import pytest

    from smorphi_rl.training.config import TrainConfigError
    from smorphi_rl.training.transfer import TransferJob

    job = TransferJob("ckpt", ("maps/val-1.yaml",), seeds=(0, 1), timesteps=5_000)
    assert job.train_config().timesteps == 5_000 and job.train_config().algo == "ppo"
    with pytest.raises(TrainConfigError, match="seeds"):
        TransferJob("ckpt", ("maps/val-1.yaml",), seeds=(0, -1))
    with pytest.raises(TrainConfigError, match="unknown algorithm"):
        TransferJob("ckpt", ("maps/val-1.yaml",), algo="a3c")
    with pytest.raises(TrainConfigError, match="share the name 'val-1'"):  # one name: its runs would collide
        TransferJob("ckpt", ("maps/val-1.yaml", "other/val-1.yaml"))
    with pytest.raises(TrainConfigError, match="share the name 'val_1'"):  # the runs' folders are named alike
        TransferJob("ckpt", ("maps/val 1.yaml", "maps/val_1.yaml"))
    with pytest.raises(TrainConfigError, match="not generated floors"):  # was "map file not found: generate:mixed"
        TransferJob("ckpt", ("generate:mixed",))


def test_reproduce_states_the_transfer_claim_with_the_ratio_of_medians():
    from smorphi_rl.reproduce import _transfer_claims

    runs = [_run("fine-tune", s, 1_000, 88.0) for s in range(3)]
    runs += [_run("scratch", s, at, 88.0) for s, at in enumerate((6_000, 6_000, 20_000))]
    adapts, line = _transfer_claims(runs)
    assert "ratio of medians 6.00" in line and "**agrees**" in line  # medians 6,000 / 1,000 (the means would give 10.7)
    assert "adapts faster" in adapts and "at 2,000 env steps" in adapts and "**undecided**" in adapts  # equal gaps
    runs[3:] = [_run("scratch", s, at, 88.0) for s, at in enumerate((6_000, None, None))]
    _, bound = _transfer_claims(runs)  # the scratch median lies past the 20,000-step budget: at least 20x
    assert "ratio of medians > 20.00" in bound and "scratch 1 of 3" in bound and "**agrees**" in bound
    _, none = _transfer_claims([_run("fine-tune", 0, None, 88.0), _run("scratch", 0, None, 88.0)])
    assert "Not testable here" in none and "fine-tuned 0 of 1" in none
    _, lone = _transfer_claims([_run("fine-tune", 0, 1_000, 88.0), _run("scratch", 0, 6_000, 88.0)])
    assert "ratio of medians 6.00 (1 seed)" in lone  # one seed decides nothing
    assert "**undecided** (1 seed: too few to decide)" in lone

    runs[3:] = [_run("scratch", s, at, 88.0) for s, at in enumerate((5_000, 5_000, 5_000))]
    _, edge = _transfer_claims(runs)  # exactly five-fold: bench_transfer.py's verdict and reproduce's are one
    assert "(meets target)" in edge and "**agrees**" in edge


def test_the_speedup_verdict_reads_the_medians_and_the_whole_interval():
    """mixed-1000001's `> 5.00 [1.50, inf]` counted as meeting the target with nothing said of its interval."""
    import math

    from smorphi_rl.stats import Interval
    from smorphi_rl.training.transfer import speedup

    v = speedup(Interval(5.0, 1.5, math.inf, 3, ">"))
    assert (v.met, v.whole, v.word) == (True, False, "**undecided**") and "its interval reaching below" in v.text
    v = speedup(Interval(6.0, 5.5, 8.0, 3))
    assert (v.met, v.whole, v.word) == (True, True, "**agrees**") and v.text.endswith("(meets target)")
    v = speedup(Interval(2.0, 1.0, 3.0, 3))
    assert (v.met, v.below, v.word) == (False, True, "**does not agree**") and v.text.endswith("(misses target)")
    v = speedup(Interval(2.0, 1.0, 8.0, 3))
    assert (v.below, v.word) == (False, "**undecided**") and "its interval reaching above" in v.text
    assert "cannot tell" in speedup(Interval(2.0, 1.0, math.inf, 3, ">")).text
    assert "no exact optimum" in speedup(Interval(2.0, 1.0, 3.0, 3), unmeasured=True).text
    assert "past the budget" in speedup(Interval(math.nan, math.nan, math.nan, 0)).text
    one = speedup(Interval(6.0, 6.0, 6.0, 1))  # one seed has no interval to agree
    assert (one.met, one.whole, one.word) == (True, False, "**undecided**") and one.text.endswith("(meets target)")
    two = speedup(Interval(7.0, 6.0, 8.0, 2))  # two seeds' range holds the median half the time: no verdict either
    assert (two.met, two.whole, two.word) == (True, False, "**undecided**")


def test_a_resume_that_leaves_out_maps_or_seeds_the_job_ran_is_one_line(tmp_path):
    """The table covers every run of the job: a resume with fewer maps or seeds would drop finished runs from it."""
    import json

    import pytest

    from smorphi_rl.training.config import TrainConfigError
    from smorphi_rl.training.transfer import JOB_FILE, TransferJob, check_nothing_left_out

    (tmp_path / JOB_FILE).write_text(json.dumps({"maps": ["maps/val-1.yaml", "maps/val-2.yaml"], "seeds": [0, 1]}))
    more = TransferJob("ckpt", ("maps/val-1.yaml", "/elsewhere/val-2.yaml", "maps/val-3.yaml"), seeds=(0, 1, 2))
    check_nothing_left_out(tmp_path, more)  # the same maps by name, and new ones: fine
    with pytest.raises(TrainConfigError, match=r"the job also ran maps/val-2\.yaml, seed 1: give every map and seed"):
        check_nothing_left_out(tmp_path, TransferJob("ckpt", ("maps/val-1.yaml",), seeds=(0,)))


@pytest.fixture
def fake_runs(tmp_path, monkeypatch):
    """`transfer` through the CLI on val-1 with the checkpoint, Ray and training replaced: `stops` names the
    training calls (1-based) stopped by Ctrl-C, after (`"reported"`) or before their first report, or as they ended
    (`"as it ended"`: the run whole), or failing (`"error"`). Returns the argv, the runs trained, `stops` and each
    run's algorithm."""
    import contextlib
    from types import SimpleNamespace

    from smorphi_rl import cluster
    from smorphi_rl.training import checkpoints, finetune, run, transfer

    monkeypatch.setattr(checkpoints, "find_checkpoint", lambda path: Path(path))
    monkeypatch.setattr(checkpoints, "load_module", lambda path: SimpleNamespace(model_config={"env_config": {}}))
    monkeypatch.setattr(finetune, "check_pretrained", lambda checkpoint, env: "digest")
    monkeypatch.setattr(cluster, "check_reachable", lambda address, client=True: None)
    monkeypatch.setattr(cluster, "ray_session", lambda address: contextlib.nullcontext())
    calls: list[str] = []
    algos: list[str] = []
    stops: dict[int, str] = {}

    def train(cfg, name, log_dir, **kwargs):
        calls.append(name)
        algos.append(cfg.algo)
        (Path(kwargs.get("optima_log_dir", log_dir)) / ".cache").mkdir(exist_ok=True)  # as the real one caches
        if stops.get(len(calls)) == "reported":
            (Path(log_dir) / name).mkdir()  # its checkpoints and results are kept
        if stops.get(len(calls)) == "error":
            raise run.TrainingError("trial failed: boom")
        late = stops.get(len(calls)) == "as it ended"  # the run whole, the stop held until its summary was written
        if len(calls) in stops and not late:
            raise KeyboardInterrupt
        (Path(log_dir) / name).mkdir()
        return SimpleNamespace(run_dir=Path(log_dir) / name, to_dict=dict, interrupted=False, stop_held=late)

    monkeypatch.setattr(run, "train", train)
    monkeypatch.setattr(transfer, "transfer_run", lambda m, seed, mode, run_dir, summary, reused=False:
                        replace(_run(mode, seed, 2_000, 88), reused=reused))  # fmt: skip
    root = Path(__file__).resolve().parents[2]
    argv = ["transfer", "--pretrained", str(tmp_path / "ckpt"), "--maps", str(root / "maps" / "val-1.yaml"),
            "--name", "job", "--log-dir", str(tmp_path / "logs")]  # fmt: skip
    return argv, calls, stops, algos


def test_transfer_trains_with_the_pretrained_policys_algorithm_unless_told(tmp_path, fake_runs, monkeypatch, capsys):
    from types import SimpleNamespace

    from smorphi_rl.cli import main
    from smorphi_rl.training import checkpoints

    argv, calls, _stops, algos = fake_runs
    config = SimpleNamespace(model_config={"env_config": {}, "algorithm": "appo"})
    monkeypatch.setattr(checkpoints, "load_module", lambda path: config)
    assert main([*argv, "--seeds", "0"]) == 0
    assert algos == ["appo", "appo"] and len(calls) == 2
    assert main([*argv[:-4], "--name", "other", "--log-dir", str(tmp_path / "logs"), "--seeds", "0", "--algo",
                 "ppo"]) == 0  # fmt: skip
    assert algos[2:] == ["ppo", "ppo"]


def test_a_stop_as_a_later_run_starts_keeps_the_finished_runs_table_and_the_resume_hint(tmp_path, fake_runs, capsys):
    """Ctrl-C before a run's first report (the run discards itself): the job still reports what finished."""
    from smorphi_rl.cli import main

    argv, calls, stops, _algos = fake_runs
    stops[2] = "before"
    assert main([*argv, "--seeds", "0"]) == 130
    out, err = capsys.readouterr()
    assert calls == ["val-1-fine-tune-seed0", "val-1-scratch-seed0"]
    rows = (tmp_path / "logs" / "job" / "transfer.csv").read_text().splitlines()
    assert len(rows) == 2 and rows[1].startswith("val-1,0,fine-tune,")
    assert "| val-1 |" in out and "the table holds the runs that finished (1)" in err
    assert "--name job --resume" in err and "Traceback" not in err


def test_a_stop_before_the_first_run_reports_leaves_no_folder(tmp_path, fake_runs, capsys):
    from smorphi_rl.cli import main

    argv, _calls, stops, _algos = fake_runs
    stops[1] = "before"
    assert main([*argv, "--seeds", "0"]) == 130
    assert not (tmp_path / "logs" / "job").exists()  # nothing trained: the name stays free
    assert capsys.readouterr().err.strip() == "smorphi-rl: interrupted"


def test_a_stop_of_the_first_run_after_it_reported_keeps_the_jobs_folder(tmp_path, fake_runs, capsys):
    from smorphi_rl.cli import main

    argv, _calls, stops, _algos = fake_runs
    stops[1] = "reported"  # a second Ctrl-C, say, after the run's first checkpoint
    assert main([*argv, "--seeds", "0"]) == 130
    assert (tmp_path / "logs" / "job" / "val-1-fine-tune-seed0").is_dir()
    assert "no run finished; continue with the same command and --name job --resume" in capsys.readouterr().err


def test_a_stop_as_a_run_ends_ends_the_job_there(tmp_path, fake_runs, capsys):
    """A Ctrl-C as run 1 wrote its results was lost: run 2 trained its whole budget and the job exited 0."""
    from smorphi_rl.cli import main

    argv, calls, stops, _algos = fake_runs
    stops[1] = "as it ended"
    assert main([*argv, "--seeds", "0"]) == 130
    assert calls == ["val-1-fine-tune-seed0"]
    assert "the table holds the runs that finished (1)" in capsys.readouterr().err
    calls.clear()
    stops.clear()
    stops[2] = "as it ended"  # on the job's last run: every run finished, and the job still says it was stopped
    assert main([*argv, "--seeds", "0", "--name", "last"]) == 130
    assert len(calls) == 2 and "the table holds the runs that finished (2)" in capsys.readouterr().err


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_stop_while_the_tables_are_written_waits_for_them(tmp_path, fake_runs, monkeypatch, capsys, signame):
    """Ray's shutdown leaves SIGTERM a kill: a SIGTERM while `transfer` wrote its tables ended it with 143 and no
    word, its tables half written."""
    import contextlib
    import signal

    from smorphi_rl import cluster
    from smorphi_rl.cli import main
    from smorphi_rl.training import transfer

    argv, calls, _stops, _algos = fake_runs

    @contextlib.contextmanager
    def ray_session(address):
        yield
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as Ray's shutdown leaves it

    def writes(job_dir, runs):
        signal.raise_signal(getattr(signal, signame))
        return write_transfer_report(job_dir, runs)

    monkeypatch.setattr(cluster, "ray_session", ray_session)
    monkeypatch.setattr(transfer, "write_transfer_report", writes)
    assert main([*argv, "--seeds", "0"]) == 130
    out, err = capsys.readouterr()
    assert err.strip().splitlines()[-1] == "smorphi-rl: interrupted as the job ended: its tables are whole"
    assert len(calls) == 2 and (tmp_path / "logs" / "job" / "transfer.md").is_file() and "table:" in out
    assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL  # SIGTERM is Ctrl-C again afterwards


def test_a_stopped_resume_still_reports_the_runs_earlier_calls_finished(tmp_path, fake_runs, monkeypatch, capsys):
    from smorphi_rl.cli import main
    from smorphi_rl.training import transfer

    argv, calls, stops, _algos = fake_runs
    job = tmp_path / "logs" / "job"
    job.mkdir(parents=True)
    (job / transfer.JOB_FILE).write_text('{"maps": [], "seeds": [1]}')
    monkeypatch.setattr(transfer, "finished_run", lambda run_dir, cfg: {} if run_dir.name.endswith("seed1") else None)
    stops[1] = "before"  # seed 0, new in this call, comes first in the job's order
    assert main([*argv, "--seeds", "0", "1", "--resume"]) == 130
    assert calls == ["val-1-fine-tune-seed0"]
    rows = (job / "transfer.csv").read_text().splitlines()[1:]
    assert [r.split(",")[:3] for r in rows] == [["val-1", "1", "fine-tune"], ["val-1", "1", "scratch"]]
    assert "the table holds the runs that finished (2)" in capsys.readouterr().err


def test_runs_on_a_map_without_an_optimum_are_not_measured(tmp_path):

    from smorphi_rl.training.transfer import by_map

    blind = {"eval_within": [float("nan")] * 2}
    runs = [replace(_run(mode, 0, None, 88.0), curve=_run(mode, 0, None, 88.0).curve | blind)
            for mode in ("fine-tune", "scratch")]  # fmt: skip
    assert by_map(runs)[0].counts == ("not measured", "not measured")
    assert by_map([_run("fine-tune", 0, None, 88.0)])[0].counts == ("0 of 1", "0 of 0")


def test_a_run_that_fails_after_others_finished_names_the_resume(tmp_path, fake_runs, capsys):
    from smorphi_rl.cli import main

    argv, _calls, stops, _algos = fake_runs
    stops[2] = "error"
    assert main([*argv, "--seeds", "0"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trial failed: boom; the runs that finished (1) are kept" in err
    assert "--name job --resume" in err and (tmp_path / "logs" / "job" / "val-1-fine-tune-seed0").is_dir()


@pytest.mark.parametrize(
    "damage",
    [{"env_steps": 10**400}, {"env_steps": -5}, {"wall_s": 10**400}, {"best": {"R1": 10**400}}],
    ids=["steps of 400 digits", "negative steps", "wall of 400 digits", "R1 of 400 digits"],
)
def test_a_damaged_run_summary_read_back_is_one_line(tmp_path, damage):
    """Integers too large for a float ended `transfer --resume` in an OverflowError traceback."""
    import json

    from smorphi_rl.inputs import InputError
    from smorphi_rl.training import result_keys as keys
    from smorphi_rl.training.transfer import transfer_run

    run = tmp_path / "val-1-scratch-seed0"
    (run / "ppo-0").mkdir(parents=True)
    (run / "ppo-0" / "result.json").write_text(json.dumps({keys.ALGO_ITERATION: 1, keys.STEPS: 1000}) + "\n")
    summary = {"env_steps": 1000, "wall_s": 1.0, "interrupted": False, "best": {"R1": 80.0}} | damage
    with pytest.raises(InputError, match="not a training run smorphi-rl wrote"):
        transfer_run("val-1", 0, "scratch", run, summary)


def test_a_result_row_nested_past_pythons_depth_read_back_is_one_line(tmp_path):
    """An episode-best list nested 100,000 deep in a finished run's result.json: a RecursionError traceback."""
    import json

    from smorphi_rl.inputs import InputError
    from smorphi_rl.training import result_keys as keys
    from smorphi_rl.training.topk import EPISODE_BEST_KEY
    from smorphi_rl.training.transfer import transfer_run

    run = tmp_path / "val-1-scratch-seed0"
    (run / "ppo-0").mkdir(parents=True)
    deep = "[" * 100_000 + "]" * 100_000
    (run / "ppo-0" / "result.json").write_text(json.dumps({keys.ALGO_ITERATION: 1, EPISODE_BEST_KEY: deep}) + "\n")
    summary = {"env_steps": 1000, "wall_s": 1.0, "interrupted": False, "best": {"R1": 80.0}}
    with pytest.raises(InputError, match="not a training run smorphi-rl wrote"):
        transfer_run("val-1", 0, "scratch", run, summary)


def test_a_finished_run_of_a_map_file_changed_since_stops_the_resume(tmp_path):
    """Its figures were measured on the old floor: read back, they would stand beside runs on the new one."""
    import json
    from pathlib import Path

    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import load_map
    from smorphi_rl.training.config import TrainConfig, TrainConfigError
    from smorphi_rl.training.transfer import finished_run

    val_1 = str(Path(__file__).resolve().parents[2] / "maps" / "val-1.yaml")
    cfg = TrainConfig(env=EnvConfig.from_dict({"maps": [val_1]}))
    run = tmp_path / "val-1-scratch-seed0"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(cfg.to_dict()))
    summary = {"interrupted": False, "map_digests": {"val-1": load_map(val_1).digest}}
    (run / "summary.json").write_text(json.dumps(summary))
    assert finished_run(run, cfg) == summary
    (run / "summary.json").write_text(json.dumps(summary | {"map_digests": {"val-1": "another floor"}}))
    with pytest.raises(TrainConfigError, match="was trained on another floor named 'val-1'"):
        finished_run(run, cfg)
    (run / "summary.json").unlink()  # a cut run: its config.json's digests, before anything trains
    assert finished_run(run, cfg) is None
    (run / "config.json").write_text(json.dumps(cfg.to_dict() | {"map_digests": {"val-1": "another floor"}}))
    with pytest.raises(TrainConfigError, match="was trained on another floor named 'val-1'"):
        finished_run(run, cfg)


def test_a_layout_this_machine_cannot_place_leaves_no_folder(tmp_path, fake_runs, capsys):
    """The capacity refusal came from the first run, after the job had made --log-dir: an empty folder stayed."""
    from smorphi_rl.cli import main

    argv, calls, _stops, _algos = fake_runs
    assert main([*argv, "--seeds", "0", "--env-runners", "1000"]) == 1
    assert "use fewer --env-runners" in capsys.readouterr().err
    assert calls == [] and not (tmp_path / "logs").exists()


def test_a_job_name_taken_by_an_earlier_job_says_how_to_continue_it(tmp_path, fake_runs, capsys):
    from smorphi_rl.cli import main

    argv, calls, _stops, _algos = fake_runs
    assert main([*argv, "--seeds", "0"]) == 0
    capsys.readouterr()
    assert main([*argv, "--seeds", "0"]) == 1
    assert "already exists: choose another --name, or add --resume to continue that job" in capsys.readouterr().err
    assert len(calls) == 2  # nothing trained the second time
    (tmp_path / "logs" / "run").mkdir()  # a folder of that name that is no transfer job: the hint would not run
    (tmp_path / "logs" / "run" / "summary.json").write_text("{}")
    assert main([*argv[:-4], "--name", "run", "--log-dir", str(tmp_path / "logs"), "--seeds", "0"]) == 1
    assert "already exists: choose another --name\n" in capsys.readouterr().err


def test_a_job_started_in_the_same_second_takes_the_next_stamped_name(tmp_path, fake_runs, monkeypatch, capsys):
    """The default name is stamped to the second: a second job in that second was refused a name its user never
    gave; it now takes `-2`."""
    from types import SimpleNamespace

    from smorphi_rl.cli import main
    from smorphi_rl.cli import train as cli_train

    argv, calls, _stops, _algos = fake_runs
    monkeypatch.setattr(cli_train, "time", SimpleNamespace(strftime=lambda fmt: "20261207-120000"))
    unnamed = [*argv[:-4], "--log-dir", str(tmp_path / "logs"), "--seeds", "0"]
    assert main(unnamed) == 0 and main(unnamed) == 0
    out = capsys.readouterr().out
    jobs = tmp_path / "logs" / "transfer-20261207-120000", tmp_path / "logs" / "transfer-20261207-120000-2"
    assert all((job / "transfer.csv").is_file() for job in jobs) and len(calls) == 4
    assert f"runs: {jobs[1]}" in out


def test_a_resumed_job_folder_holding_a_link_is_refused_before_anything_trains(tmp_path, fake_runs, capsys):
    """A handed-over job whose run folder links elsewhere: the resume would have written that run there."""
    from smorphi_rl.cli import main

    argv, calls, _stops, _algos = fake_runs
    assert main([*argv, "--seeds", "0"]) == 0
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "logs" / "job" / "val-1-fine-tune-seed1").symlink_to(tmp_path / "elsewhere")
    capsys.readouterr()
    assert main([*argv, "--seeds", "0", "1", "--resume"]) == 1
    assert "val-1-fine-tune-seed1: a link inside" in capsys.readouterr().err
    assert len(calls) == 2 and not list((tmp_path / "elsewhere").iterdir())


def test_a_jobs_runs_cache_the_exact_optima_under_the_log_dir_the_user_named(tmp_path, fake_runs, capsys):
    """They cached them under the job's own folder: `design --exact`'s optimum of the same map was searched again."""
    from smorphi_rl.cli import main

    argv, _calls, _stops, _algos = fake_runs
    assert main([*argv, "--seeds", "0"]) == 0
    assert (tmp_path / "logs" / ".cache").is_dir() and not (tmp_path / "logs" / "job" / ".cache").exists()


def test_a_stamped_name_refused_is_said_as_it_is(tmp_path, fake_runs, monkeypatch, capsys):
    """A name the command made names no job of the user's: its refusal offered to wait for, or --resume, the job
    under the first stamped name."""
    from types import SimpleNamespace

    from smorphi_rl import rundir
    from smorphi_rl.cli import main
    from smorphi_rl.cli import train as cli_train
    from smorphi_rl.training.transfer import JOB_FILE

    argv, calls, _stops, _algos = fake_runs
    monkeypatch.setattr(cli_train, "time", SimpleNamespace(strftime=lambda fmt: "20261207-120000"))

    def refused(log_dir, name):
        raise rundir.RunDirError(f"cannot create the run directory {log_dir}/{name}-2 (No space left on device)")

    monkeypatch.setattr(rundir, "prepare_stamped_run_dir", refused)
    earlier = tmp_path / "logs" / "transfer-20261207-120000"  # a job under the first stamped name: not this one's
    earlier.mkdir(parents=True)
    (earlier / JOB_FILE).write_text("{}")
    assert main([*argv[:-4], "--log-dir", str(tmp_path / "logs"), "--seeds", "0"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.endswith("-2 (No space left on device)") and "--resume" not in err and calls == []

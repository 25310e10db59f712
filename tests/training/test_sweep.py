"""A real sweep through the public command: 2 trials x 10 iterations, interrupted with Ctrl-C, then resumed; every
pickle Tune and RLlib left in the folder holds a payload by then, and none of them runs."""

from __future__ import annotations

import csv
import json
import pickle
import shutil
import subprocess
from pathlib import Path

import pytest
from cli_runs import cli, ctrl_c_after_checkpoint, holds_the_reported_policy, ray_env
from conftest import printed_command
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from smorphi_rl.training.sweep_report import result_files

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
SWEEP = f"""name: tiny
algorithms: [ppo]
maps: [{MAP_1}]
seeds: [0]
timesteps: 10000
search:
  lr: {{grid: [0.001, 0.003]}}
  train_batch_size: 1000
env: {{max_steps: 20}}
checkpoint: {{every: 1}}
env_runners: 0
"""
ITERATIONS = 10
"""10,000 steps in batches of 1,000 (16 envs: 1,008 a batch). The trials sample in their own process: this is
about stopping and resuming a sweep, and takes half the time it takes on 2 runners (whose runs test_train has)."""
pytestmark = pytest.mark.slow


def results(trial: Path) -> list[dict]:
    """Every row the trial logged, oldest first (a resume sets the earlier ones aside, `result_files`)."""
    return [json.loads(line) for path in result_files(trial) for line in path.read_text().splitlines()]


class Payload:
    """A pickle that, when loaded, writes `marker` (what a crafted file would do instead)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('ran')",))


def plant(exp: Path, marker: Path, names: set[str]) -> list[Path]:
    """Overwrite every pickle under `exp` whose name is in `names` (all but ours when empty) with a payload, but
    those of a trial that finished (the test reads its checkpoint afterwards; a trial the interrupt caught before
    its first row has an empty result file)."""
    done = {
        d for d in exp.iterdir() if (d / "result.json").is_file() and results(d)[-1:] and results(d)[-1]["smorphi_done"]
    }
    planted = []
    if not names:  # an error record Tune would read back if it were there
        for trial in {p.parent for p in exp.glob("*/params.json")} - done:
            (trial / "error.pkl").touch()
    for path in exp.rglob("*.pkl"):
        if done & set(path.parents):
            continue
        if (path.name in names) if names else path.name != "smorphi_state.pkl":
            path.write_bytes(pickle.dumps(Payload(marker)))
            planted.append(path)
    return planted


def test_sweep_interrupted_then_resumed_loses_nothing(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(SWEEP)
    exp = tmp_path / "logs" / "tiny"

    def first_row() -> bool:  # Tune writes a trial's row after it has moved the checkpoint in
        return any(results(trial) for trial in exp.glob("*_00000") if (trial / "result.json").is_file())

    code, out, err = ctrl_c_after_checkpoint(["sweep", str(config)], tmp_path, exp, "*_00000/checkpoint_000000",
                                             ready=first_row)  # fmt: skip
    assert code == 130, err[-3000:]
    assert "Traceback" not in err and f"sweep {config} --resume" in err
    assert "interrupted after" in out
    (first,) = exp.glob("*_00000")
    before = results(first)
    assert 1 <= len(before) < ITERATIONS  # enough iterations that the interrupt lands mid-run on a fast machine

    again = cli("sweep", str(config), cwd=tmp_path)  # without --resume: refused, nothing touched
    assert again.returncode == 1 and "add --resume" in again.stderr and "Traceback" not in again.stderr
    assert results(first) == before

    marker = tmp_path / "payload-ran"
    crafted = tmp_path / "crafted"  # a copy whose state file is crafted: refused before Ray starts, nothing moved
    shutil.copytree(tmp_path / "logs", crafted)
    assert plant(crafted, marker, {"smorphi_state.pkl"})
    listing = sorted(crafted.rglob("*"))
    refused = cli("sweep", str(config), "--resume", "--log-dir", str(crafted), cwd=tmp_path)
    assert refused.returncode == 1 and "Traceback" not in refused.stderr, refused.stderr[-3000:]
    assert len(refused.stderr.strip().splitlines()) == 1 and "smorphi_state.pkl: refused" in refused.stderr
    assert not marker.exists() and sorted(crafted.rglob("*")) == listing

    planted = plant(exp, marker, set())  # Tune's tuner.pkl and params.pkl, RLlib's state files
    assert {"tuner.pkl", "params.pkl", "error.pkl", "algorithm_state.pkl", "class_and_ctor_args.pkl"} <= {
        p.name for p in planted}  # fmt: skip
    resumed = subprocess.run(printed_command(err), capture_output=True, text=True, cwd=tmp_path, env=ray_env(),
                             timeout=400)  # the interrupt's hint, run exactly as printed  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert not marker.exists()  # nothing but our state file was unpickled
    assert "ran 2 of 2 trials" in resumed.stdout and "table: logs/tiny/sweep.md" in resumed.stdout

    after = results(first)
    assert after[: len(before)] == before  # what was logged before the interruption is kept as it was
    assert list((first / "before-resume-1").glob("checkpoint_*"))  # and its checkpoints, set aside
    trials = sorted(p for p in exp.iterdir() if (p / "result.json").is_file())
    assert len(trials) == 2
    for trial in trials:
        rows = results(trial)
        assert sorted({r["smorphi_iteration"] for r in rows}) == list(range(1, ITERATIONS + 1))
        per_iteration = rows[0]["num_env_steps_sampled_lifetime"]  # 1,000 rounded up to whole steps of 16 envs
        assert rows[-1]["num_env_steps_sampled_lifetime"] == ITERATIONS * per_iteration >= 10_000  # restored
        holds_the_reported_policy(trial)  # a resumed trial still ends on the policy it reports
        episodes = [p.name for p in (trial / "episodes").iterdir()]  # recorded straight into the trial's folder:
        assert episodes and not [e for e in episodes if not e.endswith(".mcap")]  # no copy caught mid-write
        evaluated = [r for r in rows if r.get("eval")]  # every trial runs train's evaluation protocol
        assert evaluated and {r["smorphi_iteration"] for r in evaluated} >= {1, 5, 10}
        assert 0 <= evaluated[-1]["eval"]["share_within_1pct"] <= 1 and evaluated[-1]["eval"]["starts"] == 20
        acc = EventAccumulator(str(trial))
        acc.Reload()
        assert {"ray/tune/env_runners/smorphi/R1_final", "ray/tune/eval/median_gap"} <= set(acc.Tags()["scalars"])
    table = list(csv.DictReader((exp / "sweep.csv").open()))
    assert sorted(r["lr"] for r in table) == ["0.001", "0.003"]
    assert all(int(r["env_steps"]) >= 10_000 and r["iterations"] == str(ITERATIONS) and float(r["best_R1"]) > 80
               for r in table)  # fmt: skip
    assert (exp / "sweep_curves.png").stat().st_size > 10_000
    # each trial's folder holds what `train` writes for a run, so `compare` takes it; the sweep's is several trials
    summary = json.loads((first / "summary.json").read_text())
    assert summary["evaluation"]["starts"] == 20 and summary["env_steps"] >= 10_000 and not summary["interrupted"]
    assert Path(summary["checkpoint"]).parent == first and (first / "top_morphologies.md").is_file()
    from smorphi_rl.maps import load_map

    assert summary["map_digests"] == {"map-1": load_map(MAP_1).digest}  # `compare` refuses another floor by it
    assert json.loads((exp / "maps.json").read_text()) == {"map-1": {"map-1": load_map(MAP_1).digest}}  # resume's
    compared = cli("compare", "--map", MAP_1, "--runs", str(first), "--step", "10", "--log-dir",
                   str(tmp_path / "compared"), cwd=tmp_path)  # fmt: skip
    assert compared.returncode == 0, compared.stderr[-3000:]
    assert f"| PPO ({first.name}) |" in (tmp_path / "compared" / "compare-map-1" / "report.md").read_text()
    several = cli("evaluate-policy", "--checkpoint", str(exp), cwd=tmp_path)
    assert several.returncode == 1 and "holds the checkpoints of 2 trials" in several.stderr

    config.write_text(SWEEP.replace("10000", "11000"))  # another sweep under the same name: refused
    changed = cli("sweep", str(config), "--resume", cwd=tmp_path)
    assert changed.returncode == 1 and "has changed since" in changed.stderr


def test_a_trial_whose_weights_overflow_ends_in_one_line_instead_of_restarting_its_runners_for_ever(tmp_path):
    """At lr 1e30 the first update leaves weights of 1e30; the 2 remote runners then fail on every sample and RLlib
    restarted them for ever (a hostile review's sweep ran past 5 minutes); the trial now ends after that update."""
    sweep = tmp_path / "huge-lr.yaml"
    sweep.write_text(f"name: huge\nalgorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\ntimesteps: 8000\nrecord_every: 0\n"
                     "search: {lr: 1.0e+30, lr_final: 1.0e+30}\n")  # fmt: skip
    proc = cli("sweep", str(sweep), "--log-dir", str(tmp_path / "logs"), cwd=tmp_path, timeout=240)
    lines = [line for line in proc.stderr.splitlines() if "error" in line]
    assert proc.returncode == 1 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert "the sweep failed: the policy diverged after 2,000 env steps: weight " in lines[0]
    assert "values beyond 1e+06 or not numbers" in lines[0]

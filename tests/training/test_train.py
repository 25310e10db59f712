"""Real Ray Tune runs: PPO through the public command, IMPALA and APPO through `train()`, reload, cluster, Ctrl-C."""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from cli_runs import cli, ctrl_c_after_checkpoint, fresh_home, holds_the_reported_policy
from conftest import optima_under, printed_command, ray_cluster
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.geometry import Morphology
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Evaluator
from smorphi_rl.protocol import CACHE_ENV, OPTIMUM_CACHE
from smorphi_rl.training.checkpoints import find_checkpoint, load_module
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.policy import rollout
from smorphi_rl.training.resume import STATE_FILE
from smorphi_rl.training.run import train

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
OUR_TAGS = [f"ray/tune/env_runners/smorphi/{m}" for m in (
    "P_c_mean", "P_len_mean", "R1_mean", "best_P_c", "best_P_len", "best_R1", "best_theta1", "best_theta2",
    "best_theta3", "R1_final")]  # fmt: skip
pytestmark = pytest.mark.slow


def trial_dir(run_dir: Path) -> Path:
    (found,) = [p for p in run_dir.iterdir() if p.is_dir() and (p / "result.json").exists()]
    return found


def last_result(run_dir: Path) -> dict:
    lines = (trial_dir(run_dir) / "result.json").read_text().splitlines()
    return json.loads(lines[-1])


def tensorboard_tags(run_dir: Path) -> set[str]:
    acc = EventAccumulator(str(trial_dir(run_dir)))
    acc.Reload()
    return set(acc.Tags()["scalars"])


@pytest.fixture(scope="module")
def home(tmp_path_factory) -> tuple[Path, list[Path]]:
    """The HOME the PPO run below runs with, and what it held before the run."""
    path = tmp_path_factory.mktemp("home")
    return path, fresh_home(path)


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory, home) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """`smorphi-rl train` for 2 iterations of 2,000 steps on 4 envs (5 episodes each), checkpointing each."""
    work = tmp_path_factory.mktemp("ppo")
    proc = cli("train", "--map", MAP_1, "--timesteps", "4000", "--envs-per-runner", "4", "--name", "smoke",
               "--checkpoint-every", "1", "--record-every", "25", cwd=work, home=home[0])  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return work / "logs" / "smoke", proc


def test_train_writes_nothing_in_the_home_folder(ppo_run, home):
    """RLlib's Algorithm makes itself a folder under ~/ray_results unless it is given the trial's storage."""
    path, before = home
    assert sorted(path.rglob("*")) == before


def test_train_prints_where_everything_is(ppo_run):
    run_dir, proc = ppo_run
    out = proc.stdout
    assert "PPO trained for 4,000 env steps" in out and "(2 iterations)" in out
    assert "best morphology: (" in out and "exact optimum on the 1-degree lattice" in out
    assert "greedy policy from 20 fixed starts: settles within 1 % of the optimum from" in out
    assert "tensorboard --logdir logs/smoke" in out
    for name in ("config.json", "summary.json", "top_morphologies.csv", "top_morphologies.md", "morphologies.csv",
                 "top_morphologies.png", "learning_curves.png"):  # fmt: skip
        assert (run_dir / name).is_file(), name
    config = json.loads((run_dir / "config.json").read_text())
    assert config["algo"] == "ppo" and config["env"]["maps"] == [MAP_1] and config["hyperparameters"]["lr"] > 0
    from smorphi_rl.maps import load_map

    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["map_digests"] == {"map-1": load_map(MAP_1).digest}  # what `compare` checks a map against


def test_metrics_exist_and_are_finite(ppo_run):
    run_dir, _ = ppo_run
    result = last_result(run_dir)
    assert result["training_iteration"] == 2 and result["num_env_steps_sampled_lifetime"] >= 4000
    ev = result["eval"]  # the protocol ran at the first and the last iteration
    assert ev["starts"] == 20 and 0 <= ev["share_within_1pct"] <= 1 and ev["median_gap"] >= 0
    ours = result["env_runners"]["smorphi"]
    for key in ("P_c_mean", "P_len_mean", "R1_mean", "best_P_c", "best_P_len", "best_R1", "best_theta1"):
        assert math.isfinite(ours[key]), key
    assert 0 < ours["best_P_c"] <= 100 and 0 <= ours["best_theta1"] <= 180
    assert ours["best_R1"] >= ours["R1_mean"]  # the best shape of an episode is at least its mean
    assert math.isfinite(result["env_runners"]["episode_return_mean"])


def test_tensorboard_holds_our_tags(ppo_run):
    run_dir, _ = ppo_run
    tags = tensorboard_tags(run_dir)
    assert "ray/tune/env_runners/episode_return_mean" in tags
    missing = [t for t in OUR_TAGS if t not in tags]
    assert not missing
    assert {"ray/tune/eval/median_gap", "ray/tune/eval/share_within_1pct", "ray/tune/eval/map-1/median_gap"} <= tags


def test_top_k_table_holds_real_fbcpp_figures(ppo_run):
    run_dir, _ = ppo_run
    rows = list(csv.DictReader((run_dir / "top_morphologies.csv").open()))
    assert 1 <= len(rows) <= 8
    r1 = [float(r["R1"]) for r in rows]
    assert r1 == sorted(r1, reverse=True)
    assert len({(r["theta1"], r["theta2"], r["theta3"]) for r in rows}) == len(rows)
    evaluator = Evaluator(load_map(MAP_1))
    for row in rows:
        result = evaluator.evaluate(Morphology.of((float(row["theta1"]), float(row["theta2"]), float(row["theta3"]))))
        assert float(row["P_c"]) == pytest.approx(result.P_c, abs=1e-3) and int(row["P_len"]) == result.P_len
        assert float(row["R1"]) == pytest.approx(result.P_c - 0.1 * result.P_len, abs=1e-3)


def test_checkpoint_reloads_and_rolls_out_deterministically(ppo_run):
    run_dir, _ = ppo_run
    checkpoint = find_checkpoint(run_dir)
    assert checkpoint.name == "checkpoint_000001"  # the newest of the two
    module = load_module(checkpoint)
    env = MorphologyEnv(module.model_config["env_config"])
    first, second = rollout(module, env, seed=3), rollout(module, env, seed=3)
    assert first.thetas == second.thetas and first.steps == EnvConfig().max_steps
    assert first.best["R1"] == max(env.score(t).R1 for t in first.thetas)  # the best of the shapes it visited


def test_the_final_checkpoint_holds_the_policy_the_last_evaluation_reports(ppo_run):
    """A run ends on its best evaluated policy, chosen on other seeded starts (--select-starts), which may be an
    earlier one: the last evaluation names its env steps and the final checkpoint holds exactly that policy."""
    run_dir, _ = ppo_run
    assert last_result(run_dir)["eval"]["policy_env_steps"] > 0
    holds_the_reported_policy(trial_dir(run_dir))


def test_evaluate_policy_command(ppo_run, tmp_path):
    run_dir, _ = ppo_run
    proc = cli("evaluate-policy", "--checkpoint", str(run_dir), "--episodes", "2", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    docs = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [d["seed"] for d in docs] == [0, 1] and all(d["map"] == "map-1" for d in docs)
    for d in docs:
        assert d["best"]["R1"] >= d["start"]["R1"] and d["best"]["R1"] >= d["settled"]["R1"] - 1e-9
    png = tmp_path / "settled.png"
    proc = cli("evaluate-policy", "--checkpoint", str(run_dir), "--map", MAP_1, "--plot", str(png), "--record",
               "rec", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0 and "settled" in proc.stdout and png.stat().st_size > 10_000
    (recording,) = (tmp_path / "rec").glob("*.mcap")  # the greedy episode, recorded
    from smorphi_rl.recording import read_episode

    episode = read_episode(recording)
    settled = docs[0]["settled"]
    assert episode.metadata["algorithm"] == "greedy ppo" and len(episode.steps) == 201
    assert settled["theta"] in [s["theta"] for s in episode.steps[-20:]]  # the same seeded greedy episode


def test_train_records_episodes_that_replay_lists(ppo_run, tmp_path):
    run_dir, proc = ppo_run
    files = sorted((run_dir / "episodes").glob("*.mcap"))
    assert len(files) >= 2  # each runner's first episode at least (every 25th)
    assert "episodes: logs/smoke/episodes" in proc.stdout
    hint = printed_command(proc.stdout)  # the summary's `smorphi-rl replay ...`, run as printed where train ran
    listing = subprocess.run(hint, capture_output=True, text=True, cwd=run_dir.parents[1], timeout=120)
    assert listing.returncode == 0 and f"{len(files)} recordings" in listing.stdout
    shown = cli("replay", str(files[0]), cwd=tmp_path)
    assert shown.returncode == 0 and "(PPO, seed 0)" in shown.stdout and "steps      200" in shown.stdout


def test_compare_takes_a_training_run(ppo_run, tmp_path):
    run_dir, _ = ppo_run
    proc = cli("compare", "--map", MAP_1, "--runs", str(run_dir), "--step", "10", "--log-dir", str(tmp_path),
               cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    report = (tmp_path / "compare-map-1" / "report.md").read_text()
    assert "| PPO (smoke) | 4,000 env steps |" in report


def test_fine_tuning_puts_the_pretrained_policy_in_every_runner(ppo_run, tmp_path):
    from smorphi_rl.training.finetune import PRETRAINED_KEY
    from smorphi_rl.training.module import MorphologyModule
    from smorphi_rl.training.runners import policy_digest

    run_dir, _ = ppo_run
    checkpoint = find_checkpoint(run_dir)
    trained = load_module(checkpoint)
    fresh = MorphologyModule(
        observation_space=trained.observation_space, action_space=trained.action_space, model_config={}
    )
    assert policy_digest(fresh.get_state()) != policy_digest(trained.get_state())  # the check can fail
    cfg = TrainConfig(timesteps=2000, pretrained=str(run_dir), checkpoint_every=1, envs_per_runner=4)
    summary = train(cfg, name="tuned", log_dir=tmp_path, out=open(os.devnull, "w"))  # noqa: SIM115
    assert summary.pretrained == checkpoint and summary.pretrained_in_runners is True
    first = json.loads((trial_dir(summary.run_dir) / "result.json").read_text().splitlines()[0])
    assert first["training_iteration"] == 1 and first[PRETRAINED_KEY] == 1.0


@pytest.fixture(scope="module")
def transfer_job(ppo_run, tmp_path_factory) -> tuple[Path, list[str], subprocess.CompletedProcess[str]]:
    """`smorphi-rl transfer` on val-1, seed 0, 2,000 steps a run, from an exported policy (as the shipped designer
    is): (the folder it ran in, its arguments, the process)."""
    from smorphi_rl.training.export import export_policy

    run_dir, _ = ppo_run
    work = tmp_path_factory.mktemp("transfer")
    exported = export_policy(find_checkpoint(run_dir), work / "exported", {})
    args = ["transfer", "--pretrained", str(exported), "--maps", str(ROOT / "maps" / "val-1.yaml"), "--timesteps",
            "2000", "--seeds", "0", "--name", "job"]  # fmt: skip
    with optima_under(work / "logs"):  # the suite's optima, where the job looks
        return work, args, cli(*args, cwd=work, drop=(CACHE_ENV,))


def test_transfer_job_fine_tunes_and_trains_from_scratch(transfer_job):
    """The weights the exported policy holds are the ones every runner gets."""
    work, _, proc = transfer_job
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = list(csv.DictReader((work / "logs" / "job" / "transfer.csv").open()))
    assert [(r["map"], r["mode"]) for r in rows] == [("val-1", "fine-tune"), ("val-1", "scratch")]
    assert rows[0]["pretrained_in_runners"] == "True" and rows[1]["pretrained_in_runners"] == ""
    assert "| val-1 |" in (work / "logs" / "job" / "transfer.md").read_text()
    assert (work / "logs" / "job" / "transfer_curves.png").is_file() and "warning" not in proc.stdout
    assert not list((work / "logs" / "job").rglob(OPTIMUM_CACHE))  # the --log-dir's cache served it, as design's


def test_transfer_resume_reads_finished_runs_back_and_trains_the_one_cut_short(transfer_job, tmp_path):

    work, args, proc = transfer_job
    assert proc.returncode == 0, proc.stderr[-3000:]
    shutil.copytree(work / "logs", tmp_path / "logs")
    job = tmp_path / "logs" / "job"
    tuned, scratch = job / "val-1-fine-tune-seed0", job / "val-1-scratch-seed0"
    summary = json.loads((scratch / "summary.json").read_text())
    (scratch / "summary.json").write_text(json.dumps(summary | {"interrupted": True}))  # as a stopped run writes it
    tuned_files = {p: p.read_bytes() for p in tuned.rglob("*") if p.is_file()}

    other = cli(*[("4000" if a == "2000" else a) for a in args], "--resume", cwd=tmp_path)  # another budget
    assert other.returncode != 0 and "Traceback" not in other.stderr
    assert "trained with other settings (timesteps: 2000, this job: 4000)" in other.stderr.strip().splitlines()[-1]
    assert sorted(p.name for p in job.iterdir() if p.is_dir()) == [tuned.name, scratch.name]
    good = (tuned / "summary.json").read_text()
    (tuned / "summary.json").write_text(json.dumps(json.loads(good) | {"env_steps": "many"}))  # a damaged run
    damaged = cli(*args, "--resume", cwd=tmp_path)
    assert damaged.returncode != 0 and "Traceback" not in damaged.stderr
    assert "not a training run smorphi-rl wrote" in damaged.stderr.strip().splitlines()[-1]
    assert sorted(p.name for p in job.iterdir() if p.is_dir()) == [tuned.name, scratch.name]
    (tuned / "summary.json").write_text(good)

    resumed = cli(*args, "--resume", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "read back (--resume): 1 of 2 runs, finished earlier in this job" in resumed.stdout
    assert {p: p.read_bytes() for p in tuned.rglob("*") if p.is_file()} == tuned_files  # read, not retrained
    assert "resuming val-1-scratch-seed0 from its checkpoint of 2,000 env steps" in resumed.stdout + resumed.stderr
    assert not list(job.glob("*.cut-*"))  # continued from its checkpoint (as `train --resume`), not trained again
    assert json.loads((scratch / "summary.json").read_text())["interrupted"] is False
    before = {r["mode"]: r for r in csv.DictReader((work / "logs" / "job" / "transfer.csv").open())}
    rows = list(csv.DictReader((job / "transfer.csv").open()))
    assert [r["mode"] for r in rows] == ["fine-tune", "scratch"]
    assert rows[0] == before["fine-tune"] and rows[1]["env_steps"] == before["scratch"]["env_steps"]

    (scratch / "summary.json").unlink()  # cut short with no checkpoint whose state reads: set aside, trained again
    for state in scratch.rglob(STATE_FILE):
        state.write_bytes(b"\x80\x04")
    again = cli(*args, "--resume", cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    cut = job / "val-1-scratch-seed0.cut-1"
    assert cut.is_dir() and not (cut / "summary.json").exists()  # kept, never deleted
    assert json.loads((scratch / "summary.json").read_text())["interrupted"] is False  # trained again
    assert int(list(csv.DictReader((job / "transfer.csv").open()))[1]["env_steps"]) >= 2000


@pytest.mark.parametrize(
    ("extra", "message"),
    [(["--resume"], "--resume continues a job: give its --name"),
     (["--resume", "--name", "none"], "is not a transfer job"),
     (["--resume", "--name", "smoke", "--log-dir", "TRAIN"], "is not a transfer job")],  # a train run's folder
)  # fmt: skip
def test_transfer_resume_of_no_job_is_one_line(ppo_run, tmp_path, extra, message):
    run_dir, _ = ppo_run
    before = sorted(run_dir.rglob("*"))
    extra = [str(run_dir.parent) if a == "TRAIN" else a for a in extra]
    proc = cli("transfer", "--pretrained", str(run_dir), "--maps", str(ROOT / "maps" / "val-1.yaml"), *extra,
               cwd=tmp_path)  # fmt: skip
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert message in proc.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "logs").exists() and sorted(run_dir.rglob("*")) == before


def test_transfer_refuses_a_map_the_policy_was_trained_on(ppo_run, tmp_path):
    from smorphi_rl.training.config import TrainConfigError
    from smorphi_rl.training.transfer import TransferJob, run_transfer

    run_dir, _ = ppo_run
    job = TransferJob(run_dir, (str(ROOT / "maps" / "val-1.yaml"), MAP_1), seeds=(0,), timesteps=2000)
    with pytest.raises(TrainConfigError, match=r"map-1\.yaml is one the pretrained policy was trained on"):
        run_transfer(job, name="same", log_dir=tmp_path)
    assert not (tmp_path / "same").exists()


def test_pretrained_checkpoint_must_fit_the_env(ppo_run, tmp_path):
    from smorphi_rl.training.checkpoints import CheckpointError

    run_dir, _ = ppo_run
    cfg = TrainConfig(pretrained=str(run_dir)).with_env(obs_size=32)
    with pytest.raises(
        CheckpointError, match=r"observation 'map': the policy's \(2, 64, 64\), the env's \(2, 32, 32\)"
    ):
        train(cfg, name="misfit", log_dir=tmp_path)
    assert not (tmp_path / "misfit").exists()  # refused before anything was written


def test_evaluate_policy_refuses_a_map_of_another_observation_size(ppo_run, tmp_path):
    run_dir, _ = ppo_run
    module = load_module(find_checkpoint(run_dir))
    env = MorphologyEnv({"maps": [MAP_1], "obs_size": 32})
    from smorphi_rl.training.checkpoints import CheckpointError
    from smorphi_rl.training.policy import check_fits

    with pytest.raises(CheckpointError, match=r"expects map observations of shape \(2, 64, 64\)"):
        check_fits(module, env)


@pytest.mark.parametrize("algo", ["impala", "appo"])
def test_async_learners_train_and_report(algo, tmp_path):
    # Asynchronous: the first iteration or two report no samples while the runners start, so run
    # to a step budget (at least 2 iterations) rather than a fixed number of iterations.
    cfg = TrainConfig(algo=algo, timesteps=1000, checkpoint_every=1, envs_per_runner=2)
    summary = train(cfg, name=algo, log_dir=tmp_path, out=open(os.devnull, "w"))  # noqa: SIM115
    assert summary.iterations >= 2 and not summary.interrupted and summary.env_steps >= 1000
    assert summary.best is not None and summary.checkpoint is not None
    # an iteration in which no episode ended reports NaN (a loaded machine makes the last one such an iteration)
    rows = [json.loads(line) for line in (trial_dir(summary.run_dir) / "result.json").read_text().splitlines()]
    assert any(math.isfinite(r["env_runners"].get("smorphi", {}).get("best_R1", math.nan)) for r in rows)
    assert not [t for t in OUR_TAGS if t not in tensorboard_tags(summary.run_dir)]
    # the learner thread steps on after the last evaluation unless the run's end holds its updates
    holds_the_reported_policy(trial_dir(summary.run_dir))


def test_a_run_that_ends_before_its_budget_is_evaluated_and_chosen_at_its_end(tmp_path):
    """A run cut by `max_iterations` (a sweep's stop criterion alike) ends as one that reaches its budget: its last
    iteration is evaluated and the final checkpoint holds the policy that evaluation reports."""
    cfg = TrainConfig(timesteps=10**6, max_iterations=3, eval_every=5, num_env_runners=0, envs_per_runner=4)
    summary = train(cfg, name="cut", log_dir=tmp_path, out=open(os.devnull, "w"))  # noqa: SIM115
    assert summary.iterations == 3 and not summary.interrupted
    rows = [json.loads(line) for line in (trial_dir(summary.run_dir) / "result.json").read_text().splitlines()]
    assert [r["smorphi_iteration"] for r in rows if r.get("eval")] == [1, 3]
    assert summary.evaluation["starts"] == 20
    holds_the_reported_policy(trial_dir(summary.run_dir))


def test_attaches_to_a_running_cluster(tmp_path):
    with ray_cluster(2) as address:
        proc = cli("train", "--address", address, "--timesteps", "2000", "--name", "attached",
                   "--map", MAP_1, "--env-runners", "2", "--envs-per-runner", "2", cwd=tmp_path)  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert "PPO trained for 2,000 env steps" in proc.stdout
        assert json.loads((tmp_path / "logs" / "attached" / "config.json").read_text())["address"] == address


def test_ctrl_c_ends_the_run_with_its_final_policy_checkpointed(tmp_path):
    """Tune's own handler stopped the trial at its next report: with no checkpoint due yet, the summary named a
    final policy that no checkpoint held. The first Ctrl-C now ends the run as its budget's end would."""
    run_dir = tmp_path / "logs" / "stopped"
    argv = ["train", "--map", MAP_1, "--timesteps", "1000000", "--name", "stopped", "--eval-every", "1"]

    def reported() -> bool:
        return any(f.stat().st_size for f in run_dir.glob("*/result.json"))

    code, out, err = ctrl_c_after_checkpoint(argv, tmp_path, run_dir, "*/result.json", ready=reported)
    assert code == 130, err[-3000:]
    assert "Traceback" not in err and "stopping: the run ends after this iteration" in err
    assert err.strip().splitlines()[-1] == "smorphi-rl: interrupted: it ended early, its final policy checkpointed"
    assert "interrupted after" in out
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["interrupted"] and Path(summary["checkpoint"]).resolve() == find_checkpoint(run_dir).resolve()
    holds_the_reported_policy(trial_dir(run_dir))


def test_a_run_stopped_early_continues_with_resume(tmp_path):
    """A scheduler sends SIGTERM before its kill: the run ended early, its summary saying so, and `--resume`
    refused it as finished. It now continues, from the policy it ended on, to its budget."""
    run_dir = tmp_path / "logs" / "early"
    argv = ["train", "--map", MAP_1, "--timesteps", "16000", "--name", "early", "--env-runners", "1",
            "--envs-per-runner", "4", "--eval-every", "4", "--eval-starts", "4", "--select-starts", "0",
            "--record-every", "0"]  # fmt: skip

    def reported() -> bool:
        return any(f.stat().st_size for f in run_dir.glob("*/result.json"))

    code, _, err = ctrl_c_after_checkpoint(argv, tmp_path, run_dir, "*/result.json", ready=reported)
    stopped = json.loads((run_dir / "summary.json").read_text())
    assert code == 130 and stopped["interrupted"] and stopped["env_steps"] < 16000, err[-2000:]
    proc = cli(*argv, "--resume", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert not summary["interrupted"] and summary["env_steps"] >= 16000
    assert summary["resumed_at"] == stopped["env_steps"] and summary["iterations"] == 8

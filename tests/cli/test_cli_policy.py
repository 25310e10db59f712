"""`evaluate-policy --starts` reads and writes exact optima where the checkpoint's run cached them."""

from __future__ import annotations

import shutil
from pathlib import Path

from conftest import optima_under

from smorphi_rl.cli import main
from smorphi_rl.cli.common import DEFAULT_LOG_DIR
from smorphi_rl.cli.policy import run_log_dir
from smorphi_rl.protocol import CACHE_ENV, OPTIMUM_CACHE

ROOT = Path(__file__).resolve().parents[2]
DESIGNER = ROOT / "smorphi_rl" / "policies" / "designer"
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def a_run(logs: Path, cache: bool) -> Path:
    """A `train` run's folder under `logs` (its summary.json) holding a checkpoint, with `logs/.cache` if `cache`."""
    checkpoint = logs / "ppo-map-1" / "ppo-0_00000" / "checkpoint_000000"
    shutil.copytree(DESIGNER, checkpoint)
    (logs / "ppo-map-1" / "summary.json").write_text("{}")
    if cache:
        (logs / OPTIMUM_CACHE).mkdir()
    return checkpoint


def test_the_log_folder_of_a_run_is_the_one_that_holds_its_cache(tmp_path):
    assert run_log_dir(a_run(tmp_path / "logs", cache=True)) == str(tmp_path / "logs")
    assert run_log_dir(a_run(tmp_path / "bare", cache=False)) == DEFAULT_LOG_DIR  # no cache there: nothing to reuse
    assert run_log_dir(DESIGNER) == DEFAULT_LOG_DIR
    job = a_run(tmp_path / "tr" / "job", cache=False)  # a transfer's run: the cache is beside the job's folder
    (tmp_path / "tr" / OPTIMUM_CACHE).mkdir()
    assert run_log_dir(job) == str(tmp_path / "tr")


def test_the_protocol_on_a_run_writes_nothing_where_it_is_called_from(tmp_path, monkeypatch, capsys):
    """It cached map-1's optimum in ./logs/.cache of whatever folder it was called from, and computed it again
    there though the run had cached it beside itself."""
    checkpoint = a_run(tmp_path / "logs", cache=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    with optima_under(tmp_path / "logs"):  # the suite's optima, where the run would have cached them
        monkeypatch.delenv(CACHE_ENV)
        assert main(["evaluate-policy", "--checkpoint", str(checkpoint), "--map", MAP_1, "--starts", "2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"policy  {checkpoint}\n") and "map-1" in out and not any(elsewhere.iterdir())


def test_evaluate_policy_stopped_while_recording_says_what_it_recorded(tmp_path, capsys, monkeypatch):
    """A Ctrl-C during `evaluate-policy --episodes N --record DIR` said a bare 'interrupted' (42 recordings kept)."""
    from smorphi_rl.recording import episode_files, read_episode
    from smorphi_rl.training import policy

    real, calls = policy.rollout, []

    def stopped(module, env, seed):
        calls.append(seed)
        if len(calls) == 3:
            env.reset(seed=seed)  # the third episode has begun, then the stop
            env.step(env.action_space.sample())
            raise KeyboardInterrupt
        return real(module, env, seed)

    monkeypatch.setattr(policy, "rollout", stopped)
    record = tmp_path / "rec"
    argv = ["evaluate-policy", "--checkpoint", str(DESIGNER), "--map", MAP_1, "--episodes", "5", "--record",
            str(record)]  # fmt: skip
    assert main(argv) == 130
    out, err = capsys.readouterr()
    assert err.strip().splitlines()[-1] == (
        f"smorphi-rl: interrupted: after 2 episodes of 5, whose lines are printed; their recordings are whole in "
        f"{record} (the one cut short ends with a note)"
    )
    assert [line.split(" (")[0] for line in out.splitlines() if line.startswith("episode")] == [
        "episode 0",
        "episode 1",
    ]
    files = episode_files(record)
    assert len(files) == 3 and sum(read_episode(f).cut_short is not None for f in files) == 1


def test_evaluate_policy_stopped_keeps_the_json_lines_of_the_episodes_that_ended(capsys, monkeypatch):
    """Every episode's line was printed at the end: a Ctrl-C after 3 of 50 left stdout empty."""
    import json

    from smorphi_rl.training import policy

    real, calls = policy.rollout, []

    def stopped(module, env, seed):
        calls.append(seed)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(module, env, seed)

    monkeypatch.setattr(policy, "rollout", stopped)
    argv = ["evaluate-policy", "--checkpoint", str(DESIGNER), "--map", MAP_1, "--episodes", "5", "--json"]
    assert main(argv) == 130
    out, err = capsys.readouterr()
    assert [json.loads(line)["episode"] for line in out.splitlines()] == [0, 1]
    assert err.strip() == "smorphi-rl: interrupted: after 2 episodes of 5, whose JSON lines are printed"


def test_the_protocol_refuses_a_seed_its_fixed_starts_would_not_use(capsys):
    """`--starts 2 --seed 5` gave seed 0's starts without a word."""
    for seed in ("5", "0"):
        argv = ["evaluate-policy", "--checkpoint", str(DESIGNER), "--map", MAP_1, "--starts", "2", "--seed", seed]
        assert main(argv) == 1
        assert "--seed sets the --episodes roll-outs' starts" in capsys.readouterr().err


def test_the_protocol_as_json_lines_gives_each_start_its_gap_to_the_optimum(capsys):
    """One line a start; the gap is the optimum's R1 less the settled R1, rounded (it read 0.35999999999999943)."""
    import json

    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import load_map
    from smorphi_rl.policy_file import read_policy
    from smorphi_rl.protocol import exact_optimum

    assert main(["evaluate-policy", "--checkpoint", str(DESIGNER), "--map", MAP_1, "--starts", "3", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(lines) == 3 and {line["map"] for line in lines} == {"map-1"}
    gaps = [line["settled"]["gap"] for line in lines]
    assert all(g >= 0 and g == round(g, 9) for g in gaps)
    policy_env = EnvConfig.recorded(read_policy(DESIGNER).env_config)  # the policy's own weights and planner
    best = exact_optimum(MAP_1, policy_env.weights_on(load_map(MAP_1)), policy_env.planning).R1
    assert all(abs(line["settled"]["R1"] + line["settled"]["gap"] - best) < 1e-8 for line in lines)
    assert all(abs(line["optimum"]["R1"] - best) < 1e-8 for line in lines)  # named in each line, as is the band
    assert [line["within_1pct"] for line in lines] == [line["settled"]["gap"] <= 0.01 * best + 1e-9 for line in lines]


def test_a_replayed_evaluation_episode_names_the_seed_it_was_reset_with(tmp_path, capsys):
    """`evaluate-policy --seed 5` resets episode i with seed 5 + i; replay labelled every episode 'seed 5'."""
    from smorphi_rl.recording import episode_files

    record = tmp_path / "rec"
    argv = ["evaluate-policy", "--checkpoint", str(DESIGNER), "--map", MAP_1, "--episodes", "2", "--seed", "5",
            "--record", str(record)]  # fmt: skip
    assert main(argv) == 0
    second = sorted(episode_files(record))[1]
    capsys.readouterr()
    assert main(["replay", str(second)]) == 0
    assert ", episode 1 (reset with seed 6)" in capsys.readouterr().out


def test_a_folder_name_cannot_forge_a_line_of_the_output(tmp_path, capsys):
    """A checkpoint folder named `evil\\rpolicy /opt/trusted\\nepisode 0 ...` printed a forged policy line."""
    import shutil

    forged = tmp_path / "evil\rpolicy      /opt/trusted\nepisode 0 (seed 0, map map-1, return 99.9)"
    shutil.copytree(DESIGNER, forged)
    assert main(["evaluate-policy", "--checkpoint", str(forged), "--map", MAP_1, "--episodes", "1"]) == 0
    out = capsys.readouterr().out
    assert "\r" not in out and out.splitlines()[0].endswith(
        "evil\\rpolicy      /opt/trusted\\nepisode 0 (seed 0, map map-1, return 99.9)"
    )
    assert sum(line.startswith("episode 0") for line in out.splitlines()) == 1

"""Sweep files: the shipped ones load; every mistake is named with the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from smorphi_rl.training.presets import PRESETS
from smorphi_rl.training.sweep_config import SweepConfigError, load_sweep

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
MAP_2 = str(ROOT / "maps" / "map-2.yaml")


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return path


def base(extra: str = "") -> str:
    return f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\n{extra}"


@pytest.mark.parametrize("name", ["paper-ppo-vs-impala", "hparams", "pretrain-multimap"])
def test_shipped_sweeps_load(name, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # from anywhere: their maps are named relative to the file
    cfg = load_sweep(ROOT / "tune_configs" / f"{name}.yaml")
    assert cfg.name == name
    expected = {"paper-ppo-vs-impala": 12, "hparams": 27, "pretrain-multimap": 3}[name]
    assert cfg.num_grid_trials == expected
    assert all(Path(m).parent == ROOT / "maps" for s in cfg.map_sets for m in s)
    assert len(cfg.seeds) >= 3  # every group of seeds gets its median with an interval


def test_paper_sweep_is_both_algorithms_on_both_maps_with_three_seeds(monkeypatch):
    monkeypatch.chdir(ROOT)
    cfg = load_sweep(ROOT / "tune_configs" / "paper-ppo-vs-impala.yaml")
    assert cfg.algorithms == ("ppo", "impala") and cfg.seeds == (0, 1, 2)
    assert [tuple(Path(m).name for m in s) for s in cfg.map_sets] == [("map-1.yaml",), ("map-2.yaml",)]


def test_multimap_trains_one_policy_on_both_maps(monkeypatch):
    monkeypatch.chdir(ROOT)
    cfg = load_sweep(ROOT / "tune_configs" / "pretrain-multimap.yaml")
    (maps,) = cfg.map_sets
    assert [Path(m).name for m in maps] == ["map-1.yaml", "map-2.yaml"]
    trial = cfg.base_config("ppo", maps, 0, {})
    assert len(trial.env.maps) == 2


def test_a_stop_on_env_steps_below_the_budget_is_the_trials_budget(tmp_path):
    """The progress line counted to `timesteps` (60,000) while every trial stopped at its `stop` (30,000)."""
    assert load_sweep(write(tmp_path, base("timesteps: 60000\n"))).step_budget == 60_000
    capped = base("timesteps: 60000\nstop: {num_env_steps_sampled_lifetime: 30000, time_total_s: 5}\n")
    assert load_sweep(write(tmp_path, capped)).step_budget == 30_000
    above = base("timesteps: 60000\nstop: {num_env_steps_sampled_lifetime: 90000}\n")
    assert load_sweep(write(tmp_path, above)).step_budget == 60_000


def test_search_space_kinds_and_overrides(tmp_path):
    cfg = load_sweep(write(tmp_path, base(
        "search:\n  lr: {loguniform: [0.0001, 0.01]}\n  entropy_coeff: {choice: [0.0, 0.01]}\n"
        "  lambda: {grid: [0.9, 0.95]}\n  gamma: 0.98\nnum_samples: 3\n")))  # fmt: skip
    assert {k: s.kind for k, s in cfg.search.items()} == {
        "lr": "loguniform", "entropy_coeff": "choice", "lambda_": "grid", "gamma": "constant"}  # fmt: skip
    assert cfg.num_grid_trials == 2 * 3
    seeds = load_sweep(write(tmp_path, f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0, 1]\nnum_samples: 2\n"
                                       "search:\n  lr: {loguniform: [0.0001, 0.01]}\n"))  # fmt: skip
    drawn = {(t["seed"], t["hp"]["lr"]) for t in seeds.trials()}
    assert len(drawn) == 4 and len({lr for _, lr in drawn}) == 2  # each sample's draw is shared by the seeds
    trial = cfg.base_config("ppo", cfg.map_sets[0], 0, {"lr": 0.002, "lambda_": 0.9, "gamma": 0.98})
    hp = trial.hyperparameters
    assert (hp.lr, hp.lambda_, hp.gamma, hp.num_epochs) == (0.002, 0.9, 0.98, PRESETS["fast"]["ppo"].num_epochs)


def test_map_paths_resolve_next_to_the_sweep_file(tmp_path, monkeypatch):
    (tmp_path / "m").mkdir()
    for suffix in (".yaml", ".pgm"):
        (tmp_path / "m" / f"map-1{suffix}").write_bytes((ROOT / "maps" / f"map-1{suffix}").read_bytes())
    monkeypatch.chdir(ROOT / "scripts")  # not where the map is
    cfg = load_sweep(write(tmp_path, "algorithms: [ppo]\nmaps: [m/map-1.yaml]\nseeds: [1]\n"))
    assert cfg.map_sets == ((str((tmp_path / "m" / "map-1.yaml").resolve()),),)
    (tmp_path / "m" / "current.yaml").symlink_to(tmp_path / "m" / "map-1.yaml")  # read as itself, as nav2 reads it
    cfg = load_sweep(write(tmp_path, "algorithms: [ppo]\nmaps: [m/current.yaml]\nseeds: [1]\n"))
    assert cfg.map_sets == ((str((tmp_path / "m").resolve() / "current.yaml"),),)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (base("learning_rate: 0.1\n"), "key 'learning_rate': unknown key"),
        (f"algorithms: [ppo]\nmaps: [{MAP_1}]\n", "key 'seeds': missing"),
        (f"algorithms: [dqn]\nmaps: [{MAP_1}]\nseeds: [0]\n", "key 'algorithms': unknown algorithm 'dqn'"),
        (
            f"algorithms: ppo\nmaps: [{MAP_1}]\nseeds: [0]\n",
            "key 'algorithms': input should be a valid list, got 'ppo'",
        ),
        (
            f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [zero]\n",
            "key 'seeds[0]': input should be a valid integer, got 'zero'",
        ),
        ("algorithms: [ppo]\nmaps: [nowhere.yaml]\nseeds: [0]\n", "key 'maps[0]': map file 'nowhere.yaml' not found"),
        (base("timesteps: -5\n"), "key 'timesteps': input should be greater than or equal to 1, got -5"),
        (base("timesteps: 1.5\n"), "key 'timesteps': input should be a valid integer, got 1.5"),
        (base("timesteps: 99999999999999999999999\n"), "key 'timesteps': timesteps 99,999,"),  # it named maps[0]
        (base("envs_per_runner: 100000\n"), "key 'envs_per_runner': envs_per_runner must be at most 1,024"),
        (base("evaluation: {starts: 999999}\n"), "key 'evaluation.starts': evaluation.starts must be at most 1,000"),
        (base("evaluation: {design_budget: 99999999}\n"), "'evaluation.design_budget': evaluation.design_budget must"),
        (base("search: {policy_angle_frequencies: 100000}\n"), "must be at most 64, got 100000"),
        (base("preset: slow\n"), "key 'preset': unknown preset 'slow'"),
        (f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [1, 1]\n", "key 'seeds[1]': 1 is given twice"),
        (f"algorithms: [ppo, ppo]\nmaps: [{MAP_1}]\nseeds: [1]\n", "key 'algorithms[1]': 'ppo' is given twice"),
        (f"algorithms: [ppo]\nmaps: [{MAP_1}, {MAP_1}]\nseeds: [1]\n", "key 'maps[1]': "),
        (f"algorithms: [ppo]\nmaps: [[{MAP_1}, {MAP_2}], [{MAP_2}, {MAP_1}]]\nseeds: [1]\n", "key 'maps[1]': "),
        (base("env: {move_cost: 1.0e+300}\n"), "key 'env.move_cost': env_config 'move_cost' must be in [0, 1e+06]"),
        (base("env: {max_step: 10}\n"), "key 'env': env_config: unknown key 'max_step'"),
        (base("search: {lr: {choice: [0.001, 0.001]}}\nnum_samples: 2\n"), "two of the 2 samples draw the same values"),
        (
            base("search: {lr: {choice: [0.001]}}\nnum_samples: 3\n"),
            "key 'num_samples': two of the 3 samples draw the same values (lr=0.001), so their trials would run twice",
        ),
        (
            base("evaluation: {maps: ['generate:rooms']}\n"),
            "key 'evaluation.maps': evaluation.maps must be map files, folders or globs",
        ),
        (base("search: {lr: {uniform: [0.1, 0.01]}}\n"), "key 'search.lr': uniform takes [low, high] with low < high"),
        (base("search: {lr: {normal: [0, 1]}}\n"), "key 'search.lr': expected a number or one of"),
        (base("search: {lr: {grid: [fast]}}\n"), "key 'search.lr': grid takes a list of numbers"),
        (base("search: {lr: {grid: [0.001, 0.001]}}\n"), "key 'search.lr': grid [0.001, 0.001] gives a value twice"),
        (
            base("num_samples: 3\nsearch: {lr: {grid: [0.001, 0.003]}}\n"),
            "key 'num_samples': 3 samples of a search with no random part would repeat the same trials",
        ),
        (base("search: {momentum: 0.9}\n"), "key 'search.momentum': unknown hyperparameter 'momentum'"),
        (base("search: {gamma: {grid: [0.9, 1.5]}}\n"), "key 'search.gamma': hyperparameter 'gamma' must be"),
        (
            f"algorithms: [ppo, impala]\nmaps: [{MAP_1}]\nseeds: [0]\nsearch: {{lambda: {{grid: [0.9, 1.5]}}}}\n",
            "key 'search.lambda_': hyperparameter 'lambda_' must be a number in [0, 1], got 1.5",
        ),
        (base("checkpoint: {every: 0}\n"), "key 'checkpoint.every': input should be greater than or equal to 1, got 0"),
        (base("evaluation: {every: 0}\n"), "key 'evaluation.every': input should be greater than or equal to 1, got 0"),
        (base("checkpoint: {often: 1}\n"), "key 'checkpoint.often': unknown key (known: every, keep)"),
        (
            base("evaluation: {bogus: 1}\n"),
            "key 'evaluation.bogus': unknown key (known: every, starts, select_starts, maps, design_budget)",
        ),
        (base("name: 'a b'\n"), "key 'name': expected a plain folder name"),
        (base("name: '..'\n"), "key 'name': expected a plain folder name"),
        (base("name: ../../etc\n"), "key 'name': expected a plain folder name"),
        (base("stop: {time_total_s: soon}\n"), "key 'stop.time_total_s': input should be a valid number, got 'soon'"),
        (f"algorithms: []\nmaps: [{MAP_1}]\nseeds: [0]\n", "key 'algorithms': list should have at least 1 item"),
        (base("seeds: [true]\n").replace("seeds: [0]\n", ""), "key 'seeds[0]': input should be a valid integer"),
        (base("maps: [[]]\n").replace(f"maps: [{MAP_1}]\n", ""), "key 'maps[0]': expected a map path"),
        ("- just\n- a list\n", "expected a mapping of keys"),
        ("algorithms: [ppo\n", "not valid YAML at line"),
        (base("pretrained: /no/such/ckpt\n"), "key 'pretrained': checkpoint '/no/such/ckpt' not found"),
        (
            base("search:\n  minibatch_size: {grid: [250, 1000]}\n  train_batch_size: {grid: [500, 4000]}\n"),
            "key 'search': trial 2 (ppo, minibatch_size=1000, train_batch_size=500): minibatch_size (1000) must not",
        ),
        (
            base("search:\n  minibatch_size: {grid: [250, 1000]}\n  train_batch_size: {grid: [4000, 500]}\n"),
            "key 'search': trial 3 (ppo, minibatch_size=1000, train_batch_size=500): minibatch_size (1000) must not",
        ),
        (base("search:\n  lambda: 0.5\n  lambda_: 0.9\n"), "key 'search.lambda_': lambda and lambda_ are one"),
        (
            base(
                f"pretrained: {ROOT / 'smorphi_rl' / 'policies' / 'designer'}\n"
                "search:\n  policy_angle_frequencies: {grid: [0, 8]}\n"
            ),
            "key 'search.policy_angle_frequencies': a pretrained policy is fine-tuned in the layout it was",
        ),
        (
            base("maps: [[" + MAP_1 + ", " + MAP_1 + "]]\n").replace(f"maps: [{MAP_1}]\n", ""),
            "key 'maps[0]': " + MAP_1 + " is given twice in one set",
        ),
    ],
)
def test_mistakes_name_the_file_and_the_key(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(SweepConfigError) as info:
        load_sweep(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


def test_a_setting_that_needs_another_searched_beside_it_loads(tmp_path):
    """lr_knee_at was checked alone, and refused as placing an lr_knee not set, though the file set both; values
    that do not suit each other but that no trial draws together are no trial's problem."""
    cfg = load_sweep(write(tmp_path, base("search:\n  lr_knee: 0.0001\n  lr_knee_at: {grid: [0.3, 0.6]}\n")))
    assert [t["hp"]["lr_knee_at"] for t in cfg.trials()] == [0.3, 0.6]
    text = "search:\n  minibatch_size: {choice: [128, 1500]}\n  train_batch_size: {choice: [1000, 8000]}\n"
    (trial,) = load_sweep(write(tmp_path, base(text))).trials()
    assert trial["hp"]["minibatch_size"] <= trial["hp"]["train_batch_size"]


def test_numbers_with_an_exponent_are_numbers(tmp_path):
    """YAML 1.1 reads 1e-4 as a string and 3e5 as 300000.0: `lr: 1e-4` was refused as no number, `timesteps: 3e5` as
    no integer."""
    text = base(
        "timesteps: 3e5\nevaluation: {starts: 1e1}\nsearch: {lr: 1e-4, entropy_coeff: {grid: [1e-3, 1E-2]},"
        " num_epochs: {grid: [1e0, 2e0]}}\n"
    ).replace("seeds: [0]", "seeds: [0, 1e0]")
    sweep = load_sweep(write(tmp_path, text))
    assert sweep.timesteps == 300_000 and type(sweep.timesteps) is int and sweep.evaluation.starts == 10
    assert sweep.search["lr"].values == (1e-4,) and sweep.search["entropy_coeff"].values == (1e-3, 1e-2)
    assert sweep.search["num_epochs"].values == (1, 2) and sweep.seeds == (0, 1)
    assert all(type(v) is int for v in (*sweep.search["num_epochs"].values, *sweep.seeds))


def test_a_start_or_block_that_does_not_fit_a_map_names_the_env_key(tmp_path, capsys):
    """Checked on the maps before Ray starts; the line named neither the file nor the key."""
    from smorphi_rl.cli import main

    for env, message in (
        ("{start_xy: [100, 100]}", "key 'env.start_xy': env_config 'start_xy': map map-1: point"),
        ("{block_side_m: 50}", "key 'env.block_side_m': env_config 'block_side_m' on map-1: a block"),
    ):
        path = write(tmp_path, base(f"env: {env}\n"))
        assert main(["sweep", str(path), "--log-dir", str(tmp_path / "logs")]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"{path}: {message}" in err, err
    assert not (tmp_path / "logs").exists()


def test_a_checkpoint_resolves_next_to_the_sweep_file_and_a_bad_one_names_the_key(tmp_path, monkeypatch, capsys):
    (tmp_path / "ck").mkdir()
    monkeypatch.chdir(ROOT / "scripts")  # not where the checkpoint is
    path = write(tmp_path, base("pretrained: ck\n"))
    assert load_sweep(path).pretrained == str((tmp_path / "ck").resolve())
    from smorphi_rl.cli import main

    assert main(["sweep", str(path), "--log-dir", str(tmp_path / "logs")]) == 1  # a folder that is no checkpoint
    said = capsys.readouterr().err
    assert f"{path}: key 'pretrained': {(tmp_path / 'ck').resolve()}: holds no RLlib checkpoint" in said
    assert not (tmp_path / "logs").exists()


def test_two_map_files_of_one_name_in_different_map_sets_are_refused(tmp_path):
    """Each trial alone is fine, but the tables grouped both floors as seeds of one map 'map-1'."""
    other = tmp_path / "other"
    other.mkdir()
    (other / "map-1.yaml").write_text(Path(MAP_2).read_text())
    (other / "map-2.pgm").write_bytes(Path(MAP_2).with_suffix(".pgm").read_bytes())
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"algorithms: [ppo]\nseeds: [0]\nmaps: [{MAP_1}, {other / 'map-1.yaml'}]\n")
    with pytest.raises(SweepConfigError, match=r"key 'maps': .* share the name 'map-1', which names the trials"):
        load_sweep(sweep)


def test_a_file_name_that_is_no_folder_name_is_said_to_be_the_files(tmp_path):
    """With no `name` key the experiment takes the file's name; the complaint says so rather than blame a key."""
    sweep = tmp_path / "my sweep.yaml"
    sweep.write_text(base())
    with pytest.raises(SweepConfigError, match="key 'name': missing, and the file's name 'my sweep', the default,"):
        load_sweep(sweep)


def test_missing_file(tmp_path):
    with pytest.raises(SweepConfigError, match="no such sweep file"):
        load_sweep(tmp_path / "absent.yaml")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (base("seeds: [1]\n"), "duplicate key 'seeds'"),
        (base("stop: {time_total: 60}\n"), "key 'stop': unknown metric 'time_total'"),
        (base("stop: {training_iteration: -1}\n"), "key 'stop.training_iteration': must be above 0"),
        (base("stop: {time_total_s: 0}\n"), "key 'stop.time_total_s': must be above 0"),
        (base("num_samples: 1000000000\nsearch: {lr: {uniform: [0.001, 0.01]}}\n"), "key 'num_samples'"),
    ],
)
def test_silent_acceptance_is_refused(tmp_path, text, message):
    with pytest.raises(SweepConfigError, match=message):
        load_sweep(write(tmp_path, text))


def test_a_sweep_can_plan_with_the_footprint_safe_planner(tmp_path):
    cfg = load_sweep(write(tmp_path, base("env: {planner: fit, start_xy: [2.5, 0.5]}\n")))
    train = cfg.base_config("ppo", (MAP_1,), 0, {})
    assert train.env.planner == "fit" and train.env.start_xy == (2.5, 0.5)
    with pytest.raises(SweepConfigError, match="planner"):
        load_sweep(write(tmp_path, base("env: {planner: astar}\n")))


def test_a_sweep_whose_trials_could_not_be_evaluated_is_refused_before_anything_is_written(tmp_path):
    """Every trial is measured against an exact optimum: generated floors with no evaluation maps, or a map over
    the cells an optimum is computed on, are one line naming the key; the command writes nothing."""
    import subprocess
    import sys

    import numpy as np
    import yaml
    from PIL import Image

    from smorphi_rl.protocol import OPTIMUM_MAX_CELLS

    generated = "algorithms: [ppo]\nmaps: ['generate:mixed']\nseeds: [0]\n"
    with pytest.raises(SweepConfigError, match=r"key 'evaluation.maps': the maps of maps\[0\] are generated"):
        load_sweep(write(tmp_path, generated))
    load_sweep(write(tmp_path, generated + f"evaluation: {{maps: [{MAP_1}]}}\n"))  # evaluated on a fixed floor
    side = int(OPTIMUM_MAX_CELLS**0.5) + 1
    pixels = np.full((side, side), 254, dtype=np.uint8)
    pixels[0, :] = 0
    Image.fromarray(pixels).save(tmp_path / "large.pgm")
    doc = {"image": "large.pgm", "resolution": 0.05, "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}
    (tmp_path / "large.yaml").write_text(yaml.safe_dump(doc))
    large = "algorithms: [ppo]\nmaps: [large.yaml]\nseeds: [0]\n"
    with pytest.raises(SweepConfigError, match=rf"key 'maps\[0\]': .*large.yaml: {side * side:,} cells, over the"):
        load_sweep(write(tmp_path, large))
    with pytest.raises(SweepConfigError, match=r"key 'evaluation.maps': .*large.yaml: .* cells, over the"):
        load_sweep(write(tmp_path, base("evaluation: {maps: [large.yaml]}\n")))
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = subprocess.run([sys.executable, "-m", "smorphi_rl.cli", "sweep", "s.yaml"], capture_output=True,
                          text=True, cwd=tmp_path, timeout=120)  # fmt: skip
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "cells, over the" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no logs folder, nothing else


def test_a_trial_folder_name_too_long_for_the_file_system_is_refused_before_anything_is_written(tmp_path):
    """A 245-character map name failed only once Ray ran the trial, leaving a folder that blocked the sweep's name."""
    import shutil

    long = "L" * 190
    shutil.copy(Path(MAP_1).with_suffix(".pgm"), tmp_path / "map-1.pgm")
    (tmp_path / f"{long}.yaml").write_text(Path(MAP_1).read_text())
    with pytest.raises(SweepConfigError, match=r"key 'maps\[0\]': its trials. folders would be named 206 bytes long"):
        load_sweep(write(tmp_path, f"algorithms: [ppo]\nmaps: [{long}.yaml]\nseeds: [0]\n"))

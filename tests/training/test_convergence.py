"""The one definition of convergence, and a sweep's table read back from its trial folders."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from smorphi_rl.training.convergence import TOLERANCE, convergence
from smorphi_rl.training.sweep_report import group_curves, read_sweep, read_trial, write_sweep_tables


def test_converges_where_the_curve_enters_the_band_for_good():
    steps = np.arange(1, 21) * 1000.0
    curve = np.r_[np.linspace(80, 88, 8), np.full(12, 88.0)]  # rises for 8 iterations, then flat
    at, plateau = convergence(steps, curve)
    assert plateau == 88.0
    first_inside = np.flatnonzero(np.abs(curve - 88) <= TOLERANCE * 88)[0]
    assert at == steps[first_inside] and 1000 < at < 8000


def test_a_late_excursion_moves_convergence_after_it():
    steps = np.arange(1, 21) * 1000.0
    curve = np.full(20, 88.0)
    curve[12] = 80.0  # one iteration far outside the band
    at, _ = convergence(steps, curve)
    assert at == 14000.0


def test_a_flat_curve_converges_at_once_and_nan_iterations_do_not_count_as_inside():
    steps = np.arange(1, 11) * 1000.0
    assert convergence(steps, np.full(10, 85.0))[0] == 1000.0
    curve = np.r_[np.nan, np.nan, np.full(8, 85.0)]  # no episode finished in the first two iterations
    assert convergence(steps, curve)[0] == 3000.0
    at, plateau = convergence(steps, np.full(10, np.nan))
    assert at is None and math.isnan(plateau)


def test_a_curve_still_moving_at_its_end_has_not_converged():
    steps = np.arange(1, 11) * 1000.0
    curve = np.r_[np.full(8, 80.0), 95.0, 95.0]  # in the band only over the plateau window itself
    at, plateau = convergence(steps, curve)
    assert at is None and plateau == 95.0
    curve = np.r_[np.full(7, 80.0), 95.0, 95.0, 95.0]  # and one iteration before it: converged there
    assert convergence(steps, curve)[0] == 8000.0


def _trial(root: Path, name: str, algo: str, lr: float, rows: list[dict]) -> Path:
    d = root / name
    d.mkdir()
    (d / "params.json").write_text(json.dumps({"algo": algo, "maps": ["/x/map-1.yaml"], "seed": 0, "hp": {"lr": lr}}))
    (d / "result.json").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    return d


def _row(i: int, r1: float, best: float) -> dict:
    p_len = int(200 - 2 * best)  # distinct morphologies for distinct R1
    return {"smorphi_iteration": i, "num_env_steps_sampled_lifetime": 1000 * i, "time_this_iter_s": 2.0,
            "env_runners": {"episode_return_mean": 17000.0 + i, "smorphi": {"R1_final": r1 - 1.0}},
            "eval": {"settled_R1_mean": r1, "median_gap": 90.0 - r1, "share_within_1pct": 0.5},
            "smorphi_episode_best": json.dumps([["map-1", 10.0, 20.0, 30.0, 95.0, p_len, best]])}  # fmt: skip


def test_trial_rows_count_iterations_re_run_after_a_restore_once(tmp_path):
    rows = [_row(1, 82.0, 88.0), _row(2, 85.0, 89.0), _row(2, 86.0, 89.5), _row(3, 86.0, 90.0)]
    d = _trial(tmp_path, "ppo-a", "ppo", 0.001, rows)
    with (d / "result.json").open("a") as fh:
        fh.write('{"smorphi_iteration": 4, "num_env')  # cut short by a kill
    row = read_trial(d)
    assert row is not None
    assert (row.iterations, row.env_steps, row.wall_s) == (3, 3000, 6.0)
    assert row.curve["eval_R1"] == [82.0, 86.0, 86.0]  # the re-run iteration 2 replaced the first
    assert row.curve["final_R1"] == [81.0, 85.0, 85.0]
    assert row.best is not None and row.best.R1 == 90.0 and row.best.angles == "(10, 20, 30)"
    assert row.hyperparameters == {"lr": 0.001} and row.maps == "map-1"


def test_sweep_table_and_curves(tmp_path):
    _trial(tmp_path, "ppo-a", "ppo", 0.001, [_row(i, 80.0 + i, 85.0 + i) for i in range(1, 6)])
    _trial(tmp_path, "ppo-b", "ppo", 0.003, [_row(i, 81.0, 84.0) for i in range(1, 4)])
    (tmp_path / "not-a-trial").mkdir()
    rows = read_sweep(tmp_path)
    assert [r.trial for r in rows] == ["ppo-a", "ppo-b"]
    write_sweep_tables(rows, tmp_path / "s.csv", tmp_path / "s.md")
    lines = (tmp_path / "s.csv").read_text().splitlines()
    assert lines[0].startswith("trial,algo,maps,seed,lr,env_steps")
    assert lines[1].startswith("ppo-a,ppo,map-1,0,0.001,5000,5,10,90.00,")  # sorted by best R1
    groups = group_curves(rows)
    (lines_by_label,) = groups.values()
    assert set(lines_by_label) == {"PPO lr=0.001 (1 seed)", "PPO lr=0.003 (1 seed)"}
    line = lines_by_label["PPO lr=0.001 (1 seed)"]
    assert math.isnan(line["eval_R1_mean"][0]) and line["eval_R1_mean"][-1] == 85.0

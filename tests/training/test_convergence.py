"""The one definition of convergence, and a sweep's table read back from its trial folders."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from smorphi_rl.training.convergence import SHARE, converged_at, convergence, plateau
from smorphi_rl.training.sweep_report import group_curves, read_sweep, read_trial, write_sweep_tables


def test_converges_at_the_first_evaluation_from_which_90_percent_of_starts_stay_within_1_percent():
    steps = np.arange(1, 11) * 1000.0
    within = np.array([0.1, 0.5, 0.95, 0.85, 0.9, 0.9, 1.0, 0.95, 1.0, 0.9])  # dips under 90 % once, at 4,000
    assert converged_at(steps, within) == 5000.0
    assert converged_at(steps, np.full(10, 1.0)) == 1000.0  # from the first evaluation
    assert SHARE == 0.9


def test_a_run_under_90_percent_at_its_end_has_not_converged():
    steps = np.arange(1, 11) * 1000.0
    assert converged_at(steps, np.r_[np.full(9, 1.0), 0.85]) is None
    assert converged_at(steps, np.full(10, np.nan)) is None  # never evaluated


def test_iterations_without_an_evaluation_are_skipped():
    steps = np.arange(1, 11) * 1000.0
    within = np.array([0.2, np.nan, np.nan, 0.95, np.nan, 0.9, np.nan, np.nan, 1.0, np.nan])
    assert converged_at(steps, within) == 4000.0


def test_the_plateau_is_the_mean_settled_r1_of_the_last_fifth_of_evaluations():
    curve = {"env_steps": [1000.0 * i for i in range(1, 12)], "eval_within": [0.0] * 8 + [1.0, np.nan, 1.0],
             "eval_R1": [80.0] * 8 + [90.0, np.nan, 92.0]}  # fmt: skip
    at, level = convergence(curve)
    assert at == 9000.0 and level == 91.0  # the last 2 of 10 measured points
    assert math.isnan(plateau(np.full(3, np.nan)))


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
    rows_a = [_row(i, 80.0 + i, 85.0 + i) for i in range(1, 6)]
    rows_a[-1]["smorphi_done"] = True  # the last row of a trial that reached its budget
    _trial(tmp_path, "ppo-a", "ppo", 0.001, rows_a)
    _trial(tmp_path, "ppo-b", "ppo", 0.003, [_row(i, 81.0, 84.0) for i in range(1, 4)])  # cut short
    (tmp_path / "not-a-trial").mkdir()
    rows = read_sweep(tmp_path)
    assert [r.trial for r in rows] == ["ppo-a", "ppo-b"]
    write_sweep_tables(rows, tmp_path / "s.csv", tmp_path / "s.md")
    lines = (tmp_path / "s.csv").read_text().splitlines()
    assert lines[0].startswith("trial,algo,maps,seed,lr,env_steps")
    assert lines[0].endswith("kept_median_gap,kept_share_within_1pct,trained_share_within_1pct,"
                             "converged_at_env_steps,settled_R1_plateau,finished")  # fmt: skip
    assert lines[1].startswith("ppo-a,ppo,map-1,0,0.001,5000,5,10,90.00,")  # sorted by best R1
    assert lines[1].endswith(",5.00,0.50,0.50,not converged,85.00,yes")  # the last evaluation: gap 5, half within 1 %
    assert lines[2].endswith(",no")
    groups = group_curves(rows)
    (lines_by_label,) = groups.values()
    assert set(lines_by_label) == {"PPO lr=0.001 (1 seed)"}  # a trial cut short is in no group
    line = lines_by_label["PPO lr=0.001 (1 seed)"]
    assert math.isnan(line["eval_R1_mean"][0]) and line["eval_R1_mean"][-1] == 85.0


def test_runs_that_never_converged_are_censored_at_their_own_budget():
    from smorphi_rl.training.convergence import censored_steps

    least, most = censored_steps([(4_000, 10_000), (None, 10_000), (6_000, 10_000), (None, 5_000)])
    assert least == [4_000, 10_000, 6_000, 5_000] and most == [4_000, math.inf, 6_000, math.inf]
    assert censored_steps([]) == ([], [])


def test_a_curve_is_read_at_equal_env_steps_from_its_last_evaluation_by_then():
    from smorphi_rl.training.convergence import at_steps

    curve = {"env_steps": [1_000.0, 2_000.0, 3_000.0], "eval_gap": [4.0, math.nan, 1.0]}
    assert at_steps(curve, "eval_gap", 2_500) == 4.0  # the evaluation at 2,000 measured nothing
    assert at_steps(curve, "eval_gap", 3_000) == 1.0 and math.isnan(at_steps(curve, "eval_gap", 500))
    from smorphi_rl.training.convergence import first_measured_steps

    assert (
        first_measured_steps(curve, "eval_gap") == 1_000
        and first_measured_steps({"env_steps": []}, "eval_gap") == math.inf
    )


def test_a_trial_that_ends_on_an_earlier_policy_shows_both_shares(tmp_path):
    """The kept policy's share stood beside a convergence read from the trained policy's curve, unnamed: a row
    said 95 % within 1 % and not converged."""
    rows = [_row(i, 85.0, 88.0 + i) for i in range(1, 4)]
    rows[-1]["eval"] |= {"share_within_1pct": 0.95, "trained": {"share_within_1pct": 0.5, "settled_R1_mean": 85.0}}
    rows[-1]["smorphi_done"] = True
    _trial(tmp_path, "ppo-a", "ppo", 0.001, rows)
    write_sweep_tables(read_sweep(tmp_path), tmp_path / "s.csv", tmp_path / "s.md")
    header, row = csv.reader((tmp_path / "s.csv").read_text().splitlines())
    figures = dict(zip(header, row, strict=True))
    assert figures["kept_share_within_1pct"] == "0.95" and figures["trained_share_within_1pct"] == "0.50"
    assert figures["converged_at_env_steps"] == "not converged"


def test_figures_a_trial_lacks_are_empty_cells_not_nan(tmp_path):
    rows = [_row(i, 85.0, 88.0 + i) for i in range(1, 3)]
    for r in rows:
        del r["time_this_iter_s"], r["eval"]
    _trial(tmp_path, "ppo-a", "ppo", 0.001, rows)
    write_sweep_tables(read_sweep(tmp_path), tmp_path / "s.csv", tmp_path / "s.md")
    header, row = csv.reader((tmp_path / "s.csv").read_text().splitlines())
    figures = dict(zip(header, row, strict=True))
    assert figures["wall_s"] == figures["settled_R1_plateau"] == figures["kept_median_gap"] == ""
    assert "nan" not in (tmp_path / "s.csv").read_text() + (tmp_path / "s.md").read_text()

"""A sweep's tables over seeds, from synthetic trials (no Ray): intervals, and trials that never converged."""

import numpy as np

from smorphi_rl.stats import band
from smorphi_rl.training.sweep_report import TrialRow, group_curves, write_sweep_groups
from smorphi_rl.training.topk import Found


def _trial(seed: int, lr: float, plateau: float, converged_at: float | None, measured: bool = True) -> TrialRow:
    steps = [0.0, 5_000.0, 10_000.0]
    within = [0.0, 0.5, 0.9 - seed / 10] if measured else [np.nan] * 3  # NaN: a map without an exact optimum
    curve = {"env_steps": steps, "episode_return_mean": [1.0, 2.0, 3.0], "eval_R1": [80.0, 85.0 + seed, plateau],
             "eval_within": within}  # fmt: skip
    best = Found("ppo", "map-1", (1.0, 2.0, 3.0), 95.0, 60, 89.0 + seed / 10, 100)
    return TrialRow(f"t{seed}-{lr}", "ppo", "map-1", seed, {"lr": lr}, 10_000, 5, 60.0, best, converged_at, plateau,
                    curve, median_gap=1.0 + seed, share_within_1pct=0.9 - seed / 10)  # fmt: skip


def test_groups_table_gives_intervals_over_seeds_and_counts_non_converged(tmp_path):
    rows = [_trial(0, 1e-3, 88.0, 4_000), _trial(1, 1e-3, 88.6, 6_000), _trial(2, 1e-3, 87.1, None),
            _trial(0, 3e-4, 86.0, None)]  # fmt: skip
    write_sweep_groups(rows, tmp_path / "groups.md")
    lines = (tmp_path / "groups.md").read_text().splitlines()
    first = next(line for line in lines if "lr=0.001" in line)
    cells = [c.strip() for c in first.strip("|").split("|")]
    # seeds, median gap, share within 1 %, converged, env steps to converge, plateau: medians with intervals
    assert cells[2] == "3" and cells[3].startswith("2.00 [") and cells[4].startswith("0.80 [") and cells[5] == "2 of 3"
    assert cells[6] == "6,000 [4,000, inf]" and cells[7].startswith("88.00 [")  # the third trial: past 10,000
    lone = next(line for line in lines if "lr=0.0003" in line)
    assert "| > 10,000 (1 seed) |" in lone and "0 of 1" in lone
    assert (tmp_path / "groups.md").read_text().count("| map-1 |") == 2


def test_curves_are_banded_by_the_bootstrap_interval_of_the_mean():
    curves = group_curves([_trial(0, 1e-3, 88.0, 4_000), _trial(1, 1e-3, 89.0, 6_000), _trial(2, 1e-3, 90.0, None)])
    line = next(iter(curves["map-1"].values()))
    mean, lo, hi = line["eval_R1_mean"], line["eval_R1_lo"], line["eval_R1_hi"]
    assert np.isclose(mean[-1], 89.0) and lo[-1] < 89.0 < hi[-1] and hi[-1] <= 90.0 and lo[-1] >= 88.0


def test_band_of_one_curve_is_the_curve():
    mean, lo, hi = band(np.array([[1.0, 2.0, np.nan]]))
    assert np.array_equal(hi[:2], mean[:2])
    assert np.array_equal(mean[:2], [1.0, 2.0]) and np.array_equal(lo[:2], mean[:2]) and np.isnan(mean[2])


def test_a_trial_cut_short_is_left_out_of_its_group_and_said_so(tmp_path):
    from dataclasses import replace

    cut = replace(_trial(2, 1e-3, 70.0, None), finished=False)
    write_sweep_groups([_trial(0, 1e-3, 88.0, 4_000), _trial(1, 1e-3, 88.6, 6_000), cut], tmp_path / "groups.md")
    text = (tmp_path / "groups.md").read_text()
    assert "1 unfinished trial (sweep.md) is left out" in text and "| 2 of 2 |" in text


def test_trials_on_a_map_without_an_optimum_are_not_measured_rather_than_not_converged(tmp_path):
    from smorphi_rl.training.sweep_report import write_sweep_tables

    rows = [_trial(0, 1e-3, 88.0, None, measured=False), _trial(1, 1e-3, 88.6, None, measured=False)]
    write_sweep_groups(rows, tmp_path / "groups.md")
    assert "| not measured |" in (tmp_path / "groups.md").read_text()
    write_sweep_tables([*rows, _trial(2, 1e-3, 87.0, None)], tmp_path / "sweep.csv", tmp_path / "sweep.md")
    cells = [line.split(",")[-3] for line in (tmp_path / "sweep.csv").read_text().splitlines()[1:]]
    assert sorted(cells) == ["not converged", "not measured", "not measured"]


def test_an_interrupted_sweep_counts_the_trials_that_finished_apart_from_those_cut_short(tmp_path):
    from dataclasses import replace

    from smorphi_rl.training.sweep import SweepSummary, format_sweep_summary

    rows = [_trial(0, 1e-3, 88.0, 4_000), replace(_trial(1, 1e-3, 80.0, None), finished=False)]
    head = format_sweep_summary(SweepSummary(tmp_path / "s", rows, 3, 60.0, True, {})).splitlines()[0]
    assert "interrupted after 1 of 3 trials finished (1 cut short)" in head
    assert "ran 2 of 3 trials" in format_sweep_summary(SweepSummary(tmp_path / "s", rows, 3, 60.0, False, {}))


def test_a_resumed_sweep_says_how_many_trials_it_trained_and_how_many_it_read_back(tmp_path):
    from smorphi_rl.training.sweep import SweepSummary, format_sweep_summary

    rows = [_trial(0, 1e-3, 88.0, 4_000), _trial(1, 1e-3, 80.0, None)]
    resumed = SweepSummary(tmp_path / "s", rows, 2, 60.0, False, {}, read_back=1)
    assert "ran 2 of 2 trials (1 this call, 1 finished before) in" in format_sweep_summary(resumed).splitlines()[0]
    fresh = format_sweep_summary(SweepSummary(tmp_path / "s", rows, 2, 60.0, False, {})).splitlines()[0]
    assert "this call" not in fresh


def test_a_trial_without_an_evaluation_is_named_in_its_groups_figures(tmp_path):
    """Its NaN figures were filtered out before the median: "1.50 [1.00, 2.00]" under a group of 3 seeds."""
    from dataclasses import replace

    rows = [_trial(0, 1e-3, 88.0, 4_000), _trial(1, 1e-3, 88.6, 6_000),
            replace(_trial(2, 1e-3, 87.1, None), median_gap=np.nan, share_within_1pct=np.nan, best=None)]  # fmt: skip
    write_sweep_groups(rows, tmp_path / "groups.md")
    line = next(line for line in (tmp_path / "groups.md").read_text().splitlines() if "lr=0.001" in line)
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[3] == "1.50 [1.00, 2.00] (2 of 3 seeds)" and cells[4].endswith("(2 of 3 seeds)"), cells
    assert cells[-1].endswith("(2 of 3 seeds)"), cells


def test_a_resumed_sweeps_progress_shows_the_best_its_finished_trials_found(tmp_path):
    """A resume's status line said 'best R1 -' until a trial of this call reported, whatever earlier ones found."""
    import io
    from types import SimpleNamespace

    from smorphi_rl.training.sweep import _SweepProgress

    out = io.StringIO()
    progress = _SweepProgress(SimpleNamespace(name="tiny", timesteps=2000), 2, out)  # type: ignore[arg-type]
    rows = [_trial(0, 1e-3, 88.0, 4_000), _trial(1, 1e-3, 88.6, None)]
    progress.found([r.best for r in rows if r.best is not None])
    progress.complete("trial 0")
    assert "best R1 89.10 (1, 2, 3) on map-1" in out.getvalue()  # seed 1's, the better


def test_a_sweep_that_measured_the_designer_shows_its_gap_per_trial_and_group(tmp_path):
    """A designer sweep's sweep.md and sweep_groups.md left the design gap out (it was in summary.json alone)."""
    from dataclasses import replace

    from smorphi_rl.training.sweep_report import write_sweep_tables

    rows = [replace(_trial(s, 1e-3, 88.0, 4_000), design_gap_pct=0.2 + s / 10) for s in range(3)]
    write_sweep_tables(rows, tmp_path / "sweep.csv", tmp_path / "sweep.md")
    header, *lines = (tmp_path / "sweep.md").read_text().splitlines()
    column = [c.strip() for c in header.strip("|").split("|")].index("design_median_gap_pct")
    assert sorted(line.strip("|").split("|")[column].strip() for line in lines[1:]) == ["0.200", "0.300", "0.400"]
    write_sweep_groups(rows, tmp_path / "groups.md")
    text = (tmp_path / "groups.md").read_text()
    assert "| design median gap (%) |" in text and "| 0.30 [0.20, 0.40] |" in text
    write_sweep_tables([_trial(0, 1e-3, 88.0, 4_000)], tmp_path / "plain.csv", tmp_path / "plain.md")
    assert "design" not in (tmp_path / "plain.md").read_text()  # a sweep without the designer: no empty column


def test_draws_that_round_alike_are_two_groups_each_named_exactly(tmp_path):
    """A random search's 0.99999 and 0.999995 both read "1": their trials were pooled as seeds of one group, and
    sweep.csv kept neither value."""
    from smorphi_rl.training.sweep_report import write_sweep_tables

    rows = [_trial(0, 0.99999, 88.0, 4_000), _trial(1, 0.999995, 88.6, 6_000), _trial(2, 3e-4, 87.0, None)]
    write_sweep_groups(rows, tmp_path / "groups.md")
    text = (tmp_path / "groups.md").read_text()
    assert "| PPO lr=0.99999 | 1 |" in text and "| PPO lr=0.999995 | 1 |" in text
    assert "| PPO lr=0.0003 | 1 |" in text  # a value no other rounds to keeps its short label
    write_sweep_tables(rows, tmp_path / "sweep.csv", tmp_path / "sweep.md")
    lrs = {line.split(",")[4] for line in (tmp_path / "sweep.csv").read_text().splitlines()[1:]}
    assert lrs == {"0.99999", "0.999995", "0.0003"}


def test_the_progress_line_breaks_a_tie_in_r1_as_the_tables_do():
    """A sweep's line showed one shape of R1 89.50 and its tables another: the tables rank a tie by P_c."""
    import io
    from types import SimpleNamespace

    from smorphi_rl.training.sweep import _SweepProgress
    from smorphi_rl.training.topk import EpisodeBest

    out = io.StringIO()
    progress = _SweepProgress(SimpleNamespace(name="tie", timesteps=2000), 1, out)  # type: ignore[arg-type]
    first, covering = EpisodeBest("map-1", (175, 80, 110), 96.4, 69, 89.5), EpisodeBest("map-1", (180, 104, 81),
                                                                                     97.4, 79, 89.5)  # fmt: skip
    progress.found([first, covering])
    progress.complete("trial 0")
    assert "best R1 89.50 (180, 104, 81) on map-1" in out.getvalue()


def test_result_rows_skip_a_line_longer_than_any_row_and_read_the_rest(tmp_path, monkeypatch):
    """A crafted result.json of gigabytes without a newline was read whole into memory (4.7 GB for 2 GB)."""
    import json

    from smorphi_rl.training import sweep_report

    monkeypatch.setattr(sweep_report, "MAX_RESULT_LINE", 64)
    rows = [{"training_iteration": i, "x": i} for i in (1, 2)]
    path = tmp_path / "result.json"
    path.write_text(json.dumps(rows[0]) + "\n" + "0" * 1000 + "\n" + json.dumps(rows[1]) + "\n" + "9" * 300)
    assert sweep_report.result_rows(path) == rows

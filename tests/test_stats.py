"""Bootstrap intervals over seeds."""

from __future__ import annotations

import math

from smorphi_rl.stats import mean_interval


def test_interval_brackets_the_mean_and_narrows_with_agreement():
    wide = mean_interval([1.0, 5.0, 9.0])
    narrow = mean_interval([4.9, 5.0, 5.1])
    assert wide.lo <= wide.mean <= wide.hi and narrow.lo <= narrow.mean <= narrow.hi
    assert (narrow.hi - narrow.lo) < (wide.hi - wide.lo)
    assert mean_interval([1.0, 5.0, 9.0]) == wide  # seeded: one answer


def test_degenerate_inputs():
    assert mean_interval([3.0]).text() == "3.00 (1 seed)"
    assert mean_interval([2.0, 2.0]).lo == 2.0
    assert math.isnan(mean_interval([float("nan")]).mean) and mean_interval([]).text() == "-"


def test_ratio_of_medians_of_runs_that_all_converged():
    from smorphi_rl.stats import censored_ratio_interval

    iv = censored_ratio_interval([10.0, 50.0, 300.0], [10.0, 10.0, 40.0], budget=400.0)
    assert iv.mean == 5.0 and iv.bound == ""  # medians 50 / 10; the means would give 6.0
    assert iv.lo <= 5.0 <= iv.hi and iv.n == 3
    single = censored_ratio_interval([10.0], [5.0], budget=400.0)
    assert (single.mean, single.lo, single.hi) == (2.0, 2.0, 2.0)
    assert math.isnan(censored_ratio_interval([], [1.0], budget=400.0).mean)


def test_a_run_that_never_converged_counts_past_the_budget_never_left_out():
    from smorphi_rl.stats import censored_median_interval

    inf = math.inf
    one_late = censored_median_interval([80_000, 130_000, inf], budget=200_000)
    assert one_late.mean == 130_000 and one_late.bound == ""  # the median is an order statistic: still exact
    assert one_late.hi == inf and one_late.text(",.0f") == "130,000 [80,000, inf]"
    assert censored_median_interval([80_000, 130_000], budget=200_000).mean == 105_000  # leaving it out flatters
    most_late = censored_median_interval([130_000, inf, inf], budget=200_000)
    assert (most_late.mean, most_late.bound, most_late.lo) == (200_000, ">", 130_000)
    assert most_late.text(",.0f") == "> 200,000 [130,000, inf]"
    assert censored_median_interval([inf, inf, inf], budget=200_000).text(",.0f") == "> 200,000"


def test_a_ratio_past_the_budget_is_a_bound_in_the_right_direction():
    from smorphi_rl.stats import censored_ratio_interval

    inf = math.inf
    faster = censored_ratio_interval([90_000, inf, inf], [40_000, 60_000, 40_000], budget=200_000)
    assert (faster.mean, faster.bound) == (5.0, ">") and faster.text().startswith("> 5.00 [")  # 200,000 / 40,000
    assert faster.hi == inf and faster.lo < 5.0
    slower = censored_ratio_interval([150_000, 110_000, 110_000], [inf, inf, inf], budget=200_000)
    assert (slower.mean, slower.bound, slower.lo) == (0.55, "<", 0.0) and slower.hi == 0.75
    assert censored_ratio_interval([inf, inf, 1.0], [inf, inf, inf], budget=200_000).n == 0  # both past: no ratio
    exact = censored_ratio_interval([110_000, 90_000, 110_000], [50_000, 50_000, 80_000], budget=200_000)
    assert exact.bound == "" and exact.mean == 2.2 and exact.lo < exact.mean

"""Bootstrap intervals over seeds."""

from __future__ import annotations

import math

from smorphi_rl.stats import mean_interval


def test_interval_brackets_the_mean_and_narrows_with_agreement():
    wide = mean_interval([1.0, 5.0, 9.0])
    narrow = mean_interval([4.9, 5.0, 5.1])
    assert wide.lo <= wide.point <= wide.hi and narrow.lo <= narrow.point <= narrow.hi
    assert (narrow.hi - narrow.lo) < (wide.hi - wide.lo)
    assert mean_interval([1.0, 5.0, 9.0]) == wide  # seeded: one answer


def test_degenerate_inputs():
    assert mean_interval([3.0]).text() == "3.00 (1 seed)"
    assert mean_interval([2.0, 2.0]).lo == 2.0
    assert math.isnan(mean_interval([float("nan")]).point) and mean_interval([]).text() == "-"


def _bounds(times: list[float], budget: float) -> tuple[list[float], list[float]]:
    """(least, most) of runs with one budget, inf for a run that did not converge within it."""
    return [budget if math.isinf(t) else t for t in times], times


def test_ratio_of_medians_of_runs_that_all_converged():
    from smorphi_rl.stats import censored_ratio_interval

    iv = censored_ratio_interval(_bounds([10.0, 50.0, 300.0], 400), _bounds([10.0, 10.0, 40.0], 400))
    assert iv.point == 5.0 and iv.bound == ""  # medians 50 / 10; the means would give 6.0
    assert iv.lo <= 5.0 <= iv.hi and iv.n == 3
    single = censored_ratio_interval(([10.0], [10.0]), ([5.0], [5.0]))
    assert (single.point, single.lo, single.hi) == (2.0, 2.0, 2.0)
    assert math.isnan(censored_ratio_interval(([], []), ([1.0], [1.0])).point)
    assert math.isnan(censored_ratio_interval(([1.0], [1.0]), ([0.0], [0.0])).point)  # no ratio to a zero median


def test_a_ratio_of_one_run_against_several_resamples_the_several_alone():
    """A transfer stopped after seed 1's fine-tuning had 2 fine-tuned runs against 1 from scratch: scipy refused the
    one-run sample, and the stopped job's table was a traceback."""
    from smorphi_rl.stats import censored_ratio_interval

    iv = censored_ratio_interval(([150_000.0], [150_000.0]), ([40_000.0, 20_000.0], [40_000.0, 20_000.0]))
    assert iv.point == 5.0 and iv.n == 1 and iv.lo == 150_000 / 40_000 and iv.hi == 150_000 / 20_000
    assert iv.text() == "5.00 (1 seed)"


def test_a_run_that_never_converged_counts_past_the_budget_never_left_out():
    from smorphi_rl.stats import censored_median_interval

    inf = math.inf
    one_late = censored_median_interval(*_bounds([80_000, 130_000, inf], 200_000))
    assert one_late.point == 130_000 and one_late.bound == ""  # the median is an order statistic: still exact
    assert one_late.hi == inf and one_late.text(",.0f") == "130,000 [80,000, inf]"
    assert censored_median_interval(*_bounds([80_000, 130_000], 200_000)).point == 105_000  # leaving it out flatters
    most_late = censored_median_interval(*_bounds([130_000, inf, inf], 200_000))
    assert (most_late.point, most_late.bound, most_late.lo) == (200_000, ">", 130_000)
    assert most_late.text(",.0f") == "> 200,000 [130,000, inf]"
    assert censored_median_interval(*_bounds([inf, inf, inf], 200_000)).text(",.0f") == "> 200,000"
    # an even count: the median averages a run that converged with one that did not, so it is only at least
    even = censored_median_interval(*_bounds([90_000, inf], 200_000))
    assert (even.point, even.bound) == (145_000, ">")
    # budgets that differ (an async run stops a little past its budget): still at least, never dropped
    uneven = censored_median_interval([100_000, 200_000, 200_320], [100_000, inf, 200_320])
    assert (uneven.point, uneven.bound) == (200_000, ">")


def test_a_ratio_past_the_budget_is_a_bound_in_the_right_direction():
    from smorphi_rl.stats import censored_ratio_interval

    inf = math.inf
    tuned = _bounds([40_000, 60_000, 40_000], 200_000)
    faster = censored_ratio_interval(_bounds([90_000, inf, inf], 200_000), tuned)
    assert (faster.point, faster.bound) == (5.0, ">") and faster.text().startswith("> 5.00 [")  # 200,000 / 40,000
    assert faster.hi == inf and faster.lo < 5.0
    even = censored_ratio_interval(_bounds([90_000, inf], 200_000), _bounds([40_000, 40_000], 200_000))
    assert (even.point, even.bound) == (145_000 / 40_000, ">")  # at least 3.6, not 5
    slower = censored_ratio_interval(_bounds([150_000, 110_000, 110_000], 200_000), _bounds([inf, inf, inf], 200_000))
    assert (slower.point, slower.bound, slower.lo) == (0.55, "<", 0.0) and slower.hi == 0.75
    both = censored_ratio_interval(_bounds([inf, inf, 1.0], 200_000), _bounds([inf, inf, inf], 200_000))
    assert both.n == 0  # both medians past the budget: no ratio
    exact = censored_ratio_interval(_bounds([110_000, 90_000, 110_000], 200_000), _bounds([50_000, 50_000, 80_000],
                                                                                          200_000))  # fmt: skip
    assert exact.bound == "" and exact.point == 2.2 and exact.lo < exact.point


def test_a_seed_without_a_figure_is_named_as_left_out():
    """A NaN (a trial never evaluated) was dropped without a word: 3.50 [3.00, 4.00] under a "3 seeds" heading."""
    from smorphi_rl.stats import median_interval

    assert median_interval([math.nan, 3.0, 4.0]).text() == "3.50 [3.00, 4.00] (2 of 3 seeds)"
    assert median_interval([math.nan, 3.0]).text() == "3.00 (1 of 2 seeds)"
    assert median_interval([math.nan, math.nan]).text() == "-"


def test_the_few_seeds_note_says_what_the_interval_is():
    """FEW_SEEDS_NOTE, under every table over seeds: with 3-5 seeds the median's interval is the seeds' range (and
    the mean's with 3), which holds the true median with probability 1 - 2^(1 - n)."""
    import numpy as np

    from smorphi_rl.stats import FEW_SEEDS_NOTE, median_interval

    rng = np.random.default_rng(5)
    for n in (3, 4, 5):
        x = rng.normal(size=n)
        got = median_interval(list(x))
        assert (got.lo, got.hi) == (x.min(), x.max())
    got = mean_interval([1.0, 2.0, 9.0])
    assert (got.lo, got.hi) == (1.0, 9.0)
    samples = rng.normal(size=(20_000, 3))
    held = np.mean((samples.min(axis=1) < 0) & (samples.max(axis=1) > 0))  # the true median is 0
    assert abs(held - 0.75) < 0.02 and "75 %" in FEW_SEEDS_NOTE and f"{100 * (1 - 2**-4):.0f} %" in FEW_SEEDS_NOTE

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


def test_ratio_interval_brackets_the_ratio_of_means():
    from smorphi_rl.stats import ratio_interval

    iv = ratio_interval([40_000, 50_000, 60_000], [20_000, 25_000, 30_000])
    assert iv.mean == 2.0 and iv.lo < 2.0 < iv.hi and iv.n == 3
    single = ratio_interval([10.0], [5.0])
    assert (single.mean, single.lo, single.hi) == (2.0, 2.0, 2.0)
    assert math.isnan(ratio_interval([], [1.0]).mean)


def test_ratio_interval_of_medians():
    import numpy as np

    from smorphi_rl.stats import ratio_interval

    iv = ratio_interval([10.0, 50.0, 300.0], [10.0, 10.0, 40.0], statistic=np.median)
    assert iv.mean == 5.0  # medians 50 / 10; the means would give 6.0
    assert iv.lo <= 5.0 <= iv.hi and iv.n == 3

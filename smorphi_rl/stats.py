"""Figures over seeds with 95 % bootstrap intervals (scipy.stats.bootstrap; no hand-written resampling).

A claim about learning is a statistic per seed (a run's median gap, its share of starts within 1 %),
summarised over seeds as the mean or the median with a percentile bootstrap interval; transfer's steps to
converge are medians of times some runs never reach within their budget (right-censored). With 3-5 seeds such
intervals are wide; they say so honestly rather than hide it.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 10_000
FEW_SEEDS_NOTE = (
    "With few seeds a percentile bootstrap interval holds less than 95 %: a median's over up to 5 seeds (a mean's "
    "over 3) is the seeds' range, which holds the true median 1 - 2^(1-n) of the time: 50 % for 2 seeds (too few "
    "for a verdict), 75 % for 3, 88 % for 4, 94 % for 5."
)
"""How to read an interval over 3-5 seeds, under every table of them: P(all n seeds on one side of the median)
is 2^-n, and a resampled median of n <= 5 values (mean of 3) falls on the least value more than 2.5 % of the
time."""


VERDICT_SEEDS = 3
"""The fewest seeds a verdict (agrees, does not agree) is drawn from: two seeds' range holds the true median half the
time, and two equal methods' ranges fall apart in a given direction 1 time in 6."""


def too_few(n: int) -> str:
    """Why `n` seeds decide nothing ("" from `VERDICT_SEEDS` on)."""
    return "" if n >= VERDICT_SEEDS else "no seed" if n == 0 else f"{n} seed{'s' if n > 1 else ''}: too few to decide"


def cell(value: float, spec: str = ".4g") -> str:
    """A figure as a table's or CSV's cell: empty where there is none (NaN, never the text "nan")."""
    return f"{value:{spec}}" if math.isfinite(value) else ""


@dataclass(frozen=True)
class Interval:
    """A mean (or median) over seeds and its 95 % bootstrap interval (lo = hi = the value with one seed)."""

    point: float
    """The mean or the median, as the function that made it says."""
    lo: float
    hi: float
    n: int
    bound: str = ""
    """">" when the value is a lower bound only, "<" an upper bound (figures past a budget, `censored_...`)."""
    given: int = 0
    """How many values were given, counting those left out as not finite (0: as many as `n`)."""

    def text(self, fmt: str = ".2f") -> str:
        point = f"{self.bound} {self.point:{fmt}}".lstrip()
        left_out = f" ({self.n} of {self.given} seeds)" if self.given > self.n else ""
        if self.n < 2 or not math.isfinite(self.lo):
            return (f"{point} (1 seed)" if self.n == 1 and not left_out else f"{point}{left_out}") if self.n else "-"
        if self.bound == ">" and self.lo == self.point and math.isinf(self.hi):
            return point + left_out  # every resample past the budget: no interval to add
        return f"{point} [{self.lo:{fmt}}, {self.hi:{fmt}}]".replace(f"{math.inf:{fmt}}", "inf") + left_out


def mean_interval(values: Sequence[float], seed: int = 0) -> Interval:
    """Mean of `values` (one per seed) with its 95 % percentile bootstrap interval."""
    return _interval(values, np.mean, seed)


def median_interval(values: Sequence[float], seed: int = 0) -> Interval:
    """Median of `values` (one per seed) with its 95 % percentile bootstrap interval (`Interval.point` holds it)."""
    return _interval(values, np.median, seed)


def _interval(values: Sequence[float], statistic: Any, seed: int) -> Interval:
    from scipy.stats import bootstrap

    data = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    given = len(values)  # a seed whose figure is missing (NaN) is left out, and the text says so
    if data.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0, given=given)
    point = float(statistic(data))
    if data.size < 2 or np.all(data == data[0]):
        return Interval(point, point, point, int(data.size), given=given)
    res = bootstrap((data,), statistic, confidence_level=CONFIDENCE, n_resamples=RESAMPLES, method="percentile",
                    random_state=np.random.default_rng(seed))  # fmt: skip
    low, high = float(res.confidence_interval.low), float(res.confidence_interval.high)
    return Interval(point, low, high, int(data.size), given=given)


def censored_median_interval(least: Sequence[float], most: Sequence[float], seed: int = 0) -> Interval:
    """Median over seeds of the env steps until an event (a run's convergence), each run's time known to lie in
    [least, most]: its time where it happened, [its env steps, inf] where it did not happen within its budget
    (right-censored), with its 95 % percentile bootstrap interval.

    The median is monotone in every time, so it lies between the medians of `least` and of `most`: exact where they
    agree (a median that falls on a run that converged, later than every censored run's budget), otherwise known
    only to be at least the first (`bound` ">"). The interval's low end resamples `least`, its high end `most`
    (the same resamples), so it is never narrower than the data say."""
    low_times, high_times = (np.asarray(v, dtype=float) for v in (least, most))
    if low_times.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    point, upper = float(np.median(low_times)), float(np.median(high_times))
    low = _censored_distribution((low_times,), np.median, seed)
    high = _censored_distribution((high_times,), np.median, seed)
    return Interval(point, _end(low, 2.5), _end(high, 97.5), int(low_times.size), "" if point == upper else ">")


Bounds = tuple[Sequence[float], Sequence[float]]
"""Times over seeds as (least, most): each run's time lies between the two (`censored_median_interval`)."""


def censored_ratio_interval(numerator: Bounds, denominator: Bounds, seed: int = 0) -> Interval:
    """median(numerator) / median(denominator) of two independent sets of such times, each given as (least, most)
    (Table 5's speed-up, scratch / fine-tuned; `censored_median_interval`), with its 95 % percentile bootstrap
    interval (each set resampled on its own). Exact where both medians are; where only the numerator's is
    uncertain, a lower bound (">"); where only the denominator's, an upper bound ("<"); NaN (no ratio) where both
    are (with one budget for both sets, as transfer's, the ratio is then anywhere from 0 to infinity), or a median
    is not positive. The interval's low end takes each resample's least possible ratio, its high
    end the greatest."""
    (a_least, a_most), (b_least, b_most) = ((np.asarray(x, dtype=float), np.asarray(y, dtype=float))
                                            for x, y in (numerator, denominator))  # fmt: skip
    if a_least.size == 0 or b_least.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    a_lo, a_hi, b_lo, b_hi = (float(np.median(v)) for v in (a_least, a_most, b_least, b_most))
    a_exact, b_exact = a_lo == a_hi, b_lo == b_hi
    if not (a_exact or b_exact) or b_lo <= 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    least_ratio = a_lo / b_hi  # b exact here, or the ratio is only bounded above (x / inf = 0)
    most_ratio = a_hi / b_lo
    point, bound = ((least_ratio, "") if a_exact and b_exact else (least_ratio, ">") if b_exact
                    else (most_ratio, "<"))  # fmt: skip

    def of_ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.median(x, axis=axis) / np.median(y, axis=axis)

    low = _censored_distribution((a_least, b_most), of_ratio, seed)  # x / inf = 0: no less than that
    high = _censored_distribution((a_most, b_least), of_ratio, seed)
    return Interval(point, _end(low, 2.5), _end(high, 97.5), int(min(a_least.size, b_least.size)), bound)


def _censored_distribution(samples: tuple[np.ndarray, ...], statistic: Any, seed: int) -> np.ndarray:
    """The statistic over scipy's bootstrap resamples of `samples` (inf allowed): the same resamples for one seed."""
    from scipy.stats import bootstrap

    if all(s.size < 2 or np.all(s == s[0]) for s in samples):
        return np.atleast_1d(np.asarray(statistic(*samples), dtype=float))
    drawn = tuple(s for s in samples if s.size >= 2)  # a single value resamples to itself (scipy refuses it)

    def of_drawn(*draws: np.ndarray, axis: int = -1) -> np.ndarray:
        each = iter(draws)
        return statistic(*(next(each) if s.size >= 2 else s for s in samples), axis=axis)

    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's own interval of a distribution holding inf; only its draws are used
        res = bootstrap(drawn, of_drawn, confidence_level=CONFIDENCE, n_resamples=RESAMPLES, method="percentile",
                        random_state=np.random.default_rng(seed))  # fmt: skip
    return np.asarray(res.bootstrap_distribution, dtype=float)


def _end(distribution: np.ndarray, q: float) -> float:
    """A percentile of a bootstrap distribution; with inf in it, the nearest draw outward (no interpolation to inf)."""
    if np.isinf(distribution).any():
        return float(np.percentile(distribution, q, method="higher" if q > 50 else "lower"))
    return float(np.percentile(distribution, q))


def band(curves: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, lo, hi) over seeds (rows) at every point (column) of `curves`: the 95 % bootstrap band of the
    mean curve, for shaded plots. Points where a seed has no value yet fall back to the mean of those that do."""
    from scipy.stats import bootstrap

    data = np.asarray(curves, dtype=float)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # columns with no value at all stay NaN
        mean = np.nanmean(data, axis=0)
    lo, hi = mean.copy(), mean.copy()
    full = np.isfinite(data).all(axis=0) & (np.ptp(np.nan_to_num(data), axis=0) > 0)
    if data.shape[0] >= 2 and full.any():
        res = bootstrap((data[:, full],), np.mean, axis=0, confidence_level=CONFIDENCE, n_resamples=RESAMPLES // 5,
                        method="percentile", random_state=np.random.default_rng(seed))  # fmt: skip
        lo[full], hi[full] = res.confidence_interval.low, res.confidence_interval.high
    return mean, lo, hi

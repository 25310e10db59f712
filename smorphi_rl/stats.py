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


@dataclass(frozen=True)
class Interval:
    """A mean (or median) over seeds and its 95 % bootstrap interval (lo = hi = the value with one seed)."""

    mean: float
    lo: float
    hi: float
    n: int
    bound: str = ""
    """">" when the value is a lower bound only, "<" an upper bound (figures past a budget, `censored_...`)."""

    def text(self, fmt: str = ".2f") -> str:
        point = f"{self.bound} {self.mean:{fmt}}".lstrip()
        if self.n < 2 or not math.isfinite(self.lo):
            return f"{point} (1 seed)" if self.n == 1 else "-"
        if self.bound == ">" and self.lo == self.mean and math.isinf(self.hi):
            return point  # every resample past the budget: no interval to add
        return f"{point} [{self.lo:{fmt}}, {self.hi:{fmt}}]".replace(f"{math.inf:{fmt}}", "inf")


def mean_interval(values: Sequence[float], seed: int = 0) -> Interval:
    """Mean of `values` (one per seed) with its 95 % percentile bootstrap interval."""
    return _interval(values, np.mean, seed)


def median_interval(values: Sequence[float], seed: int = 0) -> Interval:
    """Median of `values` (one per seed) with its 95 % percentile bootstrap interval (`Interval.mean` holds it)."""
    return _interval(values, np.median, seed)


def _interval(values: Sequence[float], statistic: Any, seed: int) -> Interval:
    from scipy.stats import bootstrap

    data = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if data.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    point = float(statistic(data))
    if data.size < 2 or np.all(data == data[0]):
        return Interval(point, point, point, int(data.size))
    res = bootstrap((data,), statistic, confidence_level=CONFIDENCE, n_resamples=RESAMPLES, method="percentile",
                    random_state=np.random.default_rng(seed))  # fmt: skip
    return Interval(point, float(res.confidence_interval.low), float(res.confidence_interval.high), int(data.size))


def censored_median_interval(times: Sequence[float], budget: float, seed: int = 0) -> Interval:
    """Median over seeds of the env steps until an event (a run's convergence), `inf` for a run in which it did not
    happen within `budget`, every run having had that budget, with its 95 % percentile bootstrap interval.

    Such a run is right-censored: later than every time observed. The median is an order statistic, so it is exact
    while it falls on an observed time, and otherwise known only to lie past the budget (`bound` ">", `mean` the
    budget). A resample's median past the budget counts as the budget for the interval's low end and as inf for its
    high end, so the interval is never narrower than the data say."""
    data = np.asarray(times, dtype=float)
    if data.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    point = float(np.median(data))
    low = _censored_distribution((_at_budget(data, budget),), np.median, seed)
    high = _censored_distribution((data,), np.median, seed)
    past = math.isinf(point)
    return Interval(budget if past else point, _end(low, 2.5), _end(high, 97.5), int(data.size), ">" if past else "")


def censored_ratio_interval(numerator: Sequence[float], denominator: Sequence[float], budget: float,
                            seed: int = 0) -> Interval:  # fmt: skip
    """median(numerator) / median(denominator) of two independent sets of such times (Table 5's speed-up, scratch /
    fine-tuned; `censored_median_interval`), with its 95 % percentile bootstrap interval (each set resampled on its
    own). Exact where both medians are; where one lies past the budget, the budget bounds it: a lower bound (">")
    when it is the numerator's, an upper bound ("<") when the denominator's; NaN (no ratio) when both are. The
    interval's low end takes each resample's least possible ratio, its high end the greatest."""
    a, b = (np.asarray(v, dtype=float) for v in (numerator, denominator))
    if a.size == 0 or b.size == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    top, bottom = float(np.median(a)), float(np.median(b))
    if math.isinf(top) and math.isinf(bottom):
        return Interval(math.nan, math.nan, math.nan, 0)
    bound = ">" if math.isinf(top) else "<" if math.isinf(bottom) else ""
    point = (budget if math.isinf(top) else top) / (budget if math.isinf(bottom) else bottom)

    def of_ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.median(x, axis=axis) / np.median(y, axis=axis)

    low = _censored_distribution((_at_budget(a, budget), b), of_ratio, seed)  # x / inf = 0: no less than that
    high = _censored_distribution((a, _at_budget(b, budget)), of_ratio, seed)
    return Interval(point, _end(low, 2.5), _end(high, 97.5), int(min(a.size, b.size)), bound)


def _censored_distribution(samples: tuple[np.ndarray, ...], statistic: Any, seed: int) -> np.ndarray:
    """The statistic over scipy's bootstrap resamples of `samples` (inf allowed): the same resamples for one seed."""
    from scipy.stats import bootstrap

    if all(s.size < 2 or np.all(s == s[0]) for s in samples):
        return np.atleast_1d(np.asarray(statistic(*samples), dtype=float))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's own interval of a distribution holding inf; only its draws are used
        res = bootstrap(samples, statistic, confidence_level=CONFIDENCE, n_resamples=RESAMPLES, method="percentile",
                        random_state=np.random.default_rng(seed))  # fmt: skip
    return np.asarray(res.bootstrap_distribution, dtype=float)


def _at_budget(times: np.ndarray, budget: float) -> np.ndarray:
    """The times with each one past the budget (inf) at the budget: the least it can be."""
    return np.where(np.isinf(times), budget, times)


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

"""Figures over seeds with 95 % bootstrap intervals (scipy.stats.bootstrap; no hand-written resampling).

A claim about learning is a statistic per seed (a run's median gap, its share of starts within 1 %),
summarised over seeds as the mean or the median (transfer's steps to converge) with a percentile bootstrap
interval. With 3-5 seeds such intervals are wide; they say so honestly rather than hide it.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
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

    def text(self, fmt: str = ".2f") -> str:
        if self.n < 2 or not math.isfinite(self.lo):
            return f"{self.mean:{fmt}} (1 seed)" if self.n == 1 else "-"
        return f"{self.mean:{fmt}} [{self.lo:{fmt}}, {self.hi:{fmt}}]"


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


def ratio_interval(
    numerator: Sequence[float], denominator: Sequence[float], seed: int = 0, statistic: Callable[..., Any] = np.mean
) -> Interval:
    """statistic(numerator) / statistic(denominator) of two independent sets of seeds (a Table-5 speed-up: the
    mean by default, `np.median` for medians), with its 95 % percentile bootstrap interval (each set resampled on
    its own)."""
    from scipy.stats import bootstrap

    a = np.asarray([v for v in numerator if math.isfinite(v)], dtype=float)
    b = np.asarray([v for v in denominator if math.isfinite(v)], dtype=float)
    if a.size == 0 or b.size == 0 or statistic(b) == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    ratio = float(statistic(a) / statistic(b))
    n = int(min(a.size, b.size))
    if n < 2 or (np.all(a == a[0]) and np.all(b == b[0])):
        return Interval(ratio, ratio, ratio, n)

    def of_ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
        return statistic(x, axis=axis) / statistic(y, axis=axis)

    res = bootstrap((a, b), of_ratio, confidence_level=CONFIDENCE, n_resamples=RESAMPLES, method="percentile",
                    random_state=np.random.default_rng(seed))  # fmt: skip
    return Interval(ratio, float(res.confidence_interval.low), float(res.confidence_interval.high), n)


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

"""bench_transfer's verdict on a map's ratio of medians: met by the medians, and whether the interval agrees."""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
from bench_transfer import ratio_verdict

from smorphi_rl.stats import Interval


def test_a_ratio_met_by_the_medians_only_says_its_interval_reaches_below():
    """mixed-1000001's `> 5.00 [1.50, inf]` counted as meeting the target with nothing said of its interval."""
    text, met, whole = ratio_verdict(Interval(5.0, 1.5, math.inf, 3, ">"))
    assert (met, whole) == (True, False) and "meets target, its interval reaching below" in text
    text, met, whole = ratio_verdict(Interval(6.0, 5.5, 8.0, 3))
    assert (met, whole) == (True, True) and text.endswith("(meets target)")
    assert ratio_verdict(Interval(2.0, 1.0, 3.0, 3))[1:] == (False, False)
    assert "cannot tell" in ratio_verdict(Interval(2.0, 1.0, math.inf, 3, ">"))[0]
    assert "no exact optimum" in ratio_verdict(Interval(2.0, 1.0, 3.0, 3), unmeasured=True)[0]
    assert "past the budget" in ratio_verdict(Interval(math.nan, math.nan, math.nan, 0))[0]


def test_one_seed_has_no_interval_to_agree():
    assert ratio_verdict(Interval(6.0, 6.0, 6.0, 1))[1:] == (True, False)

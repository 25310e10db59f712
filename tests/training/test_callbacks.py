"""How a run ranks its evaluated policies when it chooses the one it ends on."""

from __future__ import annotations

from smorphi_rl.protocol import MapEvaluation, Optimum, Outcome
from smorphi_rl.training.callbacks import selection_score

OPTIMUM = Optimum((0.0, 0.0, 0.0), 90.0, 100.0, 1)


def _evaluation(*settled_R1: float) -> list[MapEvaluation]:
    outcomes = tuple(Outcome((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), r, 100.0, 1, 1) for r in settled_R1)
    return [MapEvaluation("map-1", "policy", OPTIMUM, outcomes)]


def test_more_starts_within_one_percent_rank_first_then_the_smaller_median_gap():
    three_in = selection_score(_evaluation(89.9, 89.5, 89.2, 80.0))  # 89.2 is within 1 % of 90 (band 89.1)
    two_in_close = selection_score(_evaluation(90.0, 89.95, 89.0, 89.0))
    two_in_far = selection_score(_evaluation(89.5, 89.2, 85.0, 85.0))
    assert three_in > two_in_close > two_in_far
    assert selection_score(_evaluation(90.0, 80.0)) == (1, -5.0)

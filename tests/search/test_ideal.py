"""The value-iteration ceiling: on a small synthetic lattice the optimal policy walks to the best shape."""

import numpy as np
import pytest

from smorphi_rl.search.ideal import greedy_settled, move_values


def _landscape(n: int = 13) -> np.ndarray:
    """A global peak at (9, 3, 10) and a lesser local one at (2, 2, 2), with a valley between."""
    idx = np.indices((n, n, n)).transpose(1, 2, 3, 0)
    far = np.abs(idx - np.array([9, 3, 10])).sum(-1)
    near = np.abs(idx - np.array([2, 2, 2])).sum(-1)
    return np.maximum(10.0 - far, 7.0 - 2 * near)


@pytest.mark.parametrize("mode", ["level", "improvement"])
def test_optimal_policy_reaches_the_global_peak_past_a_local_one(mode: str) -> None:
    r1 = _landscape()
    w = move_values(r1, mode, gamma=0.99)
    starts = np.array([[2, 2, 2], [0, 12, 0], [12, 12, 12], [9, 3, 10]])
    assert greedy_settled(w, starts, max_steps=60) == [(9, 3, 10)] * 4


def test_a_short_horizon_settles_on_the_nearer_peak() -> None:
    """Discounting hard makes the lesser, nearer shape worth more than the walk to the best one."""
    w = move_values(_landscape(), "level", gamma=0.3)
    assert greedy_settled(w, np.array([[2, 2, 2]]), max_steps=60) == [(2, 2, 2)]


def test_paper_mode_pays_for_standing_still() -> None:
    """With R2 = -beta for standing still, the optimal policy steps between the peak and a neighbour."""
    r1 = _landscape()
    w = move_values(r1, "paper", gamma=0.9, beta=5.0)
    (settled,) = greedy_settled(w, np.array([[9, 3, 10]]), max_steps=40, stay=5.0)
    assert np.abs(np.array(settled) - np.array([9, 3, 10])).max() <= 1


@pytest.mark.parametrize("mode", ["level", "peak"])
def test_a_move_cost_keeps_the_global_peak_and_stops_the_walk_where_moving_gains_too_little(mode: str) -> None:
    """A small move cost leaves the optimal policy's destination where it was; one larger than anything a
    walk can gain keeps every start where it is."""
    r1 = _landscape()
    starts = np.array([[2, 2, 2], [0, 12, 0], [12, 12, 12], [9, 3, 10]])
    w = move_values(r1, mode, gamma=0.99, move_cost=0.01)
    assert greedy_settled(w, starts, max_steps=60, move=0.01) == [(9, 3, 10)] * 4
    w = move_values(r1, mode, gamma=0.99, move_cost=1e6)
    assert greedy_settled(w, starts, max_steps=60, move=1e6) == [tuple(s) for s in starts]


def test_unknown_mode_and_bad_discount_are_refused() -> None:
    with pytest.raises(ValueError, match="commit"):
        move_values(_landscape(5), "commit", 0.9)
    with pytest.raises(ValueError, match="discount"):
        move_values(_landscape(5), "level", 1.0)

"""R1, the one formula every ranking uses."""

import numpy as np
import pytest

from smorphi_rl.score import Weights, degenerate_warning


def test_r1_of_one_result_and_of_arrays():
    weights = Weights(1.0, 0.1)
    assert weights.r1(97.0, 66) == 97.0 - 6.6
    out = weights.r1(np.array([97.0, 90.0]), np.array([66, 50]))
    assert out.dtype == np.float64 and np.allclose(out, [90.4, 85.0])
    assert weights.formula() == "R1 = 1 P_c - 0.1 P_len"


def test_the_per_area_path_term_states_w2_for_25_square_metres_of_floor():
    from smorphi_rl.score import effective_w2

    assert effective_w2(0.1, "moves", 400.0) == 0.1
    assert effective_w2(0.1, "per_area", 25.0) == pytest.approx(0.1)
    assert effective_w2(0.1, "per_area", 100.0) == pytest.approx(0.025)
    with pytest.raises(ValueError, match="unknown path term"):
        effective_w2(0.1, "per_metre", 25.0)


def test_the_env_ranks_with_the_weight_in_effect_on_its_map():
    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.env_config import EnvConfigError
    from smorphi_rl.maps import Cell

    env = MorphologyEnv({"path_term": "per_area", "reward": "paper"})
    scored = env.score((95.0, 59.0, 103.0))
    free_m2 = env.grid_map.counts[Cell.FREE] * env.grid_map.resolution_m**2
    assert pytest.approx(scored.P_c - 0.1 * 25.0 / free_m2 * scored.P_len) == scored.R1
    assert env.config.weights_on(env.grid_map) == Weights(1.0, pytest.approx(0.1 * 25.0 / free_m2))
    with pytest.raises(EnvConfigError, match="env_config 'path_term': unknown path term 'metres'"):
        MorphologyEnv({"path_term": "metres"})


@pytest.mark.parametrize(
    ("p_c", "p_len", "path_term", "warned"),
    [
        (97.32, 69, "moves", False),  # map-1's optimum: the path term is 7 % of coverage's
        (99.28, 967, "moves", True),  # depot's best: R1 2.58, positive, yet the path ranks the shapes
        (99.0, 1500, "moves", True),  # R1 negative
        (99.28, 967, "per_area", False),  # the path charged per area: the fix itself
    ],
)
def test_the_path_term_is_said_to_swamp_coverage_when_it_outweighs_half_of_it(p_c, p_len, path_term, warned):
    line = degenerate_warning(Weights(1.0, 0.1), p_c, p_len, path_term, "depot")
    assert (line is not None and "the path term swamps coverage" in line and "--path-term per_area" in line) == warned


@pytest.mark.parametrize("path_term", ["moves", "per_area"])
def test_a_best_shape_that_covers_under_half_the_floor_is_said_to_leave_the_rest_out_of_reach(path_term):
    """Four separate rooms: the best covered the start's, 37 % of the floor, and the warning blamed the path term
    (1.50 against coverage's 37.71) and the floor's size."""
    line = degenerate_warning(Weights(1.0, 0.04), 37.4, 37, path_term, "islands")
    assert line is not None and "swamps" not in line
    assert "the best shape covers 37.4 % of the floor: the rest is out of its reach (separate free areas" in line

"""SearchConfig: the one home of the search methods' defaults, validated before anything runs."""

from pathlib import Path

import pytest

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.protocol import EVAL_STARTS
from smorphi_rl.search.config import SearchConfig, SearchConfigError, run_search

MAP = str(Path(__file__).resolve().parents[2] / "maps" / "map-1.yaml")


def test_defaults_come_from_their_homes():
    cfg = SearchConfig("hillclimb", MAP)
    assert (cfg.w1, cfg.w2, cfg.path_term) == (EnvConfig.w1, EnvConfig.w2, EnvConfig.path_term)
    assert cfg.starts == EVAL_STARTS
    assert cfg.run_name == "hillclimb-map-1-seed0"
    assert SearchConfig("exhaustive", MAP, step=2.0).run_name == "exhaustive-map-1-step2"
    from smorphi_rl.coverage import Planner
    from smorphi_rl.planning import Planning

    fit = Planning(planner=Planner.FIT)  # a run of each planner on one map needs no --name
    assert SearchConfig("random", MAP, planning=fit).run_name == "random-map-1-fit-seed0"
    assert SearchConfig("optimum", MAP, planning=fit).run_name == "optimum-map-1-fit-step1"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"method": "grid"}, "unknown search method 'grid'"),
        ({"method": "random", "samples": 0}, "--samples must be >= 1, got 0"),
        ({"method": "nsga2", "pop": 1}, "--pop must be >= 2"),
        ({"method": "anneal", "budget": 0}, "--budget and --starts must be >= 1"),
        ({"method": "exhaustive", "step": 7.0}, "--step 7 does not divide 180"),
    ],
)
def test_bad_options_are_named(kwargs, message):
    with pytest.raises(SearchConfigError, match=message):
        SearchConfig(map_path=MAP, **kwargs)


def test_run_search_runs_the_configured_method():
    result = run_search(SearchConfig("random", MAP, samples=30, seed=3))
    again = run_search(SearchConfig("random", MAP, samples=30, seed=3))
    assert result.method == "random" and result.evaluations == 30
    assert (result.thetas == again.thetas).all() and (result.P_c == again.P_c).all()

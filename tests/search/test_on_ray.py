"""`search exhaustive|optimum|random|nsga2 --address`: the same results on a Ray cluster as on the local cores."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ray_cluster

from smorphi_rl.score import Weights
from smorphi_rl.search.results import load

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
RUNS = {
    "exhaustive": ["--step", "6"],
    "optimum": ["--step", "6", "--planner", "fit"],
    "random": ["--samples", "3000", "--seed", "3"],
    "nsga2": ["--pop", "20", "--generations", "5", "--seed", "3"],
}
pytestmark = pytest.mark.slow


def search(method: str, cwd: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    return subprocess.run([sys.executable, "-m", "smorphi_rl.cli", "search", method, "--map", MAP_1, *RUNS[method],
                           *extra], capture_output=True, text=True, cwd=cwd, env=env, timeout=600)  # fmt: skip


def test_the_searches_on_a_ray_cluster_equal_the_local_ones(tmp_path):
    for method in RUNS:
        assert search(method, tmp_path, "--name", f"{method}-here").returncode == 0
    with ray_cluster(2) as address:
        for method in RUNS:
            there = search(method, tmp_path, "--name", f"{method}-there", "--address", address)
            assert there.returncode == 0 and "Traceback" not in there.stderr, there.stderr[-3000:]
            assert there.stdout.splitlines()[1] == f"on the Ray cluster at {address}"
    for method in RUNS:
        here, there = load(tmp_path / "logs" / f"{method}-here"), load(tmp_path / "logs" / f"{method}-there")
        if method == "optimum":  # which footprints are pruned depends on when each worker hears of a better R1
            weights = Weights(1.0, 0.1)
            i, j = here.best(weights), there.best(weights)
            assert tuple(here.thetas[i]) == tuple(there.thetas[j]) and here.P_c[i] == there.P_c[j]
            assert here.params["distinct_footprints"] == there.params["distinct_footprints"]
            continue
        for field in ("thetas", "P_c", "P_len", "feasible"):
            assert np.array_equal(getattr(here, field), getattr(there, field)), (method, field)
        assert there.params["address"] == address and "address" not in here.params
    assert load(tmp_path / "logs" / "exhaustive-there").params["workers"] == 2  # one actor per CPU of the cluster


def test_no_cluster_there_is_one_line_and_writes_nothing(tmp_path):
    for method in RUNS:
        proc = search(method, tmp_path, "--address", "127.0.0.1:1")
        assert proc.returncode == 1 and proc.stderr.strip() == (
            "smorphi-rl: error: cannot reach a Ray cluster at 127.0.0.1:1 (Connection refused): start one there "
            "(`ray start --head --port=PORT`), or leave --address out to run on a Ray of this machine's own"
        ), proc.stderr
    assert not (tmp_path / "logs").exists()


def test_a_cluster_that_goes_away_mid_search_is_said_in_one_line():
    """Its head killed mid-pass, `search exhaustive --address` said "error: Broken pipe"."""
    import ray

    from smorphi_rl.cluster import ClusterError
    from smorphi_rl.search.on_ray import cluster_lost

    for lost in (BrokenPipeError(32, "Broken pipe"), ray.exceptions.RayActorError()):
        said = r"the Ray cluster stopped answering mid-search \(\w+: .*nothing of"
        with pytest.raises(ClusterError, match=said), cluster_lost():
            raise lost
    work = ray.exceptions.RayTaskError("plan", "Traceback ...", ValueError("a bad shape"))
    with pytest.raises(ray.exceptions.RayTaskError), cluster_lost():  # the work's own error is not the cluster's
        raise work

"""`search exhaustive|optimum|random|nsga2 --address`: the same results on a Ray cluster as on the local cores."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ray_cluster

from smorphi_rl.errors import MapError, SmorphiError
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
    with ray_cluster(2, nodes=2) as address:  # two nodes of a CPU each: the work crosses them
        for method in RUNS:
            there = search(method, tmp_path, "--name", f"{method}-there", "--address", address)
            said = [line for line in there.stderr.splitlines() if line.strip()]  # progress lines alone: no Ray log
            assert there.returncode == 0 and all(line.startswith(f"{method}: ") for line in said), there.stderr[-3000:]
            assert there.stdout.splitlines()[1] == f"on the Ray cluster at {address}"
        env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
        (tmp_path / "run").mkdir()
        refused = subprocess.run([sys.executable, "-c", STARTS_REFUSED, address, MAP_1, str(tmp_path / "run")],
                                 capture_output=True, text=True, timeout=300, env=env)  # fmt: skip
        assert refused.returncode == 0 and refused.stdout.splitlines() == [
            "2 nodes see the run folder",
            "7 of 7 tasks answered by 1 planner, as here: True",
            "1 of 3 planners did not start within 20 s (the cluster had 2 of its 2 CPUs free): other work holds its "
            "CPUs",
            "the Ray cluster's smorphi-rl plans with other code than this one's (its planner's source differs): "
            "install the same version on every node",
        ], refused.stdout + refused.stderr[-3000:]
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


STARTS_REFUSED = """
import sys
from smorphi_rl.cluster import ClusterError
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Planning
from smorphi_rl.search import on_ray
from pathlib import Path
import threading
import numpy as np
import ray
from smorphi_rl.planning import lattice_thetas
from smorphi_rl.search.lattice_tasks import footprint_keys
from smorphi_rl import cluster
address, grid_map, folder = sys.argv[1], load_map(sys.argv[2]), Path(sys.argv[3])
with cluster.ray_session(address):
    cluster.check_shared_folder(folder, address)  # one machine's two nodes share its files
    print(len(ray.nodes()), "nodes see the run folder", *folder.iterdir())  # the marker removed
with on_ray.ray_planners(grid_map, Planning(), address, None, step=30.0) as planners:
    ray.kill(planners.actors[0], no_restart=True)  # as its node went: its work goes to the other
    tasks = [("keys", lo, min(lo + 50, 343)) for lo in range(0, 343, 50)]
    answers = list(on_ray.RayTasks(planners).run(iter(tasks), threading.Event()))
    local = footprint_keys(Planning().evaluator(grid_map), lattice_thetas(30.0))
    same = all(np.array_equal(keys, local[lo:hi]) for _, lo, hi, keys in answers)
    print(len(answers), "of", len(tasks), "tasks answered by", len(planners.actors), "planner, as here:", same)
import time
with cluster.ray_session(address):  # a killed actor's CPU comes back a moment later: the next block counts both
    deadline = time.monotonic() + 60
    while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
on_ray.START_TIMEOUT_S = 20.0
for workers, digest in ((3, on_ray.planner_digest), (None, lambda: "another version")):
    on_ray.planner_digest = digest  # three actors on two CPUs: one never starts; then this side's code differs
    try:
        with on_ray.ray_planners(grid_map, Planning(), address, workers, step=30.0):
            print("started")
    except ClusterError as exc:
        print(exc)
"""


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
    said = "a search worker on the cluster failed: ValueError: a bad shape"  # as a local worker's, not a traceback
    with pytest.raises(SmorphiError, match=said), cluster_lost():  # the work's own error is not the cluster's
        raise work
    ours = ray.exceptions.RayTaskError("plan", "Traceback ...", MapError("m.yaml: no free cell"))
    with pytest.raises(MapError, match=r"^m\.yaml: no free cell$"), cluster_lost():
        raise ours


def test_a_run_folder_some_nodes_do_not_see_is_named_with_them(tmp_path):
    from smorphi_rl.cluster import unshared_line

    line = unshared_line(tmp_path / "logs" / "run", ["127.0.0.9", "127.0.0.2"], 3)
    assert line.startswith(f"{tmp_path}/logs/run is not seen from 2 nodes of the cluster's 3 (127.0.0.2, 127.0.0.9): ")
    assert line.endswith("--log-dir must be a folder every node sees at the same path (NFS, a mounted bucket)")


def test_an_actor_makes_the_lattice_rows_it_is_sent_as_the_local_workers_hold_them():
    """Each actor built the whole lattice: 1.1 GB at 0.5 degrees, one copy per CPU of the cluster."""
    from smorphi_rl.planning import Lattice, lattice_thetas

    for step in (1.0, 3.0, 7.0):
        whole, made = lattice_thetas(step), Lattice(step)
        rows = np.random.default_rng(int(step * 2)).integers(0, len(whole), 2_000)
        assert len(made) == len(whole) and np.array_equal(made[rows], whole[rows])
        assert np.array_equal(made[7:5000], whole[7:5000]) and np.array_equal(made[-3:], whole[-3:])


def test_an_actor_dropped_as_unreachable_yet_answering_loses_no_task(monkeypatch):
    """Ray's ActorUnavailableError (an actor out of reach for a moment) drops it; its other task may still answer,
    which put it back among the idle: the next task drawn for it was thrown away, its shapes never keyed."""
    import threading

    import ray

    from smorphi_rl.search.on_ray import Planners, RayTasks

    class Ref:
        def __init__(self, actor: str, task: tuple) -> None:
            self.actor, self.task = actor, task

    sent: list[Ref] = []

    class Actor:
        def __init__(self, name: str) -> None:
            self.name = name
            self.task = self  # `actor.task.remote(task)`

        def remote(self, task: tuple) -> Ref:
            sent.append(Ref(self.name, task))
            return sent[-1]

    def get(ref: Ref) -> tuple:
        if ref.actor == "a" and ref.task == ("keys", 1):  # its second task: out of reach for a moment
            raise ray.exceptions.RayActorError()
        return ref.task

    def wait(refs: list[Ref], num_returns: int, timeout: float) -> tuple[list[Ref], list[Ref]]:
        order = sorted(refs, key=lambda r: (r.task != ("keys", 1), sent.index(r)))  # the failure first
        return order[:1], order[1:]

    monkeypatch.setattr(ray, "wait", wait)
    monkeypatch.setattr(ray, "get", get)
    monkeypatch.setattr(ray, "kill", lambda actor: None)
    actors = iter([Actor("a"), Actor("b")])
    planners = Planners(lambda: next(actors), 2)
    answers = list(RayTasks(planners).run(iter([("keys", i) for i in range(10)]), threading.Event()))
    assert sorted(answers) == [("keys", i) for i in range(10)]  # each once, none lost
    assert [a.name for a in planners.actors] == ["b"]

"""Search baselines and ground truth: exhaustive equals brute force, fronts are non-dominated, seeds repeat."""

from __future__ import annotations

import itertools
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.cli import main
from smorphi_rl.maps import load_map
from smorphi_rl.planning import Evaluator, lattice_thetas
from smorphi_rl.score import Weights
from smorphi_rl.search.exhaustive import run_exhaustive
from smorphi_rl.search.nsga2 import run_nsga2
from smorphi_rl.search.pareto import pareto_front
from smorphi_rl.search.random import run_random
from smorphi_rl.search.results import load, save

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def dominated(p_c: np.ndarray, p_len: np.ndarray, i: int) -> bool:
    return bool(np.any((p_c >= p_c[i]) & (p_len <= p_len[i]) & ((p_c > p_c[i]) | (p_len < p_len[i]))))


def test_pareto_front_is_exactly_the_non_dominated_set():
    rng = np.random.default_rng(3)
    p_c = rng.integers(80, 100, 300).astype(float)
    p_len = rng.integers(50, 200, 300)
    front = pareto_front(p_c, p_len)
    assert all(not dominated(p_c, p_len, i) for i in front)
    others = set(range(300)) - set(front.tolist())
    on_front = {(p_c[i], p_len[i]) for i in front}
    assert all(dominated(p_c, p_len, i) or (p_c[i], p_len[i]) in on_front for i in others)
    assert np.all(np.diff(p_len[front]) > 0) and np.all(np.diff(p_c[front]) > 0)


def test_exhaustive_equals_brute_force_on_a_coarse_lattice():
    result = run_exhaustive(MAP_1, step_deg=15.0, workers=2)
    thetas = lattice_thetas(15.0)
    evaluator = Evaluator(load_map(MAP_1))
    batch = evaluator.evaluate_many(thetas)
    assert np.array_equal(result.thetas, thetas) and result.evaluations == 13**3
    assert np.array_equal(result.P_c, batch.P_c) and np.array_equal(result.P_len, batch.P_len)
    assert result.params["distinct_footprints"] == evaluator.cache_size()


def test_front_is_non_dominated_and_holds_the_best_r1():
    result = run_exhaustive(MAP_1, step_deg=6.0, workers=2)
    front = result.front()
    assert all(not dominated(result.P_c, result.P_len, i) for i in front)
    best = result.best(Weights(1.0, 0.1))
    assert (result.P_c[best], result.P_len[best]) in {(result.P_c[i], result.P_len[i]) for i in front}


def test_nsga2_and_random_are_seeded():
    a, b = run_nsga2(MAP_1, pop=12, generations=4, seed=5), run_nsga2(MAP_1, pop=12, generations=4, seed=5)
    assert np.array_equal(a.thetas, b.thetas) and np.array_equal(a.P_c, b.P_c) and a.evaluations == len(a.thetas)
    assert not np.array_equal(a.thetas, run_nsga2(MAP_1, pop=12, generations=4, seed=6).thetas)
    assert np.all(a.thetas == np.rint(a.thetas)) and a.thetas.min() >= 0 and a.thetas.max() <= 180
    r = run_random(MAP_1, samples=50, seed=1)
    assert np.array_equal(r.thetas, run_random(MAP_1, samples=50, seed=1).thetas) and r.evaluations == 50


def test_results_round_trip(tmp_path):
    result = run_random(MAP_1, samples=30, seed=2)
    save(result, tmp_path, Weights(1.0, 0.1))
    back = load(tmp_path)
    assert back.method == "random" and np.array_equal(back.P_len, result.P_len)
    assert np.array_equal(back.thetas, result.thetas) and np.array_equal(back.P_c, result.P_c)


def test_exhaustive_command_prints_the_front_as_json(capsys, tmp_path):
    code = main(["search", "exhaustive", "--map", MAP_1, "--step", "10", "--json", "--log-dir", str(tmp_path)])
    out, err = capsys.readouterr()
    rows = [json.loads(line) for line in out.splitlines()]
    assert code == 0 and rows and set(rows[0]) == {"theta", "P_c", "P_len"}
    assert [r["P_len"] for r in rows] == sorted(r["P_len"] for r in rows)
    run = tmp_path / "exhaustive-map-1-step10"
    assert err.strip().splitlines()[-1] == f"results: {run}"  # where the rest is, on stderr
    assert {p.name for p in run.iterdir()} >= {"results.npz", "front.csv", "summary.json", "pareto.png"}


@pytest.mark.parametrize(
    ("argv", "code", "message"),
    [
        (["search", "exhaustive", "--step", "7"], 1, "--step 7 does not divide 180"),
        (["search", "exhaustive", "--step", "0"], 1, "--step must be in (0, 180]"),
        (["search", "random", "--samples", "0"], 1, "--samples must be >= 1, got 0"),
        (["search", "nsga2", "--pop", "1"], 1, "--pop must be >= 2"),
        (["search", "annealing"], 2, "invalid choice: 'annealing'"),
        (["search", "random", "--map", "/no/map.yaml"], 1, "map file not found"),
    ],
)
def test_search_rejects_bad_input(capsys, tmp_path, argv, code, message):
    try:
        got = main([*argv, "--log-dir", str(tmp_path)] if argv[1] != "annealing" else argv)
    except SystemExit as exc:
        got = int(exc.code or 0)
    err = capsys.readouterr().err
    assert got == code and message in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_reward_weights_rank_the_best_shape(tmp_path, capsys):
    for w2 in ("0.1", "0.5"):
        assert main(["search", "exhaustive", "--map", MAP_1, "--step", "10", "--w2", w2, "--name", f"w{w2}",
                     "--log-dir", str(tmp_path)]) == 0  # fmt: skip
    light, heavy = (json.loads((tmp_path / f"w{w2}" / "summary.json").read_text()) for w2 in ("0.1", "0.5"))
    assert light["weights"]["w2"] == 0.1 and heavy["weights"]["w2"] == 0.5
    assert heavy["best"]["P_len"] <= light["best"]["P_len"]  # a heavier path weight never favours a longer path


def test_pool_workers_die_with_a_killed_search(tmp_path):
    """SIGKILL of `search exhaustive` (no chance to clean up) leaves none of its pool workers behind."""
    import signal
    import subprocess
    import sys
    import time

    argv = [sys.executable, "-m", "smorphi_rl.cli", "search", "exhaustive", "--map", MAP_1, "--log-dir", str(tmp_path)]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def children() -> list[int]:
        out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(proc.pid)], capture_output=True, text=True).stdout
        return [int(p) for p in out.split()]

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(children()) < 2:
        time.sleep(0.2)
    workers = children()
    assert workers, "the search started no pool workers within 60 s"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    deadline = time.monotonic() + 10
    alive = workers
    while time.monotonic() < deadline and alive:
        alive = [w for w in alive if _running(w)]
        time.sleep(0.2)
    assert not alive, f"pool workers {alive} outlived their killed parent"


def _running(pid: int) -> bool:
    """A process that exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize(("signame", "group"), [("SIGINT", False), ("SIGTERM", False), ("SIGTERM", True)])
def test_an_interrupted_search_stops_its_workers_at_once_and_frees_its_name(tmp_path, signame, group):
    """Sent to the search, or (as `timeout` and schedulers do) to its whole process group, workers included."""
    import os
    import signal
    import subprocess
    import sys
    import time

    argv = [sys.executable, "-m", "smorphi_rl.cli", "search", "exhaustive", "--map", MAP_1, "--log-dir",
            str(tmp_path), "--name", "ex"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=group)
    listing = ["ps", "-o", "pid=", "--ppid", str(proc.pid)]
    deadline = time.monotonic() + 60
    while (
        time.monotonic() < deadline and len(subprocess.run(listing, capture_output=True, text=True).stdout.split()) < 2
    ):
        time.sleep(0.2)
    workers = [int(p) for p in subprocess.run(listing, capture_output=True, text=True).stdout.split()]
    assert workers, "the search started no pool workers within 60 s"
    time.sleep(1.0)  # into the planning; the signal is handled alike at any point of it
    if group:
        os.killpg(proc.pid, getattr(signal, signame))
    else:
        proc.send_signal(getattr(signal, signame))
    _, err = proc.communicate(timeout=60)  # a hang guard, not a speed: the cores may be busy
    assert proc.returncode == 130, err
    said = err.strip().splitlines()[-1]  # while planning, with the best shape settled so far
    assert "Traceback" not in err and (said == "smorphi-rl: interrupted" or said.endswith("; nothing was written"))
    deadline = time.monotonic() + 10  # the parent has exited: its workers are reaped, or dying
    while time.monotonic() < deadline and [w for w in workers if _running(w)]:
        time.sleep(0.1)
    assert not [w for w in workers if _running(w)]
    assert not (tmp_path / "ex").exists()  # nothing finished: the name is free again


def test_a_random_search_stopped_mid_kernel_exits_cleanly(tmp_path):
    """SIGTERM while the kernel scores a large batch: a KeyboardInterrupt raised as the kernel returned crashed the
    process (SIGSEGV, nothing on stderr) in 2 of 3 tries; the search now stops between chunks."""
    import signal
    import subprocess
    import sys
    import time

    argv = [sys.executable, "-m", "smorphi_rl.cli", "search", "random", "--map", MAP_1, "--samples", "6000000",
            "--log-dir", str(tmp_path), "--name", "rnd"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(6)  # start-up, then into the scoring, which lasts about 40 s on this machine's core
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (proc.returncode, err)
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "smorphi-rl: interrupted"
    assert not (tmp_path / "rnd").exists()


def test_a_floor_too_large_for_the_weights_is_named_with_the_fix(tmp_path, capsys):
    from smorphi_rl.maps import Map, save_map

    hall = save_map(Map(np.zeros((300, 300), dtype=np.uint8), 0.1, name="hall"), tmp_path / "hall.yaml")
    argv = ["search", "random", "--map", str(hall), "--samples", "20", "--log-dir", str(tmp_path / "logs")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "the path term swamps coverage" in err and "--path-term per_area" in err
    assert main([*argv, "--json", "--name", "j"]) == 0  # stdout is the front's JSON lines, the warning on stderr
    captured = capsys.readouterr()
    assert "swamps coverage" in captured.err and "swamps" not in captured.out
    assert main([*argv, "--path-term", "per_area", "--name", "b"]) == 0
    assert "swamps" not in capsys.readouterr().err


def test_chunks_shrink_where_plans_are_slow_so_progress_comes_within_seconds():
    from smorphi_rl.planning import PAPER_PLANNING
    from smorphi_rl.search.exhaustive import CHUNK_SHAPES, chunk_bounds, chunk_shapes, shapes_per_chunk

    # timed, so only its range is asserted (a plan of map-1 takes microseconds, longer on a loaded machine)
    assert 64 <= chunk_shapes(load_map(MAP_1), PAPER_PLANNING) <= CHUNK_SHAPES
    assert shapes_per_chunk(5e-6) == CHUNK_SHAPES and shapes_per_chunk(0.01) == 100 and shapes_per_chunk(1.0) == 64
    for most in (64, 1000, CHUNK_SHAPES):
        chunks = chunk_bounds(5_929_741, 2, most)
        assert chunks[0][0] == 0 and chunks[-1][1] == 5_929_741
        assert all(a == b for (_, a), (b, _) in itertools.pairwise(chunks))  # contiguous
        assert max(hi - lo for lo, hi in chunks) <= most


def test_a_start_on_a_speck_is_named_with_the_fix_and_the_summary_says_what_the_best_covers(tmp_path, capsys):
    """The paper's planner starts at the first free cell in row order: on a speck of noise below the floor it
    cleans the speck. The warning names --start-xy; summary.json gives the free floor covered and the bound."""
    from smorphi_rl.maps import Cell, Map, save_map

    cells = np.full((60, 60), Cell.OCCUPIED, dtype=np.uint8)
    cells[0, 5] = Cell.FREE  # the speck, first in row order (row 0 is the lowest y)
    cells[30:58, 5:55] = Cell.FREE  # beyond a wall thicker than any tile
    floor = save_map(Map(cells, 0.1, name="speck"), tmp_path / "speck.yaml")
    argv = ["search", "random", "--map", str(floor), "--samples", "20", "--log-dir", str(tmp_path / "logs")]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "plans start in a free area holding 0.1 % of the free cells (around (0.55, 0.05) m)" in captured.err
    assert "--start-xy X Y" in captured.err and "swamps" not in captured.err
    assert "of the free floor; any path from its start could cover" in captured.out
    summary = json.loads((tmp_path / "logs" / "random-speck-seed0" / "summary.json").read_text())
    assert summary["best"]["coverage_free_pct"] < 1.0 and summary["best"]["coverable_pct"] < 1.0
    assert main([*argv, "--start-xy", "2.5", "3.0", "--name", "b"]) == 0
    assert "plans start in a free area" not in capsys.readouterr().err


def test_a_search_that_scores_a_shape_twice_counts_its_shapes_apart_from_its_evaluations(tmp_path, capsys):
    """anneal said '4,000 evaluations (3,997 feasible)' of 3,997 distinct shapes, every one feasible: it read as
    three infeasible shapes, which no 1-degree shape is."""
    assert main(["search", "anneal", "--map", MAP_1, "--log-dir", str(tmp_path)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    said = re.fullmatch(r"anneal on map-1: 4,000 evaluations in [\d.]+ s \(([\d,]+) distinct shapes, ([\d,]+) "
                        r"feasible\)", first)  # fmt: skip
    assert said is not None, first
    shapes = np.load(next(tmp_path.glob("anneal-*")) / "results.npz")["thetas"]
    assert said[1] == said[2] == f"{len(shapes):,}" and len(np.unique(shapes, axis=0)) == len(shapes) < 4_000
    # NSGA-II keeps a row per evaluation, a child equal to a parent too: it said "(2,000 feasible)" and its summary
    # "distinct_shapes": 2000 of 1,961
    assert main(["search", "nsga2", "--map", MAP_1, "--log-dir", str(tmp_path)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    run = next(tmp_path.glob("nsga2-*"))
    rows = np.load(run / "results.npz")["thetas"]
    distinct = len(np.unique(rows, axis=0))
    assert distinct < len(rows) == 2_000 and f"({distinct:,} distinct shapes, {distinct:,} feasible)" in first
    summary = json.loads((run / "summary.json").read_text())
    assert summary["distinct_shapes"] == distinct and summary["rows"] == 2_000 and load(run).evaluations == 2_000


def test_a_stop_as_the_plot_is_drawn_is_not_lost_in_a_garbage_collector_callback(tmp_path, capsys, monkeypatch):
    """A Ctrl-C raised in a weakref callback as matplotlib drew was printed "Exception ignored" and dropped: the
    search exited 0. Stops now wait for the files and the plot, then the command says it was stopped."""
    import contextlib
    import signal

    from smorphi_rl import interrupts, plots

    real = plots.plot_pareto

    def drawn(*args, **kwargs):
        with contextlib.suppress(KeyboardInterrupt):  # where Python drops what a callback raises
            signal.raise_signal(signal.SIGINT)
        return real(*args, **kwargs)

    monkeypatch.setattr(plots, "plot_pareto", drawn)
    assert main(["search", "random", "--map", MAP_1, "--samples", "50", "--log-dir", str(tmp_path)]) == 130
    run_dir = tmp_path / "random-map-1-seed0"
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said == f"smorphi-rl: interrupted: as the search ended: its results and plot are whole in {run_dir}"
    assert (run_dir / "summary.json").is_file() and (run_dir / "pareto.png").is_file()
    assert signal.getsignal(signal.SIGINT) is interrupts.interrupt  # the hold's handler is gone: the CLI's is back


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="CPU affinity is Linux's")
def test_the_exhaustive_search_forks_one_planner_per_core_it_may_use_not_per_core_of_the_machine(tmp_path):
    """Under `taskset` or a batch job's cpuset it forked a planner for every core of the machine, all on the
    cores it was given (128 workers on 4 cores of a cluster node)."""
    argv = [sys.executable, "-m", "smorphi_rl.cli", "search", "exhaustive", "--map", MAP_1, "--step", "30",
            "--log-dir", str(tmp_path), "--name", "one"]  # fmt: skip
    one_core = min(os.sched_getaffinity(0))
    proc = subprocess.run(argv, capture_output=True, text=True, preexec_fn=lambda: os.sched_setaffinity(0, {one_core}))
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "one" / "summary.json").read_text())["params"]["workers"] == 1

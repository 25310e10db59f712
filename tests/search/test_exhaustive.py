"""The exhaustive search's two passes and its branch and bound: every shape keyed by its footprint, each footprint
planned once, and the best R1 found by the bound equal to the best of every shape (docs/exact-search.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl import _kernels as k
from smorphi_rl.coverage import Planner
from smorphi_rl.floorplans import generate_floor
from smorphi_rl.maps import Cell, load_map, save_map
from smorphi_rl.planning import Planning, lattice_thetas
from smorphi_rl.score import Weights
from smorphi_rl.search.exhaustive import footprint_classes, footprint_keys, run_exhaustive

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
FIT = Planning(planner=Planner.FIT)


@pytest.fixture(scope="module")
def floors(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """map-1 and two generated floors of other kinds and resolutions."""
    out = tmp_path_factory.mktemp("floors")
    made = [save_map(generate_floor(kind, seed), out / f"{kind}.yaml") for kind, seed in (("rooms", 3), ("hall", 5))]
    return [MAP_1, *(str(p) for p in made)]


def test_keys_are_equal_exactly_when_footprints_are():
    evaluator = FIT.evaluator(load_map(MAP_1))
    thetas = np.random.default_rng(4).integers(0, 181, size=(3000, 3)).astype(float)
    thetas[1000:1500] = np.round(thetas[1000:1500] / 30) * 30  # many repeats
    keys = footprint_keys(evaluator, thetas)
    out, bits = k.footprints_batch(thetas, evaluator.block_side_m, 0.1, evaluator.footprint_side)
    feasible = out[:, k.COL_FEASIBLE] > 0
    assert np.array_equal(keys.any(axis=1), feasible)
    rows = np.flatnonzero(feasible)
    f_bytes = [bits[i].tobytes() + bytes(out[i, [k.COL_L, k.COL_W]].astype(np.uint8)) for i in rows]
    key_of = [keys[i].tobytes() for i in rows]
    assert len(set(zip(f_bytes, key_of, strict=True))) == len(set(f_bytes)) == len(set(key_of)) < len(rows)


def test_classes_fall_back_to_both_words_when_first_words_collide():
    keys = np.array([[1, 7], [1, 8], [2, 7], [1, 7]], dtype=np.uint64)
    first, inverse = footprint_classes(keys)
    assert inverse[0] == inverse[3] and len({inverse[0], inverse[1], inverse[2]}) == 3
    assert np.array_equal(keys[first[inverse]], keys)


@pytest.mark.parametrize("planning", [FIT, Planning()], ids=["fit", "paper"])
def test_each_footprint_is_planned_once_with_the_results_of_every_shape(floors, planning):
    thetas = lattice_thetas(10.0)
    for path in floors[:2]:
        result = run_exhaustive(path, 10.0, planning, workers=2)
        evaluator = planning.evaluator(load_map(path))
        batch = evaluator.evaluate_many(thetas)
        assert np.array_equal(result.thetas, thetas) and result.evaluations == len(thetas)
        assert np.array_equal(result.P_c, batch.P_c) and np.array_equal(result.P_len, batch.P_len)
        assert np.array_equal(result.feasible, batch.feasible)
        assert result.params["distinct_footprints"] == evaluator.cache_size() == evaluator.misses


@pytest.mark.parametrize(
    ("weights", "start_xy"),
    [(Weights(1.0, 0.1), None), (Weights(1.0, 0.01), None), (Weights(2.0, 0.5), None), (Weights(1.0, 0.1), (1.0, 1.0))],
    ids=["default", "light-path", "heavy-path", "start-point"],
)
def test_branch_and_bound_finds_the_best_r1_of_every_shape_and_prunes(floors, weights, start_xy):
    pruned = 0
    for path in floors:
        grid_map = load_map(path)
        if start_xy is not None and grid_map.cells[grid_map.cell_of(*start_xy)] != Cell.FREE:
            continue
        planning = Planning(planner=Planner.FIT, start_xy=start_xy)
        full = run_exhaustive(path, 6.0, planning, workers=2)
        best = run_exhaustive(path, 6.0, planning, workers=2, best_for=weights)
        i, j = full.best(weights), best.best(weights)
        assert tuple(best.thetas[j]) == tuple(full.thetas[i])  # the same shape: the first of equal ones
        assert (best.P_c[j], best.P_len[j]) == (full.P_c[i], full.P_len[i])
        r1 = weights.r1(full.P_c, full.P_len)
        at = (np.round(best.thetas / 6.0).astype(int) * [31 * 31, 31, 1]).sum(axis=1)  # rows of the 6-degree lattice
        assert np.array_equal(weights.r1(best.P_c, best.P_len), r1[at])
        assert (
            best.params["planned_footprints"] + best.params["pruned_footprints"] == full.params["distinct_footprints"]
        )
        pruned += best.params["pruned_footprints"]
    assert pruned > 0  # the bound cuts work on these floors


def test_the_bound_never_falls_below_a_plan(floors):
    """A footprint is pruned only when its plan scores below the R1 to beat (so a pruned footprint could never have
    won), shape by shape on random shapes of three floors under three weights."""
    thetas = np.random.default_rng(5).integers(0, 181, size=(150, 3)).astype(float)
    pruned_any = 0
    for path in floors:
        evaluator = FIT.evaluator(load_map(path), cache=False)
        batch = evaluator.evaluate_many(thetas)
        for weights in (Weights(1.0, 0.1), Weights(1.0, 0.001), Weights(3.0, 2.0)):
            r1 = weights.r1(batch.P_c, batch.P_len)
            threshold = float(np.median(r1))
            for i in range(len(thetas)):
                result, pruned = evaluator.evaluate_bounded(
                    thetas[i : i + 1], evaluator.prune_bound(weights, threshold)
                )
                if pruned[0]:
                    pruned_any += 1
                    assert r1[i] < threshold
                else:
                    assert (result.P_c[0], result.P_len[0]) == (batch.P_c[i], batch.P_len[i])
    assert pruned_any > 0


def test_the_paper_planner_is_never_pruned(floors):
    result = run_exhaustive(floors[0], 12.0, Planning(), workers=2, best_for=Weights(1.0, 0.1))
    assert result.params["pruned_footprints"] == 0 and result.method == "optimum"


def test_optimum_command_reports_the_best_and_what_the_bound_saved(tmp_path, capsys):
    from smorphi_rl.cli import main

    argv = ["search", "optimum", "--map", MAP_1, "--planner", "fit", "--step", "6", "--log-dir", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "optimum on map-1: the best R1 of 29,791 shapes (6-degree lattice)" in out
    assert "pruned by the bound" in out and "best R1 (w1 1, w2 0.1):" in out
    full = run_exhaustive(MAP_1, 6.0, FIT, workers=2)
    i = full.best(Weights(1.0, 0.1))
    assert f"P_c {full.P_c[i]:.2f} %, P_len {full.P_len[i]}" in out
    # --json: the optimum alone (its planned shapes' front is dominated by shapes of the lattice it never planned)
    assert main([*argv, "--name", "again", "--json"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert json.loads(line) == {"theta": [float(t) for t in full.thetas[i]], "P_c": float(full.P_c[i]),
                                "P_len": int(full.P_len[i])}  # fmt: skip


def test_a_stop_as_the_workers_fork_stops_the_search(monkeypatch):
    """A Ctrl-C as the workers forked was raised in the parent's at-fork hook (logging's), which Python prints as
    "Exception ignored" and drops: the search ran to its end and exited 0. Stops are now held before the fork."""
    import contextlib
    import signal

    from smorphi_rl.search import exhaustive

    real = exhaustive._Workers.__init__

    def forking(self, *args, **kwargs):
        with contextlib.suppress(KeyboardInterrupt):  # where an at-fork hook runs: whatever it raises is dropped
            signal.raise_signal(signal.SIGINT)
        real(self, *args, **kwargs)

    monkeypatch.setattr(exhaustive._Workers, "__init__", forking)
    path = str(Path(__file__).resolve().parents[2] / "maps" / "map-1.yaml")
    with pytest.raises(KeyboardInterrupt):
        exhaustive.run_exhaustive(path, step_deg=30.0, workers=1)


def test_a_stop_as_the_last_answers_come_in_stops_the_search():
    """The loop over the workers' answers ended without looking at the stop once the last came in, and leaving the
    hold put the old handlers back: the stop was lost and the search exited 0."""
    import signal

    from smorphi_rl.search import exhaustive

    ends: list[int] = []

    def progress(done: int, total: int) -> None:
        if done == total:
            ends.append(done)
            if len(ends) == 2:  # the settling pass's last answer (the keying pass's end came first): the stop now
                signal.raise_signal(signal.SIGINT)

    path = str(Path(__file__).resolve().parents[2] / "maps" / "map-1.yaml")
    with pytest.raises(KeyboardInterrupt):
        exhaustive.run_exhaustive(path, step_deg=30.0, workers=1, progress=progress)


def test_a_search_stopped_as_it_plans_says_the_best_shape_it_settled():
    """A stop an hour into a 97-minute search kept nothing and said nothing of what it had found."""
    from smorphi_rl.search.exhaustive import SearchStopped, run_exhaustive

    seen = {"last": -1, "planning": 0}

    def stop_in_the_second_pass(done: int, total: int) -> None:
        if done < seen["last"] or seen["planning"]:  # the count starts again: the planning pass
            seen["planning"] += 1
        seen["last"] = done
        if seen["planning"] == 2:  # as a Ctrl-C lands: some footprints planned
            raise KeyboardInterrupt

    with pytest.raises(SearchStopped) as stopped:
        run_exhaustive(MAP_1, 2.0, progress=stop_in_the_second_pass)
    stop, weights = stopped.value, Weights(1.0, 0.1)
    assert 0 < stop.settled < stop.total == len(lattice_thetas(2.0)) and len(stop.thetas)
    r1 = weights.r1(stop.p_c, stop.p_len)
    t = stop.thetas[int(np.argmax(r1))]
    said = stop.best_so_far(weights)
    assert said.startswith("stopped with ") and "% of the shapes settled; the best of them, not the optimum: " in said
    assert f"({t[0]:g}, {t[1]:g}, {t[2]:g}) " in said and f"R1 {r1.max():.2f}; nothing was written" in said
    empty = SearchStopped(10, 100, np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int32))
    none_yet = "stopped with 10 % of the shapes settled, none planned yet; nothing was written"
    assert empty.best_so_far(weights) == none_yet


def test_a_lattice_search_reads_back_the_lattice_s_own_angles(tmp_path):
    """results.npz holds float32 angles: at a step of 180/31, one shape of the 32,768 read back onto another
    footprint (P_c 98.72 recorded, 99.04 planned again), so `compare` took a genuine run for a hand-edited one. A
    lattice search's angles read back as its lattice's."""
    from smorphi_rl.search.results import load, save

    step = 180 / 31
    result = run_exhaustive(MAP_1, step, FIT, workers=1)
    save(result, tmp_path, Weights(1.0, 0.1))
    back = load(tmp_path)
    assert np.array_equal(back.thetas, lattice_thetas(step)) and back.thetas.dtype == np.float64
    assert not np.array_equal(back.thetas, lattice_thetas(step).astype(np.float32))  # what the file holds
    evaluator = FIT.evaluator(load_map(MAP_1), cache=False)
    worst = np.abs(evaluator.evaluate_many(back.thetas).P_c - back.P_c).max()
    assert worst == 0, worst

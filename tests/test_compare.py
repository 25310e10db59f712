"""`compare`: hypervolume arithmetic, the report against the exact front, and its input errors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.cli import main
from smorphi_rl.compare import hypervolume
from smorphi_rl.search.results import distinct_rows, load

ROOT = Path(__file__).resolve().parent.parent
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
MAP_2 = str(ROOT / "maps" / "map-2.yaml")


def test_hypervolume_is_the_union_of_rectangles():
    # Points (P_len, P_c) = (2, 5) and (4, 8) against reference (10, 0): 8*5 + 6*3 = 58.
    assert hypervolume(np.array([2, 4]), np.array([5.0, 8.0]), 10, 0) == pytest.approx(58.0)
    # A dominated point and one beyond the reference add nothing.
    assert hypervolume(np.array([2, 4, 3, 12]), np.array([5.0, 8.0, 4.0, 9.0]), 10, 0) == pytest.approx(58.0)
    assert hypervolume(np.array([11]), np.array([5.0]), 10, 0) == 0.0


@pytest.fixture(scope="module")
def searches(tmp_path_factory) -> Path:
    logs = tmp_path_factory.mktemp("logs")
    assert main(["search", "random", "--map", MAP_1, "--samples", "200", "--log-dir", str(logs)]) == 0
    assert main(["search", "nsga2", "--map", MAP_1, "--pop", "6", "--generations", "30", "--log-dir", str(logs)]) == 0
    assert main(["search", "exhaustive", "--map", MAP_1, "--step", "10", "--log-dir", str(logs)]) == 0
    assert main(["search", "optimum", "--map", MAP_1, "--step", "10", "--log-dir", str(logs)]) == 0
    return logs


def test_compare_reports_every_method_against_the_exact_front(searches, capsys):
    capsys.readouterr()
    hc = ["search", "hillclimb", "--map", MAP_1, "--budget", "20", "--starts", "3", "--name", "hc"]
    assert main([*hc, "--log-dir", str(searches)]) == 0
    runs = ["--random", str(searches / "random-map-1-seed0"), "--nsga2", str(searches / "nsga2-map-1-seed0"),
            "--local", str(searches / "hc")]  # fmt: skip
    code = main(["compare", "--map", MAP_1, *runs, "--step", "10", "--log-dir", str(searches)])
    out, err = capsys.readouterr()
    assert code == 0 and "exact front: read from" in err  # the module's `search exhaustive --step 10`'s front
    report = (searches / "compare-map-1" / "report.md").read_text()
    assert "Planner paper (docs/spec/fbcpp.md): plans start at the first traversable tile." in report  # which planner
    rows = [line for line in report.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert [r.split("|")[1].strip().split(" ")[0] for r in rows] == ["exact", "nsga2", "random", "hillclimb"]
    exact_row = rows[0].split("|")
    assert exact_row[-4].strip() == "0.00" and exact_row[-3].strip() == "1.0000" and exact_row[-2].strip() == "-"
    for row in rows[1:]:  # integer-degree shapes may beat the 10-degree lattice, so a fraction may pass 1
        assert float(row.split("|")[-3]) > 0 and float(row.split("|")[-4]) > -5
    # ... and the report says so, rather than a gap below 0 going unexplained
    assert "The exact front is the 10-degree lattice's, and shapes of 3 runs lie off it (nsga2" in report
    assert "--step 1 for whole degrees" in out
    nsga2 = load(searches / "nsga2-map-1-seed0")  # its children repeat shapes: its evaluations are not all new
    distinct = len(distinct_rows(nsga2))
    assert distinct < nsga2.evaluations == 180  # the column says both, as a local search's budget counts distinct
    assert rows[1].split("|")[2].strip() == f"180 FBCPP evaluations ({distinct} distinct shapes)"
    assert rows[3].split("|")[2].strip() == "60 FBCPP evaluations"  # hill climbing's: 3 starts x 20 distinct
    settled = rows[-1].split("|")[-2].strip()  # hill climbing settles from the fixed starts: the protocol's figures
    assert re.fullmatch(r"-?\d+\.\d\d \(\d+ %\)", settled), settled
    assert (searches / "compare-map-1" / "compare.png").stat().st_size > 10_000 and "report:" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "give at least one run to compare"),
        (["--random", "/no/such/run"], "/no/such/run: not a run folder"),
        (["--random", "{logs}"], "runs, not one run's results; give each run's folder, such as"),
        (["--random", "{logs}/random-map-1-seed0", "--map", MAP_2], "results are for map 'map-1', not 'map-2'"),
        (["--random", "{logs}/nsga2-map-1-seed0"], "a `search nsga2` run, given as random (pass it with --nsga2)"),
        (["--local", "{logs}/random-map-1-seed0"], "given as hillclimb or anneal (pass it with --random)"),
        (
            ["--runs", "{logs}/random-map-1-seed0"],
            "a `search random` run, given as a training run (pass it with --random)",
        ),
        (
            ["--random", "{logs}/exhaustive-map-1-step10"],
            "a `search exhaustive` run, given as random (pass it with --exhaustive)",
        ),
        (
            ["--random", "{logs}/optimum-map-1-step10"],
            "an optimum run holds only the shapes it planned: compare the "
            "methods against a `search exhaustive` run's front (--exhaustive)",
        ),  # it named a flag compare lacks
    ],
)
def test_compare_rejects_bad_runs(searches, capsys, tmp_path, argv, message):
    argv = [a.replace("{logs}", str(searches)) for a in argv]
    capsys.readouterr()
    code = main(["compare", "--log-dir", str(tmp_path), *argv])
    err = capsys.readouterr().err
    assert code == 1 and message in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_a_compare_name_taken_is_refused_before_the_runs_are_read(searches, tmp_path, capsys):
    """It read and planned every run again (5 s on a real map) before it said the name was taken."""
    (tmp_path / "compare-map-1").mkdir()
    (tmp_path / "compare-map-1" / "report.md").write_text("kept")
    capsys.readouterr()
    code = main(["compare", "--log-dir", str(tmp_path), "--random", str(searches)])  # a folder of runs: refused later
    err = capsys.readouterr().err
    assert code == 1 and "compare-map-1 already exists" in err and err.count("\n") == 1
    assert (tmp_path / "compare-map-1" / "report.md").read_text() == "kept"


def test_compare_given_a_sweeps_folder_names_one_of_its_trials(tmp_path, capsys):
    sweep = tmp_path / "logs" / "tiny"
    for trial in ("ppo-map-1-seed0_00000", "ppo-map-1-seed1_00001"):
        (sweep / trial).mkdir(parents=True)
        (sweep / trial / "morphologies.csv").write_text("")
    (sweep / "sweep.md").write_text("")
    capsys.readouterr()
    assert main(["compare", "--runs", str(sweep), "--log-dir", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "holds the folders of 2 runs, not one run's results" in err
    assert f"such as {sweep / 'ppo-map-1-seed0_00000'}" in err and err.count("\n") == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["compare", "--runs", str(empty), "--log-dir", str(tmp_path / "out")]) == 1
    assert "holds no results (no morphologies.csv" in capsys.readouterr().err
    (empty / "summary.json").write_text("{}")  # a run too short for an episode to end
    assert main(["compare", "--runs", str(empty), "--log-dir", str(tmp_path / "out")]) == 1
    assert "a training run that ranked no shape (no morphologies.csv): none of its episodes" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("flag", ["--nsga2", "--random", "--local"])
def test_compare_refuses_a_training_run_given_as_a_search(tmp_path, capsys, flag):
    run = tmp_path / "logs" / "ppo-map-1"
    run.mkdir(parents=True)
    (run / "morphologies.csv").write_text("")
    capsys.readouterr()
    code = main(["compare", flag, str(run), "--log-dir", str(tmp_path / "out"), "--step", "30"])
    err = capsys.readouterr().err
    assert code == 1 and "a training run, given as" in err and "(pass it with --runs)" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_compare_refuses_runs_scored_by_another_planner(tmp_path, capsys):
    from smorphi_rl.cli import main

    assert (
        main(["search", "random", "--samples", "20", "--planner", "fit", "--log-dir", str(tmp_path), "--name", "r"])
        == 0
    )
    capsys.readouterr()
    assert main(["compare", "--random", str(tmp_path / "r"), "--log-dir", str(tmp_path), "--step", "30"]) != 0
    err = capsys.readouterr().err
    assert "scored by the fit planner" in err and "--planner fit" in err and not (tmp_path / "compare-map-1").exists()


def test_compare_refuses_runs_planned_from_another_start(tmp_path, capsys):
    from smorphi_rl.cli import main

    argv = ["search", "random", "--samples", "20", "--planner", "fit", "--start-xy", "1.0", "1.0"]
    assert main([*argv, "--log-dir", str(tmp_path), "--name", "r"]) == 0
    capsys.readouterr()
    compare = [
        "compare",
        "--random",
        str(tmp_path / "r"),
        "--planner",
        "fit",
        "--log-dir",
        str(tmp_path),
        "--step",
        "30",
    ]
    assert main(compare) != 0
    err = capsys.readouterr().err
    assert "planned from (1, 1) m, the exact front here from the planner's default start: pass --start-xy 1 1" in err
    assert err.count("\n") == 1 and not (tmp_path / "compare-map-1").exists()
    assert main([*compare, "--start-xy", "1.0", "1.0"]) == 0
    report = (tmp_path / "compare-map-1" / "report.md").read_text()
    assert "Planner fit (docs/fbcpp-fit.md): plans start at (1, 1) m, 100.0 % of the free cells." in report
    import json

    for damaged in ("[1e400, 1.0]", "[1" + "0" * 400 + ", 1]"):  # a hint of `--start-xy inf 1`, or a traceback
        summary = tmp_path / "r" / "summary.json"
        record = json.loads(summary.read_text())
        summary.write_text(json.dumps(record).replace(json.dumps(record["params"]["start_xy"]), damaged))
        capsys.readouterr()
        assert main([*compare, "--name", "again"]) == 1
        err = capsys.readouterr().err
        assert "its start_xy" in err and "is not a point (two finite numbers, in metres)" in err, err
        assert err.count("\n") == 1 and not (tmp_path / "again").exists()


@pytest.mark.parametrize("kind", ["random", "exhaustive", "training"])
def test_compare_refuses_runs_of_another_floor_with_the_same_name(searches, capsys, tmp_path, kind):
    """ROS maps are often all `map.yaml`: map-2 filed as map-1 once read a random search of map-1 as beating the
    exact optimum (gap -0.02)."""
    import json

    (tmp_path / "map-1.yaml").write_text((ROOT / "maps" / "map-2.yaml").read_text())
    (tmp_path / "map-2.pgm").write_bytes((ROOT / "maps" / "map-2.pgm").read_bytes())
    runs = ["--random", str(searches / "random-map-1-seed0")]
    if kind == "exhaustive":  # a search of this floor, against the exact front of the other
        other = ["search", "random", "--map", str(tmp_path / "map-1.yaml"), "--samples", "20", "--name", "here"]
        assert main([*other, "--log-dir", str(tmp_path)]) == 0
        (front,) = searches.glob("exhaustive-map-1*")
        runs = ["--random", str(tmp_path / "here"), "--exhaustive", str(front)]
    if kind == "training":  # what `train` writes beside its table: each map's digest by name
        from smorphi_rl.maps import load_map

        run = tmp_path / "ppo-map-1"
        run.mkdir()
        (run / "morphologies.csv").write_text("algorithm,map,theta1,theta2,theta3,P_c,P_len,R1,first_seen_env_steps,"
                                              "variants\nppo,map-1,95,59,103,97.2400,90,80.0,10,1\n")  # fmt: skip
        (run / "summary.json").write_text(
            json.dumps({"env_steps": 10, "map_digests": {"map-1": load_map(MAP_1).digest}})
        )
        runs = ["--runs", str(run)]
    capsys.readouterr()
    step = [] if kind == "exhaustive" else ["--step", "30"]
    code = main(["compare", "--map", str(tmp_path / "map-1.yaml"), *runs, *step, "--log-dir", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and "another floor" in err and "the cells differ" in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()
    if kind == "training":  # the same run against the floor it was trained on is compared
        assert main(["compare", "--map", MAP_1, *runs, "--step", "30", "--log-dir", str(tmp_path / "out")]) == 0


@pytest.mark.parametrize("settled", [["abc"], [[1, 2], 3], {"median_gap": "x"}, [10**400]])
def test_a_local_search_whose_settled_figures_are_damaged_is_one_line(tmp_path, capsys, settled):
    """A hand-edited `settled_R1` ended `compare` in a ValueError or OverflowError traceback."""
    import json

    argv = ["search", "hillclimb", "--map", MAP_1, "--budget", "5", "--starts", "2", "--name", "hc"]
    assert main([*argv, "--log-dir", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "hc" / "summary.json").read_text())
    summary["params"]["settled_R1"] = settled
    (tmp_path / "hc" / "summary.json").write_text(json.dumps(summary))
    capsys.readouterr()
    code = main(["compare", "--local", str(tmp_path / "hc"), "--step", "30", "--log-dir", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "its settled_R1 is not what smorphi-rl writes" in err, err
    assert not (tmp_path / "out").exists()


def test_a_results_archive_larger_than_its_summary_says_is_refused_before_it_is_read(searches, tmp_path, capsys):
    """A 487 KB crafted results.npz of 20 million rows, under a summary of 200 shapes, took `compare` to 2.2 GB."""
    import json
    import shutil

    run = tmp_path / "random"
    shutil.copytree(searches / "random-map-1-seed0", run)
    n = 1_000_000
    np.savez_compressed(run / "results.npz", thetas=np.zeros((n, 3), np.float32), P_c=np.zeros(n),
                        P_len=np.zeros(n, np.int32), feasible=np.zeros(n, bool))  # fmt: skip
    assert json.loads((run / "summary.json").read_text())["distinct_shapes"] <= 200
    capsys.readouterr()
    code = main(["compare", "--random", str(run), "--step", "30", "--log-dir", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and "more than its summary's" in err and err.count("\n") == 1, err


def test_a_search_written_before_its_summary_counted_rows_still_loads(searches, tmp_path):
    """Summaries before 2026-12-07 held `distinct_shapes` as the row count, and no `rows`."""
    import json
    import shutil

    run = tmp_path / "random"
    shutil.copytree(searches / "random-map-1-seed0", run)
    summary = json.loads((run / "summary.json").read_text())
    rows = summary.pop("rows")
    (run / "summary.json").write_text(json.dumps(summary | {"distinct_shapes": rows}))
    assert len(load(run).thetas) == rows == 200


def test_a_results_archive_that_unpacks_far_beyond_its_size_is_refused_whatever_its_summary_claims(
    searches, tmp_path, capsys
):  # fmt: skip
    """A 1.2 MB results.npz of zeros under a summary claiming its 50 million rows took `compare` to 3.35 GB: the
    summary's count bounds nothing a crafted folder does not choose, so the archive's own size bounds it too."""
    import json
    import shutil

    run = tmp_path / "random"
    shutil.copytree(searches / "random-map-1-seed0", run)
    n = 1_000_000
    np.savez_compressed(run / "results.npz", thetas=np.zeros((n, 3), np.float32), P_c=np.zeros(n),
                        P_len=np.zeros(n, np.int32), feasible=np.zeros(n, bool))  # fmt: skip
    summary = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(json.dumps(summary | {"rows": n, "distinct_shapes": n, "evaluations": n}))
    capsys.readouterr()
    code = main(["compare", "--random", str(run), "--step", "30", "--log-dir", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 1 and "which no search's figures compress to" in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["training", "exhaustive"])
def test_a_best_shape_whose_recorded_figures_the_planner_does_not_give_is_refused(searches, capsys, tmp_path, kind):
    """compare read P_c and P_len from a run's files: a hand-edited row (here 100 % coverage on a path of 1)
    "beat" the exact optimum. Each run's best shape is planned again."""
    import json
    import shutil

    from smorphi_rl.maps import load_map

    run = tmp_path / "ppo-map-1"
    run.mkdir()
    header = "algorithm,map,theta1,theta2,theta3,P_c,P_len,R1,first_seen_env_steps,variants\n"
    (run / "summary.json").write_text(json.dumps({"env_steps": 10, "map_digests": {"map-1": load_map(MAP_1).digest}}))
    (run / "morphologies.csv").write_text(header + "ppo,map-1,95,59,103,97.2400,90,80.0,10,1\n")
    argv = ["compare", "--map", MAP_1, "--runs", str(run), "--step", "30"]
    if kind == "exhaustive":
        front = tmp_path / "front"
        shutil.copytree(next(searches.glob("exhaustive-map-1*")), front)
        with np.load(front / "results.npz") as z:
            arrays = dict(z)
        r1 = np.where(arrays["feasible"], arrays["P_c"] - 0.1 * arrays["P_len"], -np.inf)
        arrays["P_c"][np.argmax(r1)] = 100.0  # its best shape, now covering all
        np.savez_compressed(front / "results.npz", **arrays)
        argv = ["compare", "--map", MAP_1, "--runs", str(run), "--exhaustive", str(front)]
    else:
        assert main([*argv, "--log-dir", str(tmp_path / "ok")]) == 0  # the planner's own figures pass
        (run / "morphologies.csv").write_text(header + "ppo,map-1,95,59,103,100.0000,1,99.9,10,1\n")
    capsys.readouterr()
    assert main([*argv, "--log-dir", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "is recorded at P_c 100.0000 %" in err and "another version of the planner" in err, err
    assert err.count("\n") == 1 and not (tmp_path / "out").exists()


def test_a_training_run_of_another_block_size_is_refused_by_its_block(tmp_path, capsys):
    """Its right figures read as "edited by hand": compare plans the default block, the run planned a 0.2 m one."""
    import json

    from smorphi_rl.maps import load_map

    run = tmp_path / "ppo-map-1"
    run.mkdir()
    header = "algorithm,map,theta1,theta2,theta3,P_c,P_len,R1,first_seen_env_steps,variants\n"
    (run / "morphologies.csv").write_text(header + "ppo,map-1,95,59,103,90.8000,49,80.0,10,1\n")
    (run / "summary.json").write_text(json.dumps({"env_steps": 10, "map_digests": {"map-1": load_map(MAP_1).digest}}))
    (run / "config.json").write_text(json.dumps({"env": {"block_side_m": 0.2}}))
    capsys.readouterr()
    argv = ["compare", "--map", MAP_1, "--runs", str(run), "--step", "30", "--log-dir", str(tmp_path / "out")]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "planned with a 0.2 m block, the exact front here with 0.17 m" in err and err.count("\n") == 1, err


def test_an_episode_best_that_was_infeasible_is_no_shape_on_the_front(tmp_path, capsys):
    """An episode that met only infeasible shapes records P_c = P_len = 0 (R1 0): under weights where every
    feasible R1 is negative it was the run's "best" shape."""
    import json

    from smorphi_rl.maps import load_map

    run = tmp_path / "ppo-map-1"
    run.mkdir()
    header = "algorithm,map,theta1,theta2,theta3,P_c,P_len,R1,first_seen_env_steps,variants\n"
    (run / "summary.json").write_text(json.dumps({"env_steps": 10, "map_digests": {"map-1": load_map(MAP_1).digest}}))
    argv = ["compare", "--map", MAP_1, "--runs", str(run), "--step", "30", "--w2", "5"]
    (run / "morphologies.csv").write_text(header + "ppo,map-1,0,180,0,0.0000,0,0.0,10,1\n")
    assert main([*argv, "--log-dir", str(tmp_path / "none")]) == 1
    assert "found no feasible morphologies on map 'map-1'" in capsys.readouterr().err
    (run / "morphologies.csv").write_text(header + "ppo,map-1,0,180,0,0.0000,0,0.0,10,1\n"
                                          "ppo,map-1,95,59,103,97.2400,90,-352.8,10,1\n")  # fmt: skip
    assert main([*argv, "--log-dir", str(tmp_path / "out")]) == 0
    assert "| PPO (ppo-map-1) | 10 env steps | (95, 59, 103) |" in capsys.readouterr().out


def test_compare_reads_the_front_a_search_exhaustive_left_in_its_log_dir(tmp_path, capsys):
    """It computed the front again beside a `search exhaustive` run of the same map (109-206 s on a real floor)."""
    assert main(["search", "random", "--map", MAP_1, "--samples", "50", "--log-dir", str(tmp_path)]) == 0
    assert main(["search", "exhaustive", "--map", MAP_1, "--step", "30", "--log-dir", str(tmp_path)]) == 0
    capsys.readouterr()
    argv = ["compare", "--map", MAP_1, "--random", str(tmp_path / "random-map-1-seed0"), "--log-dir", str(tmp_path)]
    assert main([*argv, "--step", "30"]) == 0
    err = capsys.readouterr().err
    assert f"exact front: read from {tmp_path / 'exhaustive-map-1-step30'}" in err
    computed = tmp_path / "computed"
    assert main([*argv, "--step", "30", "--log-dir", str(computed)]) == 0  # no run there: computed, the same report
    assert "exact front: read" not in capsys.readouterr().err
    assert (computed / "compare-map-1" / "report.md").read_text() == (
        tmp_path / "compare-map-1" / "report.md"
    ).read_text()
    assert main([*argv, "--step", "60", "--name", "other-step"]) == 0  # another lattice: not that run's front
    assert "exact front: read" not in capsys.readouterr().err


def _training_run(tmp_path: Path, env: dict, map_name: str = "map-1") -> Path:
    """A training run's files as `train` writes them: one shape found, the protocol's figures, its env settings."""
    import json

    from smorphi_rl.maps import load_map

    run = tmp_path / "ppo-run"
    run.mkdir()
    header = "algorithm,map,theta1,theta2,theta3,P_c,P_len,R1,first_seen_env_steps,variants\n"
    (run / "morphologies.csv").write_text(header + f"ppo,{map_name},95,59,103,97.2400,90,88.24,10,1\n")
    summary = {"env_steps": 10, "map_digests": {"map-1": load_map(MAP_1).digest},
               "evaluation": {map_name: {"median_gap": 3.36, "share_within_1pct": 0.25}}}  # fmt: skip
    (run / "summary.json").write_text(json.dumps(summary))
    (run / "config.json").write_text(json.dumps({"env": env}))
    return run


def test_settled_figures_measured_under_other_weights_are_left_out_and_said(tmp_path, capsys):
    """A run trained with `per_area` (a designer's fine-tune) showed its own gap, to its own optimum, under a table
    headed by another optimum; under a `per_area` table its figures are shown."""
    run = _training_run(tmp_path, {"path_term": "per_area"})
    argv = ["compare", "--map", MAP_1, "--runs", str(run), "--step", "30"]
    capsys.readouterr()
    assert main([*argv, "--log-dir", str(tmp_path / "moves")]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| PPO (ppo-run)"))
    assert row.endswith("| - |") and "PPO (ppo-run): its settled figures were measured under R1 = 1 P_c - " in out
    assert "left out (pass the run's --w1, --w2 and --path-term to read them)" in out
    assert main([*argv, "--path-term", "per_area", "--log-dir", str(tmp_path / "per_area")]) == 0
    out = capsys.readouterr().out
    assert "| 3.36 (25 %) |" in out and "settled figures were measured" not in out


def test_a_training_run_of_another_map_names_the_map_it_trained_on(tmp_path, capsys):
    """It read "found no feasible morphologies on map 'map-1'", as if its shapes could not fit."""
    run = _training_run(tmp_path, {}, map_name="map-2")
    capsys.readouterr()
    assert main(["compare", "--map", MAP_1, "--runs", str(run), "--step", "30", "--log-dir", str(tmp_path)]) == 1
    assert "its shapes are of 'map-2', not 'map-1': give --map the map it trained on" in capsys.readouterr().err


def test_a_hypervolume_share_with_no_exact_area_reads_as_none_not_nan():
    """An exact front of one shape spans no area: its share of it is not a number, and the table said "nan"."""
    from smorphi_rl.compare import MethodScore, method_table

    one = np.array([5.0]), np.array([90.0])
    exact = MethodScore("exact", "1 shape", (0.0, 180.0, 0.0), 90.0, 5, 89.5, 0.0, float("nan"), *one)
    found = MethodScore("random", "10", (0.0, 180.0, 0.0), 90.0, 5, 89.5, 0.0, float("nan"), *one)
    rows = [line for line in method_table(exact, [found]) if line.startswith("| exact") or line.startswith("| random")]
    assert len(rows) == 2 and all("nan" not in row and "| - |" in row for row in rows)

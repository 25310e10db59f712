"""The command line: outputs, JSON shape, batch files, plots, and one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import smorphi_rl
from smorphi_rl.cli import main
from smorphi_rl.coverage import sweep_positions

ROOT = Path(__file__).resolve().parent.parent
MAP_1 = str(ROOT / "maps" / "map-1.yaml")
JSON_KEYS = {"theta", "P_c", "coverage_free_pct", "P_len", "path_length_m", "feasible", "footprint_cells"}


def run(capsys, *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse's usage errors (exit 2)
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_evaluate_prints_every_metric(capsys):
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "95", "59", "103")
    assert code == 0
    for label in ("P_c", "coverage", "P_len", "path length", "footprint", "feasible"):
        assert f"\n{label}" in out
    assert "F 8 x 4 cells" in out and "feasible     yes" in out


def test_evaluate_json(capsys):
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "0", "180", "0", "--json")
    doc = json.loads(out)
    assert code == 0 and doc.keys() >= JSON_KEYS
    assert doc["theta"] == [0, 180, 0] and doc["footprint_cells"] == [3, 3] and doc["feasible"] is True
    assert doc["P_c"] == 100.0  # the O-shape fills its tile


def test_json_output_stays_json_with_a_plot(capsys, tmp_path):
    """`--json --plot`: evaluate names its plot in the object (as design does); evaluate-policy's stdout stays one
    JSON object per episode (its plot line went to stdout, so a JSON reader failed on the last line)."""
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "0", "180", "0", "--json", "--plot",
                       str(tmp_path / "e.png"))  # fmt: skip
    assert code == 0 and json.loads(out)["plot"] == str(tmp_path / "e.png") and (tmp_path / "e.png").exists()
    designer = str(Path(smorphi_rl.__file__).parent / "policies" / "designer")
    code, out, err = run(capsys, "evaluate-policy", "--checkpoint", designer, "--map", MAP_1, "--episodes", "2",
                         "--json", "--plot", str(tmp_path / "p.png"))  # fmt: skip
    assert code == 0 and [json.loads(line)["episode"] for line in out.splitlines()] == [0, 1]
    assert f"plot        {tmp_path / 'p.png'}" in err and (tmp_path / "p.png").exists()


@pytest.mark.parametrize("planner", ["paper", "fit"])
def test_evaluate_json_path_lets_anyone_check_the_plan(capsys, planner):
    """--path adds F and the robot's placements: re-stamping F there must give the reported coverage."""
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "0", "180", "0", "--json", "--path",
                       "--planner", planner)  # fmt: skip
    doc = json.loads(out)
    assert code == 0 and doc["planner"] == planner and len(doc["placements"]) == doc["P_len"] + 1
    f = np.array(doc["footprint"], dtype=bool)
    assert f.shape == tuple(doc["footprint_cells"])
    from smorphi_rl.maps import Cell, load_map

    grid = load_map(MAP_1).cells
    swept = np.zeros_like(grid, dtype=bool)
    rows, cols = np.nonzero(f)
    for r, c in sweep_positions(doc["placements"]):
        inside = (r + rows < grid.shape[0]) & (c + cols < grid.shape[1])
        swept[r + rows[inside], c + cols[inside]] = True
    covered = swept & (grid == Cell.FREE)
    assert covered.sum() == round(doc["coverage_free_pct"] * (grid == Cell.FREE).sum() / 100)
    assert planner == "paper" or not (swept & (grid != Cell.FREE)).any()


def test_a_shape_that_fits_nowhere_is_one_line(capsys, tmp_path):
    from smorphi_rl.maps import Map, save_map

    box = save_map(Map.from_text("#####\n#...#\n#...#\n#...#\n#####", 0.1, name="box"), tmp_path / "box.yaml")
    code, out, err = run(capsys, "evaluate", "--map", str(box), "--angles", "0", "0", "0", "--planner", "fit")
    assert code != 0 and out == "" and "(2 x 7 cells) fits nowhere on map box" in err and len(err.splitlines()) == 1


def test_evaluate_path_needs_json_and_one_shape(capsys):
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles", "0", "180", "0", "--path")
    assert code != 0 and "--path" in err and "Traceback" not in err


def test_angles_file_json_lines_in_input_order(capsys, tmp_path):
    rows = [(95, 59, 103), (0, 180, 0), (12.5, 33, 170), (95, 59, 103)]
    f = tmp_path / "angles.csv"
    f.write_text("t1,t2,t3\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n\n")
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f), "--json")
    docs = [json.loads(line) for line in out.splitlines()]
    assert code == 0 and [tuple(d["theta"]) for d in docs] == rows
    _, single, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "12.5", "33", "170", "--json")
    assert docs[2] == json.loads(single)
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f))
    lines = out.splitlines()
    assert lines[0].startswith("t1,t2,t3,P_c") and len(lines) == 5 and lines[1] == lines[4]


def test_evaluate_scores_r1_as_design_and_search_weigh_it(capsys, tmp_path):
    """evaluate printed no R1: a design's or a search's answer could not be checked without arithmetic by hand."""
    code, out, _ = run(capsys, "design", "--map", MAP_1, "--json", "--budget", "30")
    design = json.loads(out)
    angles = [f"{t:g}" for t in design["theta"]]
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", *angles, "--path-term", "per_area", "--json")
    assert code == 0 and json.loads(out)["R1"] == pytest.approx(design["R1"])
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "95", "59", "103", "--w2", "0.2")
    assert "\nR1           79.2400 (R1 = 1 P_c - 0.2 P_len)" in out  # 97.24 - 0.2 x 90
    f = tmp_path / "angles.csv"
    f.write_text("95,59,103\n")
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f))
    assert out.splitlines()[0].endswith(",R1") and out.splitlines()[1].endswith(",88.240000")


def test_plot_writes_a_png(capsys, tmp_path):
    png = tmp_path / "sub" / "cov.png"
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles", "95", "59", "103", "--plot", str(png))
    assert code == 0 and str(png) in out
    with Image.open(png) as img:
        assert img.format == "PNG" and img.size[0] > 600


def test_start_and_block_side_options(capsys):
    base = ["evaluate", "--map", MAP_1, "--angles", "0", "180", "0", "--json"]
    _, a, _ = run(capsys, *base)
    _, b, _ = run(capsys, *base, "--start", "tile:5,5")
    _, c, _ = run(capsys, *base, "--block-side", "0.25")
    _, d, _ = run(capsys, *base, "--start", "xy:2.55,2.55", "--path")
    da, db, dc, dd = json.loads(a), json.loads(b), json.loads(c), json.loads(d)
    assert da["P_len"] != db["P_len"] or da["path_length_m"] != db["path_length_m"]
    assert dc["footprint_cells"] == [5, 5]
    (row, col), (rows, cols) = dd["placements"][0], np.array(dd["footprint"]).shape
    assert dd["feasible"] and row <= 25 < row + rows and col <= 25 < col + cols  # the plan starts over cell (25, 25)


def test_maps_generate_and_show(capsys, tmp_path):
    out_yaml = tmp_path / "gen.yaml"
    code, out, _ = run(capsys, "maps", "generate", "--out", str(out_yaml), "--density", "0.3", "--seed", "4")
    assert code == 0 and "occupied 30.00 %" in out and (tmp_path / "gen.pgm").exists()
    png = tmp_path / "gen.png"
    code, out, _ = run(capsys, "maps", "show", str(out_yaml), "--png", str(png))
    assert code == 0 and "occupied    30.00 %" in out and png.exists()
    before = out_yaml.read_bytes()
    code, _, err = run(capsys, "maps", "generate", "--out", str(out_yaml), "--seed", "5")
    assert code != 0 and "--force" in err and out_yaml.read_bytes() == before  # nothing overwritten


def test_maps_show_never_draws_over_the_map_s_own_image(capsys, tmp_path, monkeypatch):
    """`maps show` draws to logs/maps/NAME.png by default, where `maps generate --format png` may have put the
    map's own image."""
    monkeypatch.chdir(tmp_path)
    out_yaml = tmp_path / "logs" / "maps" / "gen.yaml"
    assert run(capsys, "maps", "generate", "--out", str(out_yaml), "--format", "png")[0] == 0
    image = (tmp_path / "logs" / "maps" / "gen.png").read_bytes()
    code, _, err = run(capsys, "maps", "show", str(out_yaml))
    assert code == 1 and f"is the image of map {out_yaml}: give --png" in err
    other = tmp_path / "other" / "gen.yaml"  # another floor of the same file name (ROS maps are often all map.yaml)
    assert run(capsys, "maps", "generate", "--out", str(other), "--seed", "9")[0] == 0
    code, _, err = run(capsys, "maps", "show", str(other))
    assert code == 1 and "is the image of map logs/maps/gen.yaml: give --png" in err
    assert (tmp_path / "logs" / "maps" / "gen.png").read_bytes() == image
    assert run(capsys, "maps", "show", str(out_yaml), "--png", str(tmp_path / "drawn.png"))[0] == 0
    for _ in range(2):  # a drawing that is no map's image is redrawn
        assert run(capsys, "maps", "show", str(ROOT / "maps" / "map-1.yaml"))[0] == 0


def _bad_files(tmp_path: Path) -> dict[str, Path]:
    files = {
        "malformed.yaml": "image: [oops",
        "nores.yaml": "image: m.pgm\n",
        "zero.yaml": "image: m.pgm\nresolution: 0\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        "noimage.yaml": "image: gone.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        "black.yaml": "image: black.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        "empty.csv": "t1,t2,t3\n\n",
        "short.csv": "1,2,3\n4,5\n",
        "words.csv": "1,2,3\na,b,c\n",
        "spaces.csv": "90 90 90\n",  # once read as a header, then "no angles in the file"
        "nan_first.csv": "nan,90,90\n10,20,30\n",  # the fast reading once skipped row 1 as a header, silently
        "semicolons.csv": "90;90;90\n10,20,30\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    Image.fromarray(np.full((5, 5), 254, np.uint8)).save(tmp_path / "m.pgm")
    Image.fromarray(np.zeros((5, 5), np.uint8)).save(tmp_path / "black.pgm")
    (tmp_path / "folder").mkdir()
    return {name: tmp_path / name for name in files}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--map", "{missing.yaml}", "--angles", "1", "2", "3"], "map file not found"),
        (["--map", "{folder}", "--angles", "1", "2", "3"], "folder is a folder: give one map YAML (train and sweep"),
        (["--map", "generate:mixed", "--angles", "1", "2", "3"], "(a generator is for train and sweep;"),
        (["--map", "{malformed.yaml}", "--angles", "1", "2", "3"], "malformed YAML"),
        (["--map", "{nores.yaml}", "--angles", "1", "2", "3"], "missing key 'resolution'"),
        (["--map", "{zero.yaml}", "--angles", "1", "2", "3"], "'resolution' must be 0.001-10 m a cell"),
        (["--map", "{noimage.yaml}", "--angles", "1", "2", "3"], "map image not found"),
        (["--map", "{black.yaml}", "--angles", "1", "2", "3"], "has no free cell"),
        (["--angles", "1", "2", "181"], "outside [0, 180]"),
        (["--angles", "-5", "2", "3"], "outside [0, 180]"),
        (["--angles", "x", "2", "3"], "argument --angles: expected a number, got 'x'"),
        (["--angles", "nan", "2", "3"], "argument --angles: expected a finite number, got 'nan'"),
        (["--angles-file", "{empty.csv}"], "no angles in the file"),
        (["--angles-file", "{short.csv}"], "line 2: expected three numbers"),
        (["--angles-file", "{words.csv}"], "line 2: expected three numbers"),
        (["--angles-file", "{spaces.csv}"], "line 1: expected three numbers t1,t2,t3, got '90 90 90'"),
        (["--angles-file", "{nothere.csv}"], "angles file not found"),
        (["--angles-file", "{nan_first.csv}"], "line 1: expected three numbers t1,t2,t3, got 'nan,90,90'"),
        (["--angles-file", "{semicolons.csv}"], "line 1: expected three numbers t1,t2,t3, got '90;90;90'"),
        (["--angles", "1", "2", "3", "--block-side", "0"], "--block-side must be > 0"),
        (["--angles", "1", "2", "3", "--start", "tile:x,1"], "tile indices must be integers"),
        (["--angles", "1", "2", "3", "--start", "corner"], "use tile:A,B or xy:X,Y"),
        (["--angles", "1", "2", "3", "--start", "tile:99,0"], "outside the"),
    ],
)
def test_bad_input_one_line_nonzero(capsys, tmp_path, args, message):
    files = _bad_files(tmp_path)
    argv = ["evaluate"]
    for a in args:
        if a.startswith("{"):
            name = a.strip("{}")
            a = str(files.get(name, tmp_path / name))
        argv.append(a)
    if "--map" not in argv:
        argv += ["--map", MAP_1]
    code, out, err = run(capsys, *argv)
    assert code != 0 and out == ""
    assert err.count("\n") == 1 and err.startswith("smorphi-rl") and message in err


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        ([], "{evaluate,maps,"),
        (["maps"], "{generate,show,crop,resample}"),
        (["search"], "{random,nsga2,exhaustive,optimum,hillclimb,anneal}"),
    ],
)
def test_a_missing_subcommand_is_named_by_its_choices(capsys, argv, named):
    """Not by argparse's dest (`maps_command`), a name no user can type."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"the following arguments are required: {named}" in err and "_command" not in err


@pytest.mark.parametrize(("argv", "message"), [
    ([], "one of the arguments --angles --angles-file is required"),
    (["--angles", "1", "2", "3", "--angles-file", "a.csv"], "argument --angles-file: not allowed with argument"),
])  # fmt: skip
def test_evaluate_without_angles_or_with_both_kinds_is_a_usage_error(capsys, argv, message):
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--map", MAP_1, *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and message in err, err


def test_an_unknown_subcommand_lists_the_choices_once_without_the_dest(capsys):
    with pytest.raises(SystemExit):
        main(["maps", "bogus"])
    err = capsys.readouterr().err
    assert "error: invalid choice: 'bogus' (choose from 'generate'," in err and err.count("generate") == 1
    assert "maps_command" not in err


def test_usage_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--angles", "1", "2"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--angles" in err


@pytest.mark.parametrize("argv", [
    ["design", "--policy", ""],  # designed with the shipped designer, saying nothing
    ["design", "--map="],
    ["evaluate-policy", "--checkpoint", ""],  # searched the working directory for checkpoints
    ["train", "--pretrained", "", "--timesteps", "100"],
    ["replay", ""],
    ["maps", "show", ""],
])  # fmt: skip
def test_an_empty_value_is_refused_not_read_as_the_working_directory(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    flags = [a for a, b in zip(argv, [*argv[1:], ""], strict=True) if a.startswith("--") and (a.endswith("=") or not b)]
    named = flags[0] if flags else {"replay": "path", "maps": "map"}[argv[0]]  # a positional, as argparse names it
    assert exc.value.code == 2 and err.count("\n") == 1
    assert f"argument {named.removesuffix('=')}: expected a value, got an empty string" in err


def test_installed_command_reports_errors_without_traceback(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "smorphi_rl.cli",
            "evaluate",
            "--map",
            str(tmp_path / "no.yaml"),
            "--angles",
            "1",
            "2",
            "3",
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == f"smorphi-rl: error: map file not found: {tmp_path / 'no.yaml'}"


@pytest.mark.parametrize("module", ["smorphi_rl.cli", "smorphi_rl"])  # `python -m smorphi_rl` had no __main__
def test_default_map_runs_from_any_directory(tmp_path, module):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-m", module, "evaluate", "--angles", "95", "59", "103", "--json"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["footprint_cells"] == [8, 4]


@pytest.mark.parametrize("planner", ["paper", "fit"])
def test_evaluate_one_shape_answers_without_the_compiled_kernels(planner):
    """One shape on a small map is planned in plain Python: numba (over a second to start) is never imported,
    and the report is the one the kernels give (`quick_result` is held equal to them in its own tests)."""
    code = (
        "import sys; from smorphi_rl.cli import main; "
        f"rc = main(['evaluate', '--map', {MAP_1!r}, '--angles', '90', '90', '90', '--planner', '{planner}', "
        "'--json']); "
        "print('numba' in sys.modules); sys.exit(rc)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    record, numba_loaded = proc.stdout.splitlines()
    assert numba_loaded == "False"
    assert json.loads(record)["planner"] == planner


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_ctrl_c_while_the_cli_loads_is_one_line(installed, monkeypatch, capsys, signame):
    """The entry point imports the CLI (seconds of libraries) inside a guard: a Ctrl-C then is one line, exit 130
    (it was a traceback through scipy's import); a SIGTERM killed the process without a word (exit 143)."""
    import builtins
    import signal

    from smorphi_rl import entry

    real_import = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name == "smorphi_rl.cli":
            signal.raise_signal(getattr(signal, signame))
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", interrupted)
    assert entry.main() == 130
    assert capsys.readouterr().err == "smorphi-rl: interrupted\n"


def test_evaluate_policy_takes_a_folder_of_maps_as_train_does(capsys, tmp_path):
    import shutil

    floors = tmp_path / "floors"
    floors.mkdir()
    for name in ("map-1.yaml", "map-1.pgm"):
        shutil.copy(ROOT / "maps" / name, floors / name)
    designer = str(ROOT / "smorphi_rl" / "policies" / "designer")
    code, out, err = run(capsys, "evaluate-policy", "--checkpoint", designer, "--map", str(floors), "--json")
    assert code == 0, err
    (episode,) = [json.loads(line) for line in out.splitlines()]
    assert episode["map"] == "map-1" and episode["settled"]["R1"] > 0


def test_a_list_option_given_twice_holds_both_lists_and_replaces_its_default():
    """`compare --random a --random b` compared only b, without a word (argparse keeps the last list)."""
    from smorphi_rl.cli import build_parser

    parse = build_parser().parse_args
    assert parse(["compare", "--random", "a", "--random", "b", "c"]).random == ["a", "b", "c"]
    assert parse(["compare", "--runs", "r"]).runs == ["r"] and parse(["compare"]).runs is None
    seeds = parse(["transfer", "--pretrained", "p", "--maps", "m", "--seeds", "4", "--seeds", "5"]).seeds
    assert seeds == [4, 5]  # the default seeds replaced, not extended
    assert parse(["transfer", "--pretrained", "p", "--maps", "m", "--maps", "n"]).maps == ["m", "n"]
    args = parse(["train", "--map", "a.yaml", "--map", "b.yaml", "--eval-maps", "c.yaml", "--eval-maps", "d.yaml"])
    assert args.map == ["a.yaml", "b.yaml"] and args.eval_maps == ["c.yaml", "d.yaml"]
    assert parse(["evaluate-policy", "--checkpoint", "x", "--map", "a", "--map", "b"]).map == ["a", "b"]


def test_evaluate_takes_start_xy_as_every_other_command_spells_it(capsys):
    """The start-area warning and `search`, `design`, `train` say `--start-xy X Y`; `evaluate` refused it."""
    args = ["evaluate", "--map", MAP_1, "--angles", "0", "180", "0", "--planner", "fit", "--json"]
    code, out, _ = run(capsys, *args, "--start-xy", "2.5", "2.5")
    assert code == 0
    assert run(capsys, *args, "--start", "xy:2.5,2.5") == (0, out, "")
    text = run(capsys, *args[:-1], "--start-xy", "2.5", "2.5")[1]
    assert "\nstart        cell (25, 25)" in text and "largest free area" in run(capsys, *args[:-1])[1]


def test_evaluate_warns_when_the_path_term_swamps_coverage_as_search_does(capsys, tmp_path):
    """On a floor too large for the weights R1 was -282.70 with no word; `search` warned and named the fix."""
    from smorphi_rl.maps import Map, save_map

    hall = save_map(Map(np.zeros((300, 300), dtype=np.uint8), 0.1, name="hall"), tmp_path / "hall.yaml")
    code, out, err = run(capsys, "evaluate", "--map", str(hall), "--angles", "0", "180", "0", "--json")
    assert code == 0 and json.loads(out)["R1"] < 0
    assert err.startswith("warning: on hall the path term swamps coverage (its R1 -") and "--path-term per_area" in err
    assert run(capsys, "evaluate", "--map", str(hall), "--angles", "0", "180", "0", "--path-term", "per_area")[2] == ""
    assert run(capsys, "evaluate", "--map", MAP_1, "--angles", "0", "180", "0")[2] == ""


def test_maps_generate_stopped_as_a_floor_is_written_finishes_that_floor(tmp_path, capsys, monkeypatch):
    """A Ctrl-C between a floor's image and its YAML left the image alone (3 of 21 stopped runs)."""
    import signal

    from smorphi_rl import rundir

    real, images = rundir.write_atomic, []

    def write(path, data):
        real(path, data)
        if path.suffix == ".pgm":
            images.append(path)
            if len(images) == 2:
                signal.raise_signal(signal.SIGINT)  # the second floor's image is written, its YAML not yet

    monkeypatch.setattr(rundir, "write_atomic", write)
    argv = ["maps", "generate", "--kind", "rooms", "--count", "5", "--seed", "7", "--out", str(tmp_path / "f")]
    assert main(argv) == 130
    assert "wrote 2 of the 5 rooms floors" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == [
        "rooms-0000007.pgm", "rooms-0000007.yaml", "rooms-0000008.pgm", "rooms-0000008.yaml"]  # fmt: skip


def test_a_map_stopped_between_its_image_and_its_yaml_leaves_neither(tmp_path, monkeypatch, room12):
    from smorphi_rl import rundir
    from smorphi_rl.maps import save_map

    real = rundir.write_atomic

    def write(path, data):
        if path.suffix == ".yaml":
            raise KeyboardInterrupt
        real(path, data)

    monkeypatch.setattr(rundir, "write_atomic", write)
    with pytest.raises(KeyboardInterrupt):
        save_map(room12, tmp_path / "room.yaml")
    assert list(tmp_path.iterdir()) == []


def test_maps_generate_stopped_says_which_floors_it_wrote(tmp_path, capsys, monkeypatch):
    """A Ctrl-C during `maps generate --count 50` said a bare 'interrupted' (40 floors were written, each whole)."""
    from smorphi_rl import floorplans

    real, calls = floorplans.generate_floor, []

    def stopped(kind, seed, *args):
        calls.append(seed)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(kind, seed, *args)

    monkeypatch.setattr(floorplans, "generate_floor", stopped)
    argv = ["maps", "generate", "--kind", "rooms", "--count", "5", "--seed", "7", "--out", str(tmp_path / "f")]
    assert main(argv) == 130
    said = f"smorphi-rl: interrupted: wrote 2 of the 5 rooms floors to {tmp_path / 'f'} (seeds 7-8), each whole\n"
    assert capsys.readouterr().err == said
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == [
        "rooms-0000007.pgm", "rooms-0000007.yaml", "rooms-0000008.pgm", "rooms-0000008.yaml"]  # fmt: skip


def test_a_command_started_with_ctrl_c_ignored_takes_it_as_a_stop_before_it_loads(installed, monkeypatch):
    """A script's `cmd &` starts it with SIGINT ignored: it was honoured only once the CLI had loaded, so a Ctrl-C in
    its first 0.3 s was lost and the command ran to its end."""
    import signal

    from smorphi_rl import cli, entry, interrupts

    seen = []
    monkeypatch.setattr(cli, "main", lambda: seen.append(signal.getsignal(signal.SIGINT)) or 0)  # as the CLI starts
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        assert entry.main() == 0
    finally:
        signal.signal(signal.SIGINT, previous)
    assert seen == [interrupts.interrupt]


def test_a_stop_that_waited_through_a_command_to_its_end_exits_as_stopped(installed, monkeypatch, capsys):
    """A stop that came inside llvmlite (numba loading a kernel) waits to be raised; if the command ends first, it
    still exits 130 rather than 0, and nothing is raised in Python's teardown."""
    from conftest import stop_inside_llvmlite

    from smorphi_rl import cli, entry

    def command() -> int:
        stop_inside_llvmlite()  # returns: the stop waits
        return 0

    monkeypatch.setattr(cli, "main", command)
    assert entry.main() == 130
    assert capsys.readouterr().err == "smorphi-rl: interrupted\n"


def test_an_angles_file_stopped_midway_ends_between_chunks_with_its_rows_whole(tmp_path, capsys, monkeypatch):
    """A Ctrl-C raised as the compiled planner loaded or a kernel returned crashed the process (a segmentation
    fault): a stop now waits for the chunk under way."""
    import signal

    from smorphi_rl.cli import evaluate as evaluate_cli

    monkeypatch.setattr(evaluate_cli, "FILE_CHUNK", 10)
    angles = tmp_path / "angles.csv"
    angles.write_text("\n".join(f"{i},{i},{i}" for i in range(35)) + "\n")
    from smorphi_rl.planning import Evaluator

    real = Evaluator.evaluate_many

    def scored(self, thetas):
        if thetas[0][0] == 10.0:  # the second chunk: the stop comes as its kernel runs
            signal.raise_signal(signal.SIGINT)
        return real(self, thetas)

    monkeypatch.setattr(Evaluator, "evaluate_many", scored)
    code, out, err = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(angles))
    assert code == 130 and err.strip().splitlines()[-1] == (
        "smorphi-rl: interrupted: after 20 of 35 shapes, whose rows are written whole"
    )
    assert len(out.strip().splitlines()) == 1 + 20  # the header and two whole chunks


def test_output_into_a_closed_pipe_exits_0_without_a_word():
    """`smorphi-rl ... | head` closed early: Python's own last flush failed, "Exception ignored ... BrokenPipeError"
    and exit 120."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # buffered, as a pipe's output is
        argv = [sys.executable, "-m", "smorphi_rl.cli", "evaluate", "--map", MAP_1, "--angles", "1", "2", "3"]
        ran = subprocess.run(argv, stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120, env=env)
    finally:
        os.close(write_end)
    assert (ran.returncode, ran.stderr) == (0, "")

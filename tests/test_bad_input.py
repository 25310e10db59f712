"""The reliability battery: each bad input gets one line naming it and a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.cli import main

ROOT = Path(__file__).resolve().parents[1]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def run(capsys, *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def one_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_angles_file_with_a_byte_order_mark_keeps_its_first_row(tmp_path, capsys):
    f = tmp_path / "bom.csv"
    f.write_bytes(b"\xef\xbb\xbf10,20,30\n40,50,60\n")
    code, out, _ = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f))
    assert code == 0 and out.splitlines()[1].startswith("10,20,30,") and len(out.splitlines()) == 3


def test_angles_file_names_the_file_and_line(tmp_path, capsys):
    f = tmp_path / "bad.csv"
    f.write_text("t1,t2,t3\n10,20,30\n\n40,500,60\n")
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f))
    assert code == 1 and one_line(err).endswith(f"{f} line 4: hinge angle t2=500 is outside [0, 180] degrees")


@pytest.mark.parametrize(
    ("block", "status", "message"),
    [
        ("0.01", 1, "smaller than one cell"),
        ("inf", 2, "finite number"),
        ("1000", 1, "spans 10,000 cells"),
        ("1e300", 1, "a block of 1e+300 m spans 1e+301 cells of this map (0.1 m); at most 400"),
    ],  # not 302 digits
)
def test_block_sizes_the_map_cannot_hold(capsys, block, status, message):
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles", "10", "20", "30", "--block-side", block)
    assert code == status and message in one_line(err)


def test_a_resolution_yaml_reads_as_text_is_still_a_number(tmp_path, capsys):
    text = Path(MAP_1).read_text().replace("resolution: 0.1", "resolution: 1e-9")
    image = Path(MAP_1).with_suffix(".pgm")
    (tmp_path / "m.yaml").write_text(text.replace("image: map-1.pgm", f"image: {image}"))
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "10", "20", "30")
    assert code == 1 and "'resolution' must be 0.001-10 m a cell, got 1e-09" in one_line(err)  # read as a number


@pytest.mark.parametrize("width", ["100000", "1e308"])  # 1e308 / 0.1 m overflowed to an OverflowError
def test_a_generated_map_too_large_is_refused(tmp_path, capsys, width):
    code, _, err = run(capsys, "maps", "generate", "--out", str(tmp_path / "big.yaml"), "--width-m", width)
    assert code == 1 and "generate at most" in one_line(err) and not list(tmp_path.iterdir())


@pytest.mark.parametrize("command", [("search", "random"), ("evaluate-policy", "--checkpoint", "x")])
def test_negative_seeds_are_usage_errors(capsys, command):
    code, _, err = run(capsys, *command, "--seed", "-1")
    assert code == 2 and "expected a non-negative integer, got -1" in err and "Traceback" not in err


def test_replay_of_a_folder_without_a_readable_recording_fails(tmp_path, capsys):
    (tmp_path / "x.mcap").write_text("not mcap")
    code, _, err = run(capsys, "replay", str(tmp_path))
    assert code == 1 and "none of its 1 *.mcap files is a readable recording" in one_line(err)


def test_compare_on_a_cut_short_result_says_so(tmp_path, capsys):
    log = tmp_path / "logs"
    assert run(capsys, "search", "random", "--map", MAP_1, "--samples", "50", "--log-dir", str(log))[0] == 0
    (result,) = log.glob("*/results.npz")
    result.write_bytes(result.read_bytes()[:100])
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(result.parent), "--log-dir", str(log))
    assert code == 1 and "holds no readable search results" in one_line(err)


BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\nc: [*b, *b, *b, *b, *b]\n"


def test_yaml_aliases_are_refused_in_a_map_and_a_sweep_file(tmp_path, capsys):
    (tmp_path / "m.yaml").write_text(Path(MAP_1).read_text().replace("image: map-1.pgm", f"image: {MAP_1[:-5]}.pgm")
                                     + BOMB)  # fmt: skip
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "aliases (*name) are not allowed" in one_line(err)
    (tmp_path / "s.yaml").write_text(f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\nenv: {{x: *q}}\n" + BOMB)
    code, _, err = run(capsys, "sweep", str(tmp_path / "s.yaml"), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "not valid YAML" in one_line(err) and not (tmp_path / "logs").exists()


@pytest.mark.parametrize("nested", ["[" * 20_000 + "]" * 20_000, "{a: " * 5_000 + "1" + "}" * 5_000])
def test_yaml_nested_past_the_limit_is_refused_in_a_map_and_a_sweep_file(tmp_path, capsys, nested):
    """Deep nesting was a RecursionError traceback of thousands of lines."""
    (tmp_path / "m.yaml").write_text(Path(MAP_1).read_text().replace("image: map-1.pgm", f"image: {MAP_1[:-5]}.pgm")
                                     + f"extra: {nested}\n")  # fmt: skip
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "nested more than 64 levels deep" in one_line(err)
    (tmp_path / "s.yaml").write_text(f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\nenv: {nested}\n")
    code, _, err = run(capsys, "sweep", str(tmp_path / "s.yaml"), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "nested more than 64 levels deep" in one_line(err) and not (tmp_path / "logs").exists()


@pytest.mark.parametrize("field", ["resolution", "seeds", "timesteps", "env w1", "search lr", "sexagesimal"])
def test_an_integer_of_thousands_of_digits_is_refused_in_a_map_and_a_sweep_file(tmp_path, capsys, field):
    """PyYAML reads 0x and 5,000 digits (Python limits only decimal ones), and each message that showed the value
    raised ValueError: a traceback. A sexagesimal one is built in time growing with the square of its length."""
    huge = "1" + ":0" * 160_000 if field == "sexagesimal" else "0x" + "f" * 5_000  # 2 s to build, growing as n^2
    text = Path(MAP_1).read_text().replace("image: map-1.pgm", f"image: {MAP_1[:-5]}.pgm")
    if field in ("resolution", "sexagesimal"):
        (tmp_path / "m.yaml").write_text(re.sub(r"resolution: .*", f"resolution: {huge}", text))
        code, _, err = run(capsys, "maps", "show", str(tmp_path / "m.yaml"))
    else:
        items = {
            "seeds": f"seeds: [{huge}]",
            "timesteps": f"seeds: [0]\ntimesteps: {huge}",
            "env w1": f"seeds: [0]\nenv: {{w1: {huge}}}",
            "search lr": f"seeds: [0]\nsearch: {{lr: {huge}}}",
        }
        (tmp_path / "s.yaml").write_text(f"algorithms: [ppo]\nmaps: [{MAP_1}]\n{items[field]}\n")
        code, _, err = run(capsys, "sweep", str(tmp_path / "s.yaml"), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "an integer of over 3,000 digits" in one_line(err) and "Traceback" not in err
    assert not (tmp_path / "logs").exists()


def test_a_duplicate_key_in_a_map_yaml_is_refused(tmp_path, capsys):
    text = Path(MAP_1).read_text().replace("image: map-1.pgm", f"image: {MAP_1[:-5]}.pgm")
    (tmp_path / "m.yaml").write_text(text + "resolution: 0.2\n")
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "duplicate key 'resolution'" in one_line(err)


def test_an_image_too_large_is_refused_before_it_is_decoded(tmp_path, capsys):
    from PIL import Image

    Image.new("L", (6000, 6000), 254).save(tmp_path / "big.png")
    (tmp_path / "big.yaml").write_text("image: big.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
                                       "occupied_thresh: 0.65\nfree_thresh: 0.196\n")  # fmt: skip
    for argv in (["evaluate", "--map", str(tmp_path / "big.yaml"), "--angles", "1", "2", "3"],
                 ["maps", "show", str(tmp_path / "big.yaml"), "--png", str(tmp_path / "x.png")]):  # fmt: skip
        code, _, err = run(capsys, *argv)
        assert code == 1 and "at most 25,000,000 pixels" in one_line(err)


def test_files_are_read_only_under_the_names_of_their_kind(tmp_path, capsys):
    """A map image must be named as an image and a recording as one, whatever their bytes hold."""
    import shutil

    shutil.copy(Path(MAP_1).with_suffix(".pgm"), tmp_path / "map.txt")
    (tmp_path / "m.yaml").write_text(Path(MAP_1).read_text().replace("image: map-1.pgm", "image: map.txt"))
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "'image' 'map.txt' is not an image file name" in one_line(err)
    (tmp_path / "episode.txt").write_bytes(b"\x89MCAP0\r\n" + bytes(64))
    code, _, err = run(capsys, "replay", str(tmp_path / "episode.txt"))
    assert code == 1 and "not a recording's name" in one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["episode.txt", "m.yaml", "map.txt"]


@pytest.mark.parametrize(("origin", "message"), [
    ("[.nan, 0, 0]", "three finite numbers"),
    ("[.inf, 0, 0]", "three finite numbers"),
    ("[18446744073709551616, 0, 0]", "x and y must lie within 1,000,000 m"),  # plots and plans degenerated
    ("[0, -1.0e+17, 0]", "x and y must lie within 1,000,000 m"),
])  # fmt: skip
def test_a_map_origin_must_be_finite_and_near(tmp_path, capsys, origin, message):
    text = Path(MAP_1).read_text().replace("image: map-1.pgm", f"image: {MAP_1[:-5]}.pgm")
    text = "\n".join(line for line in text.splitlines() if not line.startswith("origin"))
    (tmp_path / "m.yaml").write_text(text + f"\norigin: {origin}\n")
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and message in one_line(err)


@pytest.mark.parametrize("argv", [
    ["search", "random", "--start-xy", "nan", "0"],
    ["compare", "--start-xy", "inf", "1"],
    ["maps", "crop", MAP_1, "--out", "x.yaml", "--margin", "inf"],
    ["maps", "resample", MAP_1, "--out", "x.yaml", "--resolution", "nan"],
    ["evaluate", "--angles", "1", "2", "3", "--block-side", "nan"],
])  # fmt: skip
def test_nan_and_infinity_are_usage_errors(capsys, argv):
    code, _, err = run(capsys, *argv)
    assert code == 2 and "expected a finite number" in one_line(err)


@pytest.mark.parametrize("argv", [
    ["evaluate", "--map", MAP_1, "--angles", "1", "2", "3", "--start", "xy:1e308,1e308"],
    ["search", "random", "--map", MAP_1, "--samples", "5", "--start-xy", "1e308", "1e308"],
])  # fmt: skip
def test_a_start_point_too_far_for_an_integer_cell_is_outside_the_map(capsys, tmp_path, argv):
    """1e308 m is an infinite number of cells: it was an OverflowError traceback, -100 m a clean refusal."""
    code, _, err = run(capsys, *argv, *(["--log-dir", str(tmp_path)] if argv[0] == "search" else []))
    assert code == 1 and "lies outside the map" in one_line(err) and not list(tmp_path.iterdir())


@pytest.mark.parametrize("argv", [["train", "--seed", "4294967296"], ["search", "random", "--seed", str(2**64)]])
def test_seeds_beyond_2_32_are_refused(capsys, tmp_path, argv):
    code, _, err = run(capsys, *argv, "--log-dir", str(tmp_path))
    assert code == 2 and "at most 2^32-1" in one_line(err) and not list(tmp_path.iterdir())


def test_a_sweep_seed_beyond_2_32_is_refused(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [4294967296]\n")
    code, _, err = run(capsys, "sweep", str(tmp_path / "s.yaml"), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "seeds[0]" in one_line(err)


@pytest.mark.parametrize(("flag", "value", "message"), [
    ("--plot", "x.txt", "ending in .png"), ("--plot", ".", "ending in .png"),
    ("--plot", "{tmp}/a-file/x.png", "is not a folder this process can write into"),
])  # fmt: skip
def test_plot_paths_are_checked_before_any_work(capsys, tmp_path, flag, value, message):
    (tmp_path / "a-file").write_text("")
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles", "1", "2", "3", flag, value.format(tmp=tmp_path))
    assert code == 1 and message in one_line(err)


def test_a_plot_never_replaces_the_map_it_draws(tmp_path, capsys):
    import shutil

    shutil.copy(MAP_1, tmp_path / "m.yaml")
    shutil.copy(MAP_1[:-5] + ".pgm", tmp_path / "map-1.pgm")
    before = (tmp_path / "map-1.pgm").read_bytes()
    for argv in (["evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3", "--plot"],
                 ["maps", "show", str(tmp_path / "m.yaml"), "--png"]):  # fmt: skip
        target = tmp_path / "map-1.png"
        (tmp_path / "m.yaml").write_text((tmp_path / "m.yaml").read_text().replace("map-1.pgm", "map-1.png"))
        shutil.copy(tmp_path / "map-1.pgm", target)
        code, _, err = run(capsys, *argv, str(target))
        assert code == 1 and "is one of this command's inputs" in one_line(err)
    assert (tmp_path / "map-1.pgm").read_bytes() == before


def test_replay_gif_under_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "x.mcap").write_text("not mcap")
    code, _, err = run(capsys, "replay", str(tmp_path / "x.mcap"), "--gif", str(tmp_path / "x.mcap" / "y.gif"))
    assert code == 1 and "is not a folder this process can write into" in one_line(err)


def test_a_log_dir_that_is_a_symlink_loop_is_one_line(tmp_path, capsys):
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    code, _, err = run(capsys, "search", "random", "--map", MAP_1, "--samples", "5", "--log-dir", str(loop / "x"))
    assert code == 1 and "cannot be used" in one_line(err)


@pytest.mark.parametrize(("argv", "message"), [
    (["search", "random", "--samples", "1000000000"], "would score 1,000,000,000 shapes; at most 50,000,000"),
    (["search", "nsga2", "--pop", "100000", "--generations", "1000"], "would score 100,000,000 shapes"),
    (["search", "hillclimb", "--budget", "1000000000000"], "at most 50,000,000"),
    (["search", "exhaustive", "--step", "0.25"], "would score 374,805,361 shapes"),
    (["search", "exhaustive", "--step", "1e-300"], "would score over 10^906 shapes"),  # not a 906-digit count
    (["search", "exhaustive", "--step", "5e-324"], "does not divide 180"),  # 180 / step overflowed
    (["search", "hillclimb", "--budget", "9" * 4290], "would score over 10^4291 shapes"),  # past str()'s digits
    (["evaluate-policy", "--checkpoint", ".", "--episodes", str(10**20)], "--episodes must be in 1..10,000"),
    (["evaluate-policy", "--checkpoint", ".", "--seed", "4294967294", "--episodes", "3"], "passes 2^32-1"),
    (["train", "--eval-starts", "1000000"], "--eval-starts must be at most 1,000"),
    (["train", "--envs-per-runner", "1000000"], "--envs-per-runner must be at most 1,024"),
    (["train", "--timesteps", str(10**14)], "at most 1,000,000,000"),
    (["design", "--budget", "10000000"], "in 1..100,000"),
])  # fmt: skip
def test_budgets_beyond_reason_are_refused_before_any_work(capsys, tmp_path, argv, message):
    code, _, err = run(capsys, *argv, "--log-dir", str(tmp_path))
    assert code == 1 and message in one_line(err) and not list(tmp_path.iterdir())


@pytest.mark.parametrize(("damage", "message"), [
    (lambda run: (run / "summary.json").write_text("[1, 2]"), "expected a JSON object"),
    (lambda run: (run / "summary.json").write_text('{"method": 3, "map": "map-1", "evaluations": 50, "wall_s": 1}'),
     "summary 'method' is 3"),
    (lambda run: _rewrite(run, P_c=np.full(50, np.nan)), "not finite numbers"),
    (lambda run: _rewrite(run, P_len=np.zeros(7)), "mismatched shapes"),
    (lambda run: _rewrite(run, thetas=np.full((50, 3), 200.0)), "out of range"),
    (lambda run: _rewrite(run, P_len=np.full(50, 2**31 - 1)), "out of range (path lengths 0..250,000,000"),
    (lambda run: _rewrite(run, feasible=np.zeros(50, dtype=bool)), "holds no feasible shape among its 50"),
    (lambda run: _rewrite(run, thetas=np.zeros((0, 3)), P_c=np.zeros(0), P_len=np.zeros(0), feasible=np.zeros(0)),
     "no shapes"),
    (lambda run: (run / "summary.json").write_text("[" * 100_000 + "]" * 100_000), "RecursionError"),
    (lambda run: _resummarise(run, evaluations=10**400), "out of range"),
    (lambda run: _repack(run, zipfile.ZIP_BZIP2), "packed otherwise than `save` packs them"),  # 2.7 KB -> 2.5 GB
    (lambda run: _resummarise(run, rows=10**12), "more than its summary's 1000000000000 shapes hold"),
    (lambda run: _huge_header(run), "P_c.npy declares 1,000,000,000,000 values for 50 shapes"),
])  # fmt: skip
def test_compare_refuses_damaged_search_results(tmp_path, capsys, damage, message):
    log = tmp_path / "logs"
    assert run(capsys, "search", "random", "--map", MAP_1, "--samples", "50", "--log-dir", str(log))[0] == 0
    (result,) = log.glob("*/results.npz")
    damage(result.parent)
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(result.parent), "--log-dir", str(log),
                       "--name", "cmp")  # fmt: skip
    assert code == 1 and message in one_line(err)
    assert not (log / "cmp").exists()  # refused before its folder was made


def _resummarise(run_dir: Path, **fields) -> None:
    import json

    summary = json.loads((run_dir / "summary.json").read_text())
    (run_dir / "summary.json").write_text(json.dumps(summary | fields))


def _repack(run_dir: Path, compression: int) -> None:
    with zipfile.ZipFile(run_dir / "results.npz") as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(run_dir / "results.npz", "w", compression=compression) as archive:
        for name, data in entries.items():
            archive.writestr(name, data)


def _huge_header(run_dir: Path) -> None:
    """P_c's header declares 10^12 rows over its 50 (the archive's sizes stay honest)."""
    with zipfile.ZipFile(run_dir / "results.npz") as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    entries["P_c.npy"] = entries["P_c.npy"].replace(b"(50,)", b"(1000000000000,)")
    with zipfile.ZipFile(run_dir / "results.npz", "w") as archive:
        for name, data in entries.items():
            archive.writestr(name, data)


def _rewrite(run_dir: Path, **arrays) -> None:
    import numpy as np

    with np.load(run_dir / "results.npz") as data:
        kept = {k: data[k] for k in data.files}
    np.savez(run_dir / "results.npz", **(kept | arrays))


@pytest.mark.parametrize("argv", [
    ["maps", "generate", "--kind", "rooms", "--count", "3", "--out", "{disk}/floors"],
    ["maps", "generate", "--width-m", "20", "--height-m", "20", "--out", "{disk}/m.yaml"],
    ["maps", "crop", MAP_1, "--out", "{disk}/m.yaml"],
    ["maps", "show", MAP_1, "--png", "{disk}/m.png"],
    ["evaluate", "--map", MAP_1, "--angles", "1", "2", "3", "--plot", "{disk}/m.png"],
    ["search", "random", "--map", MAP_1, "--samples", "5", "--log-dir", "{disk}/runs"],
    ["evaluate-policy", "--checkpoint", str(ROOT / "smorphi_rl" / "policies" / "designer"), "--map", MAP_1,
     "--episodes", "2", "--record", "{disk}/rec"],
])  # fmt: skip
def test_a_full_disk_is_one_line_naming_the_file_and_leaves_nothing_half_made(small_disk, capsys, argv):
    from conftest import fill_disk

    fill_disk(small_disk, 0)
    code, _, err = run(capsys, *(a.format(disk=small_disk) for a in argv))
    line = one_line(err)
    assert code == 1 and line.startswith("smorphi-rl: error: No space left on device: ") and str(small_disk) in line
    assert sorted(p.name for p in small_disk.rglob("*") if p.is_file()) == ["filler"]


@pytest.mark.parametrize("left", [4096, 12288, 24576])
def test_a_search_the_disk_cuts_short_leaves_a_whole_run_or_none(small_disk, capsys, left):
    """Out of room part-way (its results, its summary, its plot): either no folder and the name free, or the run whole
    and said so (a folder without summary.json once kept the name, and `compare` refused it)."""
    from conftest import fill_disk

    fill_disk(small_disk, left)
    code, _, err = run(capsys, "search", "random", "--map", MAP_1, "--samples", "5", "--log-dir", str(small_disk))
    line, run_dir = one_line(err), small_disk / "random-map-1-seed0"
    assert code == 1 and line.startswith("smorphi-rl: error: No space left on device: ")
    if run_dir.exists():
        assert (run_dir / "summary.json").is_file() and "the search's results are whole in" in line
    (small_disk / "filler").unlink()
    assert run(capsys, "search", "random", "--map", MAP_1, "--samples", "5", "--log-dir", str(small_disk),
               *(["--name", "again"] if run_dir.exists() else []))[0] == 0  # fmt: skip


@pytest.mark.parametrize("cut", [OSError(28, "No space left on device", "pareto.png"), KeyboardInterrupt()])
def test_a_search_whose_plot_cannot_be_written_keeps_its_whole_run_and_says_so(tmp_path, capsys, monkeypatch, cut):
    """A full disk, or a Ctrl-C as the plot is drawn (it said a bare 'interrupted', the run kept unsaid)."""
    import smorphi_rl.plots

    def stopped(*_: object, **__: object) -> None:
        raise cut

    monkeypatch.setattr(smorphi_rl.plots, "plot_pareto", stopped)
    code, _, err = run(capsys, "search", "random", "--map", MAP_1, "--samples", "5", "--log-dir", str(tmp_path))
    run_dir = tmp_path / "random-map-1-seed0"
    assert code == (130 if isinstance(cut, KeyboardInterrupt) else 1)
    assert "the search's results are whole in" in one_line(err) and str(run_dir) in one_line(err)
    assert (run_dir / "summary.json").is_file() and (run_dir / "results.npz").is_file()


@pytest.mark.parametrize("argv", [
    ["evaluate", "--map", MAP_1, "--angles", "90", "90", "90", "--plot", "{loop}.png"],
    ["maps", "show", MAP_1, "--png", "{loop}.png"],
    ["maps", "resample", MAP_1, "--resolution", "0.2", "--out", "{loop}.yaml"],
    ["design", "--map", MAP_1, "--plot", "{loop}.png"],
])  # fmt: skip
def test_an_output_path_in_a_symlink_loop_is_one_line(tmp_path, capsys, argv):
    for suffix in (".png", ".yaml"):
        (tmp_path / f"a{suffix}").symlink_to(tmp_path / f"b{suffix}")
        (tmp_path / f"b{suffix}").symlink_to(tmp_path / f"a{suffix}")
    code, _, err = run(capsys, *(a.format(loop=tmp_path / "a") for a in argv))
    assert code == 1 and "cannot be resolved" in one_line(err)


def test_an_image_header_beyond_pillows_own_limit_is_one_line(tmp_path, capsys):
    (tmp_path / "huge.pgm").write_bytes(b"P5 100000 100000 255\n")
    (tmp_path / "huge.yaml").write_text("image: huge.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
                                        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")  # fmt: skip
    for argv in (["evaluate", "--map", str(tmp_path / "huge.yaml"), "--angles", "1", "2", "3"],
                 ["maps", "show", str(tmp_path / "huge.yaml")]):  # fmt: skip
        code, _, err = run(capsys, *argv)
        assert code == 1 and "far more than 25,000,000 pixels" in one_line(err)


def test_an_image_pillow_warns_about_is_refused_in_our_line_alone(tmp_path, capsys):
    """Between 89 and 179 million pixels Pillow prints its own two-line warning before our refusal."""
    import warnings

    (tmp_path / "big.pgm").write_bytes(b"P5 10000 10000 255\n")
    (tmp_path / "big.yaml").write_text(
        "image: big.pgm\nresolution: 0.05\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning the command lets through fails it
        code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "big.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and err.count("\n") == 1 and "a 10,000 x 10,000 image" in err, err


@pytest.mark.parametrize(("argv", "message"), [
    (["maps", "resample", MAP_1, "--resolution", "1e30", "--out", "{tmp}/r.yaml"], "a cell larger than map map-1"),
    (["maps", "generate", "--kind", "rooms", "--count", "2", "--seed", "4294967295", "--out", "{tmp}/k"],
     "passes 2^32-1"),
    (["maps", "generate", "--kind", "hall", "--out", "{tmp}/k", "--density", "0.5"], "--density: options of the rect"),
    (["search", "random", "--w2", "-1"], "--w2 must be in [0, 1e+06]"),
    (["search", "random", "--w1", "1e300"], "--w1 must be in (0, 1e+06]"),
    (["search", "random", "--log-dir", ""], "expected a name, got an empty string"),
    (["search", "random", "--name", ""], "expected a name, got an empty string"),
    (["search", "random", "--log-dir", "/dev/full"], "log directory /dev/full is not a folder"),
    (["evaluate", "--angles", "1", "2", "3", "--start", "tile:-1,-1"], "tile indices count from 0"),
    (["evaluate-policy", "--checkpoint", "{tmp}", "--starts", "2", "--episodes", "2"], "give one"),
    (["evaluate-policy", "--checkpoint", "{tmp}", "--starts", "2", "--plot", "{tmp}/p.png"], "prints its table only"),
    (["evaluate-policy", "--checkpoint", "{tmp}", "--starts", "2", "--record", "{tmp}/r"], "prints its table only"),
    (["evaluate-policy", "--checkpoint", str(ROOT / "smorphi_rl" / "policies" / "designer"), "--starts", "2",
      "--log-dir", "{tmp}/logs"], "trained on generated floors only (generate:mixed:0-900000), which have no exact"),
    (["train", "--address", "ray://127.0.0.1:1"], "under Ray Client (ray://) Tune would run on the cluster's head"),
    (["sweep", str(ROOT / "tune_configs" / "hparams.yaml"), "--address", "ray://127.0.0.1:1"], "give the cluster's"),
    (["search", "random", "--address", "ray://127.0.0.1:1"], "cannot reach a Ray cluster at ray://127.0.0.1:1"),
    (["search", "random", "--address", "http://127.0.0.1:1"], "--address must be HOST:PORT, 'auto' or ray://"),
    (["train", "--address", "grpc://127.0.0.1:1"], "--address must be HOST:PORT, 'auto' or ray://"),
    (["train", "--map", "{tmp}/none/*.yaml"], "map glob '{tmp}/none/*.yaml' matches no map YAML"),
    (["evaluate", "--angles-file", ""], "argument --angles-file: expected a value, got an empty string"),
    (["evaluate", "--angles", "1", "2", "3", "--start", ""], "argument --start: expected a value, got an empty"),
    (["evaluate", "--angles", "1", "2", "3", "--plot", ""], "argument --plot: expected a value, got an empty"),
    (["maps", "generate", "--out", "/dev/full/x.yaml"], "cannot write /dev/full/x.yaml: /dev/full is not a folder"),
    (["maps", "generate", "--out", "/dev/full/x.yaml", "--force"], "/dev/full is not a folder"),
    (["maps", "generate", "--out", "{tmp}/m.yaml", "--count", "3"], "--count: writes a set of --kind floor plans"),
    (["maps", "crop", MAP_1, "--out", "{tmp}/c.yaml", "--rect", "0", "0", "1", "1", "--margin", "0.5"],
     "--margin: applies to a crop to the known area"),
    (["search", "nsga2", "--pop", "100000000"], "(a smaller --pop or fewer --generations)"),
    (["search", "random", "--samples", "60000000"], "(fewer --samples)"),
])  # fmt: skip
def test_nonsense_is_refused_in_one_line(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)  # a default folder (`logs`) a refused command wrote would be under tmp_path too
    code, _, err = run(capsys, *(a.format(tmp=tmp_path) for a in argv))
    assert code in (1, 2) and message.format(tmp=tmp_path) in one_line(err)
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]


def _found_csv(run_dir: Path, rows: str) -> Path:
    run_dir.mkdir()
    (run_dir / "summary.json").write_text('{"env_steps": 10}')
    (run_dir / "morphologies.csv").write_bytes(rows.encode() if isinstance(rows, str) else rows)
    return run_dir


HEADER = "algorithm,map,theta1,theta2,theta3,P_c,P_len,R1,first_seen_env_steps,variants\n"


@pytest.mark.parametrize(("rows", "message"), [
    ("\x80\x81 not text", "not a readable table"),
    ("a,b\n1,2\n", "line 2: not a row smorphi-rl writes (KeyError"),
    (HEADER + "ppo,map-1,1,2,3,90,nan,80,1,1\n", "line 2: not a row smorphi-rl writes (ValueError"),
    (HEADER + "ppo,map-1,999,-5,125,150,-3,80,1,1\n", "line 2: values out of range"),
])  # fmt: skip
def test_compare_refuses_a_damaged_training_table(tmp_path, capsys, rows, message):
    run_dir = _found_csv(tmp_path / "run", rows)
    if rows.startswith("\x80"):
        (run_dir / "morphologies.csv").write_bytes(b"\x80\x81 not text")
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--runs", str(run_dir), "--step", "30",
                       "--log-dir", str(tmp_path / "logs"))  # fmt: skip
    assert code == 1 and message in one_line(err) and not (tmp_path / "logs").exists()


def test_compare_refuses_an_exact_front_of_another_planner(tmp_path, capsys):
    assert run(capsys, "search", "exhaustive", "--step", "30", "--planner", "fit", "--name", "e",
               "--log-dir", str(tmp_path))[0] == 0  # fmt: skip
    assert run(capsys, "search", "random", "--samples", "20", "--name", "r", "--log-dir", str(tmp_path))[0] == 0
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(tmp_path / "r"), "--exhaustive",
                       str(tmp_path / "e"), "--log-dir", str(tmp_path))  # fmt: skip
    assert code == 1 and "the runs were scored by different planners" in one_line(err)  # no --planner fixes it
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(tmp_path / "r"), "--exhaustive",
                       str(tmp_path / "r"), "--log-dir", str(tmp_path))  # fmt: skip
    assert code == 1 and "a `search random` run, not an exact front" in one_line(err)
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(tmp_path / "r"), "--exhaustive",
                       str(tmp_path / "e"), "--step", "10", "--planner", "fit", "--log-dir", str(tmp_path))  # fmt: skip
    assert code == 1 and "--step: the exact front is computed here only without --exhaustive" in one_line(err)
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(tmp_path / "r"), "--exhaustive",
                       str(tmp_path / "e"), "--step", "1", "--planner", "fit", "--log-dir", str(tmp_path))  # fmt: skip
    assert code == 1 and "--step: the exact front is computed here only" in one_line(err)  # even the default's value
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(tmp_path / "r"), "--runs",
                       str(tmp_path / "r"), "--log-dir", str(tmp_path))  # fmt: skip
    assert code == 1 and "is given twice" in one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e", "r"]  # nothing claimed by the refused compares


def test_compare_refuses_a_summary_whose_evaluation_is_not_numbers(tmp_path, capsys):
    import json

    run_dir = _found_csv(tmp_path / "run", HEADER + "ppo,map-1,1,2,3,90,60,84,1,1\n")
    (run_dir / "summary.json").write_text(json.dumps({"env_steps": 10, "evaluation": {"map-1": {"median_gap": "big"}}}))
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--runs", str(run_dir), "--log-dir", str(tmp_path / "l"))
    assert code == 1 and "its evaluation on 'map-1' is not what smorphi-rl writes" in one_line(err)
    assert not (tmp_path / "l").exists()


@pytest.mark.parametrize("argv", [
    ["export-policy", "--checkpoint", str(ROOT / "smorphi_rl" / "policies" / "designer"), "--out", ""],
    ["evaluate-policy", "--checkpoint", str(ROOT / "smorphi_rl" / "policies" / "designer"), "--record", ""],
])  # fmt: skip
def test_an_empty_output_folder_is_refused(argv, capsys):
    code, _, err = run(capsys, *argv)
    assert code == 2 and "expected a name, got an empty string" in one_line(err)


def test_two_forced_writers_of_one_map_never_mix_their_files(tmp_path, capsys):
    (tmp_path / ".m.yaml.lock").write_text("")  # another `maps generate --force` is writing m.yaml
    code, _, err = run(capsys, "maps", "generate", "--out", str(tmp_path / "m.yaml"), "--force")
    assert code == 1 and "is being written by another process" in one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".m.yaml.lock"]


def test_a_map_narrower_than_one_block_is_refused_where_shapes_are_planned(tmp_path, capsys):
    (tmp_path / "one.pgm").write_bytes(b"P5 1 1 255\n\xfe")
    (tmp_path / "one.yaml").write_text("image: one.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
                                       "occupied_thresh: 0.65\nfree_thresh: 0.196\n")  # fmt: skip
    for argv in (
        ["search", "random", "--samples", "5", "--log-dir", str(tmp_path / "logs")],
        ["design"],
        ["evaluate", "--angles", "1", "2", "3"],
    ):
        code, _, err = run(capsys, *argv, "--map", str(tmp_path / "one.yaml"))
        assert code == 1 and "is narrower than one block (0.17 m)" in one_line(err)
    assert not (tmp_path / "logs").exists()


def test_crop_names_the_file_that_is_in_the_way(tmp_path, capsys):
    (tmp_path / "c.pgm").write_bytes(b"not ours")
    code, _, err = run(capsys, "maps", "crop", MAP_1, "--out", str(tmp_path / "c.yaml"))
    assert code == 1 and f"{tmp_path / 'c.pgm'} exists; pass --force" in one_line(err)
    assert (tmp_path / "c.pgm").read_bytes() == b"not ours"


def test_an_angles_file_whose_first_row_holds_a_nan_names_that_row(tmp_path, capsys):
    (tmp_path / "a.csv").write_text("90,90,nan\n")
    code, _, err = run(capsys, "evaluate", "--angles-file", str(tmp_path / "a.csv"))
    assert code == 1 and "line 1: expected three numbers" in one_line(err)


def test_a_designer_whose_limits_are_not_numbers_is_refused(tmp_path, capsys):
    import json
    import shutil

    policy = tmp_path / "designer"
    shutil.copytree(ROOT / "smorphi_rl" / "policies" / "designer", policy)
    meta = json.loads((policy / "policy.json").read_text())
    (policy / "policy.json").write_text(json.dumps(meta | {"accepts": {"max_side_m": "x"}}))
    code, _, err = run(capsys, "design", "--policy", str(policy), "--budget", "20")
    assert code == 1 and "'accepts' must map" in one_line(err)


def test_an_exact_front_whose_step_was_edited_is_refused(tmp_path, capsys):
    import json

    assert run(capsys, "search", "exhaustive", "--step", "30", "--name", "e", "--log-dir", str(tmp_path))[0] == 0
    summary = tmp_path / "e" / "summary.json"
    doc = json.loads(summary.read_text())
    doc["params"]["step_deg"] = 7
    summary.write_text(json.dumps(doc))
    code, _, err = run(capsys, "compare", "--map", MAP_1, "--random", str(tmp_path / "e"), "--exhaustive",
                       str(tmp_path / "e"), "--log-dir", str(tmp_path))  # fmt: skip
    assert code == 1 and "whose step 7 does not divide 180" in one_line(err)


def test_a_sweep_whose_trials_need_more_cpus_than_there_are_is_refused_before_ray(tmp_path, capsys):
    sweep = tmp_path / "wide.yaml"
    sweep.write_text(f"name: wide\nalgorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\ntimesteps: 2000\n"
                     "env_runners: 1000\n")  # fmt: skip
    code, _, err = run(capsys, "sweep", str(sweep), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "1,000 env runners need 501 CPUs" in one_line(err)
    assert f"set fewer `env_runners` in {sweep}" in err  # the file's key, not a flag the sweep has not
    assert not (tmp_path / "logs").exists()


def test_a_sweep_whose_evaluation_map_cannot_be_read_leaves_no_folder(tmp_path, capsys):
    """The evaluated maps are read (and their optima computed) before the experiment's folder is made, so the same
    command runs again once the map is mended, with no --resume."""
    (tmp_path / "broken.yaml").write_text(
        "image: missing.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"name: s\nalgorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\ntimesteps: 2000\n"
                     "evaluation: {maps: [broken.yaml]}\n")  # fmt: skip
    code, _, err = run(capsys, "sweep", str(sweep), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "missing.pgm" in one_line(err)
    assert not (tmp_path / "logs" / "s").exists()


def test_a_crop_that_holds_no_robot_is_refused(tmp_path, capsys):
    code, _, err = run(capsys, "maps", "crop", MAP_1, "--rect", "1", "1", "1.05", "1.05", "--out",
                       str(tmp_path / "c.yaml"))  # fmt: skip
    assert code == 1 and "nothing written, the crop holds no robot of 0.17 m blocks" in one_line(err)
    assert not list(tmp_path.iterdir())


def test_a_crop_margin_beyond_the_map_is_refused(tmp_path, capsys):
    code, _, err = run(capsys, "maps", "crop", MAP_1, "--margin", "1e20", "--out", str(tmp_path / "c.yaml"))
    assert code == 1 and "beyond the map's own" in one_line(err)
    assert not list(tmp_path.iterdir())


def test_an_angles_file_that_never_ends_is_refused_before_reading(tmp_path, capsys):
    import os

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # nobody writes to it: reading would block for ever
    for path in ("/dev/zero", str(fifo), str(tmp_path)):
        code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", path)
        assert code == 1 and "not a regular file" in one_line(err)


@pytest.mark.parametrize("row", ["ab,", "12,"])
def test_an_angles_file_of_one_endless_line_is_refused_by_its_length(tmp_path, capsys, row):
    """A 2 MB line was split whole to look for a header and shown whole in its refusal (a 100 MB file: 3 GB and a
    100 MB line on the terminal)."""
    f = tmp_path / "long.csv"
    f.write_text("10,20,30\n" + row * 700_000 + "1\n")
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f))
    assert code == 1 and one_line(err).endswith(f"{f} line 2: 2,100,001 characters, where a row of three angles "
                                                 "t1,t2,t3 takes a few dozen (at most 1,000)")  # fmt: skip
    f.write_text("10,20,30\n" + "x" * 900 + ",1,2\n")
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles-file", str(f))
    assert code == 1 and "line 2: expected three numbers t1,t2,t3, got 'xxx" in one_line(err)
    assert len(one_line(err)) < len(str(f)) + 200


def test_a_start_tile_beyond_the_map_is_one_line(capsys):
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles", "95", "59", "103",
                       "--start", "tile:9999999999999999999,0")  # fmt: skip
    assert code == 1 and "tile indices outside the map" in one_line(err)


def test_a_map_coarser_than_a_block_is_written_with_a_warning_naming_the_fix(tmp_path, capsys):
    code, _, err = run(capsys, "maps", "resample", MAP_1, "--resolution", "0.2", "--out", str(tmp_path / "r.yaml"))
    assert code == 0 and "block is smaller than one cell" in one_line(err) and "--block-side" in err
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "r.yaml"), "--angles", "95", "59", "103",
                       "--block-side", "0.2")  # fmt: skip
    assert code == 0, err


def _pgm_map(tmp_path: Path, name: str, free: np.ndarray) -> str:
    """A map YAML at 0.1 m whose free cells are `free` (True), the rest occupied."""
    h, w = free.shape
    pixels = np.where(free[::-1], 254, 0).astype(np.uint8)  # the image's top row is the map's highest y
    (tmp_path / f"{name}.pgm").write_bytes(f"P5 {w} {h} 255\n".encode() + pixels.tobytes())
    (tmp_path / f"{name}.yaml").write_text(f"image: {name}.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
                                           "occupied_thresh: 0.65\nfree_thresh: 0.196\n")  # fmt: skip
    return str(tmp_path / f"{name}.yaml")


@pytest.mark.parametrize("free_cells", [[(25, 25)], [(25, 25), (25, 26), (26, 25), (26, 26)]])
def test_a_floor_smaller_than_the_robot_is_refused_where_shapes_are_planned(tmp_path, capsys, free_cells):
    free = np.zeros((50, 50), dtype=bool)
    for cell in free_cells:
        free[cell] = True
    map_yaml = _pgm_map(tmp_path, "speck", free)
    for argv in (
        ["search", "random", "--samples", "5", "--log-dir", str(tmp_path / "logs")],
        ["train", "--log-dir", str(tmp_path / "logs")],
        ["design"],
        ["evaluate", "--angles", "1", "2", "3"],
    ):
        code, _, err = run(capsys, *argv, "--map", map_yaml)
        assert code == 1 and "fewer than the robot's smallest footprint (the O, 3 x 3 cells)" in one_line(err), err
    assert not (tmp_path / "logs").exists()


def test_a_floor_that_holds_neither_the_o_nor_the_i_is_refused_by_the_fit_planner(tmp_path, capsys):
    """The paper's planner lets the robot stand over obstacles (its golden corridor is one cell wide); the fit
    planner places F only on free cells, so it needs somewhere the O or the I fits."""
    free = np.zeros((50, 50), dtype=bool)
    free[10:12, 10:40] = True  # a strip of 2 x 30 cells cut every 6 cells: no I (2 x 7), no O (3 x 3)
    free[10:12, 16:40:6] = False
    map_yaml = _pgm_map(tmp_path, "strip", free)
    for argv in (
        ["search", "random", "--samples", "5", "--log-dir", str(tmp_path / "logs")],
        ["evaluate", "--angles", "0", "180", "0"],
    ):
        code, _, err = run(capsys, *argv, "--planner", "fit", "--map", map_yaml)
        assert code == 1 and "O, 3 x 3 cells, nor its I, 2 x 7 either way" in one_line(err), err
    assert not (tmp_path / "logs").exists()
    code, out, _ = run(capsys, "evaluate", "--angles", "0", "0", "0", "--map", map_yaml)  # the paper planner plans it
    assert code == 0 and "P_c" in out


def test_inputs_that_never_end_are_refused_before_reading(tmp_path, capsys):
    """A FIFO nobody writes to (or a device) as a map YAML, a map image, a sweep file or a recording: reading it
    would block for ever."""
    import os

    fifo, recording, fifo_yaml = tmp_path / "fifo.pgm", tmp_path / "r.mcap", tmp_path / "fifo.yaml"
    for path in (fifo, recording, fifo_yaml):
        os.mkfifo(path)
    (tmp_path / "m.yaml").write_text(
        "image: fifo.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    cases = [
        (["evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3"], "map image"),
        (["evaluate", "--map", str(fifo), "--angles", "1", "2", "3"], "is an image"),  # named by its suffix first
        (["evaluate", "--map", "/dev/zero", "--angles", "1", "2", "3"], "map YAML /dev/zero is not a regular file"),
        # commands that keep their outputs off their inputs, which they read first
        (["evaluate", "--map", str(fifo_yaml), "--angles", "1", "2", "3", "--plot", str(tmp_path / "p.png")], "FIFO"),
        (["maps", "crop", str(fifo_yaml), "--out", str(tmp_path / "c.yaml")], "map YAML"),
        (["maps", "show", str(fifo_yaml), "--png", str(tmp_path / "s.png")], "map YAML"),
        (["sweep", "/dev/zero", "--log-dir", str(tmp_path / "logs")], "sweep file /dev/zero is not a regular file"),
        (["replay", str(recording)], "recording " + str(recording) + " is not a regular file"),
    ]
    for argv, message in cases:
        code, _, err = run(capsys, *argv)
        assert code != 0 and message in one_line(err), (argv, err)
    assert not (tmp_path / "logs").exists()


def test_a_pgm_sample_above_its_maxval_is_refused(tmp_path, capsys):
    """Pillow reads such a file without a word: 254 under maxval 100 came out as free floor."""
    for name, header, body in (("p5", b"P5\n# a comment\n50 50\n100\n", bytes([254]) * 2500),
                               ("p2", b"P2\n2 2\n100\n0 200\n100 100\n", b"")):  # fmt: skip
        (tmp_path / f"{name}.pgm").write_bytes(header + body)
        (tmp_path / f"{name}.yaml").write_text(
            f"image: {name}.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
        )
        code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / f"{name}.yaml"), "--angles", "1", "2", "3")
        assert code == 1 and "above the PGM's maxval 100 (a corrupt image)" in one_line(err), err
    (tmp_path / "ok.pgm").write_bytes(b"P5 50 50 100\n" + bytes([100]) * 2500)  # maxval 100 within range: a map
    (tmp_path / "ok.yaml").write_text(
        "image: ok.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    code, out, err = run(capsys, "evaluate", "--map", str(tmp_path / "ok.yaml"), "--angles", "95", "59", "103")
    assert code == 0 and "free 100.0 %" in out, err


def test_a_damaged_map_image_is_one_line_whatever_pillow_raises(tmp_path, capsys):
    """A PNG whose chunk types are damaged raised Pillow's SyntaxError, and a PGM side of 5,000 digits Python's
    ValueError (no `int` of over 4,300 digits): both came out as tracebacks."""
    import io

    from PIL import Image

    cells = np.asarray(Image.open(ROOT / "maps" / "map-1.pgm"))
    png = io.BytesIO()
    Image.fromarray(cells).save(png, format="PNG")
    damaged = bytearray(png.getvalue())
    for at, value in ((135, 189), (139, 183), (150, 92), (175, 136)):  # inside the image data and its chunk types
        damaged[at] = value
    (tmp_path / "png.png").write_bytes(bytes(damaged))
    (tmp_path / "pgm.pgm").write_bytes(b"P5\n" + b"9" * 5000 + b" 50\n255\n" + cells.tobytes())
    for name in ("png", "pgm"):
        (tmp_path / f"{name}.yaml").write_text(
            f"image: {name}.{name}\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
        )
        code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / f"{name}.yaml"), "--angles", "1", "2", "3")
        assert code == 1 and f"{name}.{name}: not a readable PGM/PNG image" in one_line(err), err


def test_a_map_that_is_a_symlink_loop_is_one_line_for_the_training_jobs(tmp_path, capsys):
    """`train` resolves its maps itself (map_sources): the loop came out as `RuntimeError: Symlink loop`."""
    loop = tmp_path / "loop.yaml"
    loop.symlink_to(loop)
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder" / "x.yaml").symlink_to("x.yaml")
    for entry in (loop, tmp_path / "folder", tmp_path / "folder" / "*.yaml"):
        code, _, err = run(capsys, "train", "--map", str(entry), "--timesteps", "100", "--log-dir", str(tmp_path / "l"))
        assert code == 1 and "cannot be resolved" in one_line(err), err
    assert not (tmp_path / "l").exists()


def test_a_name_that_would_drive_the_terminal_is_printed_escaped(tmp_path, capsys):
    """A map named `x<ESC>]0;title<BEL>...`: its name in a result set the terminal's title and colours."""
    import shutil

    name = "x\x1b]0;pwned\x07\x1b[31mRED\x9b0m"
    shutil.copy(ROOT / "maps" / "map-1.pgm", tmp_path / "map-1.pgm")
    shutil.copy(ROOT / "maps" / "map-1.yaml", tmp_path / f"{name}.yaml")
    code, out, err = run(capsys, "evaluate", "--map", str(tmp_path / f"{name}.yaml"), "--angles", "1", "2", "3")
    assert code == 0 and "x\\x1b]0;pwned\\x07\\x1b[31mRED\\x9b0m" in out, out
    assert not any(c in out + err for c in "\x1b\x07\x9b")
    code, out, err = run(capsys, "design", "--map", str(tmp_path / f"{name}.yaml"), "--json")
    assert code == 0 and json.loads(out)["map"] == name  # JSON escapes it itself: unchanged, still JSON


def test_an_error_naming_a_path_with_a_newline_stays_one_line(capsys):
    code, _, err = run(capsys, "evaluate", "--map", "/no/such\nmap.yaml", "--angles", "1", "2", "3")
    assert code == 1 and "map file not found: /no/such\\nmap.yaml" in one_line(err)


def test_numbers_too_large_for_a_float_are_one_line(tmp_path, capsys):
    """YAML and JSON read 10^400 as an integer, which `math.isfinite` cannot take."""
    image = Path(MAP_1).with_suffix(".pgm")
    (tmp_path / "m.yaml").write_text(f"image: {image}\nresolution: 0.1\norigin: [{10**400}, 0, 0]\n")
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "'origin' must be three finite numbers" in one_line(err)
    (tmp_path / "r.yaml").write_text(
        f"image: {image}\nresolution: {10**400}\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "r.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "'resolution' must be a number" in one_line(err)


def test_a_crop_whose_islands_dropped_leave_no_robot_is_refused(tmp_path, capsys):
    free = np.zeros((50, 50), dtype=bool)
    for r in range(5, 45, 4):
        for c in range(5, 45, 4):
            free[r : r + 2, c : c + 2] = True  # 100 islands of 2 x 2 cells: 400 free cells, no island holds the O
    map_yaml = _pgm_map(tmp_path, "specks", free)
    argv = ["maps", "crop", map_yaml, "--out", str(tmp_path / "out" / "c.yaml"), "--min-island", "1"]
    code, _, err = run(capsys, *argv)
    assert code == 1 and "nothing written, the crop holds no robot" in one_line(err)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["design", "evaluate-policy"])
def test_a_log_dir_that_is_a_file_is_named_by_every_command_that_caches_optima(capsys, monkeypatch, tmp_path, command):
    monkeypatch.delenv("SMORPHI_RL_CACHE_DIR")  # exact optima are cached under --log-dir
    blocker = tmp_path / "table.csv"
    blocker.write_text("keep me")
    designer = str(ROOT / "smorphi_rl" / "policies" / "designer")
    argv = (["design", "--map", MAP_1, "--exact"] if command == "design" else
            ["evaluate-policy", "--checkpoint", designer, "--map", MAP_1, "--starts", "2"])  # fmt: skip
    code, _, err = run(capsys, *argv, "--log-dir", str(blocker))
    assert code == 1 and f"log directory {blocker} is not a folder" in one_line(err)
    assert blocker.read_text() == "keep me"


def test_yaml_that_pyyaml_reads_as_python_errors_is_one_line(tmp_path, capsys):
    """A mapping as a key and an integer of 5,000 digits are valid YAML that PyYAML raises on as TypeError and
    ValueError; a NUL byte in `image:` is a name no file can have."""
    cases = {"key.yaml": "? {a: 1}\n: 1\n", "digits.yaml": f"image: m.pgm\nresolution: {'9' * 5000}\n"}
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / name), "--angles", "1", "2", "3")
        assert code == 1 and "malformed YAML" in one_line(err), err
        code, _, err = run(capsys, "sweep", str(tmp_path / name), "--log-dir", str(tmp_path / "logs"))
        assert code == 1 and "not valid YAML" in one_line(err), err
    (tmp_path / "nul.yaml").write_text(
        'image: "a\\0b.pgm"\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n'
    )
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "nul.yaml"), "--angles", "1", "2", "3")
    assert code == 1 and "a\\x00b.pgm holds a NUL byte" in one_line(err), err
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "--map", MAP_1, "--angles", "95", "59", "103", "--plot", "{out}"],
        ["design", "--map", MAP_1, "--budget", "10", "--plot", "{out}"],
        ["maps", "show", MAP_1, "--png", "{out}"],
    ],
    ids=["evaluate", "design", "maps show"],
)
def test_an_output_file_that_exists_is_replaced_only_with_force(tmp_path, capsys, argv):
    """`--plot other-map.png` once replaced another map's image, and then the map read as another floor."""
    out = tmp_path / "taken.png"
    out.write_bytes(b"someone's image")
    argv = [a.replace("{out}", str(out)) for a in argv]
    code, _, err = run(capsys, *argv)
    assert code == 1 and f"{out} exists; pass --force to overwrite it" in one_line(err), err
    assert out.read_bytes() == b"someone's image"
    code, _, err = run(capsys, *argv, "--force")
    assert code == 0 and out.read_bytes()[:4] == b"\x89PNG", err


def test_a_plain_pgm_with_a_stray_token_is_judged_as_before(tmp_path, capsys):
    """A plain (P2) PGM's samples are parsed by numpy, which since 2.3 raises at a token that is no number: a
    damaged sample or a file cut short is one line, bytes after the raster are left alone (as Pillow does)."""
    cases = {"bad": (b"P2\n2 2\n255\n254 x\n254 254\n", "not a readable PGM/PNG image"),
             "cut": (b"P2\n2 2\n255\n254 254\n254\n", "not a readable PGM/PNG image"),
             "trail": (b"P2\n2 2\n255\n254 254\n254 254\n\x00junk", None)}  # fmt: skip
    for name, (data, message) in cases.items():
        (tmp_path / f"{name}.pgm").write_bytes(data)
        (tmp_path / f"{name}.yaml").write_text(
            f"image: {name}.pgm\nresolution: 0.5\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
        )
        code, out, err = run(capsys, "maps", "show", str(tmp_path / f"{name}.yaml"), "--png", str(tmp_path / "d.png"),
                             "--force")  # fmt: skip
        if message is None:
            assert code == 0 and "2 x 2 cells" in out, err
        else:
            assert code == 1 and err.count("\n") == 1 and message in err, err


def test_a_sweep_or_a_transfer_resume_whose_ray_cannot_start_leaves_nothing_behind(tmp_path, monkeypatch, capsys):
    """Ray failing to start (a temp folder under /proc) left the sweep's folder, so the same command, once Ray could
    start, was refused as a name taken; a transfer --resume recorded the seed it added, so the next --resume
    without it was refused as leaving out a seed the job had never run."""
    import json

    from smorphi_rl.training.transfer import JOB_FILE

    config = tmp_path / "s.yaml"
    config.write_text(f"name: rayfail\nalgorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\ntimesteps: 2000\n")
    monkeypatch.setenv("RAY_TMPDIR", "/proc/nope")
    code, _, err = run(capsys, "sweep", str(config), "--log-dir", str(tmp_path / "logs"))
    assert code == 1 and "cannot start or reach a local Ray" in err and not (tmp_path / "logs" / "rayfail").exists()
    job = tmp_path / "logs" / "job"
    job.mkdir()
    designer, val_1 = ROOT / "smorphi_rl" / "policies" / "designer", str(ROOT / "maps" / "val-1.yaml")
    recorded = json.dumps({"pretrained": str(designer), "maps": [val_1], "seeds": [0]})
    (job / JOB_FILE).write_text(recorded)
    code, _, err = run(capsys, "transfer", "--pretrained", str(designer), "--maps", val_1, "--seeds", "0", "7",
                       "--timesteps", "2000", "--name", "job", "--log-dir", str(tmp_path / "logs"),
                       "--resume")  # fmt: skip
    assert code == 1 and "cannot start or reach a local Ray" in err, err
    assert (job / JOB_FILE).read_text() == recorded

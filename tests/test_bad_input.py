"""The reliability battery: each bad input gets one line naming it and a non-zero exit, never a traceback."""

from __future__ import annotations

from pathlib import Path

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
    ("block", "message"), [("0.01", "smaller than one cell"), ("inf", "finite number"), ("1000", "at most 400")]
)
def test_block_sizes_the_map_cannot_hold(capsys, block, message):
    code, _, err = run(capsys, "evaluate", "--map", MAP_1, "--angles", "10", "20", "30", "--block-side", block)
    assert code == 1 and message in one_line(err)


def test_a_resolution_yaml_reads_as_text_is_still_a_number(tmp_path, capsys):
    text = Path(MAP_1).read_text().replace("resolution: 0.1", "resolution: 1e-9")
    image = Path(MAP_1).with_suffix(".pgm")
    (tmp_path / "m.yaml").write_text(text.replace("image: map-1.pgm", f"image: {image}"))
    code, _, err = run(capsys, "evaluate", "--map", str(tmp_path / "m.yaml"), "--angles", "10", "20", "30")
    assert code == 1 and "spans" in one_line(err)  # a block of 0.17 m is far too many cells of 1e-9 m


def test_a_generated_map_too_large_is_refused(tmp_path, capsys):
    code, _, err = run(capsys, "maps", "generate", "--out", str(tmp_path / "big.yaml"), "--width-m", "100000")
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

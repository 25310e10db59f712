"""Every hint the tool prints runs as printed: the flag or command it names, added as told, succeeds.

The job commands' hints (`sweep ... --resume` after Ctrl-C, `smorphi-rl replay ...` after `train`) are run
as printed by the sweep and train tests."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def smorphi(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "smorphi_rl.cli", *argv], capture_output=True, text=True, cwd=cwd,
                          timeout=300)  # fmt: skip


def hinted(err: str, hint: str) -> list[str]:
    """`hint` (a flag and its value, as the one-line error or warning in `err` prints it), as arguments."""
    assert re.search(rf"(pass|choose another|; ) ?{re.escape(hint)}\b", err), err
    return hint.split()


def test_pass_force_overwrites(tmp_path):
    argv = ["maps", "generate", "--kind", "rooms", "--count", "2", "--out", "floors"]
    assert smorphi(*argv, cwd=tmp_path).returncode == 0
    again = smorphi(*argv, cwd=tmp_path)
    assert again.returncode == 1 and hinted(again.stderr, "--force")
    assert smorphi(*argv, "--force", cwd=tmp_path).returncode == 0


def test_choose_another_name(tmp_path):
    argv = ["search", "random", "--map", MAP_1, "--samples", "20", "--name", "a"]
    assert smorphi(*argv, cwd=tmp_path).returncode == 0
    again = smorphi(*argv, cwd=tmp_path)
    assert again.returncode == 1 and hinted(again.stderr, "--name")
    assert smorphi(*argv, "--name", "b", cwd=tmp_path).returncode == 0


def test_pass_the_planner_a_run_was_made_with(tmp_path):
    assert smorphi("search", "random", "--map", MAP_1, "--samples", "20", "--planner", "fit", "--name", "r",
                   cwd=tmp_path).returncode == 0  # fmt: skip
    argv = ["compare", "--map", MAP_1, "--random", "logs/r", "--step", "30"]
    refused = smorphi(*argv, cwd=tmp_path)
    assert refused.returncode == 1
    flag = hinted(refused.stderr, "--planner fit")
    done = smorphi(*argv, *flag, cwd=tmp_path)
    assert done.returncode == 0, done.stderr


def test_the_degenerate_weights_warning_names_the_option_that_fixes_them(tmp_path):
    assert smorphi("maps", "generate", "--width-m", "30", "--height-m", "30", "--out", "big.yaml",
                   cwd=tmp_path).returncode == 0  # fmt: skip
    argv = ["search", "random", "--map", "big.yaml", "--samples", "20"]
    warned = smorphi(*argv, "--name", "moves", cwd=tmp_path)
    assert warned.returncode == 0 and "warning:" in warned.stderr
    flag = hinted(warned.stderr, "--path-term per_area")
    fixed = smorphi(*argv, "--name", "per-area", *flag, cwd=tmp_path)
    assert fixed.returncode == 0 and "warning" not in fixed.stderr


def test_a_progress_line_of_two_passes_names_each(capsys):
    """A count that goes back down starts the next pass under its own label, with its own clock."""
    from smorphi_rl.cli.common import progress_line

    show = progress_line(("x: keyed", "x: settled"))
    show(10, 10)
    show(3, 10)
    show(10, 10)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("x: keyed [") and lines[0].count("#") == 30
    assert all(line.startswith("x: settled [") for line in lines[1:]) and len(lines) == 3


def test_the_time_left_leaves_out_the_wait_for_the_first_count(capsys, monkeypatch):
    """The first count of `search optimum` comes after the planner compiles (about 35 s): at the rate from the
    start it read "about 34 min more" for a search that had seconds left."""
    from smorphi_rl.cli import common

    clock = iter([0.0, 35.0, 41.0])
    monkeypatch.setattr(common.time, "monotonic", lambda: next(clock))
    show = common.progress_line("x")
    show(100_000, 6_000_000)  # 35 s to the first count: compiling
    show(3_100_000, 6_000_000)  # 3,000,000 in 6 s: 2,900,000 left in about 6 s
    err = capsys.readouterr().err
    assert "min more" not in err
    assert err.splitlines()[-1].endswith(" 500,000/s, 6 s left")  # the rate the time left is read from


def test_a_long_time_left_is_said_once_with_the_hint(capsys, monkeypatch):
    from smorphi_rl.cli import common

    clock = iter([0.0, 1.0, 5.0, 9.0])
    monkeypatch.setattr(common.time, "monotonic", lambda: next(clock))
    show = common.progress_line("x", hint="a coarser --step")
    for done in (10, 20, 30):  # 10 shapes in 4 s: a million takes days
        show(done, 1_000_000)
    warned = [line for line in capsys.readouterr().err.splitlines() if "min more" in line]
    assert warned == ["x: about 6667 min more at this rate; a coarser --step"]

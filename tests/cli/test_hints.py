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

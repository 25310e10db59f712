"""Every script under scripts/ starts: its imports resolve against the package and `--help` prints its usage
(a benchmark is run by hand, rarely, so a renamed function would otherwise surface only there)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


@pytest.mark.parametrize("script", sorted(p.name for p in SCRIPTS.glob("*.py") if not p.name.startswith("_")))
def test_the_script_starts_and_prints_its_usage(script):
    proc = subprocess.run([sys.executable, str(SCRIPTS / script), "--help"], capture_output=True, text=True,
                          timeout=120, cwd=SCRIPTS.parent)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "usage:" in proc.stdout


@pytest.mark.parametrize(("argv", "message"), [
    (["--set", "min_time_s_per_iteration=0.4"], "bench_learning.py: error: unknown hyperparameter"),
    (["--maps", "map-1"], "bench_learning.py: error: map file not found: map-1"),  # its folder was written first
])  # fmt: skip
def test_a_bad_setting_given_to_a_benchmark_is_one_line_and_writes_nothing(argv, message, tmp_path):
    proc = subprocess.run([sys.executable, str(SCRIPTS / "bench_learning.py"), "--algos", "appo", "--no-ideal",
                           "--log-dir", str(tmp_path / "logs"), "--out", "refused", *argv], capture_output=True,
                          text=True, timeout=120, cwd=SCRIPTS.parent)  # fmt: skip
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1].startswith(message)
    assert not (tmp_path / "logs").exists()


def test_a_sweep_benchmark_of_a_missing_file_is_one_line(tmp_path):
    argv = [sys.executable, str(SCRIPTS / "bench_sweeps.py"), "no-such-sweep.yaml", "--keep", str(tmp_path / "kept")]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120, cwd=SCRIPTS.parent)
    configs = SCRIPTS.parent / "tune_configs"
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == (
        f"bench_sweeps.py: error: no sweep file {configs / 'no-such-sweep.yaml'} (the shipped ones are in {configs})"
    )
    assert not (tmp_path / "kept").exists()

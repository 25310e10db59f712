"""Benchmark the shipped sweeps: run `smorphi-rl sweep tune_configs/FILE.yaml` as a user does, time it end to end,
and print its table over seeds (medians with 95 % bootstrap intervals) and its best trials.

Target (issue 32): `paper-ppo-vs-impala.yaml` finishes within 60 minutes on 2 cores. Yardstick, measured in the
same run: the trials' own training time (the sum of their iterations' times, from their results), so the ratio
says how much of the wall time the sweep spends around its trials (Ray, the exact optima, evaluation, files).

    .venv/bin/python scripts/bench_sweeps.py [FILE.yaml ...] [--keep DIR] [--write-docs]

Without files: `paper-ppo-vs-impala.yaml` and `pretrain-multimap.yaml` (about 8 minutes on 2 cores); name
`hparams.yaml` (about 20 minutes) or `designer.yaml` (hours) to run them too. Figures are printed whatever they are.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _benchdocs import run_documented

from smorphi_rl.errors import SmorphiError
from smorphi_rl.training.sweep_config import load_sweep
from smorphi_rl.training.sweep_report import read_sweep, sweep_group_lines

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "tune_configs"
DEFAULT = ("paper-ppo-vs-impala.yaml", "pretrain-multimap.yaml")
TARGET_MIN = 60.0
"""Issue 32: `sweep tune_configs/paper-ppo-vs-impala.yaml` within 60 minutes on 2 cores."""


def _minutes(seconds: float) -> str:
    return f"{int(seconds // 60)} min {seconds % 60:04.1f} s"


def bench(path: Path, root: Path) -> None:
    """Run one sweep file through the public command under `root`; print its time and its table over seeds."""
    sweep = load_sweep(path)
    t0 = time.perf_counter()
    # the sweep's progress display goes to the terminal (stderr); its end-of-sweep summary is read from stdout
    proc = subprocess.run([sys.executable, "-m", "smorphi_rl.cli", "sweep", str(path), "--log-dir", str(root)],
                          cwd=ROOT, stdout=subprocess.PIPE, text=True)  # fmt: skip
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SmorphiError(f"{path.name}: `smorphi-rl sweep` exited {proc.returncode} after {_minutes(wall)}")
    rows = read_sweep(root / sweep.name)
    trained = sum(r.wall_s for r in rows)
    finished = sum(r.finished for r in rows)
    algos = ", ".join(a.upper() for a in sweep.algorithms)
    maps = "; ".join(" + ".join(Path(m).stem for m in ms) for ms in sweep.map_sets)
    seeds = " ".join(map(str, sweep.seeds))
    target = f" (target {TARGET_MIN:.0f} min: {'met' if wall <= TARGET_MIN * 60 else 'missed'})"
    print(f"{path.name}: {finished} of {len(sweep.trials())} trials finished ({algos} on {maps}; seeds {seeds}; "
          f"{sweep.timesteps:,} env steps each) in {_minutes(wall)} end to end"
          f"{target if path.name == DEFAULT[0] else ''}; the trials' own training {_minutes(trained)} = "
          f"{trained / wall:.2f} of it")  # fmt: skip
    print("\n".join(sweep_group_lines(rows)[2:]))
    best = [line for line in proc.stdout.splitlines() if line.startswith("  ")]
    if best:
        print("best trials (best R1 any episode visited):")
        print("\n".join(best))
    print(f"trials: {root / sweep.name}")
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", default=list(DEFAULT), help="sweep files, by name in tune_configs/")
    parser.add_argument("--keep", help="write the sweeps here (a new or empty folder) instead of a temporary one")
    args = parser.parse_args()
    paths = [(p if p.exists() else CONFIGS / p.name).resolve() for p in map(Path, args.files)]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise SmorphiError(f"no sweep file {missing[0]} (the shipped ones are in {CONFIGS})")
    root = Path(args.keep).resolve() if args.keep else Path(tempfile.mkdtemp(prefix="bench-sweeps-"))
    if root.exists() and any(root.iterdir()):
        raise SmorphiError(f"--keep {root} is not empty: give a new or empty folder")
    os.chdir(ROOT)  # the shipped sweep files name their maps from the project's root, as `make` runs them
    t0 = time.perf_counter()
    for path in paths:
        bench(path, root)
    print(f"{len(paths)} sweep(s) in {_minutes(time.perf_counter() - t0)}; experiments under {root}")


if __name__ == "__main__":
    run_documented("sweeps", "The shipped sweeps (`scripts/bench_sweeps.py`)", main)

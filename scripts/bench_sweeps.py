"""Benchmark the shipped sweeps: run `smorphi-rl sweep tune_configs/FILE.yaml` as a user does, time it end to end,
and print its table over seeds (medians with 95 % bootstrap intervals) and its best trials.

Target (issue 32): `paper-ppo-vs-impala.yaml` finishes within 60 minutes on 2 cores. Yardstick, measured in the
same run: the trials' own time (the sum of their iterations as Tune clocks them, building the algorithm,
evaluations and checkpoints included), so the ratio says how much of the wall time falls around the trials (Ray's
start, the exact optima, scheduling, the tables); above 1 where a larger machine runs trials side by side.

    .venv/bin/python scripts/bench_sweeps.py [FILE.yaml ...] [--keep DIR] [--write-docs]

Without files: `paper-ppo-vs-impala.yaml` and `pretrain-multimap.yaml` (about 17 minutes on 2 cores); name
`hparams.yaml` (about 30 minutes more) or `designer.yaml` (hours) to run them too. The experiments stay in a
temporary folder (or `--keep DIR`, a new or empty one), named at the end. Figures are printed whatever they are.
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
from smorphi_rl.progress import fmt_duration
from smorphi_rl.training.sweep_config import SweepConfig, load_sweep
from smorphi_rl.training.sweep_report import read_sweep, sweep_group_lines
from smorphi_rl.words import counted

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "tune_configs"
DEFAULT = ("paper-ppo-vs-impala.yaml", "pretrain-multimap.yaml")
TARGET_MIN = 60.0
"""Issue 32: `sweep tune_configs/paper-ppo-vs-impala.yaml` within 60 minutes on 2 cores."""


def bench(path: Path, sweep: SweepConfig, root: Path) -> None:
    """Run one sweep file through the public command under `root`; print its time and its table over seeds."""
    argv = [sys.executable, "-m", "smorphi_rl.cli", "sweep", str(path), "--log-dir", str(root)]
    t0 = time.perf_counter()
    # the sweep's progress display and its lines on a stop go to the terminal (stderr); its summary is kept
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        out, _ = proc.communicate()
    except KeyboardInterrupt:  # the sweep heard Ctrl-C too: let it stop as it does, keeping what finished
        proc.communicate()
        print(f"bench_sweeps.py: interrupted; the experiment is {root / sweep.name} (the sweep's own line above says "
              "how to resume it); nothing written to docs", file=sys.stderr)  # fmt: skip
        raise SystemExit(130) from None
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.stderr.write(out)
        raise SmorphiError(f"{path.name}: `smorphi-rl sweep` exited {proc.returncode} after {fmt_duration(wall)}")
    rows = read_sweep(root / sweep.name)
    trained = sum(r.wall_s for r in rows)
    finished = sum(r.finished for r in rows)
    algos = ", ".join(a.upper() for a in sweep.algorithms)
    maps = "; ".join(" + ".join(Path(m).stem for m in ms) for ms in sweep.map_sets)
    seeds = " ".join(map(str, sweep.seeds))
    target = f" (target {TARGET_MIN:.0f} min: {'met' if wall <= TARGET_MIN * 60 else 'missed'})"
    print(f"{path.name}: {finished} of {len(sweep.trials())} trials finished ({algos} on {maps}; seeds {seeds}; "
          f"{sweep.timesteps:,} env steps each) in {fmt_duration(wall)} end to end"
          f"{target if path.name == DEFAULT[0] else ''}; the trials' own time {fmt_duration(trained)} = "
          f"{trained / wall:.2f} of it")  # fmt: skip
    print("\n".join(sweep_group_lines(rows)))  # its key first: what "> x" and "inf" mean, and the few-seeds note
    ranked = sorted((r for r in rows if r.best is not None), key=lambda r: -r.best.R1)  # type: ignore[union-attr]
    print("best shape any episode of a trial visited, per trial:")
    for r in ranked:
        assert r.best is not None
        print(f"  {r.algo:<6} {r.maps:<14} seed {r.seed}  R1 {r.best.R1:.2f} {r.best.angles}  "
              f"({r.env_steps:,} steps, {fmt_duration(r.wall_s)})")  # fmt: skip
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
    os.chdir(ROOT)  # the shipped sweep files name their maps from the project's root, as `make` runs them
    sweeps = [load_sweep(p) for p in paths]  # every file checked before the first sweep runs
    names = [s.name for s in sweeps]
    twice = next((n for n in names if names.count(n) > 1), None)
    if twice is not None:
        raise SmorphiError(f"two sweeps are named '{twice}': each runs in its own folder, so give each file once")
    if args.keep:
        root = Path(args.keep).resolve()
        if root.exists() and (not root.is_dir() or any(root.iterdir())):
            raise SmorphiError(f"--keep {args.keep}: not a new or empty folder")
    else:
        root = Path(tempfile.mkdtemp(prefix="bench-sweeps-"))
    t0 = time.perf_counter()
    for path, sweep in zip(paths, sweeps, strict=True):
        bench(path, sweep, root)
    print(f"{counted(len(paths), 'sweep')} in {fmt_duration(time.perf_counter() - t0)}; experiments under {root}")


if __name__ == "__main__":
    run_documented("sweeps", "The shipped sweeps (`scripts/bench_sweeps.py`)", main)

"""Benchmark transfer (the paper's Table 5): pretrain PPO on map-1 and map-2, then on each held-out map
fine-tune from it and train from scratch with the same budget, over several seeds.

Held-out maps: the shipped `val-1..3` and the first `--floors` generated held-out floors of
`maps/designer/held-out` of at most 6,000 cells, 2.4 shipped maps (seeds training never draws). Prints, per
map, env steps to convergence (the README's definition, `smorphi_rl/training/convergence.py`) fine-tuned
and from scratch, median over seeds with a 95 % bootstrap interval (a run that never converged counts as past
its budget), and the ratio of the medians with its interval, or the bound on it where a median lies past the
budget; the scratch runs are the yardstick measured in the same run. Target
(issue 32): fine-tuning converges in at most one fifth of the scratch run's env steps on at least two thirds
of the maps (4 of the default 6). Figures are printed whatever they are.

    .venv/bin/python scripts/bench_transfer.py [--pretrain-steps 200000] [--steps 200000] [--seeds 0 1 2]
        [--floors 3] [--pretrained RUN] [--keep DIR [--resume]] [--write-docs]

`--resume` continues a job kept with `--keep DIR` (an interrupted one, or one whose report should be written
again): its pretraining and every finished run of the same settings are read back, the rest trained.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from _benchdocs import run_documented, whole

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.maps import load_map
from smorphi_rl.rundir import rename_cut_run
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.presets import TRANSFER_TIMESTEPS
from smorphi_rl.training.run import train
from smorphi_rl.training.transfer import (
    SPEEDUP_TARGET,
    TransferJob,
    TransferRun,
    by_map,
    finished_run,
    run_transfer,
    speedup,
    write_transfer_report,
)

MAPS = Path(__file__).resolve().parent.parent / "maps"
HELD_OUT = MAPS / "designer" / "held-out"
TARGET_SHARE = 4 / 6
"""Issue 32: the speed-up on at least 4 of 6 held-out maps."""
MAX_FLOOR_CELLS = 6_000
"""Generated floors up to about twice a shipped map's cells (50 x 50), so a run costs what a shipped map's does."""


def held_out_floors(count: int) -> list[str]:
    """The first `count` generated held-out floors (by seed) with at most MAX_FLOOR_CELLS cells."""
    small = [p for p in sorted(HELD_OUT.glob("*.yaml")) if load_map(p).cells.size <= MAX_FLOOR_CELLS]
    if len(small) < count:
        print(f"only {len(small)} held-out floors have at most {MAX_FLOOR_CELLS:,} cells; using them all")
    return [str(p) for p in small[:count]]


def _steps(runs: list[TransferRun]) -> str:
    """Env steps until each seed's run converged, or that it did not within its budget (never a number then)."""
    return ", ".join("-" if r.converged_at is None else f"{r.converged_at:,.0f}" for r in runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pretrain-steps", type=int, default=TRANSFER_TIMESTEPS)
    parser.add_argument(
        "--steps",
        type=int,
        default=TRANSFER_TIMESTEPS,
        help="budget of every run (transfer's default, which keeps the 36 runs within the hour)",
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--floors", type=int, default=3, help="generated held-out floors beside val-1..3")
    parser.add_argument("--keep", help="write the runs here instead of a temporary directory")
    parser.add_argument("--pretrained", help="reuse this pretrained run (its pretraining figures are not re-measured)")
    parser.add_argument("--resume", action="store_true", help="continue the job kept in --keep DIR")
    args = parser.parse_args()
    if args.resume and not args.keep:
        parser.error("--resume continues a job kept with --keep DIR: give that DIR")
    if args.floors < 0:
        parser.error(f"--floors {args.floors}: at least 0")
    held_out = [str(MAPS / f"val-{i}.yaml") for i in (1, 2, 3)] + held_out_floors(args.floors)
    # the job's own checks (seeds, budget, maps) before the pretraining, not minutes into it
    job = TransferJob(Path(args.pretrained or "pretrain"), tuple(held_out), tuple(args.seeds), args.steps,
                      record_every=0)  # fmt: skip
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-transfer-"))
    t0 = time.perf_counter()
    env = EnvConfig.from_dict({"maps": [str(MAPS / "map-1.yaml"), str(MAPS / "map-2.yaml")]})
    # every run's progress and summary go to stderr (a long job shows where it is); the figures to stdout
    pre_cfg = TrainConfig(env=env, timesteps=args.pretrain_steps, seed=args.seeds[0], record_every=0)
    kept = finished_run(root / "pretrain", pre_cfg) if args.resume and not args.pretrained else None
    if args.resume and not args.pretrained and kept is None and (root / "pretrain").exists():
        print(f"pretraining was cut short: kept as {rename_cut_run(root / 'pretrain')}, trained again")
    if kept is not None:
        pretrained = root / "pretrain"
        print(f"pretrained PPO on map-1 + map-2: {kept['env_steps']:,} env steps in {kept['wall_s']:.0f} s "
              f"(read back from {pretrained})")  # fmt: skip
    elif args.pretrained:
        pretrained = Path(args.pretrained)
        print(f"reusing the pretrained run {pretrained}")
    else:
        pre = whole(train(pre_cfg, name="pretrain", log_dir=root, out=sys.stderr, label="PPO pretrain"))
        pretrained = pre.run_dir
        print(f"pretrained PPO on map-1 + map-2: {pre.env_steps:,} env steps in {pre.wall_s:.0f} s")
    job = replace(job, pretrained=pretrained)
    resume = args.resume and (root / "transfer").exists()  # a job stopped in its pretraining has no runs yet
    job_dir, runs = run_transfer(job, name="transfer", log_dir=root, out=sys.stderr, resume=resume)
    files = write_transfer_report(job_dir, runs)
    print(files["md"].read_text().rstrip())
    meets = firm = 0
    for m in by_map(runs):
        verdict = speedup(m.ratio, "not measured" in m.counts)
        meets, firm = meets + verdict.met, firm + verdict.whole
        print(f"{m.map_name}: env steps to converge, seed by seed: fine-tuned {_steps(m.tuned)}; scratch "
              f"{_steps(m.scratch)}: {verdict.text}; pretrained policy in every runner: "
              f"{all(r.pretrained_in_runners for r in m.tuned)}")  # fmt: skip
    maps = len(dict.fromkeys(r.map_name for r in runs))
    target = math.ceil(TARGET_SHARE * maps)
    reused = sum(r.reused for r in runs)
    trained_min = sum(r.wall_s for r in runs) / 60
    print(f"fine-tuning {SPEEDUP_TARGET:g}x faster on {meets} of {maps} maps by the medians, {firm} by the whole "
          f"interval (target: {target} of {maps}); "
          f"{len(runs)} runs of {args.steps:,} env steps, seeds {' '.join(map(str, args.seeds))}; "
          f"{trained_min:.1f} min of training in the runs"
          f"{f' ({reused} read back from the earlier job)' if reused else ''}; "
          f"this call {(time.perf_counter() - t0) / 60:.1f} min; runs under {root}")  # fmt: skip


if __name__ == "__main__":
    run_documented("transfer", "Transfer (`scripts/bench_transfer.py`)", main)

"""Benchmark transfer (the paper's Table 5): pretrain PPO on map-1 and map-2, then on each validation
map fine-tune from it and train from scratch with the same budget and seed.

Prints env steps to convergence (the README's definition, `smorphi_rl/training/convergence.py`)
for both, and their ratio; the scratch run is the yardstick measured in the same run. Target:
fine-tuning converges in at most one fifth of the scratch run's env steps (the paper: 5 x 10^4
against 2.7 x 10^5). Figures are printed whatever they are.

    .venv/bin/python scripts/bench_transfer.py [--pretrain-steps 100000] [--steps 50000] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from _benchdocs import run_documented

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.run import train
from smorphi_rl.training.transfer import TransferJob, TransferRun, run_transfer, write_transfer_report

MAPS = Path(__file__).resolve().parent.parent / "maps"
TARGET_RATIO = 5.0


def _steps(run: TransferRun) -> str:
    """Env steps until the run converged, or that it did not within its budget (never a number then)."""
    return f"not converged within {run.env_steps:,}" if run.converged_at is None else f"{run.converged_at:,.0f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pretrain-steps", type=int, default=100_000)
    parser.add_argument("--steps", type=int, default=50_000, help="budget of every fine-tune and scratch run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", help="write the runs here instead of a temporary directory")
    parser.add_argument("--pretrained", help="reuse this pretrained run (its pretraining figures are not re-measured)")
    args = parser.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-transfer-"))
    t0 = time.perf_counter()
    env = EnvConfig.from_dict({"maps": [str(MAPS / "map-1.yaml"), str(MAPS / "map-2.yaml")]})
    with open(os.devnull, "w") as quiet:
        if args.pretrained:
            pretrained = Path(args.pretrained)
            print(f"reusing the pretrained run {pretrained}")
        else:
            pre = train(TrainConfig(env=env, timesteps=args.pretrain_steps, seed=args.seed), name="pretrain",
                        log_dir=root, out=quiet)  # fmt: skip
            pretrained = pre.run_dir
            print(f"pretrained PPO on map-1 + map-2: {pre.env_steps:,} env steps in {pre.wall_s:.0f} s")
        vals = [str(MAPS / f"val-{i}.yaml") for i in (1, 2, 3)]
        job = TransferJob(pretrained, tuple(vals), (args.seed,), args.steps)
        job_dir, runs = run_transfer(job, name="transfer", log_dir=root, out=quiet)
    files = write_transfer_report(job_dir, runs)
    print(files["md"].read_text().rstrip())
    for map_name in dict.fromkeys(r.map_name for r in runs):
        tuned = next(r for r in runs if r.map_name == map_name and r.mode == "fine-tune")
        scratch = next(r for r in runs if r.map_name == map_name and r.mode == "scratch")

        if tuned.converged_at is not None and scratch.converged_at is not None:
            ratio = scratch.converged_at / tuned.converged_at if tuned.converged_at else float("inf")
            verdict = f"{ratio:.2f}x ({'meets' if ratio >= TARGET_RATIO else 'misses'} the {TARGET_RATIO:g}x target)"
        elif tuned.converged_at is not None:
            verdict = "no ratio: the scratch run did not converge (only a lower bound, not a measurement)"
        else:
            verdict = "no ratio: the fine-tuned run did not converge"
        print(f"{map_name}: env steps to converge fine-tuned {_steps(tuned)}, scratch {_steps(scratch)}: {verdict}; "
              f"settled R1 plateau {tuned.plateau:.2f} vs {scratch.plateau:.2f}; "
              f"pretrained policy in every runner: {tuned.pretrained_in_runners}")  # fmt: skip
    print(f"total {time.perf_counter() - t0:.0f} s; runs under {root}")


if __name__ == "__main__":
    run_documented("transfer", "Transfer (`scripts/bench_transfer.py`)", main)

"""`train`, `transfer`, `sweep` and `reproduce`: the commands that run Ray."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from smorphi_rl.cli.common import (
    DEFAULT_LOG_DIR,
    DEFAULT_MAP,
    EXIT_INTERRUPTED,
    PROG,
    map_paths,
    planner_option,
    record_option,
    rel,
    run_options,
    seed_arg,
    weight_options,
)
from smorphi_rl.maps import load_map


def register(sub: Any) -> None:
    """Add `train`, `transfer`, `sweep` and `reproduce` to the command line."""
    _register_train(sub)
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.presets import ALGORITHMS, PRESETS

    tf = sub.add_parser("transfer", help="fine-tune vs from scratch on held-out maps (the paper's Table 5)")
    tf.add_argument("--pretrained", required=True, help="checkpoint, trial or run directory of the pretrained policy")
    tf.add_argument("--maps", nargs="+", required=True, help="held-out maps (map_server YAML)")
    tf.add_argument(
        "--seeds", nargs="+", type=seed_arg, default=[0], help="seeds; each map runs once per seed and mode"
    )
    tf.add_argument("--timesteps", type=int, default=TrainConfig.timesteps, help="env-step budget of every run")
    tf.add_argument("--algo", choices=ALGORITHMS, default=TrainConfig.algo)
    tf.add_argument("--preset", choices=tuple(PRESETS), default=TrainConfig.preset)
    tf.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto)")
    run_options(tf, "job name: runs go to LOG_DIR/NAME (default: transfer-TIMESTAMP)")
    record_option(tf)
    tf.set_defaults(func=cmd_transfer)

    sw = sub.add_parser("sweep", help="a Ray Tune sweep from a tune_configs/*.yaml file (resumable)")
    sw.add_argument("config", help="sweep file (schema in the README; examples in tune_configs/)")
    sw.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto)")
    sw.add_argument("--resume", action="store_true", help="continue the interrupted experiment of this sweep")
    sw.add_argument("--log-dir", default=DEFAULT_LOG_DIR, help="the experiment goes to LOG_DIR/<the sweep's name>")
    sw.set_defaults(func=cmd_sweep)

    from smorphi_rl.reproduce import BUDGETS

    rp = sub.add_parser("reproduce", help="the paper's experiments end to end, with a claim-by-claim report")
    rp.add_argument("--budget", choices=tuple(BUDGETS), default="small", help="small (~15 min), paper, tiny (smoke)")
    run_options(rp, "run name (default: reproduce-BUDGET-TIMESTAMP)")
    rp.set_defaults(func=cmd_reproduce)


def _register_train(sub: Any) -> None:
    from smorphi_rl.env import REWARD_MODES
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.presets import ALGORITHMS, PRESETS

    defaults = TrainConfig()
    tr = sub.add_parser("train", help="train PPO / IMPALA / APPO on maps through Ray Tune (the main job)")
    tr.add_argument(
        "--algo", choices=ALGORITHMS, default=defaults.algo, help="algorithm (IMPALA serves the paper's A3C)"
    )
    tr.add_argument(
        "--map", nargs="+", default=None, help=f"map_server YAML(s), one drawn per episode (default: {DEFAULT_MAP})"
    )
    tr.add_argument("--timesteps", type=int, default=defaults.timesteps, help="env steps to train for")
    tr.add_argument("--seed", type=seed_arg, default=defaults.seed)
    tr.add_argument(
        "--preset", choices=tuple(PRESETS), default=defaults.preset, help="fast (2 cores) or paper (Table 1)"
    )
    tr.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto); default: a local Ray")
    run_options(tr, "run name: results go to LOG_DIR/NAME (default: ALGO-MAP-TIMESTAMP)")
    tr.add_argument("--checkpoint-every", type=int, default=defaults.checkpoint_every,
                    help="iterations between checkpoints (and at the end)")  # fmt: skip
    tr.add_argument("--pretrained", help="start from this checkpoint (or trial or run directory): fine-tuning")
    tr.add_argument("--reward", choices=REWARD_MODES, default=None,
                    help="reward mode (ENV.md): peak, level, paper, improvement or commit (default: peak)")  # fmt: skip
    from smorphi_rl.env import EnvConfig

    tr.add_argument("--move-cost", type=float, default=None, metavar="C",
                    help=f"level and peak: what a step that changes the shape costs, so the policy settles "
                         f"(default {EnvConfig.move_cost:g}: off)")  # fmt: skip
    weight_options(tr)
    planner_option(tr, None)
    tr.add_argument("--env-runners", type=int, default=None, metavar="N",
                    help="remote env runners; 0 samples in the trial process (default: the preset's, "
                         "0 for PPO and 2 for IMPALA/APPO on the fast preset)")  # fmt: skip
    for flag, default, text in (
        ("--envs-per-runner", defaults.envs_per_runner, "envs each runner steps together, one forward pass for all"),
        ("--eval-every", defaults.eval_every, "greedy evaluation from fixed starts every N iterations (0: off)"),
        ("--eval-starts", defaults.eval_starts, "fixed seeded start shapes per map in each evaluation"),
    ):
        tr.add_argument(flag, type=int, default=default, metavar="N", help=f"{text}; default {default}")
    record_option(tr)
    tr.set_defaults(func=cmd_train)


def cmd_train(args: argparse.Namespace) -> int:
    """Train PPO, IMPALA or APPO through Ray Tune; print a progress line, then where everything is."""
    from smorphi_rl.env import EnvConfig
    from smorphi_rl.training.config import TrainConfig

    env_options = {"maps": map_paths(args.map), "reward": args.reward, "w1": args.w1, "w2": args.w2,
                   "path_term": args.path_term, "planner": args.planner, "start_xy": args.start_xy,
                   "move_cost": args.move_cost}  # fmt: skip
    cfg = TrainConfig(
        algo=args.algo,
        env=EnvConfig.from_dict({k: v for k, v in env_options.items() if v is not None}),
        timesteps=args.timesteps,
        seed=args.seed,
        preset=args.preset,
        num_env_runners=args.env_runners,
        envs_per_runner=args.envs_per_runner,
        eval_every=args.eval_every,
        eval_starts=args.eval_starts,
        checkpoint_every=args.checkpoint_every,
        pretrained=args.pretrained,
        record_every=args.record_every,
    )
    from smorphi_rl.training.run import format_summary, train

    summary = train(cfg, name=args.name, log_dir=args.log_dir, address=args.address)
    print(format_summary(summary))
    if summary.interrupted:
        print(f"{PROG}: interrupted: checkpoints written so far are kept", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def cmd_transfer(args: argparse.Namespace) -> int:
    """Fine-tune a pretrained policy and train from scratch on each held-out map; the paper's Table 5."""
    from smorphi_rl.training.transfer import TransferJob, run_transfer, write_transfer_report

    # the options and maps are checked before anything runs
    job = TransferJob(args.pretrained, tuple(str(m) for m in args.maps), tuple(args.seeds), args.timesteps,
                      args.algo, args.preset, args.record_every)  # fmt: skip
    for path in args.maps:
        load_map(path)
    name = args.name or f"transfer-{time.strftime('%Y%m%d-%H%M%S')}"
    job_dir, runs = run_transfer(job, name, args.log_dir, args.address)
    files = write_transfer_report(job_dir, runs)
    print(files["md"].read_text().rstrip())
    missing = [r for r in runs if r.mode == "fine-tune" and r.pretrained_in_runners is not True]
    if missing:
        print(f"warning: {len(missing)} fine-tuned run(s) did not confirm the pretrained policy in every env runner")
    print(f"\nruns: {rel(job_dir)}\ntable: {rel(files['md'])} (and {files['csv'].name})\ncurves: {rel(files['png'])}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run or resume a sweep file as one Ray Tune experiment; print the best trials and where the files are."""
    from smorphi_rl.training.sweep_config import load_sweep

    sweep = load_sweep(args.config)  # every problem named before Ray starts
    from smorphi_rl.training.sweep import format_sweep_summary, run_sweep

    summary = run_sweep(sweep, args.log_dir, args.address, args.resume)
    print(format_sweep_summary(summary, rel))
    if summary.interrupted:
        print(f"{PROG}: interrupted: finished trials and checkpoints are kept; continue with "
              f"`{PROG} sweep {args.config} --resume`", file=sys.stderr)  # fmt: skip
        return EXIT_INTERRUPTED
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The paper's experiments end to end; report.md with Tables 2-6 and Figures 5-7 analogues and the claims."""
    from smorphi_rl.reproduce import reproduce

    name = args.name or f"reproduce-{args.budget}-{time.strftime('%Y%m%d-%H%M%S')}"
    report = reproduce(args.budget, name, args.log_dir)
    print(f"report: {rel(report)}")
    return 0

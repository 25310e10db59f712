"""`train`, `transfer`, `sweep` and `reproduce`: the commands that run Ray."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from smorphi_rl import interrupts
from smorphi_rl.cli.common import (
    DEFAULT_LOG_DIR,
    DEFAULT_MAP,
    EXIT_INTERRUPTED,
    PROG,
    Repeated,
    map_paths,
    nonempty,
    planner_option,
    record_option,
    run_options,
    seed_arg,
    weight_options,
)
from smorphi_rl.cli.fields import field_flag, option
from smorphi_rl.config_fields import field_docs
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.maps import load_map
from smorphi_rl.rundir import rel


def held_out_files(entries: list[str]) -> tuple[str, ...]:
    """`transfer --maps`: map files, folders of them and globs, as `train --map` takes them; a generated floor has
    no exact optimum to converge to, so none is held out."""
    from smorphi_rl.map_sources import is_generator, resolve

    generated = [e for e in entries if is_generator(str(e))]
    if generated:
        raise SmorphiError(f"--maps {generated[0]}: a generated floor has no exact optimum to converge to; hold "
                           "out map files, folders or globs")  # fmt: skip
    return resolve([str(e) for e in entries])


def register(sub: Any) -> None:
    """Add `train`, `transfer`, `sweep` and `reproduce` to the command line."""
    _register_train(sub)
    from smorphi_rl.training.presets import ALGORITHMS, PRESETS
    from smorphi_rl.training.transfer import TransferJob

    tf = sub.add_parser("transfer", help="fine-tune vs from scratch on held-out maps (the paper's Table 5)")
    tf.add_argument("--pretrained", required=True, metavar="PATH", help=field_docs(TransferJob)["pretrained"])
    tf.add_argument("--maps", nargs="+", action=Repeated, required=True, metavar="MAP",
                    help=field_docs(TransferJob)["maps"])  # fmt: skip
    option(tf, TransferJob, "seeds", nargs="+", action=Repeated, type=seed_arg, metavar="S")
    option(tf, TransferJob, "timesteps", metavar="N")
    option(tf, TransferJob, "algo", unset=True, choices=ALGORITHMS, default_text="the pretrained policy's, else ppo")
    option(tf, TransferJob, "preset", choices=tuple(PRESETS))
    tf.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto)")
    run_options(tf, "job name: runs go to LOG_DIR/NAME (default: transfer-TIMESTAMP)")
    option(tf, TransferJob, "record_every", metavar="N")
    option(tf, TransferJob, "envs_per_runner", metavar="N")
    option(tf, TransferJob, "num_env_runners", "--env-runners", type=int, metavar="N",
           default_text="the preset's: 2")  # fmt: skip
    tf.add_argument("--resume", action="store_true", help="continue the job --name: its finished runs are read back, "
                    "the others trained (the same options as the job it continues)")  # fmt: skip
    tf.set_defaults(func=cmd_transfer)

    sw = sub.add_parser("sweep", help="a Ray Tune sweep from a tune_configs/*.yaml file (resumable)")
    sw.add_argument("config", help="sweep file (keys in docs/commands.md; examples in tune_configs/)")
    sw.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto)")
    sw.add_argument("--resume", action="store_true", help="continue the interrupted experiment of this sweep")
    sw.add_argument("--log-dir", type=nonempty, default=DEFAULT_LOG_DIR,
                    help=f"the experiment goes to LOG_DIR/<the sweep's name> (default: {DEFAULT_LOG_DIR})")  # fmt: skip
    sw.set_defaults(func=cmd_sweep)

    from smorphi_rl.reproduce import BUDGETS

    rp = sub.add_parser("reproduce", help="the paper's experiments end to end, with a claim-by-claim report")
    rp.add_argument("--budget", choices=tuple(BUDGETS), default="small",
                    help="small (~10 min, the default), paper (hours), tiny (smoke)")  # fmt: skip
    run_options(rp, "run name (default: reproduce-BUDGET-TIMESTAMP)")
    rp.set_defaults(func=cmd_reproduce)


TRAIN_FIELDS = ("algo", "timesteps", "seed", "preset", "checkpoint_every", "pretrained", "num_env_runners",
                "envs_per_runner", "eval_every", "eval_starts", "select_starts", "record_every")  # fmt: skip
"""TrainConfig fields `train` takes as options (the same names, dashed; num_env_runners is --env-runners)."""
ENV_FIELDS = ("reward", "move_cost", "w1", "w2", "path_term", "planner", "start_xy")
"""EnvConfig fields `train` takes as options; not given, they keep the env's (or the pretrained run's) value."""


def _register_train(sub: Any) -> None:
    from smorphi_rl.env_config import REWARD_MODES, EnvConfig
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.presets import ALGORITHMS, PRESETS

    tr = sub.add_parser("train", help="train PPO / IMPALA / APPO on maps through Ray Tune (the main job)")
    tr.add_argument(
        "--map",
        nargs="+",
        action=Repeated,
        default=None,
        help=f"map_server YAML(s), one drawn per episode (default: {DEFAULT_MAP})",
    )
    field_flag("maps", "--map")
    option(tr, TrainConfig, "algo", unset=True, choices=ALGORITHMS, default_text="the pretrained policy's, else ppo")
    option(tr, TrainConfig, "timesteps", metavar="N")
    option(tr, TrainConfig, "seed", type=seed_arg, metavar="S")
    option(tr, TrainConfig, "preset", choices=tuple(PRESETS))
    tr.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto); default: a local Ray")
    run_options(tr, "run name: results go to LOG_DIR/NAME (default: ALGO-MAP-TIMESTAMP)")
    tr.add_argument("--resume", action="store_true", help="continue the run --name that was killed before it "
                    "finished, from its last checkpoint (give the options it ran with)")  # fmt: skip
    option(tr, TrainConfig, "checkpoint_every", metavar="K")
    option(tr, TrainConfig, "pretrained", type=str, metavar="PATH")
    option(tr, EnvConfig, "reward", unset=True, choices=REWARD_MODES)
    option(tr, EnvConfig, "move_cost", unset=True, metavar="C")
    weight_options(tr)
    planner_option(tr, unset=True)
    option(tr, TrainConfig, "num_env_runners", "--env-runners", type=int, metavar="N",
           default_text="the preset's: 2")  # fmt: skip
    for name in ("envs_per_runner", "eval_every", "eval_starts", "select_starts"):
        option(tr, TrainConfig, name, metavar="N")
    option(tr, TrainConfig, "eval_maps", nargs="+", action=Repeated, type=str, metavar="MAP",
           default_text="the --map files")  # fmt: skip
    record_option(tr)
    tr.set_defaults(func=cmd_train)


def cmd_train(args: argparse.Namespace) -> int:
    """Train PPO, IMPALA or APPO through Ray Tune; print a progress line, then where everything is."""
    from smorphi_rl.training.versions import warn_once

    warn_once()
    from smorphi_rl.training.config import TrainConfig, TrainConfigError

    algo, env = train_setup(args)
    trained = {name: getattr(args, "env_runners" if name == "num_env_runners" else name) for name in TRAIN_FIELDS}
    cfg = TrainConfig(env=env, eval_maps=tuple(args.eval_maps or ()), **(trained | {"algo": algo}))
    if cfg.eval_every and not cfg.evaluation_maps:
        raise TrainConfigError(f"the maps are generated ({', '.join(cfg.env.maps)}), so the run has no exact optimum "
                               "to be measured against: name fixed floors with --eval-maps, or --eval-every 0 to "
                               "train without the evaluation protocol")  # fmt: skip
    from smorphi_rl.training.run import format_summary, train

    summary = train(cfg, name=args.name, log_dir=args.log_dir, address=args.address, graceful=True,
                    resume=args.resume)  # fmt: skip
    print(format_summary(summary))
    if summary.interrupted:
        kept = ("it ended early, its final policy checkpointed" if summary.ended_on_request and summary.checkpoint
                else "checkpoints written so far are kept")  # fmt: skip
        print(f"{PROG}: interrupted: {kept}", file=sys.stderr)
        return EXIT_INTERRUPTED
    if summary.stop_held:  # asked as the run was writing its results: they were finished first
        print(f"{PROG}: interrupted as the run ended: its tables and summary.json are whole", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def train_setup(args: argparse.Namespace) -> tuple[str, Any]:
    """The algorithm and env of `train`: the options given, on the --map files (or the default map); every other
    setting the pretrained policy's, when there is one, but its floors and start point (`finetune.MAP_FIELDS`), as
    `transfer` takes them; else the defaults."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.config import TrainConfig

    algo: str | None = None
    env: dict[str, Any] = {}
    if args.pretrained is not None:  # a bad checkpoint is named here, before anything else
        from smorphi_rl.training.finetune import pretrained_setup

        algo, env = pretrained_setup(args.pretrained)
    env |= {name: value for name in ENV_FIELDS if (value := getattr(args, name)) is not None}
    if args.map is not None:
        env["maps"] = map_paths(args.map)
    return args.algo or algo or TrainConfig.algo, EnvConfig.from_dict(env)


def cmd_transfer(args: argparse.Namespace) -> int:
    """Fine-tune a pretrained policy and train from scratch on each held-out map; the paper's Table 5."""
    from smorphi_rl.training.versions import warn_once

    warn_once()
    from smorphi_rl.training.config import TrainConfigError
    from smorphi_rl.training.transfer import TransferInterrupted, TransferJob, run_transfer, write_transfer_report

    # the options and maps are checked before anything runs
    maps = held_out_files(args.maps)
    job = TransferJob(args.pretrained, maps, tuple(args.seeds), args.timesteps,
                      args.algo, args.preset, args.record_every, args.envs_per_runner, args.env_runners)  # fmt: skip
    for path in maps:
        load_map(path)
    if args.resume and not args.name:
        raise TrainConfigError("--resume continues a job: give its --name (and --log-dir, if not the default)")
    name = args.name or f"transfer-{time.strftime('%Y%m%d-%H%M%S')}"
    stopped = False
    try:
        job_dir, runs = run_transfer(job, name, args.log_dir, args.address, resume=args.resume,
                                     stamped=not args.name)  # fmt: skip
    except TransferInterrupted as stop:  # a run was starting: the finished ones are reported, the job resumable
        job_dir, runs, stopped = stop.job_dir, stop.runs, True
    cut = sum(r.interrupted for r in runs)
    with interrupts.writes_held() as late:  # a stop as the tables are written waits for them
        if runs:
            files = write_transfer_report(job_dir, runs)
            reused = sum(r.reused for r in runs)
            if reused:
                print(f"read back (--resume): {reused} of {len(runs)} runs, finished earlier in this job")
            print(files["md"].read_text().rstrip())
            missing = [r for r in runs if r.mode == "fine-tune" and r.pretrained_in_runners is not True]
            if missing:
                print(f"warning: fine-tuned runs that did not confirm the pretrained policy in all runners: "
                      f"{len(missing)}")  # fmt: skip
            print(f"\nruns: {rel(job_dir)}\ntable: {rel(files['md'])} (and {files['csv'].name})\n"
                  f"curves: {rel(files['png'])}")  # fmt: skip
    whole = not (stopped or cut or len(runs) < len(job.maps) * len(job.seeds) * 2)
    if late.is_set() and whole:
        print(f"{PROG}: interrupted as the job ended: its tables are whole", file=sys.stderr)
        return EXIT_INTERRUPTED
    if not whole:
        listed = " (transfer.csv lists the one cut short)" if cut else ""
        held = f"the table holds the runs that finished ({len(runs) - cut}){listed}" if runs else "no run finished"
        print(f"{PROG}: interrupted: {held}; continue with the same command and --name "
              f"{shlex.quote(job_dir.name)} --resume", file=sys.stderr)  # fmt: skip
        return EXIT_INTERRUPTED
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run or resume a sweep file as one Ray Tune experiment; print the best trials and where the files are."""
    from smorphi_rl.training.versions import warn_once

    warn_once()
    from smorphi_rl.training.sweep_config import load_sweep

    sweep = load_sweep(args.config)  # every problem named before Ray starts
    from smorphi_rl.training.sweep import format_sweep_summary, run_sweep

    where = "" if args.log_dir == DEFAULT_LOG_DIR else f" --log-dir {shlex.quote(str(args.log_dir))}"
    cluster = "" if args.address is None else f" --address {shlex.quote(args.address)}"
    again = f"`{PROG} sweep {shlex.quote(str(args.config))} --resume{where}{cluster}`"
    try:
        summary = run_sweep(sweep, args.log_dir, args.address, args.resume)
    except KeyboardInterrupt as exc:  # a second Ctrl-C: at once, before the tables
        exp = Path(args.log_dir) / sweep.name
        if isinstance(exc, Interrupted) or not exp.is_dir():
            raise
        raise Interrupted(f"stopped at once; {rel(exp)} keeps the trials that finished and the checkpoints, but "
                          f"no tables; continue with {again}") from None  # fmt: skip
    print(format_sweep_summary(summary, rel))
    if summary.interrupted:
        print(f"{PROG}: interrupted: finished trials and checkpoints are kept; continue with {again}", file=sys.stderr)
        return EXIT_INTERRUPTED
    if summary.stop_held:  # asked as the sweep was writing its tables: they were finished first
        print(f"{PROG}: interrupted as the sweep ended: its tables are whole", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The paper's experiments end to end; report.md with Tables 2-6 and Figures 5-7 analogues and the claims."""
    from smorphi_rl.training.versions import warn_once

    warn_once()
    from smorphi_rl.reproduce import ReportWhole, reproduce

    name = args.name or f"reproduce-{args.budget}-{time.strftime('%Y%m%d-%H%M%S')}"
    try:  # a stop request elsewhere says where what was written is kept (Interrupted)
        report = reproduce(args.budget, name, args.log_dir, stamped=not args.name)
    except ReportWhole as stop:  # a stop as the report was written, which it waited for
        print(f"{PROG}: interrupted {stop}", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"report: {rel(report)}")
    return 0

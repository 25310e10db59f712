"""`evaluate-policy` (greedy roll-outs of a trained policy) and `replay` (recorded episodes)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from smorphi_rl import jsontext
from smorphi_rl.cli.common import (
    DEFAULT_LOG_DIR,
    Repeated,
    clipped,
    columns,
    map_paths,
    nonempty,
    one_line,
    padded,
    say_warnings,
    scored_text,
    seed_arg,
)
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.geometry import angles_text
from smorphi_rl.inputs import FORCE_HELP, MAX_SEED, output_file, resolved
from smorphi_rl.map_sources import map_files, resolve
from smorphi_rl.maps import load_map, map_inputs
from smorphi_rl.protocol import EVAL_STARTS
from smorphi_rl.rundir import rel, shell_path
from smorphi_rl.words import counted

GIF_MAX_FRAMES = 120
MAX_EPISODES = 10_000
"""evaluate-policy rolls out at most this many episodes or starts (each about 10-50 ms)."""


CHECKPOINT_HELP = "a checkpoint, a trial or run directory (its newest checkpoint), or an exported policy folder"


def register(sub: Any) -> None:
    """Add `replay` and `evaluate-policy` to the command line."""
    rl = sub.add_parser("replay", help="summarise, list or draw episodes recorded to MCAP")
    rl.add_argument("path", help="a recording (.mcap, or a .mcap.part cut short) or a folder of them")
    rl.add_argument("--steps", action="store_true", help="print every step")
    rl.add_argument("--png", help="write the start, best and final steps side by side (Figure 6 style)")
    rl.add_argument("--gif", help="write a GIF of the morphology changing over the episode")
    rl.add_argument("--force", action="store_true", help=FORCE_HELP)
    rl.set_defaults(func=cmd_replay)

    ep = sub.add_parser("evaluate-policy", help="roll a trained policy out greedily on a map")
    ep.add_argument("--checkpoint", required=True, help=CHECKPOINT_HELP)
    ep.add_argument("--map", nargs="+", action=Repeated, default=None,
                    help="map(s) to roll out on (default: the training maps)")  # fmt: skip
    ep.add_argument("--episodes", type=int, default=1, help="episodes, seeds SEED, SEED+1, ... (default: 1)")
    ep.add_argument(
        "--seed",
        type=seed_arg,
        default=None,
        help="seed of the first episode's start shape (default: 0; the protocol's starts are fixed)",
    )
    ep.add_argument("--json", action="store_true", help="one JSON object per episode")
    ep.add_argument("--plot", help="write a PNG of the first episode's settled morphology and its coverage")
    ep.add_argument("--force", action="store_true", help=FORCE_HELP)
    ep.add_argument("--record", type=nonempty, metavar="DIR", help="record every episode to MCAP in DIR (see `replay`)")
    ep.add_argument("--starts", type=int, default=None, metavar="N",
                    help=f"the evaluation protocol instead: greedy from N fixed seeded starts ({EVAL_STARTS} in "
                         "training) on each map, against the exact optimum")  # fmt: skip
    ep.add_argument("--log-dir", type=nonempty, default=None,
                    help="where the exact optima are cached (LOG_DIR/.cache; default: the log folder of the "
                         f"checkpoint's run, where `train` cached them, else {DEFAULT_LOG_DIR})")  # fmt: skip
    ep.set_defaults(func=cmd_evaluate_policy, map_default="training")

    ex = sub.add_parser("export-policy", help="write a trained policy as plain files (policy.json, weights.npz)")
    ex.add_argument("--checkpoint", required=True, help=CHECKPOINT_HELP)
    ex.add_argument("--out", type=nonempty, required=True, help="the folder to write (new, or empty)")
    ex.add_argument("--command", default="", help="the command that trained it, kept in policy.json")
    ex.set_defaults(func=cmd_export_policy)


def cmd_export_policy(args: argparse.Namespace) -> int:
    """Export a checkpoint's policy and value nets to a folder `design`, `evaluate-policy` and `--pretrained` read."""
    from smorphi_rl.training.checkpoints import find_checkpoint
    from smorphi_rl.training.export import export_policy, run_record

    out = Path(args.out)
    resolved(out, "--out")  # a symlink loop: one line
    if out.is_symlink() and not out.exists():
        raise SmorphiError(f"--out {out} is a link to {out.readlink()}, which does not exist: give a folder")
    if out.exists() and not out.is_dir():
        raise SmorphiError(f"--out {out} is a file, not a folder: give the folder the policy goes to")
    if out.exists() and any(out.iterdir()):
        raise SmorphiError(f"--out {out} is a folder that holds files already: choose another")
    checkpoint = find_checkpoint(args.checkpoint)
    from smorphi_rl.training.checkpoints import load_module

    module = load_module(checkpoint)  # a checkpoint that is refused is refused before --out is made
    from smorphi_rl.env_config import EnvConfig

    raw = (module.model_config or {}).get("env_config")
    if raw:  # one that is not a configuration (evaluate-policy and design would refuse it): refused here
        if not isinstance(raw, dict):
            raise SmorphiError(f"{checkpoint}: its env configuration is a {type(raw).__name__}, not a table")
        try:
            EnvConfig.recorded(dict(raw))
        except SmorphiError as exc:
            raise SmorphiError(f"{checkpoint}: {exc}") from None
    from smorphi_rl.policy_file import POLICY_JSON, WEIGHTS_NPZ, is_policy_dir, read_policy

    about: dict[str, Any] = {"checkpoint": str(checkpoint.resolve()), "command": args.command}
    if is_policy_dir(checkpoint):  # an exported policy again: the same weights, so what was said of them holds
        about = read_policy(checkpoint).about | ({"command": args.command} if args.command else {})
    trained = run_record(checkpoint)  # the run's env steps, where its summary names this checkpoint
    if trained is not None:
        about["trained"] = trained
    from smorphi_rl.rundir import claimed_files

    with claimed_files([out / POLICY_JSON, out / WEIGHTS_NPZ], taken="another export is writing there: choose another "
                       "--out"):  # of two exports into one folder, exactly one writes it  # fmt: skip
        written = export_policy(checkpoint, out, about, module)
    size = sum(p.stat().st_size for p in written.iterdir())
    print(f"policy   {rel(checkpoint)}\nwrote    {rel(written)} (policy.json, weights.npz: {size / 1024:.0f} KiB)")
    return 0


LISTING_PROGRESS_FROM = 200
"""`replay DIR` shows its reading's progress past this many recordings (about 10 ms each)."""


def _listed(file: Path, directory: Path) -> str:
    """A recording's name in `replay DIR`'s listing: its path below DIR (one in a subfolder is named with it)."""
    return str(file.relative_to(directory))


def _replay_listing(directory: Path) -> int:
    """`replay DIR`: every recording under DIR with its best step, one line each."""
    from smorphi_rl.recording import RecordingError, episode_files, read_episode

    files = episode_files(directory)
    if not files:
        raise SmorphiError(f"{directory}: holds no MCAP recordings (*.mcap)")
    rows: list[tuple[str, ...] | str] = []  # read first: the columns are as wide as what they hold
    unreadable = 0
    from smorphi_rl.progress import progress_line

    show = progress_line("recordings read") if len(files) > LISTING_PROGRESS_FROM else None
    for done, f in enumerate(files, start=1):
        if show is not None:
            show(done, len(files))
        try:
            ep = read_episode(f)
        except RecordingError as exc:
            rows.append(f"unreadable: {str(exc).removeprefix(str(f) + ': ')}")
            unreadable += 1
            continue
        b = ep.best
        assert b is not None
        flag = f" ({ep.cut_short})" if ep.cut_short else ""
        rows.append((_listed(f, directory), clipped(b["map"], 40), clipped(ep.metadata.get("algorithm", "-"), 16),
                     f"{len(ep.steps) - 1:>5}  {b['R1']:>7.2f}  {angles_text(b['theta']):<18} {b['P_c']:>6.2f}  "
                     f"{b['P_len']:>5}{flag}"))  # fmt: skip
    cells = [r for r in rows if isinstance(r, tuple)]
    wide = [max(len("episode"), *(columns(_listed(f, directory)) for f in files))]  # an unreadable one's name too
    wide += [max([len(head), *(columns(r[i]) for r in cells)]) for i, head in ((1, "map"), (2, "algo"))]
    print(f"{'episode':<{wide[0]}} {'map':<{wide[1]}} {'algo':<{wide[2]}} {'steps':>5}  {'best R1':>7}  best "
          "morphology     P_c %  P_len")  # fmt: skip
    for f, row in zip(files, rows, strict=True):
        text = (
            f"{padded(_listed(f, directory), wide[0])} {row}"
            if isinstance(row, str)
            else " ".join([*(padded(cell, w) for cell, w in zip(row[:3], wide, strict=True)), row[3]])
        )
        print(one_line(text))
    bad = f" ({unreadable:,} unreadable)" if unreadable else ""
    print(f"{counted(len(files), 'recording')} in {rel(directory)}{bad}")
    if unreadable == len(files):
        raise SmorphiError(f"{directory}: none of its {len(files)} *.mcap files is a readable recording")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """Summarise a recorded episode (or list a run's recordings); print its steps; draw it as PNG or GIF."""
    from smorphi_rl.recording.reader import FILE_CUT_SHORT, read_episode

    target = Path(args.path)
    if target.is_dir():
        if args.steps or args.gif or args.png:
            raise SmorphiError("--steps, --gif and --png take one recording, not a directory")
        return _replay_listing(target)
    for value, flag, suffix in ((args.png, "--png", ".png"), (args.gif, "--gif", ".gif")):
        if value is not None:
            output_file(value, flag, (suffix,), (target,), args.force)
    ep = read_episode(target)
    meta, steps, best = ep.metadata, ep.steps, ep.best
    assert best is not None
    meta = {key: clipped(value) for key, value in meta.items()}  # a long recorded value cannot fill the screen
    run = f"{meta.get('run', '-')} ({meta.get('algorithm', '-').upper()}, seed {meta.get('seed', '-')})"
    start, final = angles_text(steps[0]["theta"]), angles_text(steps[-1]["theta"])
    seeded = meta.get("reset_seed", "none") not in ("none", meta.get("seed"))  # evaluate-policy: seed + episode
    reset = f" (reset with seed {meta['reset_seed']})" if seeded else ""
    rows = [
        ("episode", rel(target)),
        ("run", f"{run}, worker {meta.get('worker', '-')}, episode {meta.get('episode', '-')}{reset}"),
        ("map", clipped(steps[0]["map"])),
        ("steps", f"{len(steps) - 1} (start {start}, final {final})"),
        ("best", f"step {best['step']}: {scored_text(best)}"),
        ("return", f"{ep.episode_return:,.1f}"),
    ]
    if ep.truncated:
        lost = "every step of the episode is here" if ep.ended else "the rest of the episode was lost"
        rows.append(("recovered", f"{len(steps) - 1} steps from a file cut short ({lost})"))
    if ep.cut_short not in (None, FILE_CUT_SHORT):  # the env's note: the run ended mid-episode
        rows.append(("ended", ep.cut_short))
    print("\n".join(one_line(f"{k:<10} {v}") for k, v in rows))  # a recording's text never drives the terminal
    if args.steps:
        print(f"\n{'step':>5}  {'theta':<18} {'action':<9} {'reward':>8} {'R1':>7} {'P_c %':>7} {'P_len':>5}  feasible")
        for st in steps:
            action = "-" if st.get("action") is None else ",".join(str(a) for a in st["action"])
            reward = "-" if st.get("reward") is None else f"{st['reward']:.2f}"
            print(f"{st['step']:>5}  {angles_text(st['theta']):<18} {action:<9} {reward:>8} {st['R1']:>7.2f} "
                  f"{st['P_c']:>7.2f} {st['P_len']:>5}  {'yes' if st['feasible'] else 'no'}")  # fmt: skip
    if args.png or args.gif:
        _draw_replay(ep, args.png, args.gif)
    return 0


def _draw_replay(ep: Any, png: str | None, gif: str | None) -> None:
    """`replay --png/--gif`: the start, best and final steps side by side; the shape changing as a GIF."""
    from smorphi_rl.plots import animate_replay, plot_replay
    from smorphi_rl.progress import progress_line

    grid_map = ep.grid_map()
    steps = ep.steps

    def title(i: int) -> str:
        st = steps[i]
        shape = f"{angles_text(st['theta'])}  P_c {st['P_c']:.2f} %  P_len {st['P_len']}  R1 {st['R1']:.2f}"
        return f"step {st['step']}: {shape}"

    if png:
        picks = {"start": 0, "best": steps.index(ep.best), "final": len(steps) - 1}
        titles = [f"{label} - {title(i)}" for label, i in picks.items()]
        covered = ep.covered(list(picks.values()), grid_map)
        frames = [ep.frame(i) | {"covered": c} for i, c in zip(picks.values(), covered, strict=True)]
        out = plot_replay(grid_map, frames, titles, png)
        print(f"png        {rel(out)}")
    if gif:
        changed = ep.changed_steps(GIF_MAX_FRAMES)
        frames = [ep.frame(i) | {"covered": c} for i, c in zip(changed, ep.covered(changed, grid_map), strict=True)]
        out = animate_replay(grid_map, frames, [title(i) for i in changed], gif,
                             progress=progress_line("gif: frames drawn"))  # fmt: skip
        print(f"gif        {rel(out)} ({counted(len(changed), 'frame')})")


def cmd_evaluate_policy(args: argparse.Namespace) -> int:
    """Roll a trained policy out greedily; report where it settles and the best shape it visited."""
    if not 1 <= args.episodes <= MAX_EPISODES:
        raise SmorphiError(f"--episodes must be in 1..{MAX_EPISODES:,}, got {args.episodes}")
    if args.starts is not None and args.seed is not None:
        raise SmorphiError("--seed sets the --episodes roll-outs' starts: the protocol's (--starts) are fixed, as in "
                           "train's evaluations, so that its figures compare with the run's")  # fmt: skip
    args.seed = 0 if args.seed is None else args.seed
    if args.seed + args.episodes - 1 > MAX_SEED:
        raise SmorphiError(f"--seed {args.seed} with --episodes {args.episodes} passes 2^32-1, the largest episode "
                           "seed")  # fmt: skip
    if args.starts is not None and not 1 <= args.starts <= MAX_EPISODES:
        raise SmorphiError(f"--starts must be in 1..{MAX_EPISODES:,}, got {args.starts}")
    if args.starts is not None and args.episodes != 1:
        raise SmorphiError("--episodes and --starts are two ways to evaluate: give one (--starts runs the protocol)")
    if args.starts is not None and (args.plot is not None or args.record is not None):
        raise SmorphiError("--plot and --record draw and record --episodes roll-outs: the protocol (--starts) prints "
                           "its table only")  # fmt: skip
    if args.record is not None and Path(args.record).exists() and not Path(args.record).is_dir():
        raise SmorphiError(f"--record {args.record} is a file: give the folder the recordings go to")
    from smorphi_rl.training.checkpoints import find_checkpoint

    checkpoint = find_checkpoint(args.checkpoint)
    maps = list(resolve(map_paths(args.map))) if args.map is not None else None  # folders and globs expanded
    for path in map_files(tuple(maps or ())):
        say_warnings(load_map(path))  # a bad map fails here, before the policy loads
    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.training.checkpoints import load_module
    from smorphi_rl.training.policy import check_fits, env_config_of, unseen_warning

    module = load_module(checkpoint)
    config = env_config_of(module, maps)
    if args.plot is not None:  # the maps it rolls out on, given or the policy's own: a plot never replaces their images
        inputs = tuple(p for m in map_files(config.maps) for p in map_inputs(m))
        output_file(args.plot, "--plot", (".png",), inputs, args.force)
    for path in map_files(config.maps) if maps is None else ():  # the policy's own maps
        say_warnings(load_map(path))
    base = MorphologyEnv(config.to_dict())
    check_fits(module, base)
    trained = env_config_of(module, None)
    if (unseen := unseen_warning(trained, config)) is not None:  # on stderr: --json's stdout stays JSON lines
        print(one_line(unseen), file=sys.stderr)
    if args.starts is not None:
        return _evaluate_protocol(args, module, base.config, checkpoint)
    if not args.json:
        print(f"policy      {rel(checkpoint)}")
    rollouts: list[Any] = []
    for i, r in enumerate(_rollouts(args, module, base, checkpoint)):  # each printed as it ends: a stop keeps them
        rollouts.append(r)
        if args.json:
            record = {"episode": i, "seed": args.seed + i, "map": r.final["map"], "steps": r.steps,
                      "return": r.episode_return, "start": r.start, "settled": r.settled.info,
                      "best": r.best}  # fmt: skip
            print(jsontext.dumps(record, default=float), flush=True)
            continue
        print(one_line(f"episode {i} (seed {args.seed + i}, map {r.final['map']}, {r.steps} steps, "
                       f"return {r.episode_return:.1f})"))  # fmt: skip
        print(f"  start     {scored_text(r.start)}")
        print(f"  settled   {scored_text(r.settled.info)}")
        print(f"  best      {scored_text(r.best)}", flush=True)
    if args.plot:
        from smorphi_rl.geometry import Morphology
        from smorphi_rl.plots import plot_coverage

        theta = rollouts[0].settled.theta
        base.reset(seed=args.seed)  # back to the first episode's map
        png = plot_coverage(base.plan(theta), base.grid_map, Morphology.of(theta), base.config.block_side_m,
                            args.plot)  # fmt: skip
        print(f"plot        {png}", file=sys.stderr if args.json else sys.stdout)  # --json: stdout is JSON lines
    if args.record is not None and not args.json:
        print(f"recordings  {rel(Path(args.record))} (smorphi-rl replay {shell_path(args.record)})")
    return 0


def _rollouts(args: argparse.Namespace, module: Any, base: Any, checkpoint: Path) -> Iterator[Any]:
    """`--episodes` greedy roll-outs from seeded starts, one at a time, recorded to MCAP with `--record`; a stop
    mid-episode says how many ended (their lines are out) and, recording, that their recordings are whole."""
    from smorphi_rl.training.policy import rollout

    env: Any = base
    if args.record is not None:
        from smorphi_rl.recording import RecordingConfig, RecordingWrapper

        meta = {"run": str(checkpoint), "algorithm": f"greedy {module.model_config.get('algorithm', 'policy')}",
                "seed": str(args.seed), "config": json.dumps(base.config.to_dict())}  # fmt: skip
        env = RecordingWrapper(base, RecordingConfig(str(Path(args.record).resolve()), every=1, metadata=meta))
    ended = 0
    try:
        for i in range(args.episodes):
            try:
                episode = rollout(module, env, args.seed + i)
            except KeyboardInterrupt:
                lines = "JSON lines" if args.json else "lines"
                kept = (f"; their recordings are whole in {rel(Path(args.record))} (the one cut short ends with a "
                        "note)") if args.record is not None else ""  # fmt: skip
                done = (f"after {counted(ended, 'episode')} of {args.episodes:,}, whose {lines} are printed" if ended
                        else "before the first episode ended")  # fmt: skip
                raise Interrupted(f"{done}{kept}") from None
            ended += 1
            yield episode
    finally:
        env.close()


def run_log_dir(checkpoint: Path) -> str:
    """The log folder of the `train` run `checkpoint` lies in (the run's folder holds its summary.json, at most two
    levels above the checkpoint), where that run cached its maps' optima: the `.cache` beside the run, or beside a
    `transfer` job's folder. DEFAULT_LOG_DIR for any other checkpoint or policy."""
    from smorphi_rl.protocol import OPTIMUM_CACHE

    here = checkpoint.resolve()
    run = next((d for d in (here, *here.parents[:2]) if (d / "summary.json").is_file()), None)
    for folder in () if run is None else run.parents[:2]:
        if (folder / OPTIMUM_CACHE).is_dir():
            return str(folder)
    return DEFAULT_LOG_DIR


def _evaluate_protocol(args: argparse.Namespace, module: Any, env_config: Any, checkpoint: Path) -> int:
    """`evaluate-policy --starts N`: the evaluation protocol on every map, against each map's exact optimum."""
    from smorphi_rl.progress import optimum_progress
    from smorphi_rl.protocol import eval_starts, exact_optimum, optimum_cache, within_band
    from smorphi_rl.score import degenerate_warning
    from smorphi_rl.training.policy import evaluate_policy

    if not env_config.map_files:
        said = "--map names" if args.map is not None else "the policy was trained on"
        raise SmorphiError(f"{said} generated floors only ({', '.join(env_config.maps)}), which have no exact "
                           "optimum to measure against: give fixed floors with --map")  # fmt: skip
    env_config = replace(env_config, maps=env_config.map_files)  # a generated floor has no optimum: files only
    cache = optimum_cache(args.log_dir if args.log_dir is not None else run_log_dir(checkpoint))
    floors = {p: load_map(p) for p in env_config.maps}
    optima = {m.name: exact_optimum(p, env_config.weights_on(m), env_config.planning, cache, optimum_progress(m.name))
              for p, m in floors.items()}  # fmt: skip
    for m in floors.values():  # a floor where the best shape's figures make the ranking mean little, as in `train`
        opt = optima[m.name]
        warned = env_config.planning.start_warning(m) or degenerate_warning(
            env_config.weights_on(m), opt.P_c, opt.P_len, env_config.path_term, m.name
        )
        if warned is not None:
            print(one_line(warned), file=sys.stderr)
    if not args.json:  # which checkpoint a run folder resolved to, as the episodes' report says
        print(f"policy  {rel(checkpoint)}")
    for ev in evaluate_policy(module, env_config, eval_starts(args.starts, env_config.angle_step_deg), optima):
        if args.json:
            optimum = {"theta": list(ev.optimum.theta), "R1": ev.optimum.R1}
            for o, gap, within in zip(ev.outcomes, ev.gaps, within_band(ev.gaps, ev.optimum.R1), strict=True):
                print(jsontext.dumps({"map": ev.map, "start": list(o.start), "evaluations": o.evaluations,
                                  "settled": {"theta": list(o.settled), "R1": o.R1, "P_c": o.P_c, "P_len": o.P_len,
                                              "gap": round(float(gap), 9)},
                                  "optimum": optimum, "within_1pct": bool(within)}))  # fmt: skip
            continue
        opt = ev.optimum
        print(one_line(f"{ev.map}: exact optimum {angles_text(opt.theta)} R1 {opt.R1:.2f}; greedy from "
                       f"{len(ev.outcomes)} fixed starts: {ev.within}/{len(ev.outcomes)} settle within 1 %, median gap "
                       f"{ev.median_gap:.2f}, mean settled R1 {ev.mean_R1:.2f}, {ev.mean_evaluations:.0f} FBCPP "
                       "evaluations a start"))  # fmt: skip
        for o, gap in zip(ev.outcomes, ev.gaps, strict=True):
            print(f"  start {angles_text(o.start):<17} settled {angles_text(o.settled):<17} R1 {o.R1:6.2f}  "
                  f"gap {gap:5.2f}")  # fmt: skip
    return 0

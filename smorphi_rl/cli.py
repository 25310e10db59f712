"""`smorphi-rl` command line: parse, validate at the edge, call one function, print.

Bad input ends with one line on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from smorphi_rl import interrupts
from smorphi_rl.coverage import CoverageResult, Start
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M, Morphology
from smorphi_rl.maps import Cell, Map, load_map

if TYPE_CHECKING:
    from smorphi_rl.env import EnvConfig as EnvConfigType

PROG = "smorphi-rl"
DEFAULT_MAP = Path("maps") / "map-1.yaml"
EXIT_INPUT, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, 130


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line, like every other error."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


def default_map() -> Path:
    """maps/map-1.yaml in the working directory, else the one shipped beside the package."""
    if DEFAULT_MAP.exists():
        return DEFAULT_MAP
    return Path(__file__).resolve().parent.parent / DEFAULT_MAP


def _seed(text: str) -> int:
    """argparse type of every --seed: a non-negative integer (numpy's generators take no negative seed)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {value}")
    return value


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SmorphiError(f"{what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise SmorphiError(f"{what} {text!r} is not a finite number")
    return value


def parse_angles(values: Sequence[str]) -> tuple[float, float, float]:
    """Three hinge angles from the command line, each a number in [0, 180]."""
    t1, t2, t3 = (_number(v, f"hinge angle t{i + 1}") for i, v in enumerate(values))
    return (t1, t2, t3)


def read_angles_file(path: Path) -> np.ndarray:
    """(N, 3) angles from a CSV file of three columns with an optional header row.

    numpy reads well-formed files fast; anything it refuses is re-read row by row to name the line."""
    try:
        with path.open(encoding="utf-8-sig") as fh:  # a spreadsheet's byte-order mark is not part of row 1
            first = fh.readline()
        header = 0 if _is_numeric_row(first.split(",")) else 1
        with warnings.catch_warnings(), path.open(encoding="utf-8-sig") as fh:
            warnings.simplefilter("ignore")  # an empty file: reported below, with its name
            values = np.loadtxt(fh, delimiter=",", skiprows=header, ndmin=2, dtype=np.float64)
        in_range = np.isfinite(values).all() and (values >= 0).all() and (values <= 180).all()
        if values.shape[0] > 0 and values.shape[1] == 3 and in_range:
            return values  # anything else is re-read row by row below, to name the file and line
    except (ValueError, UnicodeDecodeError):
        pass
    except FileNotFoundError:
        raise SmorphiError(f"angles file not found: {path}") from None
    except OSError as exc:
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = [(n, row) for n, row in enumerate(csv.reader(fh), start=1) if any(c.strip() for c in row)]
    except FileNotFoundError:
        raise SmorphiError(f"angles file not found: {path}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise SmorphiError(f"{path}: cannot read angles file ({exc})") from None
    if rows and not _is_numeric_row(rows[0][1]):
        rows = rows[1:]  # header
    if not rows:
        raise SmorphiError(f"{path}: no angles in the file (expected rows of t1,t2,t3)")
    out = np.empty((len(rows), 3))
    for i, (n, row) in enumerate(rows):
        cells = [c.strip() for c in row]
        if len(cells) != 3 or not _is_numeric_row(cells):
            raise SmorphiError(f"{path} line {n}: expected three numbers t1,t2,t3, got {','.join(row)!r}")
        out[i] = [float(c) for c in cells]
        for j, v in enumerate(out[i]):
            if not 0 <= v <= 180:
                raise SmorphiError(f"{path} line {n}: hinge angle t{j + 1}={v:g} is outside [0, 180] degrees")
    return out


def _is_numeric_row(row: Sequence[str]) -> bool:
    try:
        return all(math.isfinite(float(c)) for c in row)
    except ValueError:
        return False


def parse_start(text: str | None, grid_map: Map) -> Start:
    """--start tile:A,B (a tile of the resized map) or xy:X,Y (a free point, metres)."""
    if text is None:
        return Start()
    kind, _, rest = text.partition(":")
    parts = rest.split(",")
    if kind not in ("tile", "xy") or len(parts) != 2:
        raise SmorphiError(f"--start {text!r}: use tile:A,B or xy:X,Y")
    if kind == "tile":
        try:
            return Start.tile(int(parts[0]), int(parts[1]))
        except ValueError:
            raise SmorphiError(f"--start {text!r}: tile indices must be integers") from None
    x, y = (_number(p, "--start coordinate") for p in parts)
    return Start.point(grid_map, x, y)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate one morphology (or a file of them) with FBCPP on a map."""
    from smorphi_rl.evaluate import Evaluator

    if (args.angles is None) == (args.angles_file is None):
        raise SmorphiError("give either --angles T1 T2 T3 or --angles-file FILE")
    if args.angles_file is not None and args.plot is not None:
        raise SmorphiError("--plot draws one morphology: use it with --angles")
    if not args.block_side > 0:
        raise SmorphiError(f"--block-side must be > 0 m, got {args.block_side}")
    thetas = read_angles_file(Path(args.angles_file)) if args.angles_file else None
    morphology = Morphology.of(parse_angles(args.angles)) if args.angles else None
    grid_map = load_map(args.map)
    evaluator = Evaluator(grid_map, block_side_m=args.block_side, start=parse_start(args.start, grid_map))
    if thetas is not None:
        batch = evaluator.evaluate_many(thetas)
        if args.json:
            lines = [json.dumps(r) for r in batch.records()]
        else:
            header = "t1,t2,t3,P_c,coverage_free_pct,P_len,path_length_m,feasible,footprint_l,footprint_w"
            lines = [header, *(_csv_row(r) for r in batch)]
        sys.stdout.write("\n".join(lines) + "\n")
        return 0
    if morphology is None:  # unreachable: exactly one of --angles / --angles-file was given
        raise SmorphiError("give --angles T1 T2 T3")
    result = evaluator.plan(morphology) if args.plot else evaluator.evaluate(morphology)
    plot_path = None
    if args.plot:
        from smorphi_rl.plots import plot_coverage

        plot_path = plot_coverage(result, grid_map, morphology, args.block_side, args.plot)
    if args.json:
        print(json.dumps(result.to_dict()))
        return 0
    _print_result(result, grid_map, evaluator.start.describe(), plot_path)
    return 0


def _csv_row(r: CoverageResult) -> str:
    theta = [f"{t:g}" for t in r.theta]
    fields = [*theta, f"{r.P_c:.6f}", f"{r.coverage_free_pct:.6f}", r.P_len, f"{r.path_length_m:.4f}"]
    return ",".join(str(v) for v in [*fields, int(r.feasible), *r.footprint_cells])


def _print_result(result: CoverageResult, grid_map: Map, start: str, plot_path: Path | None) -> None:
    pct = {c: 100 * grid_map.fraction(c) for c in Cell}
    theta = ", ".join(f"{t:g}" for t in result.theta)
    l, w = result.footprint_cells
    size = f"{grid_map.width} x {grid_map.height} cells at {grid_map.resolution_m:g} m"
    fractions = ", ".join(f"{c.name.lower()} {pct[c]:.1f} %" for c in Cell)
    rows = [
        ("map", f"{grid_map.name} ({size}; {fractions})"),
        ("theta", f"({theta}) deg"),
        ("feasible", "yes" if result.feasible else "no: blocks overlap, metrics are 0"),
        ("footprint", f"{result.footprint_m[0]:.3f} x {result.footprint_m[1]:.3f} m (w x l), F {l} x {w} cells"),
        ("start", start),
        ("P_c", f"{result.P_c:.4f} % (covered + obstacle cells over all known cells)"),
        ("coverage", f"{result.coverage_free_pct:.4f} % of free cells"),
        ("P_len", f"{result.P_len} tile moves"),
        ("path length", f"{result.path_length_m:.2f} m ({result.path_length_cells} cells)"),
    ]  # fmt: skip
    if plot_path is not None:
        rows.append(("plot", str(plot_path)))
    print("\n".join(f"{k:<12} {v}" for k, v in rows))


def cmd_maps_generate(args: argparse.Namespace) -> int:
    """Write an indoor-like map of rectangular obstacles."""
    from smorphi_rl.maps import generate_map, save_map

    out = Path(args.out)
    if out.suffix != ".yaml":
        raise SmorphiError(f"--out {out}: give the map's YAML path, ending in .yaml")
    image = out.with_suffix(f".{args.format}")
    if not args.force and (out.exists() or image.exists()):
        raise SmorphiError(f"{out if out.exists() else image} exists; pass --force to overwrite it")
    rng = np.random.default_rng(args.seed)
    grid_map = generate_map(
        rng,
        width_m=args.width_m,
        height_m=args.height_m,
        resolution_m=args.resolution,
        obstacle_density=args.density,
        name=out.stem,
    )
    save_map(grid_map, out, image_format=args.format)
    occupied = 100 * grid_map.fraction(Cell.OCCUPIED)
    print(f"wrote {out} and {image}: {grid_map.width} x {grid_map.height} cells at {args.resolution:g} m, "
          f"occupied {occupied:.2f} % (seed {args.seed})")  # fmt: skip
    return 0


def cmd_maps_show(args: argparse.Namespace) -> int:
    """Print a map's size and cell fractions, and draw it."""
    from smorphi_rl.plots import plot_map

    grid_map = load_map(args.map)
    png = Path(args.png) if args.png else Path("logs") / "maps" / f"{grid_map.name}.png"
    r = grid_map.resolution_m
    rows = [
        ("map", f"{args.map}"),
        ("size", f"{grid_map.width} x {grid_map.height} cells, {grid_map.width * r:g} x {grid_map.height * r:g} m"),
        ("resolution", f"{r:g} m/cell"),
        ("origin", ", ".join(f"{v:g}" for v in grid_map.origin)),
        *((c.name.lower(), f"{100 * grid_map.fraction(c):.2f} % ({grid_map.counts[c]} cells)") for c in Cell),
        ("png", str(plot_map(grid_map, png))),
    ]
    print("\n".join(f"{k:<11} {v}" for k, v in rows))
    return 0


def _rel(path: Path) -> str:
    """`path` relative to the working directory when it lies below it (as the README shows it)."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _map_paths(value: object) -> list[str]:
    return [str(v) for v in value] if isinstance(value, list) else [str(value)]


def cmd_train(args: argparse.Namespace) -> int:
    """Train PPO, IMPALA or APPO through Ray Tune; print a progress line, then where everything is."""
    from smorphi_rl.env import EnvConfig
    from smorphi_rl.training.config import TrainConfig

    env_options = {"maps": _map_paths(args.map), "reward": args.reward, "w1": args.w1, "w2": args.w2}
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
    from smorphi_rl.training.config import TrainConfig

    TrainConfig(
        algo=args.algo, timesteps=args.timesteps, preset=args.preset, record_every=args.record_every
    )  # options checked before anything runs
    for seed in args.seeds:
        if seed < 0:
            raise SmorphiError(f"--seeds must be non-negative integers, got {seed}")
    for path in args.maps:
        load_map(path)
    from smorphi_rl.training.transfer import run_transfer, write_transfer_report

    name = args.name or f"transfer-{time.strftime('%Y%m%d-%H%M%S')}"
    job_dir, runs = run_transfer(args.pretrained, [str(m) for m in args.maps], args.seeds, args.timesteps,
                                 args.algo, args.preset, name, args.log_dir, args.address,
                                 record_every=args.record_every)  # fmt: skip
    files = write_transfer_report(job_dir, runs)
    print(files["md"].read_text().rstrip())
    missing = [r for r in runs if r.mode == "fine-tune" and r.pretrained_in_runners is not True]
    if missing:
        print(f"warning: {len(missing)} fine-tuned run(s) did not confirm the pretrained policy in every env runner")
    print(
        f"\nruns: {_rel(job_dir)}\ntable: {_rel(files['md'])} (and {files['csv'].name})\ncurves: {_rel(files['png'])}"
    )
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run or resume a sweep file as one Ray Tune experiment; print the best trials and where the files are."""
    from smorphi_rl.training.sweep_config import load_sweep

    sweep = load_sweep(args.config)  # every problem named before Ray starts
    from smorphi_rl.training.sweep import format_sweep_summary, run_sweep

    summary = run_sweep(sweep, args.log_dir, args.address, args.resume)
    print(format_sweep_summary(summary, _rel))
    if summary.interrupted:
        print(f"{PROG}: interrupted: finished trials and checkpoints are kept; continue with "
              f"`{PROG} sweep {args.config} --resume`", file=sys.stderr)  # fmt: skip
        return EXIT_INTERRUPTED
    return 0


GIF_MAX_FRAMES = 120


def _replay_listing(directory: Path) -> int:
    """`replay DIR`: every recording under DIR with its best step, one line each."""
    from smorphi_rl.recording import RecordingError, episode_files, read_episode

    files = episode_files(directory)
    if not files:
        raise SmorphiError(f"{directory}: holds no MCAP recordings (*.mcap)")
    print(f"{'episode':<44} {'map':<8} {'algo':<8} {'steps':>5}  {'best R1':>7}  best morphology     P_c %  P_len")
    unreadable = 0
    for f in files:
        try:
            ep = read_episode(f)
        except RecordingError as exc:
            print(f"{f.name:<44} unreadable: {str(exc).removeprefix(str(f) + ': ')}")
            unreadable += 1
            continue
        b = ep.best
        assert b is not None
        flag = " (cut short)" if ep.truncated else ""
        print(f"{f.name:<44} {b['map']:<8} {ep.metadata.get('algorithm', '-'):<8} {len(ep.steps) - 1:>5}  "
              f"{b['R1']:>7.2f}  {_theta_text(b['theta']):<18} {b['P_c']:>6.2f}  {b['P_len']:>5}{flag}")  # fmt: skip
    print(f"{len(files)} recordings in {_rel(directory)}")
    if unreadable == len(files):
        raise SmorphiError(f"{directory}: none of its {len(files)} *.mcap files is a readable recording")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """Summarise a recorded episode (or list a run's recordings); print its steps; draw it as PNG or GIF."""
    from smorphi_rl.recording import read_episode

    target = Path(args.path)
    if target.is_dir():
        if args.steps or args.gif or args.png:
            raise SmorphiError("--steps, --gif and --png take one recording, not a directory")
        return _replay_listing(target)
    ep = read_episode(target)
    meta, steps, best = ep.metadata, ep.steps, ep.best
    assert best is not None
    run = f"{meta.get('run', '-')} ({meta.get('algorithm', '-').upper()}, seed {meta.get('seed', '-')})"
    start, final = _theta_text(steps[0]["theta"]), _theta_text(steps[-1]["theta"])
    rows = [
        ("episode", _rel(target)),
        ("run", f"{run}, worker {meta.get('worker', '-')}, episode {meta.get('episode', '-')}"),
        ("map", steps[0]["map"]),
        ("steps", f"{len(steps) - 1} (start {start}, final {final})"),
        ("best", f"step {best['step']}: {_scored_text(best)}"),
        ("return", f"{ep.episode_return:,.1f}"),
    ]
    if ep.truncated:
        rows.append(("recovered", f"{len(steps) - 1} steps from a file cut short (the rest of the episode was lost)"))
    print("\n".join(f"{k:<10} {v}" for k, v in rows))
    if args.steps:
        print(f"\n{'step':>5}  {'theta':<18} {'action':<9} {'reward':>8} {'R1':>7} {'P_c %':>7} {'P_len':>5}  feasible")
        for st in steps:
            action = "-" if st["action"] is None else ",".join(str(a) for a in st["action"])
            reward = "-" if st["reward"] is None else f"{st['reward']:.2f}"
            print(f"{st['step']:>5}  {_theta_text(st['theta']):<18} {action:<9} {reward:>8} {st['R1']:>7.2f} "
                  f"{st['P_c']:>7.2f} {st['P_len']:>5}  {'yes' if st['feasible'] else 'no'}")  # fmt: skip
    if args.png or args.gif:
        from smorphi_rl.plots import animate_replay, plot_replay

        cells = ep.grid_cells()
        if cells is None:
            raise SmorphiError(f"{target}: the map message was not recovered; nothing to draw on")
        grid = ep.grid or {}
        pos = grid["pose"]["position"]
        grid_map = Map(cells, float(grid["cell_size"]["x"]), (pos["x"], pos["y"], 0.0), steps[0]["map"])

        def title(i: int) -> str:
            st = steps[i]
            return (f"step {st['step']}: {_theta_text(st['theta'])}  P_c {st['P_c']:.2f} %  P_len {st['P_len']}  "
                    f"R1 {st['R1']:.2f}")  # fmt: skip

        if args.png:
            picks = {"start": 0, "best": steps.index(best), "final": len(steps) - 1}
            titles = [f"{label} - {title(i)}" for label, i in picks.items()]
            out = plot_replay(grid_map, [ep.frame(i) for i in picks.values()], titles, args.png)
            print(f"png        {_rel(out)}")
        if args.gif:
            changed = [i for i in range(len(steps)) if i == 0 or steps[i]["theta"] != steps[i - 1]["theta"]]
            if len(changed) > GIF_MAX_FRAMES:
                changed = [changed[round(k)] for k in np.linspace(0, len(changed) - 1, GIF_MAX_FRAMES)]
            out = animate_replay(grid_map, [ep.frame(i) for i in changed], [title(i) for i in changed], args.gif)
            print(f"gif        {_rel(out)} ({len(changed)} frames)")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The paper's experiments end to end; report.md with Tables 2-6 and Figures 5-7 analogues and the claims."""
    from smorphi_rl.reproduce import reproduce

    name = args.name or f"reproduce-{args.budget}-{time.strftime('%Y%m%d-%H%M%S')}"
    report = reproduce(args.budget, name, args.log_dir)
    print(f"report: {_rel(report)}")
    return 0


def _theta_text(theta: Sequence[float]) -> str:
    return "(" + ", ".join(f"{t:g}" for t in theta) + ")"


def _scored_text(d: dict[str, object]) -> str:
    return f"{_theta_text(d['theta'])} P_c {d['P_c']:.2f} %, P_len {d['P_len']}, R1 {d['R1']:.2f}"  # type: ignore[arg-type]


def cmd_evaluate_policy(args: argparse.Namespace) -> int:
    """Roll a trained policy out greedily; report where it settles and the best shape it visited."""
    if args.episodes < 1:
        raise SmorphiError(f"--episodes must be >= 1, got {args.episodes}")
    from smorphi_rl.training.checkpoints import find_checkpoint

    checkpoint = find_checkpoint(args.checkpoint)
    maps = _map_paths(args.map) if args.map is not None else None
    if maps:
        for path in maps:
            load_map(path)
    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.training.checkpoints import load_module
    from smorphi_rl.training.policy import check_fits, env_config_of, rollout

    module = load_module(checkpoint)
    base = MorphologyEnv(env_config_of(module, maps).to_dict())
    check_fits(module, base)
    if args.starts is not None:
        return _evaluate_protocol(args, module, base.config)
    env: Any = base
    if args.record is not None:
        from smorphi_rl.recording import RecordingConfig, RecordingWrapper

        meta = {"run": str(checkpoint), "algorithm": f"greedy {module.model_config.get('algorithm', 'policy')}",
                "seed": str(args.seed), "config": json.dumps(base.config.to_dict())}  # fmt: skip
        env = RecordingWrapper(base, RecordingConfig(str(Path(args.record).resolve()), every=1, metadata=meta))
    try:
        rollouts = [rollout(module, env, args.seed + i) for i in range(args.episodes)]
    finally:
        env.close()
    if args.json:
        for i, r in enumerate(rollouts):
            record = {"episode": i, "seed": args.seed + i, "map": r.final["map"], "steps": r.steps,
                      "return": r.episode_return, "start": r.start, "settled": r.settled, "best": r.best}  # fmt: skip
            print(json.dumps(record, default=float))
    else:
        print(f"policy      {checkpoint}")
        for i, r in enumerate(rollouts):
            print(f"episode {i + 1} (seed {args.seed + i}, map {r.final['map']}, {r.steps} steps, "
                  f"return {r.episode_return:.1f})")  # fmt: skip
            print(f"  start     {_scored_text(r.start)}")
            print(f"  settled   {_scored_text(r.settled)}")
            print(f"  best      {_scored_text(r.best)}")
    if args.plot:
        from smorphi_rl.geometry import Morphology
        from smorphi_rl.plots import plot_coverage

        theta = rollouts[0].settled["theta"]
        base.reset(seed=args.seed)  # back to the first episode's map
        png = plot_coverage(base.plan(theta), base.grid_map, Morphology.of(theta), base.config.block_side_m,
                            args.plot)  # fmt: skip
        print(f"plot        {png}")
    if args.record is not None and not args.json:
        print(f"recordings  {_rel(Path(args.record))} (smorphi-rl replay {_rel(Path(args.record))})")
    return 0


def _evaluate_protocol(args: argparse.Namespace, module: Any, env_config: Any) -> int:
    """`evaluate-policy --starts N`: the evaluation protocol on every map, against each map's exact optimum."""
    from smorphi_rl.protocol import eval_starts, exact_optimum
    from smorphi_rl.training.policy import evaluate_policy

    if args.starts < 1:
        raise SmorphiError(f"--starts must be >= 1, got {args.starts}")
    cache = Path(args.log_dir).resolve() / ".cache"
    optima = {load_map(p).name: exact_optimum(p, env_config.w1, env_config.w2, env_config.block_side_m, cache)
              for p in env_config.maps}  # fmt: skip
    for ev in evaluate_policy(module, env_config, eval_starts(args.starts, env_config.angle_step_deg), optima):
        if args.json:
            for o in ev.outcomes:
                print(json.dumps({"map": ev.map, "start": list(o.start), "evaluations": o.evaluations,
                                  "settled": {"theta": list(o.settled), "R1": o.R1, "P_c": o.P_c, "P_len": o.P_len,
                                              "gap": ev.optimum.R1 - o.R1}}))  # fmt: skip
            continue
        opt = ev.optimum
        print(f"{ev.map}: exact optimum {_theta_text(opt.theta)} R1 {opt.R1:.2f}; greedy from {len(ev.outcomes)} "
              f"fixed starts: {ev.within}/{len(ev.outcomes)} settle within 1 %, median gap {ev.median_gap:.2f}, "
              f"mean settled R1 {ev.mean_R1:.2f}, {ev.mean_evaluations:.0f} FBCPP evaluations a start")  # fmt: skip
        for o in ev.outcomes:
            print(f"  start {_theta_text(o.start):<17} settled {_theta_text(o.settled):<17} R1 {o.R1:6.2f}  "
                  f"gap {opt.R1 - o.R1:5.2f}")  # fmt: skip
    return 0


def _progress_line(label: str) -> Callable[[int, int], None]:
    """A progress bar on stderr: rewritten in place on a terminal, every 10 % otherwise."""
    tty = sys.stderr.isatty()
    t0 = time.monotonic()
    shown = [-1]

    def show(done: int, total: int) -> None:
        frac = done / total
        tenth = int(10 * frac)
        if not tty and tenth == shown[0] and done < total:
            return
        shown[0] = tenth
        bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
        line = f"{label} [{bar}] {done:,}/{total:,} {time.monotonic() - t0:5.1f} s"
        sys.stderr.write(("\r" + line + ("\n" if done >= total else "")) if tty else line + "\n")
        sys.stderr.flush()

    return show


def cmd_search(args: argparse.Namespace) -> int:
    """Random shapes, NSGA-II or the exhaustive lattice on a map; results, front and plot under logs/<run>/."""
    from smorphi_rl.rundir import prepare_run_dir, safe_name
    from smorphi_rl.search.results import save

    weights = _weights(args)
    load_map(args.map)  # a bad map fails here, before anything is written
    if args.method == "exhaustive":
        from smorphi_rl.search.exhaustive import check_step, run_exhaustive

        check_step(args.step)
        name = args.name or safe_name(f"exhaustive-{Path(str(args.map)).stem}-step{args.step:g}")
        run_dir = prepare_run_dir(args.log_dir, name)
        result = run_exhaustive(str(args.map), args.step, progress=_progress_line("exhaustive"))
    elif args.method == "random":
        from smorphi_rl.search.random import run_random

        if args.samples < 1:
            raise SmorphiError(f"--samples must be >= 1, got {args.samples}")
        run_dir = prepare_run_dir(
            args.log_dir, args.name or safe_name(f"random-{Path(str(args.map)).stem}-seed{args.seed}")
        )
        result = run_random(str(args.map), args.samples, args.seed)
    elif args.method in ("hillclimb", "anneal"):
        from smorphi_rl.search.local import run_local_search

        if args.budget < 1 or args.starts < 1:
            raise SmorphiError(f"--budget and --starts must be >= 1, got {args.budget} and {args.starts}")
        run_dir = prepare_run_dir(
            args.log_dir, args.name or safe_name(f"{args.method}-{Path(str(args.map)).stem}-seed{args.seed}")
        )
        result = run_local_search(args.method, str(args.map), args.budget, args.seed, args.starts,
                                  {"w1": weights.w1, "w2": weights.w2})  # fmt: skip
    else:
        from smorphi_rl.search.nsga2 import run_nsga2

        if args.pop < 2 or args.generations < 1:
            raise SmorphiError(f"--pop must be >= 2 and --generations >= 1, got {args.pop} and {args.generations}")
        run_dir = prepare_run_dir(
            args.log_dir, args.name or safe_name(f"nsga2-{Path(str(args.map)).stem}-seed{args.seed}")
        )
        result = run_nsga2(str(args.map), args.pop, args.generations, args.seed)
    files = save(result, run_dir, weights.w1, weights.w2)
    front_rows = result.front_records(weights.w1, weights.w2)
    from smorphi_rl.plots import plot_pareto

    ok = np.flatnonzero(result.feasible)
    b = result.best(weights.w1, weights.w2)
    files["plot"] = plot_pareto(
        {result.method: (np.array([r["P_len"] for r in front_rows]), np.array([r["P_c"] for r in front_rows]))},
        run_dir / "pareto.png",
        f"{result.method} on {result.map_name}: {result.evaluations:,} evaluations, front of {len(front_rows)}",
        best={result.method: (float(result.P_len[b]), float(result.P_c[b]))},
    )
    if args.json:
        for row in front_rows:
            print(json.dumps({"theta": row["theta"], "P_c": row["P_c"], "P_len": row["P_len"]}))
        return 0
    extra = result.params.get("distinct_footprints")
    footprints = f", {extra:,} distinct footprints" if extra is not None else ""
    print(f"{result.method} on {result.map_name}: {result.evaluations:,} evaluations{footprints} in "
          f"{result.wall_s:.1f} s ({len(ok):,} feasible)")  # fmt: skip
    print(f"Pareto front ({len(front_rows)} points, max P_c / min P_len):")
    for row in front_rows:
        print(
            f"  {_theta_text(row['theta']):<17} P_c {row['P_c']:7.2f} %  P_len {row['P_len']:4d}  R1 {row['R1']:7.2f}"
        )
    r1_best = weights.w1 * result.P_c[b] - weights.w2 * result.P_len[b]
    print(f"best R1 (w1 {weights.w1:g}, w2 {weights.w2:g}): {_theta_text(result.thetas[b])} P_c {result.P_c[b]:.2f} %, "
          f"P_len {result.P_len[b]}, R1 {r1_best:.2f}")  # fmt: skip
    for key in ("results", "front", "summary", "plot"):
        print(f"{key + ':':<9} {_rel(files[key])}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """Put training runs and search runs against the exact front of the map; report.md and compare.png."""
    from smorphi_rl.compare import points_of_run, score_methods, write_report
    from smorphi_rl.rundir import prepare_run_dir, safe_name
    from smorphi_rl.search.exhaustive import run_exhaustive
    from smorphi_rl.search.results import load

    dirs = [Path(d) for d in [*(args.runs or []), *(args.nsga2 or []), *(args.random or []), *(args.local or [])]]
    if not dirs:
        raise SmorphiError("give at least one run to compare: --runs, --nsga2, --random or --local")
    grid_map = load_map(args.map)
    weights = _weights(args)
    runs = [points_of_run(d, grid_map.name) for d in dirs]  # every input checked before any work
    exact = load(args.exhaustive) if args.exhaustive else None
    if exact is not None and exact.map_name != grid_map.name:
        raise SmorphiError(f"{args.exhaustive}: the exact front is for map '{exact.map_name}', not '{grid_map.name}'")
    run_dir = prepare_run_dir(args.log_dir, args.name or safe_name(f"compare-{grid_map.name}"))
    if exact is None:
        exact = run_exhaustive(str(args.map), args.step, progress=_progress_line("exact front"))
    exact_score, methods = score_methods(exact, runs, weights.w1, weights.w2)
    files = write_report(exact_score, methods, grid_map.name, weights.w1, weights.w2, run_dir)
    print(files["report"].read_text().split("\n\n![")[0])
    print(f"\nreport: {_rel(files['report'])}\nplot:   {_rel(files['plot'])}")
    return 0


def _weight_options(parser: argparse.ArgumentParser) -> None:
    """--w1 / --w2: the reward weights that rank shapes by R1 = w1 P_c - w2 P_len (the env's defaults)."""
    parser.add_argument("--w1", type=float, help="weight of P_c in R1 (default: the env's)")
    parser.add_argument("--w2", type=float, help="weight of P_len in R1 (default: the env's)")


def _weights(args: argparse.Namespace) -> EnvConfigType:
    """The env configuration with --w1 / --w2 applied (validated there, defaults from there)."""
    from smorphi_rl.env import EnvConfig

    return EnvConfig.from_dict({k: v for k in ("w1", "w2") if (v := getattr(args, k)) is not None})


def _record_option(p: argparse.ArgumentParser) -> None:
    from smorphi_rl.training.config import DEFAULT_RECORD_EVERY

    p.add_argument("--record-every", type=int, default=DEFAULT_RECORD_EVERY, metavar="N",
                   help=f"record every Nth episode of each env to MCAP under the run's episodes/ "
                        f"(default {DEFAULT_RECORD_EVERY}; 0: off)")  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROG, description="Find the best Smorphi morphology for a floor map.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    ev = sub.add_parser("evaluate", help="coverage (P_c) and path length (P_len) of morphologies on a map")
    ev.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
    ev.add_argument("--angles", nargs=3, metavar=("T1", "T2", "T3"), help="hinge angles in degrees, each 0-180")
    ev.add_argument("--angles-file", help="CSV of t1,t2,t3 rows (optional header): evaluate them all")
    ev.add_argument("--json", action="store_true", help="print JSON (one object per morphology, one per line)")
    ev.add_argument("--plot", help="write a PNG of the footprint, covered area and path")
    ev.add_argument("--block-side", type=float, default=DEFAULT_BLOCK_SIDE_M, help="block side in metres")
    ev.add_argument("--start", help="start tile 'tile:A,B' or free point 'xy:X,Y' in metres (default: first tile)")
    ev.set_defaults(func=cmd_evaluate)

    maps = sub.add_parser("maps", help="generate or inspect maps")
    maps_sub = maps.add_subparsers(dest="maps_command", required=True, parser_class=_Parser)
    gen = maps_sub.add_parser("generate", help="write a map of rectangular obstacles")
    gen.add_argument("--out", required=True, help="YAML path to write (image written beside it)")
    gen.add_argument("--width-m", type=float, default=5.0)
    gen.add_argument("--height-m", type=float, default=5.0)
    gen.add_argument("--resolution", type=float, default=0.1, help="metres per cell")
    gen.add_argument("--density", type=float, default=0.2, help="target fraction of occupied cells")
    gen.add_argument("--seed", type=_seed, default=0)
    gen.add_argument("--format", choices=("pgm", "png"), default="pgm")
    gen.add_argument("--force", action="store_true", help="overwrite an existing map")
    gen.set_defaults(func=cmd_maps_generate)
    show = maps_sub.add_parser("show", help="print a map's size and fractions and draw it")
    show.add_argument("map", help="map_server YAML")
    show.add_argument("--png", help="where to draw it (default: logs/maps/NAME.png)")
    show.set_defaults(func=cmd_maps_show)

    from smorphi_rl.env import REWARD_MODES
    from smorphi_rl.protocol import EVAL_EVERY, EVAL_STARTS
    from smorphi_rl.training.presets import ALGORITHMS, DEFAULT_TIMESTEPS, ENVS_PER_RUNNER, PRESETS

    tr = sub.add_parser("train", help="train PPO / IMPALA / APPO on maps through Ray Tune (the main job)")
    tr.add_argument("--algo", choices=ALGORITHMS, default="ppo", help="algorithm (IMPALA serves the paper's A3C)")
    tr.add_argument(
        "--map", nargs="+", default=None, help=f"map_server YAML(s), one drawn per episode (default: {DEFAULT_MAP})"
    )
    tr.add_argument("--timesteps", type=int, default=DEFAULT_TIMESTEPS, help="env steps to train for")
    tr.add_argument("--seed", type=_seed, default=0)
    tr.add_argument("--preset", choices=tuple(PRESETS), default="fast", help="fast (2 cores) or paper (Table 1)")
    tr.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto); default: a local Ray")
    tr.add_argument("--name", help="run name: results go to LOG_DIR/NAME (default: ALGO-MAP-TIMESTAMP)")
    tr.add_argument("--log-dir", default="logs", help="root of the run directories (default: logs)")
    tr.add_argument("--checkpoint-every", type=int, default=10, help="iterations between checkpoints (and at the end)")
    tr.add_argument("--pretrained", help="start from this checkpoint (or trial or run directory): fine-tuning")
    tr.add_argument("--reward", choices=REWARD_MODES, default=None,
                    help="reward mode (ENV.md): paper, improvement or commit (default: the env's)")  # fmt: skip
    _weight_options(tr)
    tr.add_argument("--env-runners", type=int, default=None, metavar="N",
                    help="remote env runners; 0 samples in the trial process (default: the preset's, "
                         "0 for PPO and 2 for IMPALA/APPO on the fast preset)")  # fmt: skip
    tr.add_argument(
        "--envs-per-runner",
        type=int,
        default=ENVS_PER_RUNNER,
        metavar="N",
        help=f"envs each runner steps together, one forward pass for all (default {ENVS_PER_RUNNER})",
    )
    tr.add_argument(
        "--eval-every",
        type=int,
        default=EVAL_EVERY,
        metavar="N",
        help=f"greedy evaluation from fixed starts every N iterations (default {EVAL_EVERY}; 0: off)",
    )
    tr.add_argument(
        "--eval-starts",
        type=int,
        default=EVAL_STARTS,
        metavar="N",
        help=f"fixed seeded start shapes per map in each evaluation (default {EVAL_STARTS})",
    )
    _record_option(tr)
    tr.set_defaults(func=cmd_train)

    tf = sub.add_parser("transfer", help="fine-tune vs from scratch on held-out maps (the paper's Table 5)")
    tf.add_argument("--pretrained", required=True, help="checkpoint, trial or run directory of the pretrained policy")
    tf.add_argument("--maps", nargs="+", required=True, help="held-out maps (map_server YAML)")
    tf.add_argument("--seeds", nargs="+", type=_seed, default=[0], help="seeds; each map runs once per seed and mode")
    tf.add_argument("--timesteps", type=int, default=DEFAULT_TIMESTEPS, help="env-step budget of every run")
    tf.add_argument("--algo", choices=ALGORITHMS, default="ppo")
    tf.add_argument("--preset", choices=tuple(PRESETS), default="fast")
    tf.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto)")
    tf.add_argument("--name", help="job name: runs go to LOG_DIR/NAME (default: transfer-TIMESTAMP)")
    tf.add_argument("--log-dir", default="logs")
    _record_option(tf)
    tf.set_defaults(func=cmd_transfer)

    sw = sub.add_parser("sweep", help="a Ray Tune sweep from a tune_configs/*.yaml file (resumable)")
    sw.add_argument("config", help="sweep file (schema in the README; examples in tune_configs/)")
    sw.add_argument("--address", help="attach to a running Ray cluster (HOST:PORT or auto)")
    sw.add_argument("--resume", action="store_true", help="continue the interrupted experiment of this sweep")
    sw.add_argument("--log-dir", default="logs", help="the experiment goes to LOG_DIR/<the sweep's name>")
    sw.set_defaults(func=cmd_sweep)

    rl = sub.add_parser("replay", help="summarise, list or draw episodes recorded to MCAP")
    rl.add_argument("path", help="a recording (.mcap, or a .mcap.part cut short) or a folder of them")
    rl.add_argument("--steps", action="store_true", help="print every step")
    rl.add_argument("--png", help="write the start, best and final steps side by side (Figure 6 style)")
    rl.add_argument("--gif", help="write a GIF of the morphology changing over the episode")
    rl.set_defaults(func=cmd_replay)

    ep = sub.add_parser("evaluate-policy", help="roll a trained policy out greedily on a map")
    ep.add_argument("--checkpoint", required=True, help="a checkpoint, or a trial or run directory (newest checkpoint)")
    ep.add_argument("--map", nargs="+", default=None, help="map(s) to roll out on (default: the training maps)")
    ep.add_argument("--episodes", type=int, default=1, help="episodes, seeds SEED, SEED+1, ...")
    ep.add_argument("--seed", type=_seed, default=0, help="seed of the first episode's start morphology")
    ep.add_argument("--json", action="store_true", help="one JSON object per episode")
    ep.add_argument("--plot", help="write a PNG of the first episode's settled morphology and its coverage")
    ep.add_argument("--record", metavar="DIR", help="record every episode to MCAP in DIR (see `replay`)")
    ep.add_argument("--starts", type=int, default=None, metavar="N",
                    help="the evaluation protocol instead: greedy from N fixed seeded starts (20 in training) on "
                         "each map, against the exact optimum")  # fmt: skip
    ep.add_argument("--log-dir", default="logs", help="where the exact optima are cached (LOG_DIR/.cache)")
    ep.set_defaults(func=cmd_evaluate_policy, map_default="training")

    se = sub.add_parser("search", help="baselines and ground truth: random shapes, NSGA-II, the exhaustive lattice")
    se_sub = se.add_subparsers(dest="method", required=True, parser_class=_Parser)
    for method, text in (("random", "uniformly random integer shapes (paper Table 4)"),
                         ("nsga2", "NSGA-II over integer angles (paper Table 6, Figure 7)"),
                         ("exhaustive", "every triple on the lattice: the exact front and best R1"),
                         ("hillclimb", "steepest ascent over the 26 one-step moves from the protocol's fixed starts"),
                         ("anneal", "simulated annealing over the same moves from the same starts")):  # fmt: skip
        m = se_sub.add_parser(method, help=text)
        m.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
        m.add_argument("--name", help="run name: results go to LOG_DIR/NAME")
        m.add_argument("--log-dir", default="logs", help="root of the run directories (default: logs)")
        m.add_argument("--json", action="store_true", help="print the front as JSON lines (theta, P_c, P_len)")
        _weight_options(m)
        if method == "random":
            m.add_argument("--samples", type=int, default=1000, help="shapes to draw")
        if method == "nsga2":
            m.add_argument("--pop", type=int, default=40, help="population size")
            m.add_argument("--generations", type=int, default=50)
        if method in ("random", "nsga2", "hillclimb", "anneal"):
            m.add_argument("--seed", type=_seed, default=0)
        if method in ("hillclimb", "anneal"):
            m.add_argument("--budget", type=int, default=200, help="FBCPP evaluations per start (default 200)")
            m.add_argument("--starts", type=int, default=20, help="fixed seeded starts (default 20)")
        if method == "exhaustive":
            m.add_argument("--step", type=float, default=1.0, help="lattice step in degrees; must divide 180")
        m.set_defaults(func=cmd_search)

    co = sub.add_parser("compare", help="every method against the exact Pareto front of a map")
    co.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
    co.add_argument("--runs", nargs="+", help="training run directories (logs/<run>)")
    co.add_argument("--nsga2", nargs="+", help="`search nsga2` run directories")
    co.add_argument("--random", nargs="+", help="`search random` run directories")
    co.add_argument("--local", nargs="+", help="`search hillclimb` / `search anneal` run directories")
    co.add_argument("--exhaustive", help="a `search exhaustive` run to use as the exact front (default: compute it)")
    co.add_argument("--step", type=float, default=1.0, help="lattice step of the exact front when computed")
    co.add_argument("--name", help="run name: the report goes to LOG_DIR/NAME (default: compare-MAP)")
    co.add_argument("--log-dir", default="logs")
    _weight_options(co)
    co.set_defaults(func=cmd_compare)

    from smorphi_rl.reproduce import BUDGETS

    rp = sub.add_parser("reproduce", help="the paper's experiments end to end, with a claim-by-claim report")
    rp.add_argument("--budget", choices=tuple(BUDGETS), default="small", help="small (~17 min), paper, tiny (smoke)")
    rp.add_argument("--name", help="run name (default: reproduce-BUDGET-TIMESTAMP)")
    rp.add_argument("--log-dir", default="logs")
    rp.set_defaults(func=cmd_reproduce)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    interrupts.install()
    args = build_parser().parse_args(argv)
    if getattr(args, "map", "") is None and getattr(args, "map_default", None) is None:
        args.map = default_map()
    try:
        return int(args.func(args))
    except SmorphiError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except BrokenPipeError:  # output piped into `head` and the like (an OSError: caught first)
        sys.stderr.close()
        return 0
    except OSError as exc:
        print(f"{PROG}: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark the generalist designer against search at equal budgets, on floors it never saw.

On the held-out floors (`maps/designer/held-out`, seeds 1,000,000 and up, which training never draws) and the
shipped `val-*` maps, each at its exact 1-degree optimum: the designer's gap (per cent of the optimum's R1)
with B planner evaluations, against random search, hill climbing, simulated annealing, compass (pattern)
search and NSGA-II given the same B (5 seeds each, the designer too, the median per floor; NSGA-II's whole
generations cut to the first B shapes), at several budgets. Per-map PPO
trained from scratch and fine-tuned from the designer, at equal env steps, on a few floors; the real maps of
`../shared/realmaps` (cropped and resampled as a user would) reported apart. Intervals: 95 % bootstrap
across floors; each designer against each method by the median of the per-floor differences.

Targets (issue 31): median gap <= 1 %, 90th percentile <= 3 %, at most 200 evaluations, and a lower median
gap than random search, hill climbing and NSGA-II with the difference's interval excluding 0.

    .venv/bin/python scripts/bench_designer.py [--policy DIR ...] [--budgets 25 50 100 200 400]
        [--seeds 5] [--ppo-maps 4] [--ppo-steps 20000] [--out logs/bench-designer] [--write-docs]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _benchdocs import check_at_least, stop_interrupted, whole, write_section

from smorphi_rl import jsontext
from smorphi_rl.design import run_design
from smorphi_rl.designer import Designer, designer_env, load_designer
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.errors import SmorphiError
from smorphi_rl.maps import load_map, save_map
from smorphi_rl.policy_file import SHIPPED_DESIGNER
from smorphi_rl.protocol import eval_starts, exact_optimum
from smorphi_rl.search.local import run_local

ROOT = Path(__file__).resolve().parent.parent
HELD_OUT = ROOT / "maps" / "designer" / "held-out"
SHIPPED_VAL = sorted((ROOT / "maps").glob("val-*.yaml"))
REALMAPS = ROOT.parent / "shared" / "realmaps"
LOCAL = ("random_search", "hillclimb", "anneal", "pattern")
LABELS = {"random_search": "random search", "hillclimb": "hill climbing", "anneal": "annealing",
          "pattern": "compass search", "nsga2": "NSGA-II"}  # fmt: skip
NSGA_POP = 20


def progress(label: str, done: int, total: int, t0: float) -> None:
    """One progress line on stderr: rewritten in place on a terminal, every tenth otherwise."""
    tty = sys.stderr.isatty()
    if tty or done == total or done % max(1, total // 10) == 0:
        end = "\n" if not tty or done == total else ""
        sys.stderr.write(f"{chr(13) if tty else ''}{label} {done}/{total} ({time.perf_counter() - t0:.0f} s){end}")
        sys.stderr.flush()


def gap_pct(optimum: float, value: float) -> float:
    return 100.0 * (optimum - value) / abs(optimum)


def baseline_gaps(method: str, path: str, env_config: dict, budget: int, seeds: int, optimum: float) -> float:
    """The method's median gap over `seeds` independent runs of `budget` evaluations on one floor."""
    if method == "nsga2":
        from smorphi_rl.search.nsga2 import run_nsga2

        cfg = MorphologyEnv({**env_config, "maps": [path]}).config
        weights = cfg.weights_on(load_map(path))
        values = []
        for s in range(seeds):  # whole generations, then the first `budget` distinct shapes it scored
            result = run_nsga2(path, NSGA_POP, math.ceil(budget / NSGA_POP), s, cfg.planning)
            _, first = np.unique(result.thetas, axis=0, return_index=True)
            kept = np.sort(first)[:budget]
            values.append(float(np.max(weights.r1(result.P_c[kept], result.P_len[kept]))))
        return float(np.median([gap_pct(optimum, v) for v in values]))
    env = MorphologyEnv({**env_config, "maps": [path]})
    outcomes = run_local(method, env, eval_starts(seeds, env.config.angle_step_deg), budget, seed=11)
    return float(np.median([gap_pct(optimum, o.R1) for o in outcomes]))


def median_interval(values: np.ndarray, seed: int = 0) -> tuple[float, float, float]:
    """Median of per-floor values and its 95 % percentile bootstrap interval (`stats.median_interval`)."""
    from smorphi_rl.stats import median_interval as over

    got = over([float(v) for v in np.asarray(values, dtype=float)], seed)
    return got.point, got.lo, got.hi


def summarise(gaps: np.ndarray) -> dict[str, float]:
    med, lo, hi = median_interval(gaps)
    return {"median": med, "lo": lo, "hi": hi, "p90": float(np.percentile(gaps, 90)),
            "within": float(np.mean(gaps <= 1.0))}  # fmt: skip


def realmap_floors(work: Path) -> list[str]:
    """`tb3_world` cropped to its arena at its native 0.05 m, and a 15 m x 15 m part of `depot` resampled to
    0.1 m (the whole depot is larger than a designer takes), as `maps crop` and `maps resample` make them."""
    from smorphi_rl.maptools import crop_to_known, crop_to_rect, drop_islands, resample

    out = []
    if (REALMAPS / "tb3_world.yaml").is_file():
        tb3, _ = drop_islands(crop_to_known(load_map(REALMAPS / "tb3_world.yaml"), 0.2), 0.05)
        out.append(str(save_map(replace(tb3, name="tb3_world-arena"), work / "tb3_world-arena.yaml")))
    if (REALMAPS / "depot.yaml").is_file():
        depot = load_map(REALMAPS / "depot.yaml")
        x0, y0 = depot.origin[0], depot.origin[1]
        part = crop_to_rect(depot, x0 + 2.0, y0 + 1.5, x0 + 14.0, y0 + 13.5)
        part, _ = drop_islands(resample(part, 0.1), 0.5)
        out.append(str(save_map(replace(part, name="depot-part"), work / "depot-part.yaml")))
    return out


def per_map_ppo(designer_dir: Path, maps: list[str], steps: int, log_dir: Path, optima: dict) -> list[dict]:
    """Per-map PPO from scratch and fine-tuned from the designer, `steps` env steps each, on `maps`: the best
    shape each found and where its greedy policy settles (the protocol), against the floor's optimum."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.run import train

    designer = load_designer(designer_dir)
    rows = []
    with open(os.devnull, "w") as quiet:
        for path in maps:
            env = replace(designer.env_config, maps=EnvConfig.from_dict({"maps": [path]}).maps)
            name = Path(path).stem
            for mode in ("scratch", "fine-tune"):
                pretrained = str(designer_dir) if mode == "fine-tune" else None
                cfg = TrainConfig(env=env, timesteps=steps, eval_every=5, eval_starts=20, select_starts=0,
                                  record_every=0, pretrained=pretrained)  # fmt: skip
                summary = whole(train(cfg, name=f"{name}-{mode}", log_dir=log_dir, out=quiet))
                ev = summary.evaluation
                best = summary.best.R1 if summary.best else math.nan
                opt = optima[name]
                rows.append({"map": name, "mode": mode, "env_steps": summary.env_steps,
                             "best_gap_pct": gap_pct(opt, best),
                             "settled_gap_pct": 100 * ev.get("median_gap", math.nan) / abs(opt),
                             "within": ev.get("share_within_1pct", math.nan)})  # fmt: skip
                r = rows[-1]
                print(f"  ppo {mode:<9} {name:<16} {summary.env_steps:,} steps: best found {r['best_gap_pct']:.2f} % "
                      f"below R1*, greedy settles {r['settled_gap_pct']:.2f} % below ({100 * r['within']:.0f} % of "
                      "starts within 1 %)", flush=True)  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", nargs="+", default=[str(SHIPPED_DESIGNER)], help="designer policy folders")
    parser.add_argument("--budgets", nargs="+", type=int, default=[25, 50, 100, 200, 400])
    parser.add_argument("--budget", type=int, default=200, help="the budget of the table and the targets")
    parser.add_argument("--seeds", type=int, default=5, help="independent runs of each search per floor")
    parser.add_argument("--floors", type=int, default=0, help="use only the first N held-out floors (0: all)")
    parser.add_argument("--ppo-maps", type=int, default=4, help="floors for per-map PPO (0: skip it)")
    parser.add_argument("--ppo-steps", type=int, default=20_000)
    parser.add_argument("--no-nsga2", action="store_true")
    parser.add_argument("--train-steps", type=int, default=0, help="also train the designer's sweep trial for this "
                        "many env steps and report its rate and peak memory (0: skip)")  # fmt: skip
    parser.add_argument("--out", default=str(ROOT / "logs" / "bench-designer"), help="results.json and the PNG")
    parser.add_argument("--log-dir", default=str(ROOT / "logs"), help="where exact optima are cached")
    parser.add_argument("--write-docs", action="store_true", help="rewrite the Designer section of docs/benchmarks.md")
    parser.add_argument("--record", action="store_true", help="write designer 1's held-out figures into its "
                        "policy.json (`held_out`), beside the command that trained it")  # fmt: skip
    args = parser.parse_args()
    check_at_least(("--budget", args.budget, 1), ("--seeds", args.seeds, 1), ("--floors", args.floors, 0),
                   ("--ppo-maps", args.ppo_maps, 0), ("--ppo-steps", args.ppo_steps, 1),
                   ("--train-steps", args.train_steps, 0), *(("--budgets", b, 1) for b in args.budgets))  # fmt: skip
    t_start = time.perf_counter()
    designers = [load_designer(Path(p)) for p in args.policy]  # before anything is written
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    budgets = sorted(set(args.budgets) | {args.budget})
    env_config = designers[0].env_config
    floors = sorted(str(p) for p in HELD_OUT.glob("*.yaml"))
    floors = floors[: args.floors] if args.floors else floors
    floors += [str(p) for p in SHIPPED_VAL]
    work = Path(tempfile.mkdtemp(prefix="bench-designer-"))
    real = realmap_floors(work)
    if not real:
        print(f"real maps: {REALMAPS} not found, skipped")
    cache = Path(args.log_dir) / ".cache"
    optima: dict[str, float] = {}
    t0 = time.perf_counter()
    for i, path in enumerate(floors + real):
        grid_map = load_map(path)
        cfg = replace(env_config, maps=(str(Path(path).resolve()),))
        optima[grid_map.name] = exact_optimum(path, cfg.weights_on(grid_map), cfg.planning, cache).R1
        progress("exact optima", i + 1, len(floors) + len(real), t0)
    designer_names = [f"designer {i + 1}" for i in range(len(designers))]
    methods = designer_names + list(LOCAL) + ([] if args.no_nsga2 else ["nsga2"])
    raw = env_config.to_dict() | {"maps": None}
    gaps: dict[str, dict[int, dict[str, float]]] = {m: {b: {} for b in budgets} for m in methods}
    timing: dict[str, float] = {m: 0.0 for m in methods}
    for j, path in enumerate(floors + real):
        name = load_map(path).name
        for i, d in enumerate(designers):
            env = designer_env(d, path)
            for b in budgets:  # like every search: the median of `--seeds` seeded designs (moves drawn, restarts)
                t = time.perf_counter()
                runs = [run_design(env, d.logits, b, seed=s).best.R1 for s in range(args.seeds)]
                gaps[f"designer {i + 1}"][b][name] = float(np.median([gap_pct(optima[name], r) for r in runs]))
                timing[f"designer {i + 1}"] += time.perf_counter() - t  # over every seed, as the searches'
        for m in methods[len(designers) :]:
            for b in budgets:
                t = time.perf_counter()
                gaps[m][b][name] = baseline_gaps(m, path, {k: v for k, v in raw.items() if k != "maps"}, b, args.seeds,
                                                 optima[name])  # fmt: skip
                timing[m] += time.perf_counter() - t
        progress("floors", j + 1, len(floors) + len(real), t0)
    held = [load_map(p).name for p in floors]
    real_names = [load_map(p).name for p in real]
    report = {"budget": args.budget, "budgets": budgets, "floors": len(held), "seeds": args.seeds,
              "policies": [str(d.path) for d in designers], "methods": {}, "real": {}}  # fmt: skip
    lines = [f"Held-out floors: {len(held)} ({len(held) - len(SHIPPED_VAL)} generated with seeds that training never "
             f"draws, and the {len(SHIPPED_VAL)} shipped val-* maps); each search's gap is its median over "
             f"{args.seeds} seeded runs on a floor; [95 % bootstrap interval] across floors.", "",
             *provenance(designer_names, designers), "",
             f"| method ({args.budget} planner evaluations) | median gap | 90th percentile | floors within 1 % | "
             + " | ".join(f"{d} better by (median of per-floor differences)" for d in designer_names) + " |",
             "|---|---:|---:|---:|" + "---:|" * len(designer_names)]  # fmt: skip
    for m in methods:
        g = np.array([gaps[m][args.budget][n] for n in held])
        s = summarise(g)
        diffs = {d: median_interval(g - np.array([gaps[d][args.budget][n] for n in held])) if m != d
                 else (math.nan, math.nan, math.nan) for d in designer_names}  # fmt: skip
        report["methods"][m] = {"at_budget": s, "difference_vs_designer_1": diffs["designer 1"],
                                "differences": {d: diffs[d] for d in designer_names if d != m},
                                "curve": {b: summarise(np.array([gaps[m][b][n] for n in held])) for b in budgets},
                                "per_floor": gaps[m][args.budget], "seconds": timing[m]}  # fmt: skip
        dtext = " | ".join("-" if m == d else f"{diff[0]:+.3f} [{diff[1]:+.3f}, {diff[2]:+.3f}] %"
                           for d, diff in diffs.items())  # fmt: skip
        lines.append(f"| {LABELS.get(m, m)} | {s['median']:.3f} [{s['lo']:.3f}, {s['hi']:.3f}] % | {s['p90']:.2f} % | "
                     f"{100 * s['within']:.0f} % | {dtext} |")  # fmt: skip
    lines += ["", "Median gap (per cent of R1*) by budget:", "",
              "| method | " + " | ".join(str(b) for b in budgets) + " |", "|---|" + "---:|" * len(budgets)]  # fmt: skip
    for m in methods:
        cells = [f"{report['methods'][m]['curve'][b]['median']:.3f}" for b in budgets]
        lines.append(f"| {LABELS.get(m, m)} | " + " | ".join(cells) + " |")
    if real_names:
        lines += ["", f"Real maps (../shared/realmaps, cropped and resampled as `maps crop` / `maps resample` do), "
                  f"gap at {args.budget} evaluations:", "", "| map | " + " | ".join(LABELS.get(m, m) for m in methods)
                  + " |", "|---|" + "---:|" * len(methods)]  # fmt: skip
        for n in real_names:
            lines.append(f"| {n} | " + " | ".join(f"{gaps[m][args.budget][n]:.2f} %" for m in methods) + " |")
            report["real"][n] = {m: gaps[m][args.budget][n] for m in methods}
    if args.ppo_maps:
        print("per-map PPO, scratch and fine-tuned from designer 1:")
        rows = per_map_ppo(designers[0].path, floors[: args.ppo_maps], args.ppo_steps, work / "ppo",
                           {k: v for k, v in optima.items()})  # fmt: skip
        report["per_map_ppo"] = rows
        lines += ["", f"Per-map PPO at {args.ppo_steps:,} env steps on {args.ppo_maps} held-out floors (designer 1 "
                  f"needs no training there: {args.budget} planner evaluations); one PPO seed a floor, an "
                  "illustration: no claim is drawn from it:", "",
                  "| floor | designer 1 | PPO from scratch: best found / greedy settles | fine-tuned from the "
                  "designer: best found / greedy settles |", "|---|---:|---:|---:|"]  # fmt: skip
        for path in floors[: args.ppo_maps]:
            n = load_map(path).name
            by = {r["mode"]: r for r in rows if r["map"] == n}
            lines.append(f"| {n} | {gaps['designer 1'][args.budget][n]:.2f} % | {by['scratch']['best_gap_pct']:.2f} / "
                         f"{by['scratch']['settled_gap_pct']:.2f} % | {by['fine-tune']['best_gap_pct']:.2f} / "
                         f"{by['fine-tune']['settled_gap_pct']:.2f} % |")  # fmt: skip
    if args.train_steps:
        lines += ["", *training_cost(args.train_steps, work / "train")]
    png = plot_curves(report, methods, (ROOT / "docs" if args.write_docs else out) / "designer_gap.png")
    lines += ["", "![gap against evaluations](designer_gap.png)" if args.write_docs else f"plot: {png}"]
    d1 = report["methods"]["designer 1"]["at_budget"]
    targets = [
        f"median {d1['median']:.3f} % (target <= 1 %): {'met' if d1['median'] <= 1 else 'NOT met'}",
        f"90th percentile {d1['p90']:.2f} % (target <= 3 %): {'met' if d1['p90'] <= 3 else 'NOT met'}",
    ]
    for m in ("random_search", "hillclimb", "nsga2"):
        if m in report["methods"]:
            lo = report["methods"][m]["difference_vs_designer_1"][1]
            targets.append(f"lower than {LABELS[m]} with the interval excluding 0: {'met' if lo > 0 else 'NOT met'}")
    designs = max(1, len(held + real_names) * len(budgets) * args.seeds)
    lines += ["", "Targets: " + "; ".join(targets) + ".",
              f"Wall time {time.perf_counter() - t_start:.0f} s; designer 1 took "
              f"{timing['designer 1'] / designs * 1000:.0f} ms a design on average (NumPy policy, planner "
              "included)."]  # fmt: skip
    text = "\n".join(lines)
    print(text)
    (out / "results.json").write_text(jsontext.dumps(report, indent=2, default=float))  # NaN: null, strict JSON
    print(f"results: {out / 'results.json'}\nplot:    {png}")
    if args.record:
        record_figures(designers[0].path, report, args)
    if args.write_docs:
        print(f"docs:    {write_section('designer', '## Designer (`scripts/bench_designer.py`)' + chr(10) * 2 + text)}")


def provenance(names: list[str], designers: list[Designer]) -> list[str]:
    """A line a designer: its folder, what it was trained on and the command its export recorded (a seed's)."""
    lines = []
    for name, d in zip(names, designers, strict=True):
        command = d.policy.meta.get("command")
        folder = d.path.resolve()
        shown = folder.relative_to(ROOT) if folder.is_relative_to(ROOT) else folder
        lines.append(f"- {name}: `{shown}` ({d.summary}{f'; {command}' if isinstance(command, str) else ''})")
    return lines


def training_cost(steps: int, log_dir: Path) -> list[str]:
    """The designer's sweep trial (tune_configs/designer.yaml, seed 0) for `steps` env steps under the memory
    probe: wall time, env steps a second and the peak PSS of the process tree (Ray's processes included)."""
    from _memory import PeakMemory

    from smorphi_rl.protocol import CACHE_ENV
    from smorphi_rl.training.run import train
    from smorphi_rl.training.sweep_config import load_sweep

    sweep = load_sweep(ROOT / "tune_configs" / "designer.yaml")
    cfg = replace(sweep.base_config("ppo", sweep.map_sets[0], 0, {}), timesteps=steps)
    os.environ.setdefault(CACHE_ENV, str(ROOT / "logs" / ".cache"))  # the validation floors' optima, computed once
    t0 = time.perf_counter()
    with PeakMemory() as mem, open(os.devnull, "w") as quiet:
        summary = whole(train(cfg, name="designer-cost", log_dir=log_dir, out=quiet))
    wall = time.perf_counter() - t0
    rate = summary.env_steps / summary.wall_s
    full = sweep.step_budget / rate / 60
    print(f"designer training: {summary.env_steps:,} env steps in {summary.wall_s:.0f} s of training ({wall:.0f} s "
          f"end to end), {rate:,.0f} env steps/s, peak PSS {mem.peak_pss / 2**30:.2f} GiB")  # fmt: skip
    return [
        f"Designer training (`tune_configs/designer.yaml`'s trial, seed 0, {summary.env_steps:,} env steps on "
        f"{cfg.env_runners} env runners): {rate:,.0f} env steps/s ({full:.0f} min for its {sweep.step_budget:,}), "
        f"{wall:.0f} s end to end, "
        f"peak memory {mem.peak_pss / 2**30:.2f} GiB (PSS of the process tree, Ray's processes included)."
    ]


def record_figures(policy_dir: Path, report: dict, args: argparse.Namespace) -> None:
    """Designer 1's held-out figures into its policy.json (rewritten through a temporary file)."""
    from smorphi_rl.rundir import write_atomic

    meta_file = policy_dir / "policy.json"
    meta = json.loads(meta_file.read_text())
    d1 = report["methods"]["designer 1"]
    meta["held_out"] = {
        "floors": report["floors"], "budget": args.budget, "command": "scripts/bench_designer.py --record",
        "median_gap_pct": round(d1["at_budget"]["median"], 4), "p90_gap_pct": round(d1["at_budget"]["p90"], 4),
        "share_of_floors_within_1pct": round(d1["at_budget"]["within"], 4),
        "median_gap_pct_by_budget": {str(b): round(v["median"], 4) for b, v in d1["curve"].items()},
    }  # fmt: skip
    write_atomic(meta_file, (json.dumps(meta, indent=2) + "\n").encode())
    print(f"policy:  {meta_file} (held_out figures recorded)")


def plot_curves(report: dict, methods: list[str], png: Path) -> Path:
    """Median gap against planner evaluations for every method, with its 95 % interval across floors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for m in methods:
        curve = report["methods"][m]["curve"]
        b = sorted(curve)
        med = [curve[x]["median"] for x in b]
        ax.plot(b, med, marker="o", label=LABELS.get(m, m), lw=2.5 if m.startswith("designer") else 1.2)
        ax.fill_between(b, [curve[x]["lo"] for x in b], [curve[x]["hi"] for x in b], alpha=0.15)
    ax.set_xscale("log")
    ticks = sorted(report["budgets"])
    ax.set_xticks(ticks, [str(t) for t in ticks])  # the budgets themselves, not 3 x 10^1
    ax.minorticks_off()
    ax.set_xlabel("planner evaluations (distinct shapes scored)")
    ax.set_ylabel("median gap to the exact optimum (% of R1*)")
    ax.set_title(f"held-out floors ({report['floors']}): designer vs search at equal budgets")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM, or a training run `whole` found cut short: nothing written
        stop_interrupted()
    except SmorphiError as exc:  # a bad option or input: one line, as the CLI gives it
        print(f"{Path(sys.argv[0]).name}: error: {exc}", file=sys.stderr)
        raise SystemExit(1) from None

"""Benchmark learning against the exact optimum: do trained policies settle on the best shape?

For every map, algorithm, reward mode and seed: `train` (its own code path, default preset and
layout) for a fixed budget, then the evaluation protocol: greedy roll-outs from the 20 fixed
starts, each settled shape's gap to the exact 1-degree optimum. Yardsticks from the same starts,
seeded the same way: a random walk (uniform moves, settled as a policy's would be), hill
climbing, simulated annealing and random search, each held to the FBCPP evaluations the policies
used per start. Every figure is the mean over seeds with a 95 % bootstrap interval; a trained run's
convergence (the README's definition, `smorphi_rl/training/convergence.py`) is counted over seeds. The ceiling:
the exact optimal policy of each reward mode at the preset's discount (value iteration over the whole
lattice, `smorphi_rl/search/ideal.py`), rolled out greedily from the same starts (`--no-ideal` skips it).

    .venv/bin/python scripts/bench_learning.py [--maps maps/map-1.yaml maps/map-2.yaml]
        [--algos ppo impala appo] [--rewards peak] [--seeds 100 101 102] [--timesteps 300000]
        [--async-timesteps 600000] [--no-ideal]
        [--set NAME=VALUE ...] [--env-runners N] [--envs-per-runner N] [--out NAME]

Prints a table and writes it (learning.md), the per-run rows (learning.csv) and the greedy gap
curves (learning_curves.png) under logs/NAME (default logs/bench-learning-<time>).
"""

from __future__ import annotations

import argparse
import csv
import itertools
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from _benchdocs import run_documented, whole

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.maps import load_map
from smorphi_rl.protocol import MapEvaluation, Optimum, eval_starts, exact_optimum
from smorphi_rl.rundir import RunDirError, prepare_run_dir
from smorphi_rl.search.exhaustive import run_exhaustive
from smorphi_rl.search.ideal import IDEAL_MODES, greedy_settled, move_values, stay_move_costs
from smorphi_rl.search.local import run_local
from smorphi_rl.stats import FEW_SEEDS_NOTE, cell, censored_median_interval, mean_interval
from smorphi_rl.training.checkpoints import load_module
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.convergence import censored_steps, converged_text, convergence
from smorphi_rl.training.policy import evaluate_policy
from smorphi_rl.training.presets import DEFAULT_TIMESTEPS, ENVS_PER_RUNNER, PRESETS
from smorphi_rl.training.run import train
from smorphi_rl.training.transfer import summary_curve

ROOT = Path(__file__).resolve().parent.parent
BASELINES = ("random_walk", "hillclimb", "anneal", "random_search")
HEADLINE_SEEDS = (100, 101, 102)
"""The headline's training seeds: the presets' settings were screened with seeds 0-5 (docs/decisions.md), so figures
on those would flatter them."""


@dataclass
class Row:
    """One run (or one seeded baseline) on one map: the protocol's figures."""

    map: str
    method: str
    seed: int
    median_gap: float
    within: float
    evaluations: float
    settled_R1: float
    wall_s: float = float("nan")
    curve: tuple[list[float], list[float]] | None = None
    converged_at: float | None = None
    """A trained run's env steps until it converged (None: it did not, or it is a baseline)."""
    converged: str = ""
    """As `converged_text` says it for a trained run ("not converged", "not measured"); a baseline's: empty."""
    env_steps: float = 0.0
    """The env steps a trained run trained: where one that did not converge would have to converge past."""


def row_of(ev: MapEvaluation, method: str, seed: int, wall_s: float = float("nan"), curve=None,
           converged_at: float | None = None, converged: str = "", env_steps: float = 0.0) -> Row:  # fmt: skip
    return Row(ev.map, method, seed, ev.median_gap, ev.within / len(ev.outcomes), ev.mean_evaluations, ev.mean_R1,
               wall_s, curve, converged_at, converged, env_steps)  # fmt: skip


def converged_cell(group: list[Row]) -> str:
    """How many of a group's trained runs converged, and the median env steps to it with its interval over every
    measured run (one that did not converge counts past the env steps it trained: `convergence.censored_steps`, as
    the sweep and transfer tables count it); "-" for a baseline."""
    if not all(r.converged for r in group):
        return "-"
    measured = [r for r in group if r.converged != "not measured"]
    count = f"{sum(r.converged_at is not None for r in measured)} of {len(measured)}"
    if not measured:
        return "not measured"
    median = censored_median_interval(*censored_steps([(r.converged_at, r.env_steps) for r in measured]))
    return f"{count}, median {median.text(',.0f')} steps"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--maps", nargs="+", default=[str(ROOT / "maps" / "map-1.yaml"), str(ROOT / "maps" / "map-2.yaml")]
    )
    parser.add_argument("--algos", nargs="+", default=["ppo", "impala", "appo"])
    parser.add_argument("--rewards", nargs="+", default=["peak"], help="reward modes (default: train's; the "
                        "paper's R1 + R2 settles no policy, docs/decisions.md)")  # fmt: skip
    parser.add_argument("--seeds", nargs="+", type=int, default=list(HEADLINE_SEEDS),
                        help="training seeds (default: none the presets were screened on)")  # fmt: skip
    parser.add_argument("--timesteps", type=int, default=DEFAULT_TIMESTEPS, help="PPO's budget (the main job's)")
    parser.add_argument("--async-timesteps", type=int, default=2 * DEFAULT_TIMESTEPS,
                        help="IMPALA's and APPO's budget (the target: at most twice PPO's env steps)")  # fmt: skip
    parser.add_argument("--no-ideal", action="store_true", help="skip the value-iteration ceiling")
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                        help="hyperparameters replacing the presets' (Preset field names)")  # fmt: skip
    parser.add_argument("--env-runners", type=int, default=None, metavar="N",
                        help="remote env runners (default: the preset's; 0: in the trial process)")  # fmt: skip
    parser.add_argument("--envs-per-runner", type=int, default=ENVS_PER_RUNNER, metavar="N")
    parser.add_argument("--out", default=None, metavar="NAME", help="results go to LOG_DIR/NAME")
    parser.add_argument("--log-dir", default=str(ROOT / "logs"), metavar="DIR",
                        help="where results and the optima's cache go (default: the repository's logs/)")  # fmt: skip
    args = parser.parse_args()
    if (args.env_runners is not None and args.env_runners < 0) or args.envs_per_runner < 1:
        raise SystemExit("bench_learning.py: --env-runners must be at least 0 and --envs-per-runner at least 1")
    overrides = parse_overrides(args.set)
    layout = (args.env_runners, args.envs_per_runner)
    for algo, reward, map_path in itertools.product(args.algos, args.rewards, args.maps):  # checked before writing
        budget = args.timesteps if algo == "ppo" else args.async_timesteps
        run_config(algo, reward, 0, map_path, budget, overrides, layout)
    names = {m: load_map(m).name for m in args.maps}  # a missing map is named before anything is written
    try:
        out = prepare_run_dir(Path(args.log_dir), args.out or f"bench-learning-{time.strftime('%Y%m%d-%H%M%S')}")
    except RunDirError as exc:
        raise SystemExit(f"bench_learning.py: {exc}") from None
    starts = eval_starts()
    rows: list[Row] = []
    t_all = time.monotonic()
    for map_path in args.maps:
        name = names[map_path]
        base_env = EnvConfig.from_dict({"maps": [map_path]})
        weights = base_env.weights_on(load_map(map_path))
        optimum = exact_optimum(map_path, weights, base_env.planning, Path(args.log_dir) / ".cache")
        print(f"{name}: exact optimum R1* {optimum.R1:.2f} at {optimum.theta} (1-degree lattice); "
              f"1 % band: R1 >= {optimum.R1 - 0.01 * abs(optimum.R1):.2f}", flush=True)  # fmt: skip
        for algo in args.algos:
            for reward in args.rewards:
                for seed in args.seeds:
                    budget = args.timesteps if algo == "ppo" else args.async_timesteps
                    rows.append(train_and_evaluate(algo, reward, seed, map_path, budget, optimum, starts, out,
                                                   overrides, layout))  # fmt: skip
                    r = rows[-1]
                    print(f"  {r.method} seed {seed}: median gap {r.median_gap:.2f}, within 1 % {r.within:.0%}, "
                          f"settled R1 {r.settled_R1:.2f}, {r.evaluations:.0f} evaluations a start, {r.wall_s:.0f} s",
                          flush=True)  # fmt: skip
        if not args.no_ideal:
            rows.extend(ideal_rows(map_path, base_env, optimum, starts, args.rewards))
        policy_rows = [r for r in rows if r.map == name and not r.method.startswith("ideal")]
        budget = max(1, round(float(np.median([r.evaluations for r in policy_rows])))) if policy_rows else 200
        env = MorphologyEnv(base_env.to_dict())
        for method in BASELINES:
            for seed in args.seeds:
                outcomes = run_local(method, env, starts, budget, seed)
                rows.append(row_of(MapEvaluation(name, method, optimum, tuple(outcomes)), f"{method} ({budget} evals)",
                                   seed))  # fmt: skip
    report(rows, out, args, time.monotonic() - t_all)


def parse_overrides(pairs: list[str]) -> dict[str, float]:
    """NAME=VALUE pairs as numbers (integers where they read as one)."""
    overrides: dict[str, float] = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        try:
            overrides[name] = int(value) if value.lstrip("-").isdigit() else float(value)
        except ValueError:
            raise SystemExit(f"bench_learning.py: --set {pair!r}: expected NAME=NUMBER") from None
    return overrides


def run_config(algo: str, reward: str, seed: int, map_path: str, timesteps: int, overrides: dict[str, float],
               layout: tuple[int | None, int]) -> TrainConfig:  # fmt: skip
    """One benchmark run's configuration (a bad --set name or value is a TrainConfigError here)."""
    return TrainConfig(algo=algo, env=EnvConfig.from_dict({"maps": [map_path], "reward": reward}),
                       timesteps=timesteps, seed=seed, num_env_runners=layout[0], envs_per_runner=layout[1],
                       record_every=0, checkpoint_every=1000, overrides=overrides)  # fmt: skip


def train_and_evaluate(algo: str, reward: str, seed: int, map_path: str, timesteps: int, optimum: Optimum,
                       starts: np.ndarray, out: Path, overrides: dict[str, float],
                       layout: tuple[int | None, int] = (None, ENVS_PER_RUNNER)) -> Row:  # fmt: skip
    cfg = run_config(algo, reward, seed, map_path, timesteps, overrides, layout)
    name = f"{algo}-{reward}-{Path(map_path).stem}-seed{seed}"
    with open(os.devnull, "w") as devnull:
        summary = whole(train(cfg, name=name, log_dir=out / "runs", out=devnull))
    module = load_module(summary.checkpoint)
    (ev,) = evaluate_policy(module, cfg.env, starts, {optimum_name(map_path): optimum})
    curve = summary_curve(summary.run_dir)
    steps, gaps = curve["env_steps"], curve["eval_gap"]
    kept = [(s, g) for s, g in zip(steps, gaps, strict=True) if np.isfinite(g)]
    at = convergence(curve)[0]
    return row_of(ev, f"{algo.upper()} {reward}", seed, summary.wall_s,
                  ([s for s, _ in kept], [g for _, g in kept]), at, converged_text(at, curve),
                  summary.env_steps)  # fmt: skip


def ideal_rows(map_path: str, env: EnvConfig, optimum: Optimum, starts: np.ndarray, rewards: list[str]) -> list[Row]:
    """The exact optimal policy of each reward mode (at the PPO preset's discount), rolled out greedily."""
    from smorphi_rl.protocol import Outcome

    name = load_map(map_path).name
    result = run_exhaustive(map_path, planning=env.planning)
    n = round(len(result.thetas) ** (1 / 3))
    r1 = np.where(result.feasible, env.weights_on(load_map(map_path)).r1(result.P_c, result.P_len), 0.0)
    r1 = r1.reshape(n, n, n)
    gamma = PRESETS["fast"]["ppo"].gamma
    rows = []
    for reward in (r for r in rewards if r in IDEAL_MODES):
        t0 = time.monotonic()
        w = move_values(r1, reward, gamma, env.beta, env.move_cost)
        stay, move = stay_move_costs(reward, env.beta, env.move_cost)
        settled = greedy_settled(w, starts.astype(int), env.max_steps, stay, move)
        outcomes = []
        for start, idx in zip(starts, settled, strict=True):
            flat = (idx[0] * n + idx[1]) * n + idx[2]
            outcomes.append(Outcome(tuple(float(v) for v in start), tuple(float(v) for v in idx), float(r1[idx]),
                                    float(result.P_c[flat]), int(result.P_len[flat]), 0))  # fmt: skip
        ev = MapEvaluation(name, f"ideal {reward}", optimum, tuple(outcomes))
        rows.append(row_of(ev, f"ideal {reward} (value iteration, gamma {gamma})", 0, time.monotonic() - t0))
        r = rows[-1]
        print(f"  {r.method}: median gap {r.median_gap:.2f}, within 1 % {r.within:.0%}, {r.wall_s:.0f} s", flush=True)
    return rows


def optimum_name(map_path: str) -> str:
    return load_map(map_path).name


def report(rows: list[Row], out: Path, args: argparse.Namespace, wall_s: float) -> None:
    from smorphi_rl.plots import plot_gap_curves

    with (out / "learning.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["map", "method", "seed", "median_gap", "share_within_1pct", "evaluations_per_start",
                         "settled_R1_mean", "wall_s", "converged_at_env_steps"])  # fmt: skip
        for r in rows:
            writer.writerow([r.map, r.method, r.seed, cell(r.median_gap, ".4f"), cell(r.within, ".3f"),
                             cell(r.evaluations, ".1f"), cell(r.settled_R1, ".4f"), cell(r.wall_s, ".1f"),
                             r.converged])  # fmt: skip
    changed = f" Hyperparameters changed from the presets: {' '.join(args.set)}." if args.set else ""
    if args.env_runners is not None or args.envs_per_runner != ENVS_PER_RUNNER:
        runners = "the preset's" if args.env_runners is None else args.env_runners
        changed += f" Sampling: {runners} env runners x {args.envs_per_runner} envs."
    lines = [f"Greedy settled gap to the exact optimum, {len(args.seeds)} seeds ({', '.join(map(str, args.seeds))}), "
             f"{args.timesteps:,} env steps per PPO run and {args.async_timesteps:,} per IMPALA or APPO run, 20 fixed "
             "starts; mean over seeds [95 % bootstrap interval]. Converged: runs that converged (from some "
             "evaluation on, at least 90 % of the starts within 1 %), and the median env steps to it over the runs, "
             f"one that did not converge counting past its budget. {FEW_SEEDS_NOTE}"
             + changed, "",
             "| map | method | median gap (R1) | share of starts within 1 % | settled R1 | FBCPP evaluations a start "
             "| converged |",
             "|---|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    for map_name, method in dict.fromkeys((r.map, r.method) for r in rows):
        group = [r for r in rows if r.map == map_name and r.method == method]
        gap = mean_interval([r.median_gap for r in group])
        within = mean_interval([100 * r.within for r in group])
        r1 = mean_interval([r.settled_R1 for r in group])
        evals = float(np.mean([r.evaluations for r in group]))
        lines.append(f"| {map_name} | {method} | {gap.text()} | {within.text('.0f')} % | {r1.text()} | {evals:.0f} "
                     f"| {converged_cell(group)} |")  # fmt: skip
    lines.append("")
    lines.append(f"{len(rows)} rows in {wall_s / 60:.1f} min.")
    text = "\n".join(lines)
    (out / "learning.md").write_text(text + "\n")
    curves = {f"{r.map} {r.method}": [] for r in rows if r.curve}
    for r in rows:
        if r.curve:
            curves[f"{r.map} {r.method}"].append(r.curve)
    png = plot_gap_curves(curves, out / "learning_curves.png") if curves else None
    print("\n" + text)
    print(f"\ntable: {out / 'learning.md'}\nrows: {out / 'learning.csv'}" + (f"\ncurves: {png}" if png else ""))


if __name__ == "__main__":
    run_documented("learning", "Learning against the exact optimum (`scripts/bench_learning.py`)", main)

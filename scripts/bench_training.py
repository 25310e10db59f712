"""Benchmark training throughput on map-1: PPO and IMPALA through `smorphi-rl train`'s own code path.

Prints, in one run on this machine:
- the yardstick: the bare env stepping with random actions in this process (env steps/s), measured again
  after each training run (the machine's speed drifts): each ratio uses the mean of the measures around it;
- sampling alone: the algorithm's env runners sampling with a fresh policy, no learning (env steps/s);
- Ray start-up and shutdown, measured on their own;
- for each algorithm, `train` end to end as it reports itself ("trained for N env steps in T"): env
  steps/s and the ratio to the bare env, learner time per iteration, and the greedy evaluation at the
  end (settled R1 from the protocol's 20 fixed starts);
- peak memory (PSS summed over the driver and every Ray process) in a second run of the same training:
  the probe reads every process's /proc/PID/smaps_rollup twice a second, about 50 ms of kernel page-table
  walks each time, and slowed the run it watched by 3-10 s (PPO: 48.6 -> 58.0 s and 46.7 -> 49.9 s), so
  the timed run goes unwatched;
- learning per env step before and after: the first layout (2 runners x 1 env, 1,000-step batches,
  8 epochs of 4 minibatches) against the new default, same seed and budget, by the protocol's
  settled R1 (`--compare-layouts`);
- the cost of recording every episode to MCAP (`--recording-cost`).
Targets (2-core machine): PPO >= 2,000 env steps/s as `train` reports it, >= 0.12 of the bare env;
sampling >= 5,000/s; Ray start-up + shutdown < 15 s; IMPALA at least PPO's rate; peak < 3 GiB.

    .venv/bin/python scripts/bench_training.py [--algos ppo impala] [--timesteps 200000] [--seed 0]
        [--compare-layouts] [--recording-cost]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _benchdocs import run_documented, whole
from _memory import PeakMemory

from smorphi_rl import cluster
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.quiet import quiet
from smorphi_rl.training.config import (
    TrainConfig,
    algorithm_config,
    recording_settings,
    register_env,
    standalone_algorithm,
)
from smorphi_rl.training.run import train

TARGET_PPO_RATE = 2000.0
TARGET_RATIO = 0.12
TARGET_SAMPLING = 5000.0
TARGET_RAY_S = 15.0
TARGET_PEAK_GIB = 3.0
OLD_LAYOUT = {"num_env_runners": 2, "envs_per_runner": 1}
OLD_PPO = {"train_batch_size": 1000, "num_epochs": 8, "minibatch_size": 250}
"""The first layout and PPO preset, which `train` ran at about 174 env steps/s."""


def env_step_rate(env_config: dict[str, object], steps: int = 20_000) -> float:
    """The yardstick: a new bare env (cold caches, so every measure does the same work) stepping with random
    actions in this process."""
    env = MorphologyEnv(env_config)
    rng = np.random.default_rng(1)
    actions = rng.integers(0, 3, size=(steps, 3))
    env.reset(seed=1)
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def ray_overhead() -> float:
    """Seconds to start a local Ray for a run and shut it down again, nothing else."""
    t0 = time.perf_counter()
    with cluster.ray_session(None):
        pass
    return time.perf_counter() - t0


def sampling_rate(cfg: TrainConfig, steps: int = 20_000) -> float:
    """Env steps/s of the algorithm's env runners sampling with a fresh policy (no learning)."""
    with cluster.ray_session(None):
        register_env()
        with standalone_algorithm(algorithm_config(cfg)) as algo:
            if cfg.env_runners == 0:
                algo.env_runner.sample(num_timesteps=2000)
                t0 = time.perf_counter()
                algo.env_runner.sample(num_timesteps=steps)
                return steps / (time.perf_counter() - t0)
            runners = algo.env_runner_group
            per = steps // cfg.env_runners
            runners.foreach_env_runner(lambda r: r.sample(num_timesteps=2000), local_env_runner=False)
            t0 = time.perf_counter()
            runners.foreach_env_runner(lambda r: r.sample(num_timesteps=per), local_env_runner=False)
            return per * cfg.env_runners / (time.perf_counter() - t0)


def learner_seconds(run_dir: Path) -> float:
    """Mean learner time per iteration over the run (RLlib's smoothed timer, last value)."""
    (trial,) = [p for p in run_dir.iterdir() if (p / "result.json").exists()]
    rows = [json.loads(line) for line in (trial / "result.json").read_text().splitlines()]
    values = [r.get("timers", {}).get("learner_update_timer") for r in rows]
    values = [v for v in values if isinstance(v, float)]
    return float(values[-1]) if values else float("nan")


def run_train(cfg: TrainConfig, tmp: str, name: str) -> object:
    """`train` as the command runs it, its output discarded: the RunSummary."""
    with open(os.devnull, "w") as devnull:
        return whole(train(cfg, name=name, log_dir=tmp, out=devnull))


def peak_memory(cfg: TrainConfig, tmp: str, name: str) -> PeakMemory:
    """Peak memory of the same training, watched by the probe (which slows it: its time is not reported)."""
    with PeakMemory() as mem:
        run_train(cfg, tmp, name)
    return mem


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"))
    parser.add_argument("--algos", nargs="+", default=["ppo", "impala"])
    parser.add_argument("--timesteps", type=int, default=200_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--compare-layouts", action="store_true", help="learning per step: first layout vs new")
    parser.add_argument("--compare-steps", type=int, default=60_000, help="budget of each layout-comparison run")
    parser.add_argument("--recording-cost", action="store_true", help="also measure recording every episode")
    args = parser.parse_args()
    quiet()

    base = TrainConfig(record_every=0).with_env(maps=(str(Path(args.map).resolve()),))
    env_step_rate(base.env.to_dict(), 2_000)  # the process's first steps load its code: 22,410/s, then 40,000
    bare = env_step_rate(base.env.to_dict())
    print(f"yardstick: the bare env steps {bare:,.0f} env steps/s with random actions in this process")
    ray_s = ray_overhead()
    print(f"Ray start-up and shutdown: {ray_s:.1f} s ({'under' if ray_s < TARGET_RAY_S else 'OVER'} the "
          f"{TARGET_RAY_S:.0f} s target)")  # fmt: skip

    with tempfile.TemporaryDirectory(prefix="bench-training-") as tmp:
        rates: dict[str, float] = {}
        relative: dict[str, float] = {}  # each run's rate over the bare env measured around it
        layouts: list[tuple[str, tuple[int, int] | None]] = [(algo, None) for algo in args.algos]
        if "ppo" in args.algos:  # the other layout beside the default: sampling in the trial process
            layouts.insert(args.algos.index("ppo") + 1, ("ppo", (0, 32)))
        for algo, layout in layouts:
            cfg = replace(base, algo=algo, timesteps=args.timesteps, seed=args.seed, checkpoint_every=1000)
            if layout is not None:
                cfg = replace(cfg, num_env_runners=layout[0], envs_per_runner=layout[1])
            name = algo if layout is None else f"{algo}-{layout[0]}x{layout[1]}"
            sampling = sampling_rate(cfg)
            summary = run_train(cfg, tmp, name)
            after = env_step_rate(base.env.to_dict())  # the machine's speed drifts: measure around each run
            yardstick = (bare + after) / 2
            mem = peak_memory(cfg, tmp, f"{name}-memory")
            bare = env_step_rate(base.env.to_dict())
            rate = summary.env_steps / summary.wall_s  # type: ignore[attr-defined]
            rates[name], relative[name] = rate, rate / yardstick
            ev = summary.evaluation  # type: ignore[attr-defined]
            gib = mem.peak_pss / 2**30
            told = "the default layout" if layout is None else "the other layout"
            print(f"\n{algo.upper()} ({cfg.env_runners} remote env runners x {cfg.envs_per_runner} envs, preset fast, "
                  f"{told})")  # fmt: skip
            sampling_note = ""
            if name == "ppo":
                sampling_note = f" (target 5,000: {'met' if sampling >= TARGET_SAMPLING else 'MISSED'})"
            print(f"  sampling alone: {sampling:,.0f} env steps/s{sampling_note}")
            verdict = "met" if rate >= TARGET_PPO_RATE and rate / yardstick >= TARGET_RATIO else "MISSED"
            target = f" (PPO target 2,000/s and 0.12: {verdict})" if name == "ppo" else ""
            steps, wall = summary.env_steps, summary.wall_s  # type: ignore[attr-defined]
            print(f"  train: {steps:,} env steps in {wall:.1f} s = {rate:,.0f} env steps/s, "
                  f"{rate / yardstick:.3f} of the bare env{target}")  # fmt: skip
            print(f"  the bare env around this run: {yardstick:,.0f} env steps/s (mean of the one before it and "
                  f"{after:,.0f} measured after it)")  # fmt: skip
            print(f"  learner time per iteration: {learner_seconds(summary.run_dir):.2f} s "  # type: ignore[attr-defined]
                  f"(RLlib's smoothed timer); {summary.iterations} iterations")  # type: ignore[attr-defined]  # fmt: skip
            print(f"  peak memory (driver + every Ray process, summed PSS, in a second run): {gib:.2f} GiB "
                  f"({'under' if gib < TARGET_PEAK_GIB else 'OVER'} the 3 GiB target; summed RSS "
                  f"{mem.peak_rss / 2**30:.2f} GiB)")  # fmt: skip
            if ev:
                print(
                    f"  greedy policy at the end: mean settled R1 {ev['settled_R1_mean']:.2f}, median gap "
                    f"{ev['median_gap']:.2f}, {ev['share_within_1pct']:.0%} of {ev['starts']} starts within 1 %"
                )
        if "ppo" in rates and "impala" in rates:  # judged on each run's own yardstick: the machine's speed drifts
            ratio = relative["impala"] / relative["ppo"]
            print(f"\nIMPALA / PPO env steps/s, each over the bare env around its run: {ratio:.2f} (target >= 1: "
                  f"{'met' if ratio >= 1 else 'MISSED'}); raw {rates['impala'] / rates['ppo']:.2f}")  # fmt: skip
        if args.compare_layouts:
            compare_layouts(base, args.compare_steps, args.seed, tmp)
    if args.recording_cost:
        recording_cost(base)


def compare_layouts(base: TrainConfig, steps: int, seed: int, tmp: str) -> None:
    """Learning per env step: the first layout and PPO preset against the new default, same seed and budget."""
    print(f"\nlearning per env step, PPO, seed {seed}, {steps:,} env steps each (protocol: 20 fixed starts; one seed, "
          "an illustration: bench_learning.py measures learning over seeds):")  # fmt: skip
    for label, cfg in (("first layout (2 x 1 env, batch 1,000, 8 x 4 minibatches)",
                        replace(base, timesteps=steps, seed=seed, overrides=OLD_PPO, **OLD_LAYOUT)),
                       ("new default", replace(base, timesteps=steps, seed=seed))):  # fmt: skip
        summary = run_train(cfg, tmp, f"layout-{label.split()[0]}")
        ev = summary.evaluation  # type: ignore[attr-defined]
        rate = summary.env_steps / summary.wall_s  # type: ignore[attr-defined]
        print(f"  {label}: settled R1 {ev.get('settled_R1_mean', float('nan')):.2f}, median gap "
              f"{ev.get('median_gap', float('nan')):.2f}; {summary.wall_s:.0f} s, {rate:,.0f} env steps/s")  # type: ignore[attr-defined]  # fmt: skip


def recording_cost(cfg: TrainConfig, steps: int = 20_000, rounds: int = 2) -> None:
    """Sampling rate with every episode recorded to MCAP against none (the yardstick), alternately, in the trial
    process's env runner (the default layout's runners are remote, and the local one then holds no env)."""
    from smorphi_rl.recording import episode_files

    cfg = replace(cfg, num_env_runners=0)

    rates: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="bench-recording-") as tmp, cluster.ray_session(None):
        register_env()
        for _ in range(rounds):
            for record in (False, True):
                rec = recording_settings(replace(cfg, record_every=1), Path(tmp), "bench") if record else None
                with standalone_algorithm(algorithm_config(cfg, recording=rec)) as algo:
                    algo.env_runner.sample(num_timesteps=2000)
                    t0 = time.perf_counter()
                    algo.env_runner.sample(num_timesteps=steps)
                    rates[record].append(steps / (time.perf_counter() - t0))
        files = episode_files(Path(tmp) / "episodes")
        size = sum(f.stat().st_size for f in files) / max(1, len(files))
    off, on = float(np.median(rates[False])), float(np.median(rates[True]))
    print(f"\nrecording cost: sampling {on:,.0f} env steps/s recording every episode vs {off:,.0f}/s not recording "
          f"(yardstick, same run): {on / off:.3f}x, a {100 * (1 - on / off):.1f} % slowdown; {len(files)} files, "
          f"{size / 1024:.0f} KiB each")  # fmt: skip


if __name__ == "__main__":
    run_documented("training", "Training throughput (`scripts/bench_training.py`)", main)

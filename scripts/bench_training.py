"""Benchmark learning on map-1: PPO and IMPALA against the exact optimum and a random-policy yardstick.

For each algorithm (fixed seed, `smorphi-rl train`'s own code path, 2 env runners on a local Ray):
- env steps and wall time until the episode-best R1 first reaches 99 % of the best R1 over every
  triple on the 2-degree lattice;
- env-runner sampling throughput (env steps/s over the whole run) against the bare env's stepping
  rate in this process (the yardstick for sampling overhead);
- mean episode R1 in the first and last 10 iterations, and the greedy policy's settled R1 over 10
  seeded episodes against a uniform random policy's (the yardstick for learning);
- peak memory of the whole run (the driver and every Ray process below it, summed PSS);
- the cost of recording: env-runner sampling rate with every episode recorded to MCAP against the
  same runners with recording off (the yardstick), measured alternately on fresh algorithms.
Targets (2-core machine): PPO within 99 % in <= 100,000 env steps and <= 10 minutes; peak < 3 GiB;
recording every episode slows sampling by at most 20 %.

    .venv/bin/python scripts/bench_training.py [--algos ppo impala] [--timesteps 100000] [--seed 0]
    .venv/bin/python scripts/bench_training.py --recording-cost-only
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.evaluate import Evaluator, best_on_lattice
from smorphi_rl.maps import load_map
from smorphi_rl.training.checkpoints import load_module
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.policy import rollout
from smorphi_rl.training.run import train

TARGET_STEPS = 100_000
TARGET_WALL_S = 600.0
TARGET_PEAK_GIB = 3.0
TARGET_RECORDING_SLOWDOWN = 0.20
EVAL_EPISODES = 10


def _memory_kib(pid: int) -> tuple[int, int]:
    """(RSS, PSS) of one process in KiB: PSS splits shared pages (torch, Ray's libraries) among their users."""
    rss = pss = 0
    try:
        with open(f"/proc/{pid}/smaps_rollup") as fh:
            for line in fh:
                if line.startswith("Rss:"):
                    rss = int(line.split()[1])
                elif line.startswith("Pss:"):
                    pss = int(line.split()[1])
    except OSError:
        pass
    return rss, pss


def _tree_memory_bytes(root: int) -> tuple[int, int]:
    """Summed (RSS, PSS) of `root` and all its descendants (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(entry))
    rss = pss = 0
    stack = [root]
    while stack:
        pid = stack.pop()
        r, p = _memory_kib(pid)
        rss, pss = rss + r, pss + p
        stack.extend(children.get(pid, []))
    return rss * 1024, pss * 1024


class PeakMemory:
    """Samples the process tree's memory every 0.5 s in a thread; `.peak_pss` and `.peak_rss` in bytes."""

    def __init__(self) -> None:
        self.peak_pss = self.peak_rss = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            rss, pss = _tree_memory_bytes(os.getpid())
            self.peak_rss, self.peak_pss = max(self.peak_rss, rss), max(self.peak_pss, pss)
            self._stop.wait(0.5)

    def __enter__(self) -> PeakMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def random_policy_episode(env: MorphologyEnv, seed: int) -> tuple[float, float, float]:
    """(mean R1 over the episode, best R1, final R1) of uniform random actions from the seeded start."""
    _, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    r1, done = [], False
    while not done:
        _, _, terminated, truncated, info = env.step(rng.integers(0, 3, size=3))
        r1.append(info["R1"])
        done = terminated or truncated
    return float(np.mean(r1)), float(info["best_R1"]), float(info["R1"])


def env_step_rate(env: MorphologyEnv, steps: int = 20_000) -> float:
    rng = np.random.default_rng(1)
    actions = rng.integers(0, 3, size=(steps, 3))
    env.reset(seed=1)
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=str(Path(__file__).resolve().parent.parent / "maps" / "map-1.yaml"))
    parser.add_argument("--algos", nargs="+", default=["ppo", "impala"])
    parser.add_argument("--timesteps", type=int, default=TARGET_STEPS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--recording-cost-only", action="store_true", help="only measure the cost of recording")
    parser.add_argument("--cost-steps", type=int, default=4000, help="env steps per runner per recording-cost round")
    args = parser.parse_args()

    cfg0 = TrainConfig().with_env(maps=(str(Path(args.map).resolve()),))
    recording_cost(cfg0, args.cost_steps)
    if args.recording_cost_only:
        return
    grid_map = load_map(args.map)
    t0 = time.perf_counter()
    optimum = best_on_lattice(Evaluator(grid_map), cfg0.env.w1, cfg0.env.w2)
    target = 0.99 * optimum.R1
    print(f"{grid_map.name}: best R1 on the 2-degree lattice {optimum.R1:.2f} at {optimum.theta} "
          f"({optimum.evaluated:,} shapes, {time.perf_counter() - t0:.1f} s); 99 % = {target:.2f}")  # fmt: skip

    env = MorphologyEnv(cfg0.env.to_dict())
    bare_rate = env_step_rate(env)
    randoms = [random_policy_episode(env, s) for s in range(EVAL_EPISODES)]
    rand_mean, rand_best, rand_final = (float(np.mean(c)) for c in zip(*randoms, strict=True))
    reach = sum(b >= target for _, b, _ in randoms)
    print(f"yardsticks: bare env {bare_rate:,.0f} steps/s in this process; random policy: episode mean R1 "
          f"{rand_mean:.2f}, final R1 {rand_final:.2f}, episode best R1 {rand_best:.2f} "
          f"({reach}/{EVAL_EPISODES} episodes reach 99 %)")  # fmt: skip

    with tempfile.TemporaryDirectory(prefix="bench-training-") as tmp:
        for algo in args.algos:
            cfg = TrainConfig(algo=algo, env=cfg0.env, timesteps=args.timesteps, seed=args.seed, checkpoint_every=1000)
            with PeakMemory() as mem, open(os.devnull, "w") as quiet:
                summary = train(cfg, name=algo, log_dir=tmp, out=quiet)
            curve = summary_curve(summary.run_dir)
            hit = first_reach(curve, target)
            overall = summary.env_steps / summary.wall_s
            sampling = float(curve["runner_rate"][-1])
            first = float(np.nanmean(curve["R1_mean"][:10]))
            last = float(np.nanmean(curve["R1_mean"][-10:]))
            module = load_module(summary.checkpoint) if summary.checkpoint else None
            greedy = [rollout(module, env, s).settled["R1"] for s in range(EVAL_EPISODES)] if module else [np.nan]
            print(f"\n{algo.upper()}: {summary.env_steps:,} env steps, {summary.iterations} iterations, "
                  f"{summary.wall_s:.0f} s wall (Ray start and stop included)")  # fmt: skip
            if hit is None:
                print(f"  99 % of optimum: not reached in {summary.env_steps:,} steps")
            else:
                steps, wall, r1 = hit
                ok = "meets" if steps <= TARGET_STEPS and wall <= TARGET_WALL_S else "misses"
                goal = f"{TARGET_STEPS:,}-step / {TARGET_WALL_S:.0f} s target"
                print(f"  99 % of optimum: first reached at {steps:,.0f} env steps, {wall:.0f} s "
                      f"(episode best R1 {r1:.2f}; {ok} the {goal})")  # fmt: skip
            best = summary.best
            if best is not None:
                print(f"  best found: {best.angles} P_c {best.P_c:.2f} % P_len {best.P_len} R1 {best.R1:.2f} "
                      f"= {100 * best.R1 / optimum.R1:.2f} % of optimum")  # fmt: skip
            print(f"  sampling: the 2 env runners {sampling:,.0f} env steps/s (RLlib's lifetime throughput; "
                  f"{sampling / bare_rate:.3f}x the bare env in one process); {overall:,.0f} env steps/s "
                  f"over the whole run, start-up included")  # fmt: skip
            busy = curve["sampling_s"]
            if algo == "ppo" and np.nansum(busy) > 0:
                rate = float(np.nansum(np.diff(curve["steps"], prepend=0.0)) / np.nansum(busy))
                learn = float(np.nanmean(curve["learn_s"]))
                print(f"  PPO samples then learns: {rate:,.0f} env steps/s while sampling, "
                      f"{np.nanmean(busy):.2f} s sampling and {learn:.2f} s learning an iteration")  # fmt: skip
            g = float(np.mean(greedy))
            print(f"  learning: episode mean R1 {first:.2f} (first 10 iterations) -> {last:.2f} (last 10); "
                  f"greedy settled R1 {g:.2f} vs random final R1 {rand_final:.2f} "
                  f"({100 * g / optimum.R1:.2f} % vs {100 * rand_final / optimum.R1:.2f} % of optimum)")  # fmt: skip
            gib = mem.peak_pss / 2**30
            print(f"  peak memory (driver + every Ray process, summed PSS): {gib:.2f} GiB "
                  f"({'under' if gib < TARGET_PEAK_GIB else 'OVER'} the {TARGET_PEAK_GIB:g} GiB target; "
                  f"summed RSS, shared libraries counted per process: {mem.peak_rss / 2**30:.2f} GiB)")  # fmt: skip


def recording_cost(cfg: TrainConfig, steps: int, rounds: int = 2) -> None:
    """Env-runner sampling rate (2 runners, a fresh PPO policy) with every episode recorded vs none."""
    from smorphi_rl.recording import episode_files
    from smorphi_rl.training import cluster
    from smorphi_rl.training.config import algorithm_config, recording_settings, register_env
    from smorphi_rl.training.quiet import quiet

    quiet()
    rates: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="bench-recording-") as tmp, cluster.ray_session(None):
        register_env()
        recorded = replace(cfg, record_every=1)
        for _ in range(rounds):
            for record in (False, True):
                rec = recording_settings(recorded, Path(tmp), "bench") if record else None
                algo = algorithm_config(cfg, recording=rec).build_algo()
                try:
                    runners = algo.env_runner_group
                    runners.foreach_env_runner(lambda r: r.sample(num_timesteps=500), local_env_runner=False)
                    t0 = time.perf_counter()
                    runners.foreach_env_runner(lambda r: r.sample(num_timesteps=steps), local_env_runner=False)
                    rates[record].append(2 * steps / (time.perf_counter() - t0))
                finally:
                    algo.stop()
        files = episode_files(Path(tmp) / "episodes")
        size = sum(f.stat().st_size for f in files) / max(1, len(files))
    off, on = float(np.median(rates[False])), float(np.median(rates[True]))
    slowdown = 1 - on / off
    verdict = "meets" if slowdown <= TARGET_RECORDING_SLOWDOWN else "misses"
    print(f"recording cost: 2 env runners sample {on:,.0f} env steps/s recording every episode vs {off:,.0f}/s "
          f"not recording (yardstick, same run): {on / off:.3f}x, a {100 * slowdown:.1f} % slowdown ({verdict} the "
          f"{100 * TARGET_RECORDING_SLOWDOWN:.0f} % target); {len(files)} files, {size / 1024:.0f} KiB each "
          f"(200-step episodes, zstd)")  # fmt: skip


def summary_curve(run_dir: Path) -> dict[str, np.ndarray]:
    """Per-iteration env steps, wall time, episode-best R1 (max this iteration) and episode mean R1."""
    import json

    (trial,) = [p for p in run_dir.iterdir() if (p / "result.json").exists()]
    rows = [json.loads(line) for line in (trial / "result.json").read_text().splitlines()]
    ours = [r["env_runners"].get("smorphi", {}) for r in rows]
    return {
        "steps": np.array([r["num_env_steps_sampled_lifetime"] for r in rows], dtype=float),
        "wall": np.array([r["time_total_s"] for r in rows], dtype=float),
        "best_R1": np.array([o.get("best_R1_max", np.nan) for o in ours], dtype=float),
        "R1_mean": np.array([o.get("R1_mean", np.nan) for o in ours], dtype=float),
        "sampling_s": np.array([r.get("timers", {}).get("env_runner_sampling_timer", np.nan) for r in rows]),
        "learn_s": np.array([r.get("timers", {}).get("learner_update_timer", np.nan) for r in rows]),
        "runner_rate": np.array(
            [
                r["env_runners"]
                .get("num_env_steps_sampled_lifetime_throughput", {})
                .get("throughput_since_last_restore", np.nan)
                for r in rows
            ]
        ),
    }


def first_reach(curve: dict[str, np.ndarray], target: float) -> tuple[float, float, float] | None:
    hits = np.flatnonzero(curve["best_R1"] >= target)
    if not hits.size:
        return None
    i = int(hits[0])
    return float(curve["steps"][i]), float(curve["wall"][i]), float(curve["best_R1"][i])


if __name__ == "__main__":
    main()

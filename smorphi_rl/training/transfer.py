"""Fine-tuning from a pretrained checkpoint, with the weights provably in the env runners from the start.

RLlib's own weight sync after a restore is fire-and-forget; the notes saw it silently dropped in
2 of 3 runs, so the runners sampled with untrained weights. Here the restored module state is
pushed to every runner with a blocking call, and each runner's policy weights are digested and
reported in the first results (`smorphi_pretrained_in_runners`: 1.0 when every runner holds
exactly the checkpoint's policy).
"""

from __future__ import annotations

import csv
import hashlib
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.rundir import DEFAULT_LOG_DIR
from smorphi_rl.training.callbacks import MorphologyCallbacks
from smorphi_rl.training.checkpoints import MODULE_COMPONENT, MODULE_SUBDIR, CheckpointError, load_module
from smorphi_rl.training.config import DEFAULT_RECORD_EVERY, TrainConfig
from smorphi_rl.training.presets import ENVS_PER_RUNNER

PRETRAINED_KEY = "smorphi_pretrained_in_runners"
POLICY_PREFIX = "_pi."
"""The policy network's parameters (the value net is not used for sampling)."""


def policy_digest(state: dict[str, Any]) -> str:
    """A digest of the policy network's parameters in a module state dict."""
    h = hashlib.blake2b(digest_size=16)
    for key in sorted(k for k in state if k.startswith(POLICY_PREFIX)):
        h.update(key.encode())
        h.update(np.ascontiguousarray(np.asarray(state[key], dtype=np.float32)).tobytes())
    return h.hexdigest()


def check_pretrained(checkpoint: Path, env_config: dict[str, Any]) -> str:
    """Before Ray starts: the checkpoint is ours and its observations fit the env; returns its policy digest."""
    from smorphi_rl.env import MorphologyEnv

    module = load_module(checkpoint)
    env = MorphologyEnv(env_config)
    want, have = module.observation_space["map"].shape, env.observation_space["map"].shape  # type: ignore[index]
    if tuple(want) != tuple(have):
        raise CheckpointError(
            f"{checkpoint}: the pretrained policy expects map observations of shape {tuple(want)}, "
            f"the env gives {tuple(have)} (obs_size must match)"
        )
    return policy_digest(module.get_state())


def push_module_to_runners(algorithm: Any) -> list[str]:
    """Copy the learner's module into every env runner that samples (the remote ones, or the trial's own when
    there are none), waiting for each; returns their policy digests."""
    state = algorithm.learner_group.get_state(components="learner/rl_module", inference_only=True)
    runner_state = state["learner"]  # {"rl_module": {module id: module state}}
    runners = algorithm.env_runner_group
    local = runners.num_remote_env_runners() == 0
    runners.foreach_env_runner(lambda r: r.set_state(runner_state), local_env_runner=local)
    return runners.foreach_env_runner(lambda r: policy_digest(r.module.get_state()), local_env_runner=local)


def reseed_runners(algorithm: Any, generation: int) -> None:
    """Give every sampling env its `generation` of independent streams (after a restore)."""
    runners = algorithm.env_runner_group
    local = runners.num_remote_env_runners() == 0

    def reseed(runner: Any) -> None:
        env: Any = getattr(runner.env, "unwrapped", None)
        if env is not None and hasattr(env, "reseed"):
            env.reseed(generation)

    runners.foreach_env_runner(reseed, local_env_runner=local)


def fine_tune_callbacks(checkpoint: Path, digest: str) -> type[MorphologyCallbacks]:
    """MorphologyCallbacks that start the algorithm from `checkpoint`'s policy and value networks."""

    class FineTuneCallbacks(MorphologyCallbacks):
        pretrained = str(checkpoint.resolve())
        expected = digest
        in_runners = float("nan")

        def on_algorithm_init(self, *, algorithm: Any, **kwargs: Any) -> None:
            super().on_algorithm_init(algorithm=algorithm, **kwargs)
            algorithm.restore_from_path(str(Path(self.pretrained) / MODULE_SUBDIR), component=MODULE_COMPONENT)
            digests = push_module_to_runners(algorithm)
            self.in_runners = float(bool(digests) and all(d == self.expected for d in digests))

        def on_train_result(self, *, algorithm: Any, result: dict[str, Any], **kwargs: Any) -> None:
            super().on_train_result(algorithm=algorithm, result=result, **kwargs)
            result[PRETRAINED_KEY] = self.in_runners

    return FineTuneCallbacks


@dataclass(frozen=True)
class TransferRun:
    """One training run of the transfer job: a held-out map, a seed, fine-tuned or from scratch."""

    map_name: str
    seed: int
    mode: str
    env_steps: int
    converged_at: float | None
    plateau: float
    best_R1: float
    pretrained_in_runners: bool | None
    run_dir: Path
    curve: dict[str, list[float]]


def run_transfer(
    pretrained: str | Path,
    maps: list[str],
    seeds: list[int],
    timesteps: int,
    algo: str = TrainConfig.algo,
    preset: str = TrainConfig.preset,
    name: str = "transfer",
    log_dir: str | Path = DEFAULT_LOG_DIR,
    address: str | None = None,
    out: Any = None,
    record_every: int = DEFAULT_RECORD_EVERY,
    envs_per_runner: int = ENVS_PER_RUNNER,
) -> tuple[Path, list[TransferRun]]:
    """For every held-out map and seed: fine-tune from `pretrained` and train from scratch, same budget."""
    from smorphi_rl.env import EnvConfig
    from smorphi_rl.rundir import prepare_run_dir, safe_name
    from smorphi_rl.training.checkpoints import find_checkpoint
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.convergence import CURVE_KEY, convergence
    from smorphi_rl.training.run import train

    checkpoint = find_checkpoint(pretrained)
    env = EnvConfig.from_dict(dict(load_module(checkpoint).model_config.get("env_config") or {}))
    configs = []
    for path in maps:  # every map and the checkpoint are checked before the first run starts
        cfg = TrainConfig(algo=algo, env=replace(env, maps=EnvConfig.from_dict({"maps": [path]}).maps),
                          timesteps=timesteps, preset=preset, record_every=record_every,
                          envs_per_runner=envs_per_runner)  # fmt: skip
        check_pretrained(checkpoint, cfg.env.to_dict())
        configs.append(cfg)
    job_dir = prepare_run_dir(log_dir, name)
    runs: list[TransferRun] = []
    for cfg in configs:
        map_name = Path(cfg.env.maps[0]).stem
        for seed in seeds:
            for mode in ("fine-tune", "scratch"):
                run_cfg = replace(cfg, seed=seed, pretrained=str(checkpoint) if mode == "fine-tune" else None)
                run_name = safe_name(f"{map_name}-{mode}-seed{seed}")
                summary = train(run_cfg, name=run_name, log_dir=job_dir, address=address, out=out or sys.stderr,
                                label=f"{algo.upper()} {run_name}")  # fmt: skip
                curve = summary_curve(summary.run_dir)
                at, plateau = convergence(np.array(curve["env_steps"]), np.array(curve[CURVE_KEY]))
                best = summary.best.R1 if summary.best else float("nan")
                runs.append(TransferRun(map_name, seed, mode, summary.env_steps, at, plateau, best,
                                        summary.pretrained_in_runners, summary.run_dir, curve))  # fmt: skip
    return job_dir, runs


def summary_curve(run_dir: Path) -> dict[str, list[float]]:
    """The curves (env steps, episode return, best R1, final-shape R1) of a training run, from its result.json."""
    from smorphi_rl.training.sweep_report import result_curve, result_rows

    (trial,) = [p for p in run_dir.iterdir() if (p / "result.json").is_file()]
    return result_curve(result_rows(trial / "result.json"))


def write_transfer_report(job_dir: Path, runs: list[TransferRun]) -> dict[str, Path]:
    """transfer.csv, transfer.md (the paper's Table 5) and transfer_curves.png."""
    from smorphi_rl.plots import plot_learning_curves

    files = {"csv": job_dir / "transfer.csv", "md": job_dir / "transfer.md", "png": job_dir / "transfer_curves.png"}
    with files["csv"].open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["map", "seed", "mode", "env_steps", "converged_at_env_steps", "plateau_settled_R1", "best_R1",
                         "pretrained_in_runners"])  # fmt: skip
        for r in runs:
            at = "" if r.converged_at is None else int(r.converged_at)
            writer.writerow([r.map_name, r.seed, r.mode, r.env_steps, at, f"{r.plateau:.3f}", f"{r.best_R1:.4f}",
                             r.pretrained_in_runners])  # fmt: skip
    lines = [
        "| Map | Fine-tuned: env steps to converge (median over seeds) | From scratch | Ratio scratch / fine-tuned "
        "| Plateau greedy settled R1 fine-tuned / scratch | Best R1 fine-tuned / scratch |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for map_name in dict.fromkeys(r.map_name for r in runs):
        tuned = [r for r in runs if r.map_name == map_name and r.mode == "fine-tune"]
        scratch = [r for r in runs if r.map_name == map_name and r.mode == "scratch"]
        t, s = _median_steps(tuned), _median_steps(scratch)
        ratio = f"{s / t:.2f}" if t and s else "-"
        best = f"{max(r.best_R1 for r in tuned):.2f} / {max(r.best_R1 for r in scratch):.2f}"
        plateau = f"{np.median([r.plateau for r in tuned]):.2f} / {np.median([r.plateau for r in scratch]):.2f}"
        lines.append(f"| {map_name} | {_steps_text(t)} | {_steps_text(s)} | {ratio} | {plateau} | {best} |")
    files["md"].write_text("\n".join(lines) + "\n")
    curves = {f"{r.map_name} {r.mode} s{r.seed}": r.curve for r in runs}
    plot_learning_curves(curves, files["png"])
    return files


def _median_steps(runs: list[TransferRun]) -> float | None:
    """Median convergence step; a run that never settled counts as its whole budget."""
    values = [r.converged_at if r.converged_at is not None else float(r.env_steps) for r in runs]
    return float(np.median(values)) if values else None


def _steps_text(steps: float | None) -> str:
    return "-" if steps is None else f"{steps:,.0f}"

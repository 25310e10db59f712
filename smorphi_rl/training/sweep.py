"""`smorphi-rl sweep`: a validated sweep file run as one Ray Tune experiment, resumable after an interruption.

Each trial is the project's one trainable (`trial.run_trial`, which `train` runs too) on its (algorithm,
maps, seed, hyperparameters); it checkpoints through Tune, so `Tuner.restore` picks every unfinished
trial up from its last checkpoint.
"""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from smorphi_rl import cluster
from smorphi_rl.map_sources import map_label
from smorphi_rl.protocol import Optimum
from smorphi_rl.quiet import quiet
from smorphi_rl.rundir import DEFAULT_LOG_DIR, RunDirError, prepare_run_dir
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.failures import fit
from smorphi_rl.training.finetune import fine_tune_from
from smorphi_rl.training.run import TrainingError, fmt_duration, training_optima, trial_callbacks
from smorphi_rl.training.sweep_config import SweepConfig
from smorphi_rl.training.sweep_report import (
    TrialRow,
    group_curves,
    read_sweep,
    sweep_group_lines,
    write_sweep_groups,
    write_sweep_tables,
)
from smorphi_rl.training.topk import episode_bests
from smorphi_rl.training.trial import resources, run_trial

SWEEP_COPY = "sweep.yaml"
"""The sweep file as it was when the experiment started; --resume checks the file still matches."""


@dataclass
class SweepSummary:
    """The outcome of `run_sweep`, as printed."""

    experiment_dir: Path
    rows: list[TrialRow]
    trials_total: int
    wall_s: float
    interrupted: bool
    files: dict[str, Path]


def sweep_trainable(config: dict[str, Any], sweep: SweepConfig, optima: dict[str, Optimum]) -> None:
    """One trial of the sweep: its grid point's TrainConfig, run by the project's one trainable with the callbacks
    `train` builds (the evaluation protocol against `optima`, fine-tuning from the sweep's checkpoint)."""
    cfg = sweep.base_config(config["algo"], tuple(config["maps"]), int(config["seed"]), dict(config.get("hp") or {}))
    base = None if cfg.pretrained is None else fine_tune_from(cfg.pretrained, cfg.env.to_dict())[1]
    run_trial(cfg, trial_callbacks(cfg, optima, base))


class _SweepProgress:
    """One status line for the whole sweep: trials done, the running trial's steps, the best shape so far."""

    def __init__(self, sweep: SweepConfig, total: int, out: Any) -> None:
        self.sweep, self.total, self.out = sweep, total, out
        self.tty = bool(getattr(out, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self.done: set[str] = set()
        self.best = (float("-inf"), "")
        self._last = 0.0

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "out"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state, out=sys.stderr)

    def result(self, trial: str, config: dict[str, Any], result: dict[str, Any]) -> None:
        for b in episode_bests(result):
            if self.best[0] < b.R1:
                self.best = (b.R1, f"{b.angles} on {b.map}")
        steps = int(result.get(keys.STEPS) or 0)
        maps = "+".join(map_label(m) for m in config.get("maps", []))
        self._show(f"{config.get('algo', '?').upper()} {maps} seed {config.get('seed')} "
                   f"{steps:,}/{self.sweep.timesteps:,} steps")  # fmt: skip

    def complete(self, trial: str) -> None:
        self.done.add(trial)
        self._show("", force=True)

    def _show(self, current: str, force: bool = False) -> None:
        now = time.monotonic()
        if not self.tty and not force and now - self._last < 10:
            return
        self._last = now
        frac = len(self.done) / max(1, self.total)
        bar = "#" * int(20 * frac) + "-" * (20 - int(20 * frac))
        best = f"best R1 {self.best[0]:.2f} {self.best[1]}" if self.best[1] else "best R1 -"
        line = (f"sweep {self.sweep.name} [{bar}] {len(self.done)}/{self.total} trials  "
                f"{fmt_duration(now - self.t0)}  {current}  {best}")  # fmt: skip
        self.out.write(("\r" + line[:160].ljust(160)) if self.tty else line + "\n")
        self.out.flush()

    def finish(self) -> None:
        if self.tty:
            self.out.write("\n")
            self.out.flush()


def _tune_callback(progress: _SweepProgress) -> Any:
    from ray import tune

    class _Callback(tune.Callback):
        def on_trial_result(self, iteration: int, trials: list[Any], trial: Any, result: dict[str, Any], **info: Any):
            progress.result(trial.trial_id, trial.config, result)

        def on_trial_complete(self, iteration: int, trials: list[Any], trial: Any, **info: Any):
            progress.complete(trial.trial_id)

    return _Callback()


def prepare_experiment(sweep: SweepConfig, log_dir: str | Path, resume: bool) -> Path:
    """The experiment folder: new (refusing an existing one), or, with resume, an existing one of the same sweep."""
    exp = Path(log_dir).resolve() / sweep.name
    if not resume:
        try:
            exp = prepare_run_dir(log_dir, sweep.name)
        except RunDirError:
            if exp.is_dir():
                raise RunDirError(f"experiment folder {exp} already exists: give the sweep file another `name`, or "
                                  "add --resume to continue it") from None  # fmt: skip
            raise
        shutil.copyfile(sweep.path, exp / SWEEP_COPY)
        return exp
    copy = exp / SWEEP_COPY
    if not copy.is_file():
        raise RunDirError(f"nothing to resume: {exp} holds no sweep started by smorphi-rl")
    if yaml.safe_load(copy.read_text()) != yaml.safe_load(sweep.path.read_text()):  # comments may differ
        raise RunDirError(f"{sweep.path} has changed since {exp} started: restore it from {copy} to resume, or "
                          "give the changed sweep another `name`")  # fmt: skip
    return exp


def run_sweep(
    sweep: SweepConfig,
    log_dir: str | Path = DEFAULT_LOG_DIR,
    address: str | None = None,
    resume: bool = False,
    out: Any = None,
) -> SweepSummary:
    """Run (or resume) the sweep as one Tune experiment under `log_dir/<name>/`; write the table and curves."""
    if sweep.pretrained is not None:  # a bad checkpoint fails here, before Ray starts
        fine_tune_from(sweep.pretrained, sweep.base_config(sweep.algorithms[0], sweep.map_sets[0], sweep.seeds[0],
                                                          {}).env.to_dict())  # fmt: skip
    from smorphi_rl.env import MorphologyEnv

    for maps in sweep.map_sets:  # an unreadable map or one with no free cell fails here, before Ray starts
        MorphologyEnv(sweep.base_config(sweep.algorithms[0], maps, 0, {}).env.to_dict())
    cluster.check_reachable(address)
    layouts = [sweep.base_config(algo, sweep.map_sets[0], 0, {}) for algo in sweep.algorithms]
    widest = max(layouts, key=lambda cfg: cfg.cpus)  # a trial Ray cannot place would wait forever
    if address is None:
        cluster.check_capacity(widest.cpus, widest.env_runners, address)
    exp = prepare_experiment(sweep, log_dir, resume)
    out = out or sys.stderr
    optima: dict[str, Optimum] = {}
    for maps in sweep.map_sets:  # every evaluated map's exact optimum, before Ray starts (cached after the first)
        optima |= training_optima(sweep.base_config(sweep.algorithms[0], maps, 0, {}), log_dir, out)
    quiet()
    progress = _SweepProgress(sweep, sweep.num_grid_trials, out)
    with cluster.ray_session(address):
        if address is not None:
            cluster.check_capacity(widest.cpus, widest.env_runners, address)
        from ray import tune

        from smorphi_rl.training.tensorboard import TensorBoardLogger

        def trial_resources(config: dict[str, Any]) -> Any:
            return resources(sweep.base_config(config["algo"], tuple(config["maps"]), 0, {}))

        trainable = tune.with_resources(tune.with_parameters(sweep_trainable, sweep=sweep, optima=optima),
                                        trial_resources)  # fmt: skip
        run_config = tune.RunConfig(
            name=sweep.name,
            storage_path=str(exp.parent),
            stop=sweep.stop or None,
            checkpoint_config=tune.CheckpointConfig(num_to_keep=sweep.checkpoint_keep or None),
            callbacks=[_tune_callback(progress), TensorBoardLogger()],
            verbose=0,
        )
        t0 = time.monotonic()
        if resume and tune.Tuner.can_restore(str(exp)):
            tuner = tune.Tuner.restore(str(exp), trainable=trainable, resume_unfinished=True, resume_errored=True)
        else:
            tuner = tune.Tuner(
                trainable,
                param_space={
                    "algo": tune.grid_search(list(sweep.algorithms)),
                    "maps": tune.grid_search([list(m) for m in sweep.map_sets]),
                    "seed": tune.grid_search(list(sweep.seeds)),
                    "hp": {k: s.to_tune() for k, s in sweep.search.items()},
                },
                tune_config=tune.TuneConfig(num_samples=sweep.num_samples, trial_dirname_creator=_trial_dirname),
                run_config=run_config,
            )
        results, failed = fit(tuner, exp, "the sweep")
        wall = time.monotonic() - t0
        progress.finish()
    if failed and (failed.disk_full or results is None):
        raise TrainingError(failed.line)  # no tables either
    rows = read_sweep(exp)
    files = write_sweep_outputs(exp, rows)
    if failed:
        raise TrainingError(f"{failed.line}; tables of the finished trials under {exp}")
    trials = [results[i] for i in range(len(results))]
    finished = sum(1 for r in trials if r.metrics and r.metrics.get("done"))
    return SweepSummary(exp, rows, len(trials), wall, finished < len(trials), files)


def _trial_dirname(trial: Any) -> str:
    maps = "+".join(map_label(m) for m in trial.config["maps"])
    return f"{trial.config['algo']}-{maps}-seed{trial.config['seed']}-{trial.trial_id}"


def write_sweep_outputs(exp: Path, rows: list[TrialRow]) -> dict[str, Path]:
    """sweep.csv, sweep.md, sweep_groups.md (over seeds, with intervals) and sweep_curves.png (the paper's Figure 5
    per algorithm and map)."""
    from smorphi_rl.plots import plot_sweep_curves

    if not rows:
        return {}
    files = {"csv": exp / "sweep.csv", "md": exp / "sweep.md", "groups": exp / "sweep_groups.md",
             "png": exp / "sweep_curves.png"}  # fmt: skip
    write_sweep_tables(rows, files["csv"], files["md"])
    write_sweep_groups(rows, files["groups"])
    plot_sweep_curves(group_curves(rows), files["png"])
    return files


def format_sweep_summary(s: SweepSummary, rel: Any = str) -> str:
    """The end-of-sweep text: trials, the best of each, and where the files are."""
    state = "interrupted after" if s.interrupted else "ran"
    lines = [f"sweep {s.experiment_dir.name}: {state} {len(s.rows)} of {s.trials_total} trials "
             f"in {fmt_duration(s.wall_s)}"]  # fmt: skip
    ranked = sorted((r for r in s.rows if r.best is not None), key=lambda r: -r.best.R1)  # type: ignore[union-attr]
    for r in ranked[:5]:
        b = r.best
        assert b is not None
        hp = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in r.hyperparameters.items())
        lines.append(f"  {r.algo:<6} {r.maps:<14} seed {r.seed} {hp} best R1 {b.R1:.2f} {b.angles} "
                     f"({r.env_steps:,} steps, {fmt_duration(r.wall_s)})")  # fmt: skip
    if s.rows:
        lines.extend(["", *sweep_group_lines(s.rows)[2:], ""])
    for key, label in (("md", "table"), ("groups", "over seeds"), ("png", "curves")):
        if key in s.files:
            lines.append(f"{label}: {rel(s.files[key])}")
    lines.append(f"trials: {rel(s.experiment_dir)}")
    lines.append(f"tensorboard --logdir {rel(s.experiment_dir)}")
    return "\n".join(lines)

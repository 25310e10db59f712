"""`smorphi-rl train`: one RLlib algorithm through Ray Tune, on a local Ray or an existing cluster: a one-trial
experiment on the trainable `sweep` runs too (`trial.run_trial`).

Everything lands under `logs/<run>/`: the resolved configuration, Tune's trial directory
(TensorBoard events, result.json, checkpoints), the top-k tables and figures, and summary.json.
"""

from __future__ import annotations

import io
import math
import sys
import threading
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl import cluster, interrupts, jsontext
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.geometry import Morphology, angles_text
from smorphi_rl.map_sources import map_label
from smorphi_rl.maps import load_map
from smorphi_rl.planning import REACH_SHAPES
from smorphi_rl.progress import StatusLine, bar, fmt_duration, optimum_progress
from smorphi_rl.protocol import (
    EVAL_KEY,
    NO_OPTIMUM,
    OPTIMUM_MAX_CELLS,
    TRAINED_KEY,
    Optimum,
    cached_optimum,
    eval_starts,
    exact_optimum,
    make_cache,
    optimum_cache,
    selection_starts,
)
from smorphi_rl.quiet import quiet
from smorphi_rl.rundir import (
    DEFAULT_LOG_DIR,
    check_run_name,
    discard_run_dir,
    prepare_run_dir,
    prepare_stamped_run_dir,
    rel,
    shell_path,
    write_text_atomic,
)
from smorphi_rl.score import degenerate_warning, swamped_warning
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.callbacks import MorphologyCallbacks, with_evaluation
from smorphi_rl.training.checkpoints import checkpoints_under
from smorphi_rl.training.config import EPISODES_DIR, TrainConfig, TrainConfigError, default_run_name
from smorphi_rl.training.failures import fit
from smorphi_rl.training.finetune import PRETRAINED_KEY, fine_tune_from
from smorphi_rl.training.resume import ResumedTrial, continue_train_run
from smorphi_rl.training.stopping import GracefulStop, tune_stop_seen
from smorphi_rl.training.sweep_report import CURVE_NAMES, curve_point
from smorphi_rl.training.topk import Found, TopMorphologies, episode_bests, write_found
from smorphi_rl.training.trial import resources, run_trial

TOP_PLOT = 4
"""Morphologies drawn in top_morphologies.png (the paper's Figure 6 shows 2 per algorithm)."""


class TrainingError(SmorphiError):
    """The run could not start or a trial failed."""


@dataclass
class RunSummary:
    """The outcome of `train`, as printed and written to summary.json."""

    run_dir: Path
    algorithm: str
    env_steps: int
    iterations: int
    wall_s: float
    interrupted: bool
    best: Found | None
    optimum: dict[str, Optimum]
    checkpoint: Path | None
    files: dict[str, Path]
    pretrained: Path | None = None
    pretrained_in_runners: bool | None = None
    evaluation: dict[str, Any] = field(default_factory=dict)
    """The last greedy evaluation (the protocol's eval/... figures), empty when evaluation was off."""
    map_digests: dict[str, str] = field(default_factory=dict)
    """`Map.digest` of every map file trained or evaluated on, by name: `compare` tells same-named maps apart."""
    budget: int | None = None
    """The env steps asked for (`--timesteps`): a run stops after the iteration that reaches them."""
    ended_on_request: bool = False
    """Interrupted by a first Ctrl-C that ended it as its budget's end would (`stopping.py`): its last checkpoint
    holds the final policy."""
    stop_held: bool = False
    """A stop request (Ctrl-C, SIGTERM) reached the run: once training had ended (it waited for the tables and
    summary.json), at its budget's end, or earlier (then `interrupted` says the run was cut short). The caller stops:
    `train` exits 130, `transfer` and `reproduce` end the job there."""
    address: str | None = None
    """The Ray cluster the run trained on (`--address`, `auto` resolved); None: a Ray of this machine's own."""
    resumed_at: int | None = None
    """`train --resume`: the env steps of the checkpoint the run continued from (`wall_s` adds the training time
    before it, its state file's)."""

    def to_dict(self) -> dict[str, Any]:
        best = None
        if self.best is not None:
            b = self.best
            best = {"map": b.map, "theta": list(b.theta), "P_c": b.P_c, "P_len": b.P_len, "R1": b.R1,
                    "first_seen_env_steps": b.env_steps}  # fmt: skip
        return {
            "run_dir": str(self.run_dir),
            "algorithm": self.algorithm,
            "env_steps": self.env_steps,
            "budget": self.budget,
            "iterations": self.iterations,
            "wall_s": round(self.wall_s, 2),
            "interrupted": self.interrupted,
            "best": best,
            "exact_optimum": {m: asdict(o) for m, o in self.optimum.items()},
            "evaluation": self.evaluation,
            "map_digests": self.map_digests,
            "checkpoint": None if self.checkpoint is None else str(self.checkpoint),
            "pretrained": None if self.pretrained is None else str(self.pretrained),
            "pretrained_in_runners": self.pretrained_in_runners,
            "files": {k: str(v) for k, v in self.files.items()},
            "address": self.address,
            "resumed_at": self.resumed_at,
        }

    def to_json(self) -> str:
        """summary.json's text: strict JSON, a figure with no value (no optimum on a map too large) written null."""
        return jsontext.dumps(self.to_dict(), indent=2)


class _Progress:
    """Driver-side Tune callback: collects episode bests and curves, and shows one progress line."""

    def __init__(self, cfg: TrainConfig, out: Any = None, label: str | None = None) -> None:
        self.status = StatusLine(out)
        self.cfg = cfg
        self.label = label or cfg.algo.upper()
        self.top = TopMorphologies()
        self.curve: dict[str, list[float]] = {k: [] for k in CURVE_NAMES}
        self.t0 = time.monotonic()
        self._last_mean = math.nan
        self.last_eval: dict[str, Any] = {}
        self.pretrained_in_runners: bool | None = None
        """Fine-tuning: whether every env runner held the checkpoint's policy before the first sample."""

    def on_result(self, result: dict[str, Any]) -> None:
        steps = int(result.get(keys.STEPS) or 0)
        bests = episode_bests(result)
        self.top.add_episode_bests(self.cfg.algo, bests, steps)
        for k, v in curve_point(result).items():
            self.curve[k].append(v)
        runners = result.get(keys.ENV_RUNNERS, {})
        ev = result.get(EVAL_KEY) or {}
        if ev:
            self.last_eval = ev
        if PRETRAINED_KEY in result and self.pretrained_in_runners is None:
            self.pretrained_in_runners = bool(result[PRETRAINED_KEY] == 1.0)
        mean_r1 = runners.get(keys.METRIC_PREFIX, {}).get("R1_mean")
        if isinstance(mean_r1, int | float) and math.isfinite(mean_r1):
            self._last_mean = float(mean_r1)  # iterations in which no episode ended report NaN: keep the last
        self._show(steps, done=steps >= self.cfg.timesteps)

    def replay(self, rows: list[dict[str, Any]]) -> None:
        """Results a run recorded before it was resumed, taken in as if reported (not shown)."""
        status, self.status = self.status, StatusLine(io.StringIO())
        try:
            for row in rows:
                self.on_result(row)
        finally:
            self.status = status

    def _show(self, steps: int, done: bool) -> None:
        if not self.status.due(force=done):
            return
        budget = self.cfg.timesteps
        best = self.top.top(1)
        best_txt = f"best R1 {best[0].R1:.2f} {best[0].angles}" if best else "best R1 -"
        mean_txt = f"episode mean R1 {self._last_mean:.2f}" if math.isfinite(self._last_mean) else ""
        ev = self.last_eval.get(TRAINED_KEY) or self.last_eval  # the policy of `steps`, not the one a run keeps
        settled_txt = (f"greedy: gap {ev['median_gap']:.2f}, {ev['share_within_1pct'] * 100:.0f} % within 1 %"
                       if ev and math.isfinite(ev.get("share_within_1pct", math.nan)) else "")  # fmt: skip
        took = fmt_duration(time.monotonic() - self.t0)
        line = (f"{self.label} {bar(steps / budget, 24)} {steps:,}/{budget:,} steps  {took}  {best_txt}  {mean_txt}  "
                f"{settled_txt}").rstrip()  # fmt: skip
        self.status.write(line, end=done)

    def starting(self) -> None:
        """On a terminal, a line in place until the first iteration's bar: building the env runners and their floors
        takes seconds (a minute on a floor of millions of cells), which read as a hang."""
        if self.status.tty:  # short, to fit a narrow terminal: the first bar writes over it
            n = self.cfg.env_runners
            runners = "its envs" if n == 0 else f"{n} env runner{'' if n == 1 else 's'}"
            self.status.write(f"{self.label} starting: the trial, {runners}, their floors"[: self.status.width()])

    def finish(self) -> None:
        self.status.finish()


def _tune_callback(progress: _Progress) -> Any:
    from ray import tune

    class _Callback(tune.Callback):
        def on_trial_result(self, iteration: int, trials: list[Any], trial: Any, result: dict[str, Any], **info: Any):
            progress.on_result(result)

    return _Callback()


def write_outputs(run_dir: Path, cfg: TrainConfig, progress: _Progress, optimum: dict[str, Optimum]) -> dict[str, Path]:
    """Top-k CSV/Markdown/PNG and the learning curves, with every map's exact optimum as yardstick."""
    from smorphi_rl.plots import plot_learning_curves, plot_top_morphologies

    files = write_found(progress.top, run_dir, cfg.top_k)
    for path in cfg.env.map_files:
        grid_map = load_map(path)
        evaluator = cfg.env.planning.evaluator(grid_map)
        top = progress.top.top(TOP_PLOT, grid_map.name)
        if top:
            items = []
            for rank, f in enumerate(top, 1):
                morphology = Morphology.of(f.theta)
                items.append((f"#{rank}, R1 {f.R1:.2f}", evaluator.plan(morphology), morphology))
            single = len(cfg.env.map_files) == 1
            key = "top_png" if single else f"top_png_{grid_map.name}"
            png = run_dir / ("top_morphologies.png" if single else f"top_morphologies_{grid_map.name}.png")
            files[key] = plot_top_morphologies(items, grid_map, cfg.env.block_side_m, png)
    if progress.curve["env_steps"]:
        reference = next(iter(optimum.values())).R1 if len(optimum) == 1 else None
        kept = progress.last_eval.get("policy_env_steps")
        kept = kept if isinstance(kept, int | float) and kept < max(progress.curve["env_steps"]) else None
        labels = [map_label(entry) for entry in cfg.env.maps]
        maps = " + ".join(labels if len(labels) <= 3 else [*labels[:2], f"{len(labels) - 2} more"])
        files["curves_png"] = plot_learning_curves(
            {cfg.algo.upper(): progress.curve}, run_dir / "learning_curves.png", reference,
            f"{cfg.algo.upper()} on {maps}, seed {cfg.seed}: {run_dir.name}", kept,
        )  # fmt: skip
    return files


def map_digests(cfg: TrainConfig) -> dict[str, str]:
    """`Map.digest` of every map file the run trains or evaluates on, by name (what `compare` checks a run's map
    against), read as the run starts: a missing or unreadable map is named before anything is written or any
    exact optimum computed (MapError), and a map edited during the run does not change the record."""
    return {m.name: m.digest for m in map(load_map, dict.fromkeys((*cfg.env.map_files, *cfg.evaluation_maps)))}


def training_optima(cfg: TrainConfig, log_dir: str | Path, out: Any) -> dict[str, Optimum]:
    """The exact 1-degree optimum of every map the protocol evaluates on (seconds each the first time, then
    cached); not computed (R1 NaN, with a note) on maps over OPTIMUM_MAX_CELLS cells, where it would take far
    longer."""
    cache = optimum_cache(log_dir)
    maps = {path: load_map(path) for path in cfg.evaluation_maps}
    if any(m.cells.size <= OPTIMUM_MAX_CELLS for m in maps.values()):
        make_cache(cache)  # a folder that cannot be made: one line, before any line saying an optimum is computed
    for path in cfg.env.map_files:  # a training map the protocol does not evaluate on (--eval-maps): said too
        for said in () if path in maps else load_map(path).warnings():
            out.write(said + "\n")
    optima: dict[str, Optimum] = {}
    for path, grid_map in maps.items():
        if not cfg.env.planning.is_paper_default:
            out.write(f"{grid_map.name}: {cfg.env.planning.describe(grid_map)}\n")
        weights = cfg.env.weights_on(grid_map)
        start = cfg.env.planning.start_warning(grid_map)  # separate rooms: every shape covers the start's alone
        for line in (*grid_map.warnings(), start):
            if line:
                out.write(line + "\n")
        if grid_map.cells.size > OPTIMUM_MAX_CELLS:
            found = cached_optimum(grid_map, weights, cfg.env.planning, cache)
            if found is not None:
                out.write(f"exact optimum of {grid_map.name}: read from {rel(cache)} (a `search optimum` run's)\n")
            else:
                out.write(f"exact optimum of {grid_map.name}: not computed ({grid_map.cells.size:,} cells, over "
                          f"{OPTIMUM_MAX_CELLS:,}; `smorphi-rl search optimum --map {shell_path(path)} --log-dir "
                          f"{shell_path(log_dir)}` finds it for train); gaps are not reported\n")  # fmt: skip
            optima[grid_map.name] = found or NO_OPTIMUM
            if found is None:  # the best of a few broad shapes (long tiles, short paths) stands in for the optimum
                broad = cfg.env.planning.evaluator(grid_map, cache=False).evaluate_many(np.array(REACH_SHAPES))
                i = int(np.argmax(weights.r1(broad.P_c, broad.P_len)))
                p_c, p_len, path_term = float(broad.P_c[i]), int(broad.P_len[i]), cfg.env.path_term
                line = swamped_warning(weights, p_c, p_len, path_term, grid_map.name, whose="a broad shape's")
                if line and not start:  # a start on a speck explains it first
                    out.write(line + "\n")
                continue
        elif (known := cached_optimum(grid_map, weights, cfg.env.planning, cache)) is not None:
            out.write(f"exact optimum of {grid_map.name}: read from {rel(cache)}\n")  # a transfer's later runs
            optima[grid_map.name] = known
        else:
            out.write(f"exact optimum of {grid_map.name} (every 1-degree shape; cached under {rel(cache)})\n")
            out.flush()
            show = optimum_progress(grid_map.name, out)
            optima[grid_map.name] = exact_optimum(path, weights, cfg.env.planning, cache, show)
        opt = optima[grid_map.name]
        line = None if start else degenerate_warning(weights, opt.P_c, opt.P_len, cfg.env.path_term, grid_map.name)
        if line:
            out.write(line + "\n")
    return optima


def trial_callbacks(cfg: TrainConfig, optima: dict[str, Optimum], base: type | None = None) -> type:
    """The RLlib callbacks of one trial of `train`, `sweep` or `transfer`: `base` (ours, or fine-tuning's) with the
    evaluation protocol on `cfg`'s evaluated maps, the final-policy selection and the designer's figures, as
    `cfg` asks; the one way every job builds its trials."""
    base = base or MorphologyCallbacks
    if not cfg.eval_every or not cfg.evaluation_maps:  # generated floors alone: no fixed map to evaluate on
        return base
    step = cfg.env.angle_step_deg
    starts = eval_starts(cfg.eval_starts, step)
    selection = selection_starts(cfg.select_starts, step, starts) if cfg.select_starts else ()
    return with_evaluation(base, cfg.eval_every, starts, optima, cfg.timesteps, selection, cfg.evaluation_maps,
                           cfg.design_budget)  # fmt: skip


def _train_trainable(
    config: dict[str, Any], cfg: TrainConfig, callbacks: type | None, run_dir: Path, stop_name: str | None,
    resume_from: Path | None = None,
) -> None:  # fmt: skip
    """`train`'s one trial: the project's one trainable, recording (if on) under the run's folder; every checkpoint
    holds the state `train --resume` continues from (`resume_from`)."""
    run_trial(cfg, callbacks, run_dir, resume_from=resume_from, stop_name=stop_name, resumable=True)


def _fit(
    cfg: TrainConfig, name: str, run_dir: Path, callbacks: Any, progress: _Progress,
    stopper: GracefulStop | None, late: threading.Event, resumed: ResumedTrial | None = None,
) -> float:  # fmt: skip
    """The Tune run itself (a local Ray or a cluster is already up), its results shown and kept by `progress`: the
    wall time; a failed trial raises TrainingError in one line. With `stopper`, a first Ctrl-C ends the run as its
    budget's end would; without, a stop Tune's own handler took is set in `late`."""
    from ray import tune

    from smorphi_rl.training.tensorboard import TensorBoardLogger

    stop_name = None if stopper is None else stopper.name
    resume_from = None if resumed is None else resumed.checkpoint
    trainable = tune.with_resources(
        tune.with_parameters(
            _train_trainable,
            cfg=cfg,
            callbacks=callbacks,
            run_dir=run_dir,
            stop_name=stop_name,
            resume_from=resume_from,
        ),
        resources(cfg),
    )
    tuner = tune.Tuner(
        trainable,
        tune_config=tune.TuneConfig(
            trial_dirname_creator=lambda trial: (
                f"{cfg.algo}-{trial.trial_id}" if resumed is None else resumed.trial_dir.name
            )
        ),  # a resumed run: its own folder
        run_config=tune.RunConfig(
            name=name,
            storage_path=str(run_dir.parent),
            callbacks=[_tune_callback(progress), TensorBoardLogger()],
            verbose=0,
        ),
    )
    t0 = progress.t0 = time.monotonic()  # the bar's clock and the summary's: training alone, from here
    progress.starting()
    if stopper is None:
        with tune_stop_seen(late):
            _, failed = fit(tuner, run_dir)
    else:
        with stopper.catching(reported=lambda: bool(progress.curve["env_steps"])):
            _, failed = fit(tuner, run_dir)
    wall = time.monotonic() - t0
    progress.finish()
    if failed:
        raise TrainingError(failed.line)
    return wall


def reported_any(run_dir: Path, algo: str, progress: _Progress | None = None) -> bool:
    """Whether a trial of the run reported a result (to `progress`, or in its result file) or wrote a checkpoint: a
    run that failed or stopped before its first iteration holds nothing worth keeping. Tune stages a trial's result
    file away from the run's folder and copies it there every few seconds, so `progress` knows of a report first. On
    a full disk the result file can stay empty while checkpoints are whole: those are kept."""
    if progress is not None and progress.curve["env_steps"]:
        return True
    trials = list(run_dir.glob(f"{algo}-*"))
    rows = any((t / "result.json").is_file() and (t / "result.json").stat().st_size > 0 for t in trials)
    return rows or any(checkpoints_under(t) for t in trials)


def stopped_at_once(run_dir: Path) -> str:
    """What a run a second stop ended at once says: what its folder keeps."""
    return (f"stopped at once; {rel(run_dir)} keeps what was written so far (episodes, logs, any checkpoint), but no "
            "tables or summary.json (`train --resume` with its --name continues it)")  # fmt: skip


def nothing_kept(run_dir: Path, what: str = "run") -> str:
    """What a run (or sweep) stopped before its first report says: nothing of it was kept."""
    return f"stopped before the {what}'s first report: nothing was kept ({rel(run_dir)} was removed)"


def train(
    cfg: TrainConfig,
    name: str | None = None,
    log_dir: str | Path = DEFAULT_LOG_DIR,
    address: str | None = None,
    out: Any = None,
    label: str | None = None,
    optima_log_dir: str | Path | None = None,
    graceful: bool = False,
    resume: bool = False,
) -> RunSummary:
    """Run `cfg` through Ray Tune and write everything under `log_dir/<name>/`; the exact optima are cached under
    `optima_log_dir` (default `log_dir`), so a job's runs share the cache of the folder the user named. `graceful`
    (the `train` command): a first Ctrl-C ends the run as its budget's end would, its final policy checkpointed.
    `resume`: continue the run `name` that stopped before it finished (killed), from its last checkpoint."""
    if resume and not name:
        raise TrainConfigError("--resume continues a run: give its --name (and --log-dir, if not the default)")
    stamped = not name
    name = name or default_run_name(cfg, datetime.now().strftime("%Y%m%d-%H%M%S"))
    MorphologyEnv(cfg.env.to_dict())  # a bad map or a block too small for it fails here, before Ray starts
    digests = map_digests(cfg)
    callbacks, pretrained = None, None
    if cfg.pretrained is not None:  # a bad checkpoint fails here, before Ray starts
        pretrained, callbacks = fine_tune_from(cfg.pretrained, cfg.env.to_dict())
    cluster.check_reachable(address, client=False)
    if address is None:
        cluster.check_capacity(cfg.cpus, cfg.env_runners, address)  # a local Ray's size is known before it starts
    out = out or sys.stderr
    progress = _Progress(cfg, out, label)
    late, held = threading.Event(), ExitStack()  # a stop once training has ended waits for the tables and summary
    resumed = None
    if resume:  # its results up to the checkpoint are the run's too
        run_dir = Path(log_dir).resolve() / check_run_name(name)
        resumed = continue_train_run(run_dir, cfg.to_dict(), cfg.algo, digests)
        out.writelines(line + "\n" for line in resumed.said)
        out.write(
            f"resuming {name} from its checkpoint of {resumed.env_steps:,} env steps ({rel(resumed.checkpoint)})\n"
        )
        progress.replay(resumed.rows)
    else:  # claimed atomically; removed again if the run never starts
        run_dir = (prepare_stamped_run_dir if stamped else prepare_run_dir)(log_dir, name)
    name = run_dir.name
    try:
        optima = training_optima(cfg, log_dir if optima_log_dir is None else optima_log_dir, out)
        callbacks = trial_callbacks(cfg, optima, callbacks)
        quiet()
        stopper = GracefulStop(out) if graceful else None
        if resumed is not None and resumed.done:  # it trained its budget: its tables and summary alone are written
            wall = 0.0
            held.enter_context(interrupts.stop_requests(late, again=True))
        else:
            with cluster.ray_session(address):
                cluster.check_capacity(cfg.cpus, cfg.env_runners, address)
                config = cfg.to_dict() | {"name": name, "address": address, "map_digests": digests}
                write_text_atomic(run_dir / "config.json", jsontext.dumps(config, indent=2))
                cluster.check_shared_folder(run_dir, address)  # a kill as it checks: a run that never reported
                wall = _fit(cfg, name, run_dir, callbacks, progress, stopper, late, resumed)
                held.enter_context(interrupts.stop_requests(late, again=True))  # Ray's shutdown, the outputs
        wall += 0.0 if resumed is None else resumed.elapsed_s  # a resumed run's time before its checkpoint too
    except TrainingError:
        raise  # a trial failed: its folder holds the errors the line names, whether or not it reported
    except BaseException as exc:
        held.close()
        if not reported_any(run_dir, cfg.algo, progress):
            discard_run_dir(run_dir)  # nothing trained: the name stays free
            if isinstance(exc, KeyboardInterrupt) and not isinstance(exc, Interrupted):
                raise Interrupted(nothing_kept(run_dir)) from None
        elif isinstance(exc, KeyboardInterrupt) and not isinstance(exc, Interrupted):  # a second Ctrl-C: at once
            raise Interrupted(stopped_at_once(run_dir)) from None
        raise
    try:
        with interrupts.results_held(late, held):
            summary = _finish(run_dir, cfg, progress, optima, wall, pretrained, digests, stopper, address,
                              None if resumed is None else resumed.env_steps)  # fmt: skip
    except KeyboardInterrupt as exc:  # a second stop as the results are written: at once
        raise exc if isinstance(exc, Interrupted) else Interrupted(stopped_at_once(run_dir)) from None
    summary.stop_held = late.is_set() or (stopper is not None and stopper.requested.is_set())  # at the budget too
    return summary


def _finish(
    run_dir: Path, cfg: TrainConfig, progress: _Progress, optima: dict[str, Optimum], wall: float,
    pretrained: Path | None, digests: dict[str, str], stopper: GracefulStop | None, address: str | None,
    resumed_at: int | None = None,
) -> RunSummary:  # fmt: skip
    """A run's tables, plots and summary.json once training has ended; a run that never reported is removed."""
    if not reported_any(run_dir, cfg.algo, progress):  # stopped (Ctrl-C, SIGTERM) before its first report
        discard_run_dir(run_dir)
        raise Interrupted(nothing_kept(run_dir))
    files = write_outputs(run_dir, cfg, progress, optima)
    steps = int(progress.curve["env_steps"][-1]) if progress.curve["env_steps"] else 0
    checkpoints = checkpoints_under(run_dir)
    best = progress.top.top(1)
    summary = RunSummary(
        run_dir=run_dir,
        algorithm=cfg.algo,
        env_steps=steps,
        iterations=len(progress.curve["env_steps"]),
        wall_s=wall,
        interrupted=(cut := steps < cfg.timesteps and len(progress.curve["env_steps"]) != cfg.max_iterations),
        best=best[0] if best else None,
        optimum=optima,
        checkpoint=checkpoints[-1] if checkpoints else None,
        files=files,
        pretrained=pretrained,
        pretrained_in_runners=progress.pretrained_in_runners,
        evaluation=progress.last_eval,
        map_digests=digests,
        budget=cfg.timesteps,
        ended_on_request=cut and stopper is not None and stopper.requested.is_set(),  # not a request at the end
        address=cluster.auto_address() if address == "auto" else address,
        resumed_at=resumed_at,
    )
    if (run_dir / EPISODES_DIR).is_dir():
        files["episodes"] = run_dir / EPISODES_DIR
    files["summary"] = run_dir / "summary.json"
    write_text_atomic(files["summary"], summary.to_json())
    return summary


def format_summary(s: RunSummary) -> str:
    """The end-of-run text: best shape against the optimum, where everything is, how to look at it."""
    state = "interrupted after" if s.interrupted else "trained for"
    iterations = f"{s.iterations} iteration{'' if s.iterations == 1 else 's'}"
    if s.budget is not None and s.env_steps > s.budget:  # whole iterations: the last one runs past the budget
        iterations += f", the last ending past the {s.budget:,} asked"
    if s.resumed_at is not None:
        iterations += f"; resumed at {s.resumed_at:,} env steps"
    lines = [f"{s.algorithm.upper()} {state} {s.env_steps:,} env steps in {fmt_duration(s.wall_s)} ({iterations})"
             + (f" on the Ray cluster at {s.address}" if s.address else "")]  # fmt: skip
    if s.best is not None:
        b = s.best
        lines.append(f"best morphology: {b.angles} on {b.map}: P_c {b.P_c:.2f} %, P_len {b.P_len}, R1 {b.R1:.2f} "
                     f"(first found at {b.env_steps:,} env steps)")  # fmt: skip
        opt = s.optimum.get(b.map)
        if opt is not None and math.isfinite(opt.R1):
            t = angles_text(opt.theta)
            pct = 100 * b.R1 / opt.R1 if opt.R1 else math.nan
            lines.append(f"exact optimum on the {opt.step_deg:g}-degree lattice: {t} R1 {opt.R1:.2f} "
                         f"(best found is {pct:.2f} % of it)")  # fmt: skip
    else:  # the best shape is an episode's final one: a budget shorter than an episode finishes none
        why = ("the run stopped before any episode finished" if s.interrupted else
               f"no episode finished within {s.env_steps:,} env steps: raise --timesteps")  # fmt: skip
        lines.append(f"best morphology: none ({why})")
        for name, opt in s.optimum.items():
            if math.isfinite(opt.R1):
                lines.append(f"exact optimum of {name} on the {opt.step_deg:g}-degree lattice: "
                             f"{angles_text(opt.theta)} R1 {opt.R1:.2f}")  # fmt: skip
    ev = s.evaluation
    if ev:
        chosen = ev.get("policy_env_steps")
        if isinstance(chosen, int | float) and chosen < s.env_steps:
            lines.append(f"final policy: the one of {int(chosen):,} env steps, the best of the run's evaluations on "
                         "other seeded starts (--select-starts)")  # fmt: skip
        if math.isfinite(ev.get("share_within_1pct", math.nan)):
            lines.append(f"greedy policy from {ev.get('measured_starts', ev.get('starts', '?'))} fixed starts"
                         f"{'' if ev.get('measured_starts') == ev.get('starts') else ' (maps with an exact optimum)'}"
                         ": settles within 1 % "
                         f"of the optimum from {100 * ev['share_within_1pct']:.0f} % of them; median gap "
                         f"{ev['median_gap']:.2f} R1, mean settled R1 {ev['settled_R1_mean']:.2f}")  # fmt: skip
        else:
            lines.append(f"greedy policy from {ev.get('starts', '?')} fixed starts: mean settled R1 "
                         f"{ev['settled_R1_mean']:.2f} (no exact optimum to measure it against)")  # fmt: skip
    if s.pretrained is not None:
        held = {True: "yes", False: "NO", None: "not reported"}[s.pretrained_in_runners]
        lines.append(f"fine-tuned from: {rel(s.pretrained)} (sampling started from its weights: {held})")
    if s.checkpoint is not None:
        lines.append(f"checkpoint: {rel(s.checkpoint)}")
    plots = [(k, f"top morphologies plot ({k.removeprefix('top_png_')})") for k in s.files if k.startswith("top_png_")]
    for key, label in (("top_md", "top morphologies"), ("top_png", "top morphologies plot"), *plots,
                       ("curves_png", "learning curves"), ("summary", "summary")):  # fmt: skip
        if key in s.files:
            lines.append(f"{label}: {rel(s.files[key])}")
    if "episodes" in s.files:
        n = sum(1 for p in s.files["episodes"].iterdir() if p.name.endswith(".mcap"))
        lines.append(f"episodes: {rel(s.files['episodes'])} ({n} MCAP recordings; "
                     f"smorphi-rl replay {shell_path(s.files['episodes'])})")  # fmt: skip
    lines.append(f"logs: {rel(s.run_dir)}")
    lines.append(f"tensorboard --logdir {shell_path(s.run_dir)}")
    return "\n".join(lines)

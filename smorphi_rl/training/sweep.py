"""`smorphi-rl sweep`: a validated sweep file run as one Ray Tune experiment, resumable after an interruption.

Each trial is the project's one trainable (`trial.run_trial`, which `train` runs too) on one of the sweep's
trials (`SweepConfig.trials`: index, algorithm, maps, seed, hyperparameters), in a folder named by its index.
`--resume` never calls `Tuner.restore` (whose pickles hold code): it runs a fresh experiment of the trials that
did not finish, each in its own folder again, continuing from our state file of its last checkpoint
(`resume.py`); a finished trial is never touched.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from smorphi_rl import cluster, interrupts, jsontext
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.inputs import MAX_YAML_BYTES, strict_yaml
from smorphi_rl.map_sources import map_set_label
from smorphi_rl.progress import StatusLine, bar, fmt_duration
from smorphi_rl.protocol import Optimum
from smorphi_rl.quiet import quiet
from smorphi_rl.rundir import (
    DEFAULT_LOG_DIR,
    RunDirError,
    check_run_dir,
    claim_again,
    discard_run_dir,
    in_use_by,
    prepare_run_dir,
    refuse_links,
    rel,
    rename_cut_run,
    shell_path,
    write_atomic,
    write_text_atomic,
)
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.checkpoints import checkpoints_under
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.failures import fit
from smorphi_rl.training.finetune import fine_tune_from
from smorphi_rl.training.resume import finished, resume_point, set_aside_from, trial_spec
from smorphi_rl.training.run import (
    RunSummary,
    TrainingError,
    map_digests,
    nothing_kept,
    training_optima,
    trial_callbacks,
)
from smorphi_rl.training.stopping import tune_stop_seen
from smorphi_rl.training.sweep_config import SweepConfig, SweepConfigError, complaint, trial_dirname
from smorphi_rl.training.sweep_report import (
    TrialRow,
    group_curves,
    read_sweep,
    sweep_group_lines,
    write_sweep_groups,
    write_sweep_tables,
)
from smorphi_rl.training.topk import episode_bests, write_found
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
    read_back: int = 0
    """Trials a `--resume` found finished and read back untouched (not trained by this call)."""
    stop_held: bool = False
    """A stop request (Ctrl-C, SIGTERM) came once the trials had ended and waited for the tables (`cmd_sweep`
    exits 130 saying they are whole)."""


def sweep_trainable(
    config: dict[str, Any], sweep: SweepConfig, optima: dict[str, Optimum], resume_points: dict[int, Path],
    exp: Path,
) -> None:  # fmt: skip
    """One trial of the sweep: its TrainConfig, run by the project's one trainable with the callbacks `train`
    builds (the evaluation protocol against `optima`, fine-tuning from the sweep's checkpoint), continuing from
    its entry in `resume_points` if it has one. Its episodes are recorded straight into its folder under `exp`, as
    `train`'s are: in Tune's staging folder they were copied over as they were written, and each episode came to
    the sweep twice, a `.mcap.part` beside its `.mcap`."""
    cfg = sweep.base_config(config["algo"], tuple(config["maps"]), int(config["seed"]), dict(config.get("hp") or {}))
    base = None if cfg.pretrained is None else fine_tune_from(cfg.pretrained, cfg.env.to_dict())[1]
    run_trial(cfg, trial_callbacks(cfg, optima, base), exp / trial_dirname(config),
              resume_from=resume_points.get(int(config["index"])), stop=sweep.stop, resumable=True)  # fmt: skip


_Started = dict[int, tuple[Path, Path | None]]
"""A started trial's index -> (its folder, the checkpoint it continues from, if any)."""


MAPS_RECORD = "maps.json"
"""Each map set's `Map.digest`s as the sweep started: a resume on maps edited since is refused."""


def check_maps_unchanged(exp: Path, digests: dict[str, dict[str, str]]) -> None:
    """Refuse a resume whose maps are not the floors the sweep started on (a map file edited or replaced since, or
    relative paths read from another folder): its finished trials would be reported against the new floors."""
    from smorphi_rl.inputs import read_json_object

    record = exp / MAPS_RECORD
    if not record.exists():
        return  # a sweep started before the record was kept
    kept = read_json_object(record, "record of the sweep's maps")
    for label, now in digests.items():
        before = kept.get(label)
        changed = sorted(m for m, d in now.items() if isinstance(before, dict) and before.get(m, d) != d)
        if changed:
            raise RunDirError(f"map {changed[0]} is not the floor sweep {exp.name} started on (its cells differ): "
                              "restore it to resume, or give the sweep another `name`")  # fmt: skip


def read_resume(
    exp: Path, trials: list[dict[str, Any]], out: Any = None
) -> tuple[list[dict[str, Any]], _Started, list[Path]]:
    """(the trials left to run, the started ones among them, the folders of trials with no record) of experiment
    `exp`, moving nothing. The state files are read back safely here, before Ray starts, so a crafted one is refused
    in one line; one cut short by a kill is passed over for the checkpoint before it, said on `out`."""
    started: _Started = {}
    done: set[int] = set()
    unrecorded: list[Path] = []
    names = {trial_dirname(t) for t in trials}
    for d in sorted(p for p in exp.iterdir() if p.is_dir()):
        if d.is_symlink():  # the resume would write the trial's tables wherever the link points
            raise RunDirError(f"{d}: a link, where the sweep keeps its trials' folders; resume only sweeps you ran")
        spec = trial_spec(d)
        if spec is None:
            if (d / "params.json").exists() or (d / "params.json").is_symlink():
                raise RunDirError(f"{d}: its params.json is not a sweep trial's record; resume only sweeps you "
                                  "ran, or start this one under another `name`")  # fmt: skip
            if d.name in names and not any(d.iterdir()):  # made by Tune, stopped before the trial began
                continue  # a trial that never started: `drop_unstarted` removes the folder, and it trains
            if d.name in names and (d / "result.json").exists():  # a trial that reported, its record gone:
                raise RunDirError(f"{d}: a trial's folder without its params.json (the trial's record); restore it, "
                                  "or move the folder out of the sweep to train that trial again")  # fmt: skip
            if d.name in names:  # killed as it began: its checkpoint out, its record and results in Ray's staging
                unrecorded.append(d)  # kept aside by `set_aside_unrecorded`, and the trial trains again
            continue
        index = spec["index"]
        ours = 0 <= index < len(trials) and {k: spec.get(k) for k in trials[index]} == trials[index]
        if not ours or d.name != trial_dirname(trials[index]):
            raise RunDirError(f"{d}: not a trial of this sweep (its params.json names another); resume only "
                              "sweeps you ran, or start this one under another `name`")  # fmt: skip
        if index in done or index in started:
            raise RunDirError(f"{d}: trial {index} has another folder too; resume only sweeps you ran")
        if finished(d):
            done.add(index)
        else:
            said: list[str] = []
            started[index] = (d, resume_point(d, said))  # reads every state file it weighs: CheckpointError names it
            for line in said if out is not None else []:
                print(line, file=out)
    return [t for t in trials if t["index"] not in done], started, unrecorded


def set_aside_unrecorded(folders: list[Path], out: Any) -> None:
    """Rename each trial folder that holds no record (params.json) to `<name>.cut-N`, kept, saying so: a sweep
    killed as a trial wrote its first checkpoint left one, and every resume was refused until it was moved by hand."""
    for d in folders:
        aside = rename_cut_run(d)
        print(
            f"{rel(d)}: a trial's folder without its record (params.json; the sweep was stopped as the trial "
            f"began): kept as {aside.name}, and the trial trains again",
            file=out,
        )


def drop_unstarted(exp: Path, pending: list[dict[str, Any]]) -> None:
    """Remove the empty folders Tune made for pending trials before a stop: a sweep stopped between two trials left
    one, and its trial then trains as if it had none."""
    for trial in pending:
        d = exp / trial_dirname(trial)
        if d.is_dir() and not d.is_symlink() and not any(d.iterdir()):
            d.rmdir()


def set_aside_started(started: _Started) -> dict[int, Path]:
    """Set each started trial's checkpoints and results aside (`resume.set_aside`); the checkpoint each one
    continues from, at its new place."""
    points: dict[int, Path] = {}
    for index, (d, point) in started.items():
        moved = set_aside_from(d, point)
        if moved is not None:
            points[index] = moved
    return points


class _SweepProgress:
    """One status line for the whole sweep: trials done, the running trial's steps, the best shape so far."""

    def __init__(self, sweep: SweepConfig, total: int, out: Any) -> None:
        self.sweep, self.total, self.status = sweep, total, StatusLine(out)
        self.t0 = time.monotonic()
        self.done: set[str] = set()
        self.reported = 0
        """Results the trials reported to this process (Tune copies their result files to the folder later)."""
        self.best = (float("-inf"), float("-inf"), "")  # R1, P_c (the tables' tie-break), the shape's text

    def found(self, bests: list[Any]) -> None:
        """Take the best of these shapes (each with R1, P_c, angles and map) if it beats the one shown: higher R1,
        then higher P_c, as the tables rank a tie."""
        for b in bests:
            if self.best[:2] < (b.R1, b.P_c):
                self.best = (b.R1, b.P_c, f"{b.angles} on {b.map}")

    def result(self, trial: str, config: dict[str, Any], result: dict[str, Any]) -> None:
        self.reported += 1
        self.found(episode_bests(result))
        steps = int(result.get(keys.STEPS) or 0)
        maps = map_set_label(config.get("maps", []))
        self._show(f"{config.get('algo', '?').upper()} {maps} seed {config.get('seed')} "
                   f"{steps:,}/{self.sweep.step_budget:,} steps")  # fmt: skip

    def complete(self, trial: str) -> None:
        self.done.add(trial)
        self._show("", force=True)

    def _show(self, current: str, force: bool = False) -> None:
        if not self.status.due(force):
            return
        best = f"best R1 {self.best[0]:.2f} {self.best[2]}" if self.best[2] else "best R1 -"
        line = (f"sweep {self.sweep.name} {bar(len(self.done) / max(1, self.total), 20)} {len(self.done)}/{self.total} "
                f"trials  {fmt_duration(time.monotonic() - self.t0)}  {current}  {best}")  # fmt: skip
        self.status.write(line)

    def finish(self) -> None:
        self.status.finish()


def _tune_callback(progress: _SweepProgress) -> Any:
    from ray import tune

    class _Callback(tune.Callback):
        def on_trial_result(self, iteration: int, trials: list[Any], trial: Any, result: dict[str, Any], **info: Any):
            progress.result(trial.trial_id, trial.config, result)

        def on_trial_complete(self, iteration: int, trials: list[Any], trial: Any, **info: Any):
            progress.complete(trial.trial_id)

    return _Callback()


def _new_experiment(log_dir: str | Path, name: str, claim: Any) -> Path:
    """`claim(log_dir, name)` (`rundir.check_run_dir` or `prepare_run_dir`), saying how to continue a folder that
    already exists."""
    try:
        return Path(claim(log_dir, name))
    except RunDirError:
        try:
            exp: Path | None = Path(log_dir).resolve() / name
        except (RuntimeError, OSError):  # a symlink loop: the claim's own line says so
            exp = None
        if exp is not None and exp.is_dir() and (pid := in_use_by(exp)) is not None:
            raise RunDirError(f"experiment folder {exp} is in use by process {pid}, a sweep running now: wait for it "
                              "to finish, or give the sweep file another `name`") from None  # fmt: skip
        if exp is not None and exp.is_dir():
            raise RunDirError(f"experiment folder {exp} already exists: give the sweep file another `name`, or add "
                              "--resume to continue it") from None  # fmt: skip
        raise


def prepare_experiment(sweep: SweepConfig, log_dir: str | Path, resume: bool) -> Path:
    """The experiment folder: new (refusing an existing one), or, with resume, an existing one of the same sweep."""
    if not resume:
        exp = _new_experiment(log_dir, sweep.name, prepare_run_dir)
        write_atomic(exp / SWEEP_COPY, sweep.path.read_bytes())
        return exp
    try:
        exp = Path(log_dir).resolve() / sweep.name
    except (RuntimeError, OSError) as exc:  # a symlink loop, an unreadable folder
        raise RunDirError(f"log directory {log_dir} cannot be used ({exc})") from None
    copy = exp / SWEEP_COPY
    if copy.is_symlink() or not copy.is_file():
        lost = (exp / MAPS_RECORD).is_file() and not copy.exists() and not copy.is_symlink()  # a sweep's, less it
        why = (f"has lost {SWEEP_COPY}, the copy of the sweep file it ran, which a resume checks the file against: "
               f"copy the sweep file there to resume" if lost else "holds no sweep started by smorphi-rl")  # fmt: skip
        raise RunDirError(f"nothing to resume: {exp} {why}")
    try:
        if copy.stat().st_size > MAX_YAML_BYTES:
            raise ValueError("too large")
        kept = strict_yaml(copy.read_text())
        if not isinstance(kept, dict):  # emptied or overwritten: no sweep to restore the user's file from
            raise ValueError("not a mapping")
    except (OSError, ValueError, yaml.YAMLError, RecursionError):  # UnicodeDecodeError is a ValueError
        raise RunDirError(f"{copy}: not the sweep file smorphi-rl copied there (unreadable); resume only sweeps "
                          "you ran") from None  # fmt: skip
    if kept != strict_yaml(sweep.path.read_text()):  # comments may differ
        raise RunDirError(f"{sweep.path} has changed since {exp} started: restore it from {copy} to resume, or "
                          "give the changed sweep another `name`")  # fmt: skip
    refuse_links(exp)  # Tune and the trials would write through them
    claim_again(exp)  # refused while the sweep, or another resume of it, still runs: both would move its files
    return exp


def _fewer_runners(sweep: SweepConfig) -> str:
    """How to fit a sweep's trials on the Ray in use: the file's key, not a flag the sweep command has not."""
    return f"set fewer `env_runners` in {sweep.path}"


def run_sweep(
    sweep: SweepConfig,
    log_dir: str | Path = DEFAULT_LOG_DIR,
    address: str | None = None,
    resume: bool = False,
    out: Any = None,
) -> SweepSummary:
    """Run (or resume) the sweep as one Tune experiment under `log_dir/<name>/`; write the table and curves."""
    if sweep.pretrained is not None:  # a bad checkpoint fails here, before Ray starts, naming the file's key
        env = sweep.base_config(sweep.algorithms[0], sweep.map_sets[0], sweep.seeds[0], {}).env.to_dict()
        try:
            fine_tune_from(sweep.pretrained, env)
        except SmorphiError as exc:
            raise SweepConfigError(f"{sweep.path}: key 'pretrained': {exc}") from None
    from smorphi_rl.env import MorphologyEnv

    digests: dict[str, dict[str, str]] = {}  # each map set's digests, by its trials' `maps` label
    for i, maps in enumerate(sweep.map_sets):  # an unreadable map, one with no free cell, a start off its floor or
        base = sweep.base_config(sweep.algorithms[0], maps, 0, {})  # a block under its cell fails here, before Ray
        try:
            MorphologyEnv(base.env.to_dict())
        except SmorphiError as exc:
            key, said = complaint(str(exc), sweep.env, f"maps[{i}]")
            raise SweepConfigError(f"{sweep.path}: key '{key}': {said}") from None
        digests[map_set_label(maps)] = map_digests(base)  # every evaluated map too, before any optimum
    cluster.check_reachable(address, client=False)
    layouts = [sweep.base_config(algo, sweep.map_sets[0], 0, {}) for algo in sweep.algorithms]
    widest = max(layouts, key=lambda cfg: cfg.cpus)  # a trial Ray cannot place would wait forever
    if address is None:
        cluster.check_capacity(widest.cpus, widest.env_runners, address, _fewer_runners(sweep))
    out = out or sys.stderr
    trials = sweep.trials()
    earlier: list[TrialRow] = []
    if resume:  # the folder's checks first: they are instant, the optima are not
        exp = prepare_experiment(sweep, log_dir, resume)
        pending, started, unrecorded = read_resume(exp, trials, out)
        earlier = read_sweep(exp)  # a finished trial's damaged records: named before anything trains, not after
        check_maps_unchanged(exp, digests)
    else:
        _new_experiment(log_dir, sweep.name, check_run_dir)
    optima: dict[str, Optimum] = {}
    for maps in sweep.map_sets:  # every evaluated map's exact optimum (cached after the first), before Ray starts
        optima |= training_optima(sweep.base_config(sweep.algorithms[0], maps, 0, {}), log_dir, out)
    if resume:
        set_aside_unrecorded(unrecorded, out)
        points = set_aside_started(started)
        drop_unstarted(exp, pending)
    else:
        exp, pending, points = prepare_experiment(sweep, log_dir, resume), trials, {}
        write_text_atomic(exp / MAPS_RECORD, jsontext.dumps(digests, indent=2))
    quiet()
    progress = _SweepProgress(sweep, len(trials), out)
    progress.done |= {f"trial {t['index']}" for t in trials if t not in pending}
    progress.found([r.best for r in earlier if r.best is not None])  # a resume's: shown from the first line
    t0 = time.monotonic()
    results, failed = (None, None)
    late, held = threading.Event(), ExitStack()  # a stop once the trials have ended waits for the tables
    if pending:
        try:
            results, failed = _fit(sweep, exp, address, widest, optima, pending, points, progress, held, late)
        except KeyboardInterrupt as exc:
            held.close()
            if resume or progress.reported or isinstance(exc, Interrupted):
                raise
            discard_run_dir(exp)  # stopped before any trial reported: nothing to resume, the name stays free
            raise Interrupted(nothing_kept(exp, "sweep")) from None
        except cluster.ClusterError:  # Ray did not start, or the cluster cannot take the trials: none ran
            held.close()
            if not resume:
                discard_run_dir(exp)  # the name stays free for the same command once Ray can start
            raise
    wall = time.monotonic() - t0
    progress.finish()
    with interrupts.results_held(late, held):
        if failed and (failed.disk_full or results is None):
            raise TrainingError(failed.line)  # no tables either
        rows = read_sweep(exp)
        write_trial_files(exp, rows, optima, digests, sweep.step_budget)
        files = write_sweep_outputs(exp, rows, optima)
    if failed:
        raise TrainingError(f"{failed.line}; tables under {exp} (unfinished trials marked, left out of the groups)")
    finished_count = sum(1 for d in exp.iterdir() if d.is_dir() and trial_spec(d) is not None and finished(d))
    return SweepSummary(exp, rows, len(trials), wall, finished_count < len(trials), files, len(trials) - len(pending),
                        late.is_set())  # fmt: skip


def _fit(
    sweep: SweepConfig, exp: Path, address: str | None, widest: Any, optima: dict[str, Optimum],
    pending: list[dict[str, Any]], points: dict[int, Path], progress: _SweepProgress, held: ExitStack,
    late: threading.Event,
) -> tuple[Any, Any]:  # fmt: skip
    """The Tune experiment of the `pending` trials (Tune's results and how it failed, `failures.fit`); `widest`:
    the trial config asking for the most CPUs. Once Tune returns, stops are held in `late` (`held` keeps them so),
    through Ray's shutdown and the tables."""
    by_index = {t["index"]: t for t in pending}

    def field_of(name: str) -> Any:
        from ray import tune

        return tune.sample_from(lambda config: by_index[config["index"]][name])

    with cluster.ray_session(address):
        if address is not None:
            cluster.check_capacity(widest.cpus, widest.env_runners, address, _fewer_runners(sweep))
            cluster.check_shared_folder(exp, address)
        from ray import tune

        from smorphi_rl.training.tensorboard import TensorBoardLogger

        def trial_resources(config: dict[str, Any]) -> Any:
            return resources(sweep.base_config(config["algo"], tuple(config["maps"]), 0, {}))

        with_data = tune.with_parameters(sweep_trainable, sweep=sweep, optima=optima, resume_points=points, exp=exp)
        trainable = tune.with_resources(with_data, trial_resources)
        run_config = tune.RunConfig(
            name=sweep.name,
            storage_path=str(exp.parent),
            checkpoint_config=tune.CheckpointConfig(num_to_keep=sweep.checkpoint_keep or None),
            callbacks=[_tune_callback(progress), TensorBoardLogger()],
            verbose=0,
        )
        param_space = {"index": tune.grid_search(sorted(by_index)), **{k: field_of(k) for k in _TRIAL_FIELDS}}

        def dirname(trial: Any) -> str:
            return trial_dirname(by_index[trial.config["index"]])

        tuner = tune.Tuner(trainable, param_space=param_space, run_config=run_config,
                           tune_config=tune.TuneConfig(trial_dirname_creator=dirname))  # fmt: skip
        with tune_stop_seen(late):
            outcome = fit(tuner, exp, "the sweep")
        held.enter_context(interrupts.stop_requests(late, again=True))
        return outcome


_TRIAL_FIELDS = ("algo", "maps", "seed", "hp")
"""A trial's fields besides its index (`SweepConfig.trials`), as Tune's params.json records them."""


def write_trial_files(exp: Path, rows: list[TrialRow], optima: dict[str, Optimum],
                      digests: dict[str, dict[str, str]] | None = None, budget: int | None = None) -> None:  # fmt: skip
    """Each trial's summary.json, morphologies.csv and top-k tables in its folder, as `train` writes them for a run
    (`RunSummary`, with its map set's `digests`): `compare` takes a sweep's trial as it takes a run. Written again
    from the results on every call, so a resumed sweep's are those of all its rows."""
    for r in rows:
        trial = exp / r.trial
        files = write_found(r.top, trial, TrainConfig.top_k)
        checkpoints = checkpoints_under(trial)
        files["summary"] = trial / "summary.json"
        summary = RunSummary(run_dir=trial, algorithm=r.algo, env_steps=r.env_steps, iterations=r.iterations,
                             wall_s=r.wall_s, interrupted=not r.finished, best=r.best,
                             optimum={m: o for m, o in optima.items() if m in r.evaluation},
                             checkpoint=checkpoints[-1] if checkpoints else None, files=files,
                             evaluation=r.evaluation, map_digests=(digests or {}).get(r.maps, {}),
                             budget=budget)  # fmt: skip
        write_text_atomic(files["summary"], summary.to_json())


def write_sweep_outputs(exp: Path, rows: list[TrialRow], optima: dict[str, Optimum] | None = None) -> dict[str, Path]:
    """sweep.csv, sweep.md, sweep_groups.md (over seeds, with intervals) and sweep_curves.png (the paper's Figure 5
    per algorithm and map, over each single map's exact optimum in `optima`)."""
    from smorphi_rl.plots import plot_sweep_curves

    if not rows:
        return {}
    files = {"csv": exp / "sweep.csv", "md": exp / "sweep.md", "groups": exp / "sweep_groups.md",
             "png": exp / "sweep_curves.png"}  # fmt: skip
    write_sweep_tables(rows, files["csv"], files["md"])
    write_sweep_groups(rows, files["groups"])
    references = {name: opt.R1 for name, opt in (optima or {}).items() if math.isfinite(opt.R1)}
    plot_sweep_curves(group_curves(rows), files["png"], references)
    return files


def format_sweep_summary(s: SweepSummary, rel: Any = str) -> str:
    """The end-of-sweep text: trials, the best of each, and where the files are."""
    if s.interrupted:  # a trial cut short has rows too: count it apart from those that finished
        done = sum(r.finished for r in s.rows)
        cut = len(s.rows) - done
        head = f"interrupted after {done} of {s.trials_total} trials finished" + (f" ({cut} cut short)" if cut else "")
    else:
        head = f"ran {len(s.rows)} of {s.trials_total} trials"
        if s.read_back:  # a resume: say what this call trained
            head += f" ({s.trials_total - s.read_back} this call, {s.read_back} finished before)"
    lines = [f"sweep {s.experiment_dir.name}: {head} in {fmt_duration(s.wall_s)}"]
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
    lines.append(f"tensorboard --logdir {shell_path(s.experiment_dir)}")
    return "\n".join(lines)

"""`transfer`: fine-tune a pretrained policy and train from scratch on each held-out map (the paper's Table 5).

The fine-tuning itself (restore, verified push to the runners) is `finetune.py`; this module runs the
job and writes its table and curves.
"""

from __future__ import annotations

import csv
import itertools
import math
import sys
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from smorphi_rl import jsontext
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.inputs import first_repeat
from smorphi_rl.rundir import DEFAULT_LOG_DIR, atomic_text, safe_name, write_atomic, write_text_atomic
from smorphi_rl.stats import (
    FEW_SEEDS_NOTE,
    VERDICT_SEEDS,
    Interval,
    cell,
    censored_median_interval,
    censored_ratio_interval,
    median_interval,
)
from smorphi_rl.training.config import MAX_TIMESTEPS, TrainConfig, TrainConfigError
from smorphi_rl.training.convergence import (
    at_steps,
    censored_steps,
    converged_count,
    converged_text,
    first_measured_steps,
    measured,
)
from smorphi_rl.training.presets import TRANSFER_TIMESTEPS

JOB_FILE = "transfer.json"
"""Written when a transfer job starts or resumes (its pretrained policy, maps and seeds): `--resume` knows the
folder by it."""


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
    interrupted: bool = False
    """Stopped (Ctrl-C, SIGTERM) before its budget: the job stopped with it."""
    wall_s: float = math.nan
    """Seconds the run trained."""
    reused: bool = False
    """Finished by an earlier call of the same job (`--resume`), read back rather than trained again."""


class TransferInterrupted(KeyboardInterrupt):
    """A stop request (Ctrl-C, SIGTERM) ended the job as a run started, before that run reported: the job's folder
    and the runs that finished before it, for the table and the `--resume` hint."""

    def __init__(self, job_dir: Path, runs: list[TransferRun]) -> None:
        super().__init__(str(job_dir))
        self.job_dir, self.runs = job_dir, runs


@dataclass(frozen=True)
class TransferJob:
    """What a transfer job runs: fine-tune `pretrained` and train from scratch on each held-out map, per seed.

    Checked when made (the training options as TrainConfig checks them, the seeds), before anything runs."""

    pretrained: str | Path
    """Checkpoint, trial or run directory (its newest checkpoint) or exported policy folder of the pretrained policy."""
    maps: tuple[str, ...]
    """Held-out maps (map_server YAML)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds; each map runs once per seed and mode (three: a speed-up is a ratio of medians with an interval)."""
    timesteps: int = TRANSFER_TIMESTEPS
    """Env-step budget of every run (Table 5's: its 36 runs, 6 maps, take 44 min on 2 cores; 3 maps, 22)."""
    algo: str | None = None
    """Algorithm of every run; None: the pretrained policy's (PPO for one that does not say)."""
    preset: str = TrainConfig.preset
    """Hyperparameters of every run: fast (2 cores) or paper (Table 1)."""
    record_every: int = TrainConfig.record_every
    """Record every Nth episode of each env to MCAP; 0: no recording."""
    envs_per_runner: int = TrainConfig.envs_per_runner
    """Envs each env runner steps as one vector env."""
    num_env_runners: int | None = TrainConfig.num_env_runners
    """Remote env runners of every run (0: sample in the trial process); None: the preset's (2)."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise TrainConfigError("give at least one seed (--seeds)")
        from smorphi_rl.map_sources import is_generator, name_clash

        for m in map(str, self.maps):
            if is_generator(m):
                raise TrainConfigError(f"--maps {m}: transfer is measured on map files (against each map's exact "
                                       "optimum), not generated floors; write some with `maps generate`")  # fmt: skip
        for name, items in (("seeds", self.seeds), ("maps", tuple(str(Path(m).resolve()) for m in self.maps))):
            twice = first_repeat(items)
            if twice is not None:
                raise TrainConfigError(f"--{name} names {items[twice]} twice: each run would be trained twice")
        clash = name_clash(tuple(map(str, self.maps)), lambda m: safe_name(Path(m).stem))  # runs, folders, rows
        if clash is not None:
            raise TrainConfigError(f"--maps {clash[0]} and {clash[1]} share the name {safe_name(Path(clash[1]).stem)!r}"
                                   ", which names the runs and the table's rows: rename one")  # fmt: skip
        for seed in self.seeds:
            if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
                raise TrainConfigError(f"seeds must be non-negative integers, got {seed!r}")
        self.train_config()

    def train_config(self, env: EnvConfig | None = None) -> TrainConfig:
        """The training run of one map (its env given; else the default env) before seed and mode are set."""
        return TrainConfig(algo=self.algo or TrainConfig.algo, env=env or EnvConfig(), timesteps=self.timesteps,
                           preset=self.preset, record_every=self.record_every, envs_per_runner=self.envs_per_runner,
                           num_env_runners=self.num_env_runners)  # fmt: skip


def run_transfer(
    job: TransferJob,
    name: str = "transfer",
    log_dir: str | Path = DEFAULT_LOG_DIR,
    address: str | None = None,
    out: Any = None,
    resume: bool = False,
    optima_log_dir: str | Path | None = None,
    stamped: bool = False,
) -> tuple[Path, list[TransferRun]]:
    """For every held-out map and seed: fine-tune from the pretrained policy and train from scratch, same budget.
    `resume`: continue the job of that name: its finished runs of exactly these settings are read back, a run cut
    short continues from its last checkpoint (`train --resume`), or, with none to continue from, is set aside
    (renamed, never deleted) and trained again. A stop request before a run's first report
    raises `TransferInterrupted` with the runs that finished; one after it ends the job with that run marked. The
    exact optima are cached under `optima_log_dir` (default `log_dir`, the folder the user named). `stamped`: `name`
    is one the command made from the time, so a job started in the same second takes `<name>-2`."""
    from smorphi_rl import cluster
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.rundir import (
        RunDirError,
        claim_again,
        discard_run_dir,
        in_use_by,
        prepare_run_dir,
        prepare_stamped_run_dir,
        rename_cut_run,
    )
    from smorphi_rl.training.checkpoints import find_checkpoint, load_module
    from smorphi_rl.training.finetune import check_pretrained, model_setup
    from smorphi_rl.training.resume import can_continue
    from smorphi_rl.training.run import TrainingError, train

    checkpoint = find_checkpoint(job.pretrained)
    model = load_module(checkpoint).model_config
    algo, trained_with = model_setup(model)
    env = EnvConfig.from_dict(trained_with)
    job = replace(job, algo=job.algo or algo or TrainConfig.algo)  # the pretrained policy's
    configs = []
    its_maps = dict(model.get("env_config") or {}).get("maps")  # its own floors, whatever `trained_with` keeps
    trained_on = {Path(m).resolve() for m in EnvConfig.recorded({"maps": its_maps} if its_maps else {}).map_files}
    for path in job.maps:  # every map and the checkpoint are checked before the first run starts
        if Path(path).resolve() in trained_on:
            raise TrainConfigError(f"--maps {path} is one the pretrained policy was trained on: transfer measures "
                                   "maps it has not seen")  # fmt: skip
        cfg = job.train_config(replace(env, maps=EnvConfig.from_dict({"maps": [path]}).maps))
        check_pretrained(checkpoint, cfg.env.to_dict())
        configs.append(cfg)
    planned = []
    for cfg, seed, mode in itertools.product(configs, job.seeds, ("fine-tune", "scratch")):
        map_name = Path(cfg.env.maps[0]).stem
        run_cfg = replace(cfg, seed=seed, pretrained=str(checkpoint) if mode == "fine-tune" else None)
        planned.append((map_name, seed, mode, run_cfg, safe_name(f"{map_name}-{mode}-seed{seed}")))
    finished: dict[str, TransferRun] = {}
    job_dir = resumed_job_dir(log_dir, name) if resume else None
    if job_dir is not None:  # every earlier run is read and checked against this job before anything trains
        check_nothing_left_out(job_dir, job)
        for map_name, seed, mode, run_cfg, run_name in planned:
            earlier = finished_run(job_dir / run_name, run_cfg)
            if earlier is not None:
                finished[run_name] = transfer_run(map_name, seed, mode, job_dir / run_name, earlier, reused=True)
    cluster.check_reachable(address, client=False)  # no cluster there: one line, no folder
    if address is None:  # a layout this machine cannot place: one line, no folder (a cluster's is checked attached)
        cluster.check_capacity(configs[0].cpus, configs[0].env_runners, None)
    if job_dir is None:
        try:
            job_dir = (prepare_stamped_run_dir if stamped else prepare_run_dir)(log_dir, name)
        except RunDirError as exc:
            if stamped:  # a name the command made: no job of the user's to continue or wait for
                raise
            running = in_use_by(Path(log_dir) / name)
            if running is not None:  # a job writing there now: no resume either
                raise RunDirError(f"{Path(log_dir) / name} is in use by process {running}, a transfer job running now: "
                                  "wait for it to finish, or choose another --name") from None  # fmt: skip
            if is_transfer_job(Path(log_dir) / name):  # an earlier job of that name: it may be one to continue
                raise RunDirError(f"{exc}, or add --resume to continue that job") from None
            raise
    else:
        claim_again(job_dir)  # refused while the process that ran it still runs
    before = (job_dir / JOB_FILE).read_bytes() if resume and (job_dir / JOB_FILE).is_file() else None
    there = {n for *_, n in planned if (job_dir / n).exists()}  # the runs earlier calls left, finished or cut
    write_text_atomic(job_dir / JOB_FILE, jsontext.dumps({"pretrained": str(checkpoint), "maps": list(job.maps),
                                                          "seeds": list(job.seeds)}, indent=2))  # fmt: skip
    done: dict[str, TransferRun] = {}

    def reported() -> list[TransferRun]:  # in the job's order: the runs so far and those of earlier calls
        return [done.get(n) or finished[n] for *_, n in planned if n in done or n in finished]

    try:
        with cluster.ray_session(address):  # the job's runs share one Ray: it starts (or attaches) once
            for number, (map_name, seed, mode, run_cfg, run_name) in enumerate(planned, start=1):
                if run_name in finished:
                    continue
                cut = job_dir / run_name  # a run cut short continues from its checkpoint, else is set aside
                go_on = cut.exists() and can_continue(cut, run_cfg.algo)
                if cut.exists() and not go_on:
                    rename_cut_run(cut)
                trained = train(run_cfg, name=run_name, log_dir=job_dir, address=address, out=out or sys.stderr,
                                label=f"{run_cfg.algo.upper()} {run_name} (run {number} of {len(planned)})",
                                optima_log_dir=log_dir if optima_log_dir is None else optima_log_dir,
                                resume=go_on)  # fmt: skip
                done[run_name] = transfer_run(map_name, seed, mode, trained.run_dir, trained.to_dict())
                if trained.stop_held:  # a stop as the run ended, held until it was written: the job ends here
                    raise KeyboardInterrupt
                if trained.interrupted:
                    break  # a stop request ends the job: what finished is reported, marked as such
    except BaseException as exc:
        if before is not None and not any((job_dir / n).exists() for *_, n in planned if n not in there):
            write_atomic(job_dir / JOB_FILE, before)  # no run of the maps or seeds it added is left: it added none
        if not (resume or any((job_dir / n).exists() for *_, n in planned)):
            discard_run_dir(job_dir)  # nothing trained: the name stays free
        elif isinstance(exc, KeyboardInterrupt):  # what finished is kept, to report and to resume
            raise TransferInterrupted(job_dir, reported()) from None
        elif isinstance(exc, SmorphiError) and reported():  # a run failed: the others are kept, and resumable
            raise TrainingError(f"{exc}; the runs that finished ({len(reported())}) are kept under {job_dir}: "
                                f"continue with --name {job_dir.name} --resume") from None  # fmt: skip
        raise
    return job_dir, reported()


def is_transfer_job(folder: Path) -> bool:
    """Whether `folder` holds a transfer job (its record; a job from before the record was kept, its table)."""
    return (folder / JOB_FILE).is_file() or (folder / "transfer.csv").is_file()


def resumed_job_dir(log_dir: str | Path, name: str) -> Path:
    """The folder of the transfer job `name` under `log_dir`, which `--resume` continues; one line if there is
    none (a job from before `transfer.json` was written is known by its table)."""
    from smorphi_rl.rundir import check_run_name, refuse_links

    job_dir = Path(log_dir).resolve() / check_run_name(name)
    if not is_transfer_job(job_dir):
        raise TrainConfigError(f"--resume: {job_dir} is not a transfer job (no {JOB_FILE}; give the --name and "
                               "--log-dir of the job to continue)")  # fmt: skip
    refuse_links(job_dir)  # its runs would be written through them
    return job_dir


def check_nothing_left_out(job_dir: Path, job: TransferJob) -> None:
    """One line when a resume leaves out maps or seeds the job ran before: its table covers every run of the job,
    so a call with fewer would drop finished runs from it."""
    from smorphi_rl.inputs import read_json_object

    if not (job_dir / JOB_FILE).is_file():
        return
    earlier = read_json_object(job_dir / JOB_FILE, "transfer job")
    maps, seeds = earlier.get("maps"), earlier.get("seeds")
    names = {Path(m).stem for m in job.maps}
    gone = [str(m) for m in maps if Path(str(m)).stem not in names] if isinstance(maps, list) else []
    gone += [f"seed {s}" for s in seeds if s not in job.seeds] if isinstance(seeds, list) else []
    if gone:
        raise TrainConfigError(f"--resume: the job also ran {', '.join(gone)}: give every map and seed it ran "
                               "(its table covers them all), and any new ones")  # fmt: skip


def finished_run(run_dir: Path, cfg: TrainConfig) -> dict[str, Any] | None:
    """The summary of the run in `run_dir` when it finished its budget with exactly `cfg`'s settings; None when
    there is none to reuse (never started, or cut short). A run trained with other settings stops the resume:
    its figures would measure another job."""
    from smorphi_rl.inputs import read_json_object
    from smorphi_rl.training.run import map_digests
    from smorphi_rl.training.settings_diff import setting_differs

    if not (run_dir / "config.json").is_file():
        return None
    stored = read_json_object(run_dir / "config.json", "run configuration")
    differ = setting_differs(stored, cfg.to_dict())
    if differ is not None:
        raise TrainConfigError(f"--resume: {run_dir} was trained with other settings ({differ}); start a new job "
                               "with another --name")  # fmt: skip
    summary = read_json_object(run_dir / "summary.json", "run summary") if (run_dir / "summary.json").is_file() else {}
    # the maps' digests a run's config.json (a cut run's too) and summary record; a run from before they were kept:
    # its settings alone
    records = [r for r in (stored.get("map_digests"), summary.get("map_digests")) if isinstance(r, dict)]
    now = map_digests(cfg) if records else {}
    changed = sorted({m for r in records for m, d in now.items() if r.get(m, d) != d})
    if changed:
        raise TrainConfigError(f"--resume: {run_dir} was trained on another floor named {changed[0]!r} (the map file "
                               "changed since); restore it, or start a job with another --name")  # fmt: skip
    return None if not summary or summary.get("interrupted", True) is not False else summary


def transfer_run(map_name: str, seed: int, mode: str, run_dir: Path, summary: dict[str, Any],
                 reused: bool = False) -> TransferRun:  # fmt: skip
    """One run's Table 5 figures from its summary (`RunSummary.to_dict`) and its curves; one line naming the run
    when they are not what smorphi-rl writes (a damaged folder read back by `--resume`)."""
    from smorphi_rl.inputs import InputError
    from smorphi_rl.training.convergence import convergence

    try:
        curve = summary_curve(run_dir)
        at, plateau = convergence(curve)
        best = summary.get("best") or {}
        steps, wall = summary["env_steps"], summary.get("wall_s", math.nan)
        held = summary.get("pretrained_in_runners")
        if not (isinstance(steps, int) and 0 <= steps <= 2 * MAX_TIMESTEPS and isinstance(wall, int | float)
                and held in (True, False, None)):  # fmt: skip
            raise TypeError("env_steps, wall_s or pretrained_in_runners")
        return TransferRun(map_name, seed, mode, steps, at, plateau, float(best.get("R1", math.nan)), held, run_dir,
                           curve, bool(summary.get("interrupted")), float(wall), reused)  # fmt: skip
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError, RecursionError) as exc:  # 10^400: Overflow
        raise InputError(f"{run_dir}: not a training run smorphi-rl wrote ({type(exc).__name__}: "
                         f"{str(exc)[:80]})") from None  # fmt: skip


def summary_curve(run_dir: Path) -> dict[str, list[float]]:
    """The curves (env steps, episode return, best R1, final-shape R1) of a training run, from its result.json."""
    from smorphi_rl.training.sweep_report import result_curve, result_files, result_rows

    (trial,) = [p for p in run_dir.iterdir() if result_files(p)]  # a continued run's rows: those set aside too
    return result_curve(result_rows(*result_files(trial)))


def write_transfer_report(job_dir: Path, runs: list[TransferRun]) -> dict[str, Path]:
    """transfer.csv, transfer.md (the paper's Table 5) and transfer_curves.png."""
    from smorphi_rl.plots import plot_transfer_curves

    files = {"csv": job_dir / "transfer.csv", "md": job_dir / "transfer.md", "png": job_dir / "transfer_curves.png"}
    cut = sum(r.interrupted for r in runs)
    equal = equal_steps(runs)
    with atomic_text(files["csv"]) as fh:
        writer = csv.writer(fh)
        writer.writerow(["map", "seed", "mode", "env_steps", "converged_at_env_steps", "plateau_settled_R1", "best_R1",
                         "equal_env_steps", "median_gap_at_equal_env_steps", "pretrained_in_runners",
                         "interrupted"])  # fmt: skip
        for r in runs:
            at = converged_text(r.converged_at, r.curve)
            gap = at_steps(r.curve, GAP_KEY, equal)
            writer.writerow([r.map_name, r.seed, r.mode, r.env_steps, at, cell(r.plateau, ".3f"),
                             cell(r.best_R1, ".4f"), equal, cell(gap, ".3f"), r.pretrained_in_runners,
                             r.interrupted])  # fmt: skip
    lines = [
        "Over seeds: median [95 % bootstrap interval]. Converged: from some evaluation on, at least 90 % of the "
        "protocol's starts settle within 1 % of the optimum. A run that never converged is counted as not converged, "
        "not as a number: its env steps to converge lie past its budget, so a median that depends on it reads "
        '"> x" (at least x), a ratio of the medians bounded by it "> x" (at least) or "< x" (at most), and an '
        'interval\'s end past the budget "inf". At equal env steps (a tenth of the budget, or the first evaluation '
        "if later): each run's greedy median gap to the optimum's R1 at its last evaluation by then. Every seed "
        "fine-tunes from the one pretrained checkpoint: the intervals are over the seeds of fine-tuning and of "
        "scratch, not over pretrainings; the ratio's resamples each mode's seeds on its own (unpaired). "
        + FEW_SEEDS_NOTE
        + (f" Runs cut short ({cut}; transfer.csv) are left out." if cut else ""),
        "",
        "| Map | Fine-tuned: env steps to converge | converged | From scratch | converged "
        f"| Ratio scratch / fine-tuned | Gap at {f'{equal:,} env steps' if equal else 'equal env steps'} fine-tuned "
        "| scratch "
        "| Plateau greedy settled R1 fine-tuned | scratch | Best R1 of any seed fine-tuned / scratch |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for m in by_map(runs):
        best = " / ".join(_best_text(rs) for rs in (m.tuned, m.scratch))
        gaps = " | ".join(gap.text() for gap in m.gaps_at(equal))
        lines.append(
            f"| {m.map_name} | {m.tuned_steps.text(',.0f')} | {m.counts[0]} | {m.scratch_steps.text(',.0f')} "
            f"| {m.counts[1]} | {m.ratio.text()} | {gaps} | {median_interval([r.plateau for r in m.tuned]).text()} "
            f"| {median_interval([r.plateau for r in m.scratch]).text()} | {best} |"
        )
    write_text_atomic(files["md"], "\n".join(lines) + "\n")
    curves: dict[str, dict[str, list[tuple[list[float], list[float]]]]] = {}
    for r in runs:
        if GAP_KEY in r.curve:
            curves.setdefault(r.map_name, {}).setdefault(r.mode, []).append((r.curve["env_steps"], r.curve[GAP_KEY]))
    plot_transfer_curves(curves, files["png"], equal)
    return files


GAP_KEY = "eval_gap"
"""The curve of a run's greedy median gap to the optimum's R1 (`sweep_report.curve_point`)."""
EQUAL_SHARE = 0.1
"""The runs of a job are compared at this share of the budget, where a head start shows before either converges."""


def equal_steps(runs: list[TransferRun]) -> int:
    """The env steps at which fine-tuned and scratch runs are compared: a tenth of the fewest any whole run trained,
    or later, where a run's first evaluation came later (a short budget)."""
    whole = [r for r in runs if not r.interrupted]
    first = [first_measured_steps(r.curve, GAP_KEY) for r in whole]
    return int(max([EQUAL_SHARE * min((r.env_steps for r in whole), default=0)] + [f for f in first if f < math.inf]))


def converged_steps(runs: list[TransferRun]) -> tuple[list[float], list[float]]:
    """Env steps to convergence of each measured run as (least, most): its time where it converged, its env steps
    and inf where it did not (it would converge later, if ever: right-censored, never left out)."""
    return censored_steps([(r.converged_at, r.env_steps) for r in runs if measured(r.curve)])


@dataclass(frozen=True)
class MapTransfer:
    """One held-out map's runs over seeds and Table 5's figures: env steps to converge fine-tuned and from scratch
    (median [95 %] over every run, beside how many converged) and the ratio of the medians, scratch / fine-tuned.
    A run that did not converge counts as past its budget (`stats.censored_median_interval`): leaving it out
    would flatter its mode. Each figure is a bootstrap, computed once however often the reports read it."""

    map_name: str
    tuned: list[TransferRun]
    scratch: list[TransferRun]

    @cached_property
    def tuned_steps(self) -> Interval:
        return censored_median_interval(*converged_steps(self.tuned))

    @cached_property
    def scratch_steps(self) -> Interval:
        return censored_median_interval(*converged_steps(self.scratch))

    @cached_property
    def ratio(self) -> Interval:
        """The ratio of the medians, scratch / fine-tuned, with its interval: a lower bound (`bound` ">") where the
        scratch median depends on runs that did not converge, an upper bound ("<") where the fine-tuned one does,
        NaN (no ratio) where both do or a mode has no measured run."""
        return censored_ratio_interval(converged_steps(self.scratch), converged_steps(self.tuned))

    def gaps_at(self, env_steps: float) -> tuple[Interval, Interval]:
        """The greedy median gap of the fine-tuned and of the scratch runs at equal env steps, over seeds."""
        tuned, scratch = (median_interval([at_steps(r.curve, GAP_KEY, env_steps) for r in runs])
                          for runs in (self.tuned, self.scratch))  # fmt: skip
        return tuned, scratch

    @property
    def counts(self) -> tuple[str, str]:
        """ "k of n" converged, fine-tuned and from scratch ("not measured" on a map without an exact optimum)."""
        tuned, scratch = (converged_count(sum(r.converged_at is not None for r in runs), [r.curve for r in runs])
                          for runs in (self.tuned, self.scratch))  # fmt: skip
        return tuned, scratch


SPEEDUP_TARGET = 5.0
"""Table 5's claim: fine-tuning converges in at most a fifth of the scratch run's env steps (the paper: 5 x 10^4
against 2.7 x 10^5)."""


@dataclass(frozen=True)
class Speedup:
    """What a map's ratio of medians says of the five-fold claim, read two ways: by the medians, and by the whole
    95 % interval over seeds (one seed has none). `reproduce` and `bench_transfer.py` both say it this way."""

    text: str
    met: bool
    """The ratio of the medians (or the bound on it) reaches the target."""
    whole: bool
    """So does the whole interval, over at least `VERDICT_SEEDS` seeds."""
    below: bool
    """The whole interval lies under the target, over at least `VERDICT_SEEDS` seeds."""

    @property
    def word(self) -> str:
        """The claim's verdict over seeds: agrees only when the whole interval does."""
        return "**agrees**" if self.whole else "**does not agree**" if self.below else "**undecided**"


def speedup(ratio: Interval, unmeasured: bool = False) -> Speedup:
    """The five-fold verdict on a map's ratio of medians, scratch / fine-tuned (`MapTransfer.ratio`)."""
    if unmeasured:
        return Speedup("no ratio: the map has no exact optimum (not measured)", False, False, False)
    if not ratio.n:
        return Speedup("no ratio: both medians lie past the budget, or the fine-tuned one is 0", False, False, False)
    met = ratio.bound != "<" and ratio.point >= SPEEDUP_TARGET  # "> x": at least x, a measured bound
    missed = ratio.bound != ">" and ratio.point < SPEEDUP_TARGET
    decides = ratio.n >= VERDICT_SEEDS  # one seed has no interval to agree; two, one that holds half the time
    whole = met and decides and ratio.lo >= SPEEDUP_TARGET
    below = missed and decides and ratio.hi < SPEEDUP_TARGET
    kind = {">": " (at least: the scratch median lies past the budget)",
            "<": " (at most: the fine-tuned median lies past the budget)"}.get(ratio.bound, "")  # fmt: skip
    outcome = ("meets target" + ("" if whole or not decides else ", its interval reaching below") if met
               else "misses target" + ("" if below or not decides else ", its interval reaching above") if missed
               else "the budget cannot tell")  # fmt: skip
    return Speedup(f"ratio of medians {ratio.text()}{kind} ({outcome})", met, whole, below)


def _best_text(runs: list[Any]) -> str:
    """The best R1 any of `runs` visited; "-" when none finished an episode."""
    found = [r.best_R1 for r in runs if math.isfinite(r.best_R1)]
    return f"{max(found):.2f}" if found else "-"


def by_map(runs: list[TransferRun]) -> list[MapTransfer]:
    """The runs that finished their budget grouped by held-out map, in the order the job ran them (a run cut short
    would count a shorter budget as its mode's)."""
    whole = [r for r in runs if not r.interrupted]
    names = dict.fromkeys(r.map_name for r in whole)
    return [MapTransfer(n, *([r for r in whole if r.map_name == n and r.mode == m] for m in ("fine-tune", "scratch")))
            for n in names]  # fmt: skip

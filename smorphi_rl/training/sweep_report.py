"""A sweep's per-trial table and learning curves, read back from the trial folders. No Ray here.

Built from each trial's `result.json` and `params.json` only, so it is the same after `--resume`
(rows of iterations re-run after a restore are counted once).
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.map_sources import map_set_label
from smorphi_rl.protocol import EVAL_KEY, TRAINED_KEY
from smorphi_rl.rundir import atomic_text, write_text_atomic
from smorphi_rl.stats import FEW_SEEDS_NOTE, band, cell, censored_median_interval, median_interval
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.convergence import (
    PLATEAU_KEY,
    censored_steps,
    converged_count,
    converged_text,
    convergence,
    measured,
)
from smorphi_rl.training.topk import Found, TopMorphologies, episode_bests
from smorphi_rl.words import counted, verb

CURVE_POINTS = 100


@dataclass
class TrialRow:
    """One trial of a sweep, as the summary table shows it."""

    trial: str
    algo: str
    maps: str
    seed: int
    hyperparameters: dict[str, Any]
    env_steps: int
    iterations: int
    wall_s: float
    best: Found | None
    converged_at: float | None
    settled_R1_plateau: float
    curve: dict[str, list[float]]
    median_gap: float = math.nan
    """The last evaluation's median gap of the greedy settled R1 to the exact optimum (NaN: never evaluated), of
    the policy the trial ends on (kept: its best evaluated one, perhaps earlier than the last trained)."""
    share_within_1pct: float = math.nan
    """The last evaluation's share of starts settled within 1 % of the optimum, of the kept policy."""
    trained_share_within_1pct: float = math.nan
    """The same share of the policy last trained, the one `converged_at` reads (equal where it is the kept one)."""
    design_gap_pct: float = math.nan
    """The last evaluation's designer median gap in per cent of the optimum (NaN: the sweep measured none)."""
    finished: bool = True
    """Whether the trial reached its budget or stop criteria (False: cut short, or failed; left out of the groups)."""
    evaluation: dict[str, Any] = field(default_factory=dict)
    """The last evaluation's eval/... figures (empty: never evaluated)."""
    top: TopMorphologies = field(default_factory=TopMorphologies)
    """Every distinct shape its episodes found, best first."""


RESULTS = "result.json"
SET_ASIDE = "before-resume"
"""A resumed trial's earlier results and checkpoints are in `<trial>/before-resume-N/` (`resume.py`)."""


def aside_number(folder: Path) -> int | None:
    """N of a `before-resume-N` folder (None for any other name)."""
    head, _, n = folder.name.rpartition("-")
    return int(n) if head == SET_ASIDE and n.isdigit() and n.isascii() else None


def result_files(trial_dir: Path) -> list[Path]:
    """A trial's result.json files, oldest first: those set aside by each resume, then its own."""
    found = trial_dir.glob(f"{SET_ASIDE}-*/{RESULTS}")
    numbered = sorted((n, p) for p in found if p.is_file() and (n := aside_number(p.parent)) is not None)
    own = trial_dir / RESULTS
    older = [p for _, p in numbered]
    return [*older, own] if own.is_file() else older


MAX_RESULT_LINE = 1 << 24
"""The longest line of a result.json read (16 MiB; a row of ours is some 7 KB): a longer one is no row of ours."""
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
"""A JSON string, escapes and all."""
MIN_BYTES_PER_CONTAINER = 16
"""A row of ours opens a list or an object every 140-160 bytes; a line denser in them is no row of ours (a 67 MB
result.json of empty lists, `[[],[],...]`, took a resume to 2.1 GB: each list 3 bytes of text, some 60 in memory)."""


def _result_lines(path: Path) -> Iterator[str]:
    """The lines of a result.json one at a time, each at most MAX_RESULT_LINE long (a longer one is skipped whole): a
    crafted file of gigabytes, or a line without end, takes no more memory than one line."""
    with path.open(errors="replace") as fh:
        while line := fh.readline(MAX_RESULT_LINE + 1):
            if len(line) <= MAX_RESULT_LINE:
                yield line
                continue
            while line and not line.endswith("\n"):  # the rest of the long line
                line = fh.readline(MAX_RESULT_LINE + 1)


def result_rows(*result_json: Path) -> list[dict[str, Any]]:
    """The rows of a trial's result.json files (oldest first), one per iteration in order; a line cut short by a
    kill, or that is no result row, is skipped. A later file (a resume's) starts after the checkpoint it continued
    from: the earlier files' rows from its first iteration on belong to the training it discarded, and are dropped
    even where the resumed run stopped before it reached them again."""
    by_iter: dict[int, dict[str, Any]] = {}
    for path in result_json:
        rows = list(_rows_of(path))
        if rows:
            first = min(i for i, _ in rows)
            by_iter = {i: row for i, row in by_iter.items() if i < first}
        by_iter.update(rows)
    return [by_iter[i] for i in sorted(by_iter)]


def _rows_of(path: Path) -> Iterator[tuple[int, dict[str, Any]]]:
    """(iteration, row) of each result row in one result.json (any other line is not a result row of ours)."""
    for line in _result_lines(path):
        structure = _JSON_STRING.sub("", line)  # brackets inside strings open nothing
        if (structure.count("[") + structure.count("{")) * MIN_BYTES_PER_CONTAINER > len(line) + 64:
            continue
        try:
            row = json.loads(line)
        except (json.JSONDecodeError, RecursionError):
            continue
        iteration = row.get(keys.ALGO_ITERATION, row.get(keys.ITERATION, 0)) if isinstance(row, dict) else None
        if isinstance(iteration, int) and not isinstance(iteration, bool) and 0 <= iteration <= 10**9:
            yield iteration, row


CURVE_NAMES = ("env_steps", "episode_return_mean", "best_R1", "final_R1", "eval_R1", "eval_gap", "eval_within",
               "design_gap")  # fmt: skip
"""The learning curves every report draws (`train`, `transfer`, `sweep`), one point per result row."""


def curve_point(row: dict[str, Any]) -> dict[str, float]:
    """One result row's point of each curve: env steps, mean episode return, the iteration's best R1, the
    final-shape R1 and the greedy evaluation of the policy being trained (settled R1, median gap, share within 1 %;
    NaN where the iteration was not evaluated), never that of an earlier policy a run ends on."""
    runners = row.get(keys.ENV_RUNNERS, {})
    ev = row.get(EVAL_KEY) or {}
    learned = ev.get(TRAINED_KEY) or ev
    return {
        "env_steps": float(row.get(keys.STEPS) or 0),
        "episode_return_mean": _num(runners.get(keys.EPISODE_RETURN_MEAN)),
        "best_R1": max((b.R1 for b in episode_bests(row)), default=math.nan),
        "final_R1": _num(runners.get(keys.METRIC_PREFIX, {}).get("R1_final")),
        "eval_R1": _num(learned.get("settled_R1_mean")),
        "eval_gap": _num(learned.get("median_gap")),
        "eval_within": _num(learned.get("share_within_1pct")),
        # rows written before 2026-12-06 held the trained policy's design figures beside the kept one's protocol's
        "design_gap": _num(learned.get("design_median_gap_pct", ev.get("design_median_gap_pct"))),
    }


def result_curve(rows: list[dict[str, Any]]) -> dict[str, list[float]]:
    """The curves (CURVE_NAMES) of a trial's result rows."""
    curve: dict[str, list[float]] = {k: [] for k in CURVE_NAMES}
    for r in rows:
        for k, v in curve_point(r).items():
            curve[k].append(v)
    return curve


MAX_PARAMS_BYTES = 1 << 20
"""The largest params.json read (a trial's fields: a few hundred bytes)."""


def read_trial(trial_dir: Path) -> TrialRow | None:
    """The row of one trial folder; None before its first result."""
    params, results = trial_dir / "params.json", result_files(trial_dir)
    if not params.is_file() or not results:
        return None
    if params.stat().st_size > MAX_PARAMS_BYTES:
        raise ValueError(f"params.json of {params.stat().st_size:,} bytes")  # named by the caller, as a damaged record
    spec = json.loads(params.read_text())
    rows = result_rows(*results)
    if not rows:
        return None
    top = TopMorphologies()
    for r in rows:
        top.add_episode_bests(spec["algo"], episode_bests(r), int(r.get(keys.STEPS) or 0))
    curve = result_curve(rows)
    at, plateau = convergence(curve)
    last = next((r.get(EVAL_KEY) for r in reversed(rows) if r.get(EVAL_KEY)), None) or {}
    trained = last.get(TRAINED_KEY) or last  # where the kept policy is the last trained, no second record
    best = top.top(1)
    return TrialRow(
        trial=trial_dir.name,
        algo=spec["algo"],
        maps=map_set_label(spec["maps"]),
        seed=int(spec["seed"]),
        hyperparameters=dict(spec.get("hp") or {}),
        env_steps=int(curve["env_steps"][-1]),
        iterations=len(rows),
        wall_s=float(sum(_num(r.get("time_this_iter_s")) for r in rows)),
        best=best[0] if best else None,
        converged_at=at,
        settled_R1_plateau=plateau,
        curve=curve,
        median_gap=_num(last.get("median_gap")),
        share_within_1pct=_num(last.get("share_within_1pct")),
        trained_share_within_1pct=_num(trained.get("share_within_1pct")),
        design_gap_pct=_num(last.get("design_median_gap_pct")),
        finished=trial_done(rows),
        evaluation=last,
        top=top,
    )


def trial_done(rows: list[dict[str, Any]]) -> bool:
    """Whether a trial's last recorded result says it reached its budget or its stop criteria."""
    return bool(rows and rows[-1].get(keys.TRIAL_DONE))


class SweepReadError(SmorphiError):
    """A trial's records could not be read back."""


def read_sweep(experiment_dir: Path) -> list[TrialRow]:
    """Every trial with at least one result, in folder order; a trial whose records hold values of other types than
    ours (a damaged or hand-edited result.json) is named in one line (SweepReadError)."""
    rows = []
    for d in sorted(experiment_dir.iterdir()):
        if d.is_dir():
            try:
                rows.append(read_trial(d))
            except (ValueError, TypeError, AttributeError, KeyError, OverflowError, RecursionError) as exc:
                raise SweepReadError(
                    f"{d}: its records are not what smorphi-rl writes ({type(exc).__name__}: "
                    f"{str(exc)[:80]}); move the trial out of the sweep to train it again"
                ) from None
    return [r for r in rows if r is not None]


def write_sweep_tables(rows: list[TrialRow], csv_path: Path, md_path: Path) -> None:
    """sweep.csv (every column) and sweep.md (the same), a row per trial, best R1 first; a figure in R1 or a share
    to 2 decimals (4.00, not 4 beside 3.15)."""
    hp_keys = sorted({k for r in rows for k in r.hyperparameters})
    design = _designed(rows)
    header = ["trial", "algo", "maps", "seed", *hp_keys, "env_steps", "iterations", "wall_s", "best_R1", "best_theta",
              "best_map", "best_P_c", "best_P_len", "kept_median_gap", "kept_share_within_1pct",
              "trained_share_within_1pct",
              *(["design_median_gap_pct"] if design else []), "converged_at_env_steps", "settled_R1_plateau",
              "finished"]  # fmt: skip
    table = []
    for r in sorted(rows, key=lambda r: -(r.best.R1 if r.best else -math.inf)):
        b = r.best
        table.append([r.trial, r.algo, r.maps, r.seed, *[_exact(r.hyperparameters.get(k)) for k in hp_keys],
                      r.env_steps, r.iterations, cell(r.wall_s, ".0f"), f"{b.R1:.2f}" if b else "",
                      b.angles if b else "", b.map if b else "", f"{b.P_c:.2f}" if b else "", b.P_len if b else "",
                      cell(r.median_gap, ".2f"), cell(r.share_within_1pct, ".2f"),
                      cell(r.trained_share_within_1pct, ".2f"), *([cell(r.design_gap_pct, ".3f")] if design else []),
                      converged_text(r.converged_at, r.curve), cell(r.settled_R1_plateau, ".2f"),
                      "yes" if r.finished else "no"])  # fmt: skip
    with atomic_text(csv_path) as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(table)
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(str(c) for c in row) + " |" for row in table]
    write_text_atomic(md_path, "\n".join(md) + "\n")


def _designed(rows: list[TrialRow]) -> bool:
    """Whether the sweep measured the designer's gap (its `evaluation.design_budget`): its tables then show it."""
    return any(math.isfinite(r.design_gap_pct) for r in rows)


def _groups(rows: list[TrialRow]) -> dict[tuple[str, str], list[TrialRow]]:
    """Finished trials that differ only by seed, keyed by (map set, algorithm and hyperparameters): a trial cut
    short would count a shorter budget's figures as its group's. Trials group by their exact values (two draws of a
    random search that round alike are two groups), labelled by the values rounded to 4 digits, or exactly where
    rounding would give two groups one label."""
    exact: dict[tuple[str, str], list[TrialRow]] = {}
    for r in (r for r in rows if r.finished):
        exact.setdefault((r.maps, _label(r.algo, r.hyperparameters, _exact)), []).append(r)
    rounded = {key: _label(trials[0].algo, trials[0].hyperparameters, _fmt) for key, trials in exact.items()}
    named = Counter((maps, rounded[maps, label]) for maps, label in exact)
    groups: dict[tuple[str, str], list[TrialRow]] = {}
    for (maps, label), trials in exact.items():
        groups[maps, rounded[maps, label] if named[maps, rounded[maps, label]] == 1 else label] = trials
    return groups


def _label(algo: str, hyperparameters: dict[str, Any], fmt: Any) -> str:
    """A group's name: the algorithm and its hyperparameters as `fmt` writes them."""
    hp = " ".join(f"{k}={fmt(v)}" for k, v in sorted(hyperparameters.items()))
    return f"{algo.upper()} {hp}".strip()


def write_sweep_groups(rows: list[TrialRow], md_path: Path) -> None:
    """sweep_groups.md: the table of `sweep_group_lines`."""
    write_text_atomic(md_path, "\n".join(sweep_group_lines(rows)) + "\n")


def sweep_group_lines(rows: list[TrialRow]) -> list[str]:
    """Each algorithm and hyperparameters on each map set over its seeds, medians with 95 % bootstrap intervals;
    a trial that never converged is counted as such, not as a number (a note, a blank line, the table)."""
    unfinished = sum(not r.finished for r in rows)
    are = verb(unfinished, "is", "are")
    left_out = f" {counted(unfinished, 'unfinished trial')} (sweep.md) {are} left out." if unfinished else ""
    lines = ["Over seeds: median [95 % bootstrap interval]. Converged: from some evaluation on, at least 90 % of the "
             "protocol's starts settle within 1 % of the optimum; a trial that never converged counts as "
             "converging past its budget, so a median that depends on it reads \"> x\" (at least x) and an "
             f"interval's end past the budget \"inf\". {FEW_SEEDS_NOTE}{left_out}", "",
             "| maps | algorithm and hyperparameters | seeds | kept policy's median gap | kept policy's share within "
             "1 % | converged "
             "| env steps to converge | plateau greedy settled R1 | best R1 |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    design = _designed(rows)
    if design:  # the designer's gap on its evaluation floors, beside the protocol's figures
        lines[-2] = lines[-2].replace(" | converged ", " | design median gap (%) | converged ")
        lines[-1] += "---:|"
    for (maps, label), trials in _groups(rows).items():
        steps = censored_steps([(t.converged_at, t.env_steps) for t in trials if measured(t.curve)])
        gap = median_interval([t.median_gap for t in trials])  # a trial never evaluated: "(2 of 3 seeds)"
        within = median_interval([t.share_within_1pct for t in trials])
        plateau = median_interval([t.settled_R1_plateau for t in trials])
        best = median_interval([math.nan if t.best is None else t.best.R1 for t in trials])
        to_converge = censored_median_interval(*steps).text(",.0f")
        count = converged_count(sum(t.converged_at is not None for t in trials), [t.curve for t in trials])
        designed = f" {median_interval([t.design_gap_pct for t in trials]).text()} |" if design else ""
        lines.append(f"| {maps} | {label} | {len(trials)} | {gap.text()} | {within.text()} |{designed} {count} "
                     f"| {to_converge} | {plateau.text()} | {best.text()} |")  # fmt: skip
    return lines


def group_curves(rows: list[TrialRow]) -> dict[str, dict[str, dict[str, np.ndarray]]]:
    """{map set: {algo and hyperparameters: {env_steps, <metric>_mean/_lo/_hi}}}: seeds averaged on a common grid,
    with the 95 % bootstrap band of the mean."""
    groups: dict[str, dict[str, list[TrialRow]]] = {}
    for (maps, label), trials in _groups(rows).items():
        groups.setdefault(maps, {})[label] = trials
    out: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for maps, lines in groups.items():
        for label, trials in lines.items():
            end = min(max(t.curve["env_steps"]) for t in trials)
            grid = np.linspace(0, end, CURVE_POINTS)
            line: dict[str, np.ndarray] = {"env_steps": grid}
            keys = ["episode_return_mean", PLATEAU_KEY]
            if any(np.isfinite(t.curve.get("design_gap", [math.nan])).any() for t in trials):
                keys.append("design_gap")  # the designer's gap on held-out floors, where the sweep measured it
            for key in keys:
                ys = np.array([_interp(grid, t.curve["env_steps"], t.curve[key]) for t in trials])
                line[f"{key}_mean"], line[f"{key}_lo"], line[f"{key}_hi"] = band(ys)
            out.setdefault(maps, {})[f"{label} ({len(trials)} seed{'s' if len(trials) > 1 else ''})"] = line
    return out


def _interp(grid: np.ndarray, x: list[float], y: list[float]) -> np.ndarray:
    xs, ys = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(ys)
    if not ok.any():
        return np.full(grid.shape, np.nan)
    values = np.interp(grid, xs[ok], ys[ok])
    values[grid < xs[ok][0]] = np.nan
    return values


def _num(value: Any) -> float:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan


def _fmt(value: Any) -> str:
    """A hyperparameter for a label: floats to 4 significant digits."""
    if isinstance(value, float):
        return f"{value:.4g}"
    return "" if value is None else str(value)


def _exact(value: Any) -> str:
    """A hyperparameter as its exact value (a float's shortest text that reads back to it), for sweep.csv."""
    return "" if value is None else repr(value) if isinstance(value, float) else str(value)

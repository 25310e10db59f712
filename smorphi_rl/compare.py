"""`smorphi-rl compare`: every method against the exact Pareto front of the design space.

For each method: its best R1 and the gap to the exact optimum, the hypervolume of its
non-dominated set as a fraction of the exact front's, and the budget it used (FBCPP
evaluations or env steps). The hypervolume is measured in (P_len, P_c) against the nadir of the
whole lattice: the longest path and the lowest coverage of any feasible shape on it, so every
method's set is measured against the same point and the exact front scores 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import LATTICE_TOLERANCE_DEG, angles_text, nearest_on_lattice
from smorphi_rl.inputs import is_finite_number, read_json_object
from smorphi_rl.protocol import gaps_to, within_band
from smorphi_rl.rundir import write_text_atomic
from smorphi_rl.score import Weights
from smorphi_rl.search.pareto import pareto_front
from smorphi_rl.search.results import SearchResult, distinct_rows, load
from smorphi_rl.stats import cell
from smorphi_rl.training.topk import FOUND_CSV, read_csv

if TYPE_CHECKING:
    from smorphi_rl.maps import Map
    from smorphi_rl.planning import Evaluator, Planning


@dataclass(frozen=True)
class MethodScore:
    """One method's non-dominated set and its figures against the exact optimum."""

    label: str
    budget: str
    best_theta: tuple[float, float, float]
    best_P_c: float
    best_P_len: int
    best_R1: float
    gap_R1: float
    hv_fraction: float
    front_len: np.ndarray
    front_pc: np.ndarray
    protocol: str = "-"
    """The evaluation protocol's figures from the fixed starts (median settled gap, share within 1 %), for
    methods that settle from starts (trained policies, hill climbing, annealing); '-' for the others."""


def hypervolume(p_len: np.ndarray, p_c: np.ndarray, ref_len: float, ref_pc: float) -> float:
    """Area dominated by the points (minimise P_len, maximise P_c) up to the reference point."""
    keep = (np.asarray(p_len) <= ref_len) & (np.asarray(p_c) >= ref_pc)
    x, y = np.asarray(p_len, dtype=float)[keep], np.asarray(p_c, dtype=float)[keep]
    if not x.size:
        return 0.0
    front = pareto_front(y, x)
    area, prev_y = 0.0, ref_pc
    for i in front:  # P_len and P_c both increase along the front
        area += (ref_len - x[i]) * (y[i] - prev_y)
        prev_y = y[i]
    return area


Points = tuple[str, str, np.ndarray, np.ndarray, np.ndarray, Any]
"""(label, budget, thetas, P_c, P_len, settled) of one method's run; `settled` is the protocol's summary of a
trained policy (dict), the settled R1 of each start of a local search (list), or None."""


def _env_of_run(run_dir: Path) -> dict[str, Any] | None:
    """A training run's env settings as its config.json records them ({} where they are not an object); None for a
    folder without one (a search run, or not a run)."""
    config = run_dir / "config.json"
    if not config.is_file():
        return None
    env = read_json_object(config, "run configuration").get("env")
    return env if isinstance(env, dict) else {}


def planner_of_run(run_dir: Path) -> str:
    """The coverage planner a training or search run scored its shapes with ("paper" for runs from before
    there was a choice)."""
    env = _env_of_run(run_dir)
    if env is not None:
        return str(env.get("planner", "paper"))
    if (run_dir / "results.npz").is_file():
        return str(load(run_dir).params.get("planner", "paper"))
    return "paper"


def start_of_run(run_dir: Path) -> tuple[float, float] | None:
    """The point (metres) a training or search run's plans started from; None: the planner's default start (and
    for runs from before a start could be given)."""
    raw: Any = None
    env = _env_of_run(run_dir)
    if env is not None:
        raw = env.get("start_xy")
    elif (run_dir / "results.npz").is_file():
        raw = load(run_dir).params.get("start_xy")
    return start_from(raw, run_dir)


def block_of_run(run_dir: Path) -> float:
    """The block side (metres) a training run planned its shapes with (an env setting; the searches and `compare`
    plan with the default)."""
    from smorphi_rl.geometry import DEFAULT_BLOCK_SIDE_M

    raw: Any = (_env_of_run(run_dir) or {}).get("block_side_m")
    return float(raw) if is_finite_number(raw) else DEFAULT_BLOCK_SIDE_M


def start_from(raw: Any, where: Path | str) -> tuple[float, float] | None:
    """A start point as a run records it ([x, y] in metres), or None where it records none (or not one of ours);
    two numbers of which one is not finite (1e400 in JSON) are refused: no hint could name that start."""
    ok = isinstance(raw, list | tuple) and len(raw) == 2 and all(isinstance(v, int | float) for v in raw)
    if ok and not all(is_finite_number(v) for v in raw):
        raise SmorphiError(f"{where}: its start_xy {raw} is not a point (two finite numbers, in metres)")
    return (float(raw[0]), float(raw[1])) if ok else None


def feasible_of(result: SearchResult, run_dir: Path) -> np.ndarray:
    """The mask of a search result's feasible shapes; refused when it has none (nothing to put on a front)."""
    if not result.feasible.any():
        raise SmorphiError(
            f"{run_dir}: holds no feasible shape among its {len(result.feasible):,} (nothing to compare)"
        )
    return result.feasible


def another_floor(where: Path | str, map_name: str) -> SmorphiError:
    """A run, or an exact front, of another floor than --map's under the same name (its recorded digest differs)."""
    return SmorphiError(f"{where}: its map '{map_name}' is another floor than --map's (the cells differ): compare "
                        "runs of the same map file")  # fmt: skip


def start_text(start: tuple[float, float] | None) -> str:
    """Where plans start, as the refusals say it."""
    return "the planner's default start" if start is None else f"({start[0]:g}, {start[1]:g}) m"


def exact_front_under(log_dir: Path, map_path: str, grid_map: Map, planning: Planning, step: float) -> Path | None:
    """The folder `search exhaustive` names by default under `log_dir`, when it holds that search's front of this
    very map (cells and resolution), planner and lattice step from the planner's own start; None otherwise (compare
    computes the front). Not with a start point: a run does not record the origin that put its start on a cell."""
    from smorphi_rl.search.config import SearchConfig

    folder = log_dir / SearchConfig("exhaustive", map_path, planning=planning, step=step).run_name
    if planning.start_xy is not None or not (folder / "summary.json").is_file():
        return None
    try:
        run = load(folder)
        same = (run.method == "exhaustive" and run.map_name == grid_map.name and run.map_digest == grid_map.digest
                and run.params.get("planner", "paper") == planning.planner.value and run.feasible.any()
                and run.params.get("step_deg") == step and run.params.get("start_xy") is None)  # fmt: skip
    except SmorphiError:
        return None
    return folder if same else None


def check_exact_front(exact: SearchResult, where: str, step_given: bool) -> None:
    """An exact front to compare against: a `search exhaustive` run with feasible shapes, whose lattice is its own
    (`step_given`: a lattice step was asked for as well)."""
    feasible_of(exact, Path(where))
    if exact.method != "exhaustive":
        raise SmorphiError(f"{where}: a `search {exact.method}` run, not an exact front (give a `search "
                           "exhaustive` run)")  # fmt: skip
    if step_given:
        raise SmorphiError("--step: the exact front is computed here only without --exhaustive (its lattice is the "
                           "run's own)")  # fmt: skip


def check_comparable(
    dirs: list[Path], planning: Planning, grid_map: Map, exact: SearchResult | None = None, where: str = ""
) -> None:
    """Refuse runs whose shapes cannot be set against this map's exact front (and the front at `where`, given):
    scored by another planner, planned from another start or with another block, or of another floor."""
    planners = {str(d): planner_of_run(d) for d in dirs}
    if exact is not None:
        planners[where] = str(exact.params.get("planner", "paper"))
    if len(set(planners.values())) > 1:
        told = ", ".join(f"{run}: {p}" for run, p in planners.items())
        raise SmorphiError(f"the runs were scored by different planners ({told}): compare runs of one planner")
    for run, made_with in planners.items():
        if made_with != planning.planner.value:
            raise SmorphiError(f"{run}: its shapes were scored by the {made_with} planner, the exact front here by "
                               f"{planning.planner.value}: pass --planner {made_with}")  # fmt: skip
    starts = {str(d): start_of_run(d) for d in dirs}
    if exact is not None:
        starts[where] = start_from(exact.params.get("start_xy"), where)
    for run, start in starts.items():
        if start != planning.start_xy:
            fix = "leave --start-xy out" if start is None else f"pass --start-xy {start[0]:g} {start[1]:g}"
            raise SmorphiError(f"{run}: its shapes were planned from {start_text(start)}, the exact front here from "
                               f"{start_text(planning.start_xy)}: {fix}")  # fmt: skip
    for d in dirs:
        if not math.isclose(block := block_of_run(d), planning.block_side_m):
            raise SmorphiError(f"{d}: its shapes were planned with a {block:g} m block, the exact front here with "
                               f"{planning.block_side_m:g} m (`search` and `compare` plan the default block): compare "
                               "runs of the default block")  # fmt: skip
    if exact is not None and exact.map_name != grid_map.name:
        raise SmorphiError(f"{where}: the exact front is for map '{exact.map_name}', not '{grid_map.name}'")
    if exact is not None and exact.map_digest not in (None, grid_map.digest):
        raise another_floor(where, grid_map.name)


def weights_of_run(run_dir: Path, grid_map: Map) -> Weights | None:
    """The R1 weights in effect on `grid_map` that a run measured its settled figures under: a training run's env
    settings (w1, w2, path_term), a search run's recorded weights; None where the run records none."""
    env = _env_of_run(run_dir)
    if env is not None:
        from smorphi_rl.env_config import EnvConfig

        given: dict[str, Any] = {k: env[k] for k in ("w1", "w2", "path_term") if k in env}
        try:
            return EnvConfig.from_dict(given).weights_on(grid_map)
        except SmorphiError:
            return None
    summary = run_dir / "summary.json"
    recorded = read_json_object(summary, "search summary").get("weights") if summary.is_file() else None
    if isinstance(recorded, dict) and all(is_finite_number(recorded.get(k)) for k in ("w1", "w2")):
        return Weights(float(recorded["w1"]), float(recorded["w2"]))
    return None


def settled_under(
    runs: list[Points], dirs: list[Path], weights: Weights, grid_map: Map
) -> tuple[list[Points], list[str]]:
    """The runs with the settled figures of those measured under other R1 weights than the table's left out (their
    gaps are to another optimum), and a note naming each: the best shapes are scored again here, those figures not."""
    kept, notes = [], []
    for points, run_dir in zip(runs, dirs, strict=True):
        own = weights_of_run(run_dir, grid_map)
        if (
            points[5] is not None
            and own is not None
            and not (math.isclose(own.w1, weights.w1) and math.isclose(own.w2, weights.w2))
        ):
            notes.append(f"{points[0]}: its settled figures were measured under {own.formula()}, not the "
                         f"table's {weights.formula()}: left out (pass the run's --w1, --w2 and --path-term to "
                         "read them)")  # fmt: skip
            points = (*points[:5], None)
        kept.append(points)
    return kept, notes


def off_lattice(runs: list[Points], exact: SearchResult) -> list[str]:
    """A note naming the runs whose shapes lie off the exact front's lattice: their gaps are to a coarser lattice's
    optimum (below 0 where they beat it) and their hypervolume may pass 1."""
    step = exact.params.get("step_deg")
    if not isinstance(step, int | float) or step <= 0:
        return []

    def away(thetas: np.ndarray) -> np.ndarray:
        """Per shape, whether a hinge lies off the lattice (beyond what a file's rounding moves an angle)."""
        return np.asarray((np.abs(nearest_on_lattice(thetas, step) - thetas) > LATTICE_TOLERANCE_DEG).any(axis=1))

    off = [(p[0], p[2][np.argmax(away(p[2]))]) for p in runs if len(p[2]) and away(p[2]).any()]
    if not off:
        return []
    named = "; ".join(f"{label}: {angles_text(tuple(float(a) for a in t))}" for label, t in off)
    return [
        f"The exact front is the {step:g}-degree lattice's, and shapes of {len(off)} "
        f"{'run lie' if len(off) == 1 else 'runs lie'} off it ({named}): their gaps are to that lattice's "
        "optimum, below 0 where they beat it, and their hypervolume may pass 1; compare on the runs' own "
        "lattice (--step 1 for whole degrees) to measure them against theirs."
    ]


TRAINING_RUN = ("a training run",)
"""`points_of_run`'s `methods` for a folder given as a training run (`compare --runs`)."""


def points_of_run(run_dir: Path, map_name: str, methods: tuple[str, ...] = (), digest: str | None = None) -> Points:
    """What a training run directory or a search run directory found on `map_name`; `methods`: the search methods
    the folder was given as, or TRAINING_RUN (a `search nsga2` run given as random search is refused, a search run
    given as a training run too), empty for any; `digest`: the
    map's `Map.digest`, which a run that recorded its map's must match (another floor filed under the same name)."""

    def check_digest(recorded: Any, where: Path) -> None:
        if digest is not None and isinstance(recorded, str) and recorded != digest:
            raise another_floor(where, map_name)

    if not run_dir.is_dir():
        raise SmorphiError(f"run directory not found: {run_dir}")
    if (run_dir / FOUND_CSV).is_file():
        if methods and methods != TRAINING_RUN:  # its label says PPO or IMPALA: it would sit under another name
            raise SmorphiError(f"{run_dir}: a training run, given as {' or '.join(methods)} (pass it with --runs)")
        every = read_csv(run_dir / FOUND_CSV)
        if not every:
            raise SmorphiError(f"{run_dir / FOUND_CSV}: holds no rows of the table smorphi-rl writes")
        rows = [f for f in every if f.map == map_name and f.P_c > 0]  # an episode that met only infeasible shapes
        trained_on = sorted({f.map for f in every})
        if map_name not in trained_on:
            raise SmorphiError(f"{run_dir}: its shapes are of {', '.join(repr(m) for m in trained_on)}, not "
                               f"'{map_name}': give --map the map it trained on")  # fmt: skip
        if not rows:  # records its best as P_c = P_len = 0: no shape to put on a front
            raise SmorphiError(f"{run_dir}: found no feasible morphologies on map '{map_name}'")
        summary = read_json_object(run_dir / "summary.json", "run summary")
        digests = summary.get("map_digests")
        check_digest(digests.get(map_name) if isinstance(digests, dict) else None, run_dir)
        steps = summary.get("env_steps", 0) if isinstance(summary.get("env_steps", 0), int) else 0
        thetas = np.array([f.theta for f in rows], dtype=float)
        label = f"{rows[0].algorithm.upper()} ({run_dir.name})"
        found = summary.get("evaluation")
        evaluation: dict[str, Any] = found if isinstance(found, dict) else {}
        settled = evaluation.get(map_name)
        if settled is not None and not (
            isinstance(settled, dict)
            and all(is_finite_number(settled.get(k)) for k in ("median_gap", "share_within_1pct"))
        ):
            raise SmorphiError(f"{run_dir / 'summary.json'}: its evaluation on '{map_name}' is not what smorphi-rl "
                               "writes (median_gap and share_within_1pct as numbers)")  # fmt: skip
        if steps < 0:
            raise SmorphiError(f"{run_dir / 'summary.json'}: env_steps {steps} is negative")
        return (label, f"{steps:,} env steps", thetas, np.array([f.P_c for f in rows]),
                np.array([f.P_len for f in rows]), settled)  # fmt: skip
    if not (run_dir / "results.npz").is_file():
        inside = sorted(d for d in run_dir.iterdir() if (d / FOUND_CSV).is_file() or (d / "results.npz").is_file())
        if inside:  # a sweep's, a transfer job's or a log folder: its runs are one level down
            raise SmorphiError(f"{run_dir}: holds the folders of {len(inside)} runs, not one run's results; give each "
                               f"run's folder, such as {inside[0]}")  # fmt: skip
        if (run_dir / "summary.json").is_file():  # a run too short for one episode to end: nothing ranked
            raise SmorphiError(f"{run_dir}: a training run that ranked no shape (no {FOUND_CSV}): none of its "
                               "episodes ended within its budget (its recordings hold episodes cut short), or it "
                               "stopped before its tables were written")  # fmt: skip
        raise SmorphiError(
            f"{run_dir}: holds no results (no {FOUND_CSV} of a training run, no results.npz of a search)"
        )
    result = load(run_dir)
    if methods and result.method not in methods:
        from smorphi_rl.search.config import LOCAL_METHODS  # loads the planner: only where a search run is read

        given = f"{run_dir}: a `search {result.method}` run, given as {' or '.join(methods)}"
        if result.method == "optimum":  # it holds only the shapes it planned: no front to draw, no flag takes it
            raise SmorphiError(f"{given}; an optimum run holds only the shapes it planned: compare the methods against "
                               "a `search exhaustive` run's front (--exhaustive)")  # fmt: skip
        raise SmorphiError(f"{given} (pass it with --{'local' if result.method in LOCAL_METHODS else result.method})")
    if result.map_name != map_name:
        raise SmorphiError(f"{run_dir}: results are for map '{result.map_name}', not '{map_name}'")
    check_digest(result.map_digest, run_dir)
    ok = feasible_of(result, run_dir)
    settled = result.params.get("settled_R1")
    if settled is not None and not (isinstance(settled, list) and all(is_finite_number(v) for v in settled)):
        raise SmorphiError(f"{run_dir / 'summary.json'}: its settled_R1 is not what smorphi-rl writes (a list of "
                           "numbers, one a start)")  # fmt: skip
    return (f"{result.method} ({run_dir.name})", search_budget(result), result.thetas[ok], result.P_c[ok],
            result.P_len[ok], settled)  # fmt: skip


def search_budget(result: SearchResult) -> str:
    """The evaluations a search paid for, and the distinct shapes among them where it drew a shape twice (random
    search, NSGA-II): a local search's budget counts distinct shapes, so the two read alike only side by side."""
    distinct = len(distinct_rows(result))
    repeats = f" ({distinct:,} distinct shapes)" if distinct < result.evaluations else ""
    return f"{result.evaluations:,} FBCPP evaluations{repeats}"


PC_TOLERANCE = 1e-4
"""How far a recorded P_c may lie from the planner's: morphologies.csv writes it to 4 decimals."""


def check_best_as_planned(thetas: np.ndarray, p_c: np.ndarray, p_len: np.ndarray, evaluator: Evaluator,
                          weights: Weights, where: Path | str) -> None:  # fmt: skip
    """A run's best shape (by `weights`) among the shapes it recorded, planned again here, must score what the run
    recorded: a row edited by hand, or written by another version of the planner, would otherwise be set against
    the exact front (a hand-edited row read as beating the optimum). One plan a run."""
    b = int(np.argmax(weights.r1(p_c, p_len)))
    again = evaluator.evaluate_many(np.asarray(thetas[b : b + 1], dtype=float))
    recorded = f"P_c {float(p_c[b]):.4f} %, P_len {int(p_len[b])}"
    why = "a table edited by hand, or made by another version of the planner"
    if not again.feasible[0]:
        raise SmorphiError(f"{where}: its best shape {angles_text(thetas[b])} ({recorded}) is infeasible on this map "
                           f"as planned here: {why}")  # fmt: skip
    planned = f"P_c {float(again.P_c[0]):.4f} %, P_len {int(again.P_len[0])}"
    if abs(float(again.P_c[0]) - float(p_c[b])) > PC_TOLERANCE or int(again.P_len[0]) != int(p_len[b]):
        raise SmorphiError(f"{where}: its best shape {angles_text(thetas[b])} is recorded at {recorded} but plans at "
                           f"{planned} here: {why}")  # fmt: skip


def score_methods(exact: SearchResult, runs: list[Points], weights: Weights) -> tuple[MethodScore, list[MethodScore]]:
    """The exact front's own score and every run's, all against the same optimum and reference point."""
    ok = exact.feasible
    ref_len, ref_pc = float(exact.P_len[ok].max()), float(exact.P_c[ok].min())
    exact_front = exact.front()
    hv_exact = hypervolume(exact.P_len[exact_front], exact.P_c[exact_front], ref_len, ref_pc)
    b = exact.best(weights)
    optimum = float(weights.r1(exact.P_c[b], exact.P_len[b]))

    def score(label: str, budget: str, thetas: np.ndarray, p_c: np.ndarray, p_len: np.ndarray,
              settled: Any = None) -> MethodScore:  # fmt: skip
        scores = weights.r1(p_c, p_len)
        b = int(np.argmax(scores))
        front = pareto_front(p_c, p_len)
        hv = hypervolume(p_len[front], p_c[front], ref_len, ref_pc)
        t1, t2, t3 = (float(t) for t in thetas[b])
        return MethodScore(label, budget, (t1, t2, t3), float(p_c[b]), int(p_len[b]), float(scores[b]),
                           float(gaps_to(optimum, scores[b])), hv / hv_exact if hv_exact else float("nan"),
                           p_len[front].astype(float), p_c[front], _protocol_text(settled, optimum))  # fmt: skip

    step = exact.params.get("step_deg")
    label = f"exact ({step:g}-degree lattice)" if isinstance(step, int | float) else "exact"
    budget = f"{exact.evaluations:,} FBCPP evaluations"
    exact_score = score(label, budget, exact.thetas[ok], exact.P_c[ok], exact.P_len[ok])
    return exact_score, [score(*points) for points in runs]


def _protocol_text(settled: Any, optimum: float) -> str:
    """'median gap (share within 1 %)' from a trained run's summary or a local search's settled R1 per start."""
    if isinstance(settled, dict) and "median_gap" in settled:
        return f"{float(settled['median_gap']):.2f} ({100 * float(settled['share_within_1pct']):.0f} %)"
    if isinstance(settled, list) and settled:
        gaps = gaps_to(optimum, settled)
        return f"{float(np.median(gaps)):.2f} ({100 * float(np.mean(within_band(gaps, optimum))):.0f} %)"
    return "-"


def method_table(exact: MethodScore, methods: list[MethodScore]) -> list[str]:
    """The Markdown lines of every method's row against the exact optimum, with the paragraph that reads them."""
    lines = [
        "Best shape: the best any shape the method scored (visited). Settled from the fixed starts: the evaluation "
        "protocol's median gap of the shape each start ends on, and the share of starts within 1 % of the optimum "
        "(trained policies: greedy roll-outs; hill climbing and annealing: where each start ended).",
        "",
        "| Method | Budget | Best shape (θ1, θ2, θ3) | P_c (%) | P_len | R1 | Gap to optimum | Hypervolume "
        "| Settled from the fixed starts: median gap (within 1 %) |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for m in [exact, *methods]:
        hv = cell(m.hv_fraction, ".4f") or "-"  # none where the exact front spans no area (one shape's P_c or P_len)
        lines.append(f"| {m.label} | {m.budget} | {angles_text(m.best_theta)} | {m.best_P_c:.2f} | {m.best_P_len} "
                     f"| {m.best_R1:.2f} | {m.gap_R1:.2f} | {hv} | {m.protocol} |")  # fmt: skip
    return lines


def report_lines(exact: MethodScore, methods: list[MethodScore], map_name: str, weights: Weights,
                 planning: str, notes: list[str] | None = None) -> list[str]:  # fmt: skip
    """The comparison as Markdown lines: title, how to read it, the table (what `compare` prints) and `notes` (what
    was left out of it); `planning` is `Planning.describe`'s line, so reports of two planners on one map say which
    is which."""
    return [
        f"# Every method against the exact optimum on {map_name}",
        "",
        f"{planning[0].upper()}{planning[1:]}. {weights.formula()}. Hypervolume in (P_len, P_c) against the "
        "lattice nadir (longest path, lowest coverage of any feasible shape), as a fraction of the exact front's.",
        "",
        *method_table(exact, methods),
        *(["", *(f"- {note}" for note in notes)] if notes else []),
    ]


def write_report(exact: MethodScore, methods: list[MethodScore], map_name: str, weights: Weights,
                 planning: str, run_dir: Path, notes: list[str] | None = None) -> dict[str, Path]:  # fmt: skip
    """report.md (`report_lines` and the plot) and compare.png under `run_dir`."""
    from smorphi_rl.plots import plot_pareto

    lines = report_lines(exact, methods, map_name, weights, planning, notes)
    files = {"report": run_dir / "report.md"}
    files["plot"] = plot_pareto(
        {m.label: (m.front_len, m.front_pc) for m in methods},
        run_dir / "compare.png",
        f"Non-dominated shapes of each method on {map_name}, over the exact front",
        front=(exact.front_len, exact.front_pc),
        best={m.label: (float(m.best_P_len), m.best_P_c) for m in methods},
    )
    lines += ["", f"![Pareto plot]({files['plot'].name})", ""]
    write_text_atomic(files["report"], "\n".join(lines))
    return files

"""`search random|nsga2|exhaustive|hillclimb|anneal` and `compare`: the baselines and the exact front."""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl import jsontext
from smorphi_rl.cli.common import (
    DEFAULT_MAP,
    Parser,
    Repeated,
    name_choices,
    planner_option,
    planning_of,
    run_options,
    say_warnings,
    seed_arg,
    weight_options,
    weights,
)
from smorphi_rl.cli.fields import UNSET, option
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.geometry import angles_text, check_step, lattice_size
from smorphi_rl.interrupts import stop_requests
from smorphi_rl.maps import load_map
from smorphi_rl.progress import progress_line
from smorphi_rl.rundir import rel
from smorphi_rl.score import Weights


def register(sub: Any) -> None:
    """Add `search METHOD` and `compare` to the command line."""
    se = sub.add_parser("search", help="baselines and ground truth: random shapes, NSGA-II, the exhaustive lattice")
    se_sub = se.add_subparsers(dest="method", required=True, parser_class=Parser)
    from smorphi_rl.search.config import METHOD_FIELDS, METHODS, RAY_METHODS, SearchConfig

    for method, text in METHODS.items():
        m = se_sub.add_parser(method, help=text)
        m.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
        run_options(m)
        printed = "its optimum as a JSON line" if method == "optimum" else "the front as JSON lines"
        m.add_argument("--json", action="store_true", help=f"print {printed} (theta, P_c, P_len)")
        weight_options(m)
        planner_option(m)
        for name in METHOD_FIELDS[method]:
            option(m, SearchConfig, name, type=seed_arg if name == "seed" else None)
        if method in RAY_METHODS:
            m.add_argument("--address", help="plan on the Ray cluster at HOST:PORT (or auto), one actor per CPU, "
                           "with the same results; default: the cores this process may use (`taskset -c 0-3` "
                           "limits them)")  # fmt: skip
        m.set_defaults(func=cmd_search)
    name_choices(se, se_sub)

    co = sub.add_parser("compare", help="every method against the exact Pareto front of a map")
    co.add_argument("--map", default=None, help=f"map_server YAML (default: {DEFAULT_MAP})")
    co.add_argument("--runs", nargs="+", action=Repeated, help="training run directories (logs/<run>)")
    co.add_argument("--nsga2", nargs="+", action=Repeated, help="`search nsga2` run directories")
    co.add_argument("--random", nargs="+", action=Repeated, help="`search random` run directories")
    co.add_argument("--local", nargs="+", action=Repeated, help="`search hillclimb` / `search anneal` run directories")
    co.add_argument("--exhaustive", help="a `search exhaustive` run to use as the exact front (default: the one "
                    "`search exhaustive` names under --log-dir, where it holds this front; else computed)")  # fmt: skip
    option(co, SearchConfig, "step", unset=True, default_text=f"{SearchConfig.step:g}, when the front is computed here")
    run_options(co, "run name: the report goes to LOG_DIR/NAME (default: compare-MAP)")
    weight_options(co)
    planner_option(co)  # the exact front's planner: compare runs made with the same one
    co.set_defaults(func=cmd_compare)


PROGRESS_UNITS: dict[str, str | tuple[str, ...]] = {
    **{m: (f"{m}: shapes keyed by footprint", f"{m}: shapes settled") for m in ("exhaustive", "optimum")},
    "nsga2": "nsga2: generations", "hillclimb": "hillclimb: starts", "anneal": "anneal: starts",
}  # fmt: skip
"""What each method's progress line counts (the lattice methods: two passes)."""


def cut_hint(method: str) -> str:
    """What the line that says a run will take over a minute suggests (`search.config.CUTS`, and more)."""
    from smorphi_rl.search.config import CUTS, LATTICE_METHODS, RAY_METHODS

    ways = [CUTS[method], *(["`maps resample` to a coarser resolution", "`maps crop`"] if method in LATTICE_METHODS
                            else []), *(["--address CLUSTER"] if method in RAY_METHODS else [])]  # fmt: skip
    return ", ".join(ways[:-1]) + f" or {ways[-1]} cut the work" if len(ways) > 1 else f"{ways[0]} cuts the work"


def cmd_search(args: argparse.Namespace) -> int:
    """Random shapes, NSGA-II, local search or the exhaustive lattice on a map; results, front and plot under
    LOG_DIR/<run>/."""
    from smorphi_rl.plots import plot_pareto
    from smorphi_rl.rundir import discarded_on_failure, prepare_run_dir
    from smorphi_rl.search.config import METHOD_FIELDS, SearchConfig, run_search
    from smorphi_rl.search.exhaustive import SearchStopped
    from smorphi_rl.search.results import save

    w = weights(args)
    grid_map = load_map(args.map)
    planning = planning_of(args, grid_map)  # a bad map or start fails here, before anything is written
    from smorphi_rl.coverage import Planner
    from smorphi_rl.maps import check_fits

    check_fits(grid_map, planning.block_side_m, whole_footprint=planning.planner is Planner.FIT)
    say_warnings(grid_map)
    options = {k: getattr(args, k) for k in METHOD_FIELDS[args.method]}
    address = getattr(args, "address", None)
    if address is not None:
        from smorphi_rl import cluster

        cluster.check_reachable(address)  # no cluster there: one line, nothing written
        address = cluster.auto_address() if address == "auto" else address  # the run records the cluster it used
    cfg = SearchConfig(args.method, str(args.map), planning, w.w1, w.w2, w.path_term, **options, address=address)
    on_map = w.weights_on(grid_map)
    run_dir = prepare_run_dir(args.log_dir, args.name or cfg.run_name)
    hint = cut_hint(args.method)
    with ExitStack() as held:  # a hold of stops, left (its handlers put back) with the plot drawn, however it ends
        with discarded_on_failure(run_dir):  # interrupted, failed, or a full disk mid-way: no whole run, the name free
            try:
                result = run_search(cfg, progress_line(PROGRESS_UNITS.get(args.method, args.method), hint))
            except SearchStopped as stop:  # an hour's search stopped still says what it found
                raise Interrupted(stop.best_so_far(on_map)) from None
            # from here a stop waits for the files and the plot (a second is at once): raised as it came, it could land
            # in a callback of the garbage collector, which Python prints as "ignored" and drops
            late = held.enter_context(stop_requests(again=True))
            if planning.start_xy is not None:
                result.params["start_xy"] = list(planning.start_xy)  # `compare` checks it
            b = result.best(on_map)
            from smorphi_rl.geometry import Morphology

            best_plan = planning.evaluator(grid_map).evaluate(Morphology(*(float(t) for t in result.thetas[b])))
            cover = {"coverage_free_pct": best_plan.coverage_free_pct, "coverable_pct": best_plan.coverable_pct}
            files = save(result, run_dir, on_map, cover)  # `compare` reads summary.json, written last
        if cfg.method == "optimum" and cfg.step == 1.0 and result.map_digest == grid_map.digest:  # the map unchanged
            from smorphi_rl.protocol import Optimum, optimum_cache, remember_optimum  # what `train` searches first

            found = Optimum.of(result.thetas, result.P_c, result.P_len, on_map)
            remember_optimum(grid_map, on_map, planning, optimum_cache(args.log_dir), found)
        front_rows = result.front_records(on_map)
        try:
            title = f"{result.method} on {result.map_name}: {result.evaluations:,} evaluations, front of "
            title += str(len(front_rows))
            if cfg.method == "optimum":  # it planned only the footprints its bound could not rule out
                title += " among them (not the lattice's: `search exhaustive`)"
            files["plot"] = plot_pareto(
                {result.method: (np.array([r["P_len"] for r in front_rows]), np.array([r["P_c"] for r in front_rows]))},
                run_dir / "pareto.png", title, best={result.method: (float(result.P_len[b]), float(result.P_c[b]))},
            )  # fmt: skip
        except OSError as exc:  # the run is whole without its picture: kept, and said so
            missing = f"{rel(run_dir)} (`compare` reads them), only its plot is missing"
            raise SmorphiError(f"{exc.strerror or exc}: {rel(run_dir / 'pareto.png')}; the search's results are whole "
                               f"in {missing}") from None  # fmt: skip
        except KeyboardInterrupt:
            raise Interrupted(f"stopped while drawing the plot: the search's results are whole in {rel(run_dir)} "
                              "(`compare` reads them), only its plot is missing") from None  # fmt: skip
    from smorphi_rl.score import degenerate_warning

    if args.json:  # an optimum's planned shapes hold the optimum, not the lattice's front: the optimum alone
        optimum = {"theta": [float(t) for t in result.thetas[b]], "P_c": float(result.P_c[b]),
                   "P_len": int(result.P_len[b])}  # fmt: skip
        rows = [optimum] if cfg.method == "optimum" else front_rows
        for row in rows:
            print(jsontext.dumps({"theta": row["theta"], "P_c": row["P_c"], "P_len": row["P_len"]}))
        print(f"results: {rel(run_dir)}", file=sys.stderr)  # stdout stays the front's JSON lines
    else:
        said = "" if planning.is_paper_default else planning.describe(grid_map)
        print(format_search(result, front_rows, on_map, files, said, cover))

    line = planning.start_warning(grid_map, best_plan.coverage_free_pct) or degenerate_warning(
        on_map, float(result.P_c[b]), float(result.P_len[b]), w.path_term, grid_map.name
    )  # a start on a speck explains a small coverage first
    if line:
        print(line, file=sys.stderr)
    if late.is_set():
        raise Interrupted(f"as the search ended: its results and plot are whole in {rel(run_dir)}")
    return 0


def format_search(
    result: Any,
    front_rows: list[dict[str, Any]],
    weights: Weights,
    files: dict[str, Path],
    planning: str = "",
    cover: dict[str, float] | None = None,
) -> str:
    """The human-readable report of a search: its size, (a non-default) planning, its front, its best shape (with
    the free floor it covers and its coverable bound, given `cover`) and where the files are."""
    extra = result.params.get("distinct_footprints")
    footprints = f", {extra:,} distinct footprints" if extra is not None else ""
    from smorphi_rl.search.results import distinct_rows

    distinct = distinct_rows(result)  # a local search keeps a shape scored twice once; random and NSGA-II repeat it
    feasible = int(np.count_nonzero(result.feasible[distinct]))
    shapes = len(distinct)
    said = (
        f"{feasible:,} feasible"
        if shapes == result.evaluations
        else f"{shapes:,} distinct shapes, {feasible:,} feasible"
    )
    if result.method == "optimum":
        p = result.params
        n_lattice = lattice_size(p["step_deg"])
        lines = [f"optimum on {result.map_name}: the best R1 of {n_lattice:,} shapes ({p['step_deg']:g}-degree "
                 f"lattice) in {result.wall_s:.1f} s: {extra:,} distinct footprints, {p['planned_footprints']:,} "
                 f"planned, {p['pruned_footprints']:,} pruned by the bound",
                 *([planning] if planning else [])]  # fmt: skip
    else:
        lines = [f"{result.method} on {result.map_name}: {result.evaluations:,} evaluations{footprints} in "
                 f"{result.wall_s:.1f} s ({said})",
                 *([planning] if planning else []),
                 f"Pareto front ({len(front_rows)} points, max P_c / min P_len):"]  # fmt: skip
        for row in front_rows:
            theta, p_c, p_len, r1 = angles_text(row["theta"]), row["P_c"], row["P_len"], row["R1"]
            lines.append(f"  {theta:<17} P_c {p_c:7.2f} %  P_len {p_len:4d}  R1 {r1:7.2f}")
    if result.params.get("address") is not None:  # said, as the summary records it: the run was not this machine's
        lines.insert(1, f"on the Ray cluster at {result.params['address']}")
    b = result.best(weights)
    r1_best = float(weights.r1(result.P_c[b], result.P_len[b]))
    lines.append(f"best R1 (w1 {weights.w1:g}, w2 {weights.w2:.4g}): {angles_text(result.thetas[b])} "
                 f"P_c {result.P_c[b]:.2f} %, P_len {result.P_len[b]}, R1 {r1_best:.2f}")  # fmt: skip
    if cover is not None:
        lines.append(f"  it covers {cover['coverage_free_pct']:.2f} % of the free floor; any path from its start "
                     f"could cover {cover['coverable_pct']:.2f} % (its coverable bound)")  # fmt: skip
    lines.extend(f"{key + ':':<9} {rel(files[key])}" for key in ("results", "front", "summary", "plot"))
    return "\n".join(lines)


def cmd_compare(args: argparse.Namespace) -> int:
    """Put training runs and search runs against the exact front of the map; report.md and compare.png."""
    from smorphi_rl.compare import (
        TRAINING_RUN,
        check_best_as_planned,
        check_comparable,
        check_exact_front,
        exact_front_under,
        off_lattice,
        points_of_run,
        report_lines,
        score_methods,
        settled_under,
        write_report,
    )
    from smorphi_rl.rundir import check_run_dir, discarded_on_failure, prepare_run_dir, safe_name
    from smorphi_rl.search.config import LOCAL_METHODS
    from smorphi_rl.search.exhaustive import run_exhaustive
    from smorphi_rl.search.results import load

    dirs = [Path(d) for d in [*(args.runs or []), *(args.nsga2 or []), *(args.random or []), *(args.local or [])]]
    if not dirs:
        raise SmorphiError("give at least one run to compare: --runs, --nsga2, --random or --local")
    for i, d in enumerate(dirs):
        if not d.is_dir():
            raise SmorphiError(f"{d}: not a run folder (give the folder a `train` or `search` run wrote)")
        if any(d.resolve() == earlier.resolve() for earlier in dirs[:i]):
            raise SmorphiError(f"{d} is given twice: the report would list it twice")
    grid_map = load_map(args.map)
    say_warnings(grid_map)  # before the exact front, which may search the whole lattice
    name = args.name or safe_name(f"compare-{grid_map.name}")
    check_run_dir(args.log_dir, name)  # a name taken is said before the runs are read and planned again
    given = {**{str(d): TRAINING_RUN for d in args.runs or []}, **{str(d): ("nsga2",) for d in args.nsga2 or []},
             **{str(d): ("random",) for d in args.random or []},
             **{str(d): LOCAL_METHODS for d in args.local or []}}  # fmt: skip
    digest = grid_map.digest  # hashed once, for every run and the exact front
    runs = [points_of_run(d, grid_map.name, given.get(str(d), ()), digest) for d in dirs]  # what each run is, first
    on_map = weights(args).weights_on(grid_map)
    planning = planning_of(args, grid_map)
    from smorphi_rl.search.config import SearchConfig

    step = SearchConfig.step if args.step is UNSET else args.step
    check_step(step)
    found = None if args.exhaustive else exact_front_under(Path(args.log_dir), str(args.map), grid_map, planning, step)
    exhaustive = str(found) if found is not None else args.exhaustive  # a front `search exhaustive` left here
    exact = load(exhaustive) if exhaustive else None
    if exact is not None:
        check_exact_front(exact, exhaustive, step_given=found is None and args.step is not UNSET)
    check_comparable(dirs, planning, grid_map, exact, exhaustive or "")
    evaluator = planning.evaluator(grid_map)  # each run's best shape planned again: the figures are the planner's
    for d, (_, _, thetas, p_c, p_len, _) in zip(dirs, runs, strict=True):
        check_best_as_planned(thetas, p_c, p_len, evaluator, on_map, d)
    if exact is not None:
        ok = exact.feasible
        check_best_as_planned(exact.thetas[ok], exact.P_c[ok], exact.P_len[ok], evaluator, on_map, exhaustive)
    if found is not None:  # said once it is known to be this map's front
        print(f"exact front: read from {found} (a `search exhaustive` run of this map, planner and step; "
              "--exhaustive names another)", file=sys.stderr)  # fmt: skip
    run_dir = prepare_run_dir(args.log_dir, name)
    with discarded_on_failure(run_dir):  # no report: the name stays free
        if exact is None:
            exact = run_exhaustive(
                str(args.map),
                step,
                planning,
                progress=progress_line(("exact front: shapes keyed by footprint", "exact front: shapes settled")),
            )
        runs, notes = settled_under(runs, dirs, on_map, grid_map)
        notes += off_lattice(runs, exact)
        exact_score, methods = score_methods(exact, runs, on_map)
        planned = planning.describe(grid_map)
        files = write_report(exact_score, methods, grid_map.name, on_map, planned, run_dir, notes)
    print("\n".join(report_lines(exact_score, methods, grid_map.name, on_map, planned, notes)))
    print(f"\nreport: {rel(files['report'])}\nplot:   {rel(files['plot'])}")
    return 0

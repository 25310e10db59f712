"""`design`: a shape for a floor from a trained designer policy, within a budget of planner evaluations.

Reads the policy with NumPy alone (`policy_file.py`, `numpy_policy.py`): no torch and no Ray start, so an
answer comes in about a second.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from smorphi_rl import jsontext
from smorphi_rl.cli.common import DEFAULT_LOG_DIR, clipped, nonempty, one_line, say_warnings, start_option
from smorphi_rl.design import DEFAULT_BUDGET, PROGRESS_FROM
from smorphi_rl.geometry import angles_text
from smorphi_rl.inputs import FORCE_HELP, output_file
from smorphi_rl.maps import map_inputs
from smorphi_rl.policy_file import SHIPPED_DESIGNER
from smorphi_rl.progress import progress_line
from smorphi_rl.rundir import rel
from smorphi_rl.words import counted


def register(sub: Any) -> None:
    """Add `design` to the command line."""
    ds = sub.add_parser("design", help="propose a shape for a floor with the trained designer policy (no Ray)")
    ds.add_argument("--map", default=None, help="map_server YAML of the floor (default: maps/map-1.yaml)")
    ds.add_argument("--policy", default=None, help=f"an exported policy folder (default: the shipped designer, "
                    f"{rel(SHIPPED_DESIGNER)})")  # fmt: skip
    ds.add_argument("--budget", type=int, default=DEFAULT_BUDGET, metavar="N",
                    help=f"planner evaluations (distinct shapes) at most (default: {DEFAULT_BUDGET}); tens of "
                    "thousands take longer than --exact's search of every shape")  # fmt: skip
    ds.add_argument("--exact", action="store_true", help="also find the exact 1-degree optimum (every shape, about "
                    "10 s to 2.5 min the first time, by the floor's size; cached under LOG_DIR/.cache) and report "
                    "the gap")  # fmt: skip
    start_option(ds)  # the floor to clean where plans would start in another room; the designer's planner stays
    ds.add_argument("--json", action="store_true", help="print one JSON object")
    ds.add_argument("--plot", help="write a PNG of the proposed shape's coverage on the floor")
    ds.add_argument("--force", action="store_true", help=FORCE_HELP)
    ds.add_argument("--log-dir", type=nonempty, default=DEFAULT_LOG_DIR, help=f"where --exact caches optima (default: "
                    f"{DEFAULT_LOG_DIR})")  # fmt: skip
    ds.set_defaults(func=cmd_design)


def cmd_design(args: argparse.Namespace) -> int:
    """A shape for the floor from the shipped (or a given) designer within a budget of planner evaluations."""
    from smorphi_rl.design import check_budget, run_design
    from smorphi_rl.designer import design_warnings, designer_env, load_designer
    from smorphi_rl.protocol import make_cache, optimum_cache

    t0 = time.perf_counter()
    check_budget(args.budget)
    cache = make_cache(optimum_cache(args.log_dir)) if args.exact else None  # one that cannot be: said before work
    plot = None if args.plot is None else output_file(args.plot, "--plot", (".png",), map_inputs(args.map), args.force)
    designer = load_designer(Path(args.policy) if args.policy else SHIPPED_DESIGNER)
    start = None if args.start_xy is None else (float(args.start_xy[0]), float(args.start_xy[1]))
    env = designer_env(designer, str(args.map), start)
    say_warnings(env.grid_map)  # said first: the design, and --exact's search above all, costs the frame
    large = args.budget >= PROGRESS_FROM
    bar = progress_line(f"design of {env.grid_map.name}", "a smaller --budget") if large else None
    result = run_design(env, designer.logits, args.budget, progress=bar)
    best = result.best
    record: dict[str, Any] = {
        "map": env.grid_map.name, "policy": str(designer.path), "theta": list(best.theta), "P_c": best.P_c,
        "coverage_free_pct": best.coverage_free_pct, "P_len": best.P_len, "R1": best.R1,
        "weights": env.floor.weights.formula(), "evaluations": result.evaluations,
        "planner_calls": result.planner_calls, "rollouts": result.rollouts, "refined": result.refined,
        "budget": result.budget, "planner": env.config.planning.planner.value,
    }  # fmt: skip
    if start is not None:
        record["start_xy"] = list(start)
    unfamiliar, reach = design_warnings(designer, env, best)  # after the design: a floor it refuses says one line
    warnings = (unfamiliar and unfamiliar + ("" if args.exact else " (--exact measures the gap)"), reach)
    for warning in filter(None, warnings):  # on stderr: --json's stdout stays one object
        print(one_line(warning), file=sys.stderr)
    grid_map, about = env.grid_map, clipped(designer.summary, 200)  # what a policy.json says of itself
    walked = result.evaluations - result.refined
    lines = [
        ("map", f"{grid_map.name} ({grid_map.width} x {grid_map.height} cells at {grid_map.resolution_m:g} m)"),
        ("policy", f"{'the shipped designer' if args.policy is None else rel(designer.path)} ({about})"),
        ("design", f"{angles_text(best.theta)}  P_c {best.P_c:.2f} %, P_len {best.P_len}, R1 {best.R1:.2f} "
                   f"({record['weights']}; planner {record['planner']})"),
        ("cost", f"{counted(result.evaluations, 'planner evaluation')} of {result.budget:,} "
                 f"({counted(result.planner_calls, 'footprint')} planned): {counted(result.rollouts, 'roll-out')} of "
                 f"the policy ({counted(walked, 'shape')}), {counted(result.refined, 'shape')} of compass search"),
    ]  # fmt: skip
    if not args.json:  # the design before --exact's search: a stop during that search keeps it on the screen
        _print(lines)
    if args.exact:
        from smorphi_rl.map_sources import absolute_map
        from smorphi_rl.progress import optimum_progress
        from smorphi_rl.protocol import exact_optimum, gaps_to

        show = optimum_progress(env.floor.grid_map.name)
        opt = exact_optimum(absolute_map(args.map), env.floor.weights, env.config.planning, cache, show)
        gap = float(gaps_to(opt.R1, best.R1))
        record["exact"] = {"theta": list(opt.theta), "R1": opt.R1, "P_c": opt.P_c, "P_len": opt.P_len, "gap": gap,
                           "gap_pct": 100 * gap / abs(opt.R1) if opt.R1 else float("nan")}  # fmt: skip
        pct = record["exact"]["gap_pct"]
        said = ("the design ties the 1-degree optimum" if gap <= 0 else
                f"the design is {gap:.2f} R1 ({pct:.2f} %) below the 1-degree optimum")  # fmt: skip
        lines = [("exact", f"{angles_text(opt.theta)}  R1 {opt.R1:.2f}: {said}")]
    else:
        lines = []
    if plot is not None:
        from smorphi_rl.geometry import Morphology
        from smorphi_rl.plots import plot_coverage

        record["plot"] = str(plot_coverage(env.plan(best.theta), env.grid_map, Morphology.of(best.theta),
                                           env.config.block_side_m, plot))  # fmt: skip
        lines.append(("plot", rel(Path(record["plot"]))))
    record["wall_s"] = round(time.perf_counter() - t0, 3)
    if args.json:
        print(jsontext.dumps(record))
        return 0
    _print([*lines, ("time", f"{record['wall_s']:.2f} s")])
    return 0


def _print(lines: list[tuple[str, str]]) -> None:
    """Labelled lines, each kept to one line (a policy's text never drives the terminal), at once."""
    print("\n".join(one_line(f"{k:<7} {v}") for k, v in lines), flush=True)

"""Matplotlib figures (the only module that imports matplotlib): maps, footprints, coverage."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.coverage import CoverageResult, path_points_m
from smorphi_rl.geometry import Morphology, all_corners, angles_text
from smorphi_rl.maps import CELL_COLOURS, PATH_COLOUR, Cell, Map
from smorphi_rl.rundir import atomic_path, own_temp_folder, writable_folder
from smorphi_rl.words import counted


def config_fallback() -> str | None:
    """Where matplotlib should keep its config and font cache when it cannot write its own folders (an unwritable
    HOME, on Linux): it would make a fresh temp folder each run, rebuild its font cache there and print two lines
    saying so; None where it can, or MPLCONFIGDIR says."""
    if os.environ.get("MPLCONFIGDIR") or not sys.platform.startswith(("linux", "freebsd")):
        return None  # (elsewhere matplotlib keeps one folder, ~/.matplotlib, which is left to it)
    own = [Path(os.path.expanduser(os.environ.get(name) or default)) / "matplotlib"
           for name, default in (("XDG_CONFIG_HOME", "~/.config"), ("XDG_CACHE_HOME", "~/.cache"))]  # fmt: skip
    if not all(folder.is_absolute() for folder in own) or all(writable_folder(folder) for folder in own):
        return None  # (no home to expand ~ in: matplotlib's own fallback)
    return own_temp_folder("matplotlib")


if (_fallback := config_fallback()) is not None:
    os.environ["MPLCONFIGDIR"] = _fallback  # read as matplotlib loads, here and in the processes this one starts

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402

matplotlib.rcParams["text.parse_math"] = False  # names are the user's (a map `r$1_$2.yaml`): text, never TeX

BLOCK_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd")
# free, occupied, unknown, covered free
MAP_COLOURS = ListedColormap(list(CELL_COLOURS))


MAX_GRID_LINES = 60
"""Tile lattices with more lines than this across are not drawn (they would grey the map over)."""


def _extent(grid_map: Map) -> tuple[float, float, float, float]:
    x0, y0 = grid_map.origin[0], grid_map.origin[1]
    r = grid_map.resolution_m
    return (x0, x0 + grid_map.width * r, y0, y0 + grid_map.height * r)


def known_extent(grid_map: Map, margin_m: float = 0.2) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) metres of the known (free or occupied) cells and a margin: what a plot shows of a
    recorded map, which is mostly unknown space."""
    rows, cols = np.nonzero(grid_map.cells != Cell.UNKNOWN)
    x0, x1, y0, y1 = _extent(grid_map)
    if rows.size == 0:
        return x0, x1, y0, y1
    r = grid_map.resolution_m
    ox, oy = grid_map.origin[0], grid_map.origin[1]
    return (max(x0, ox + cols.min() * r - margin_m), min(x1, ox + (cols.max() + 1) * r + margin_m),
            max(y0, oy + rows.min() * r - margin_m), min(y1, oy + (rows.max() + 1) * r + margin_m))  # fmt: skip


def draw_map(ax: plt.Axes, grid_map: Map, covered: np.ndarray | None = None) -> None:
    """Free white, occupied black, unknown grey and, if given, covered free cells green; zoomed to the known
    cells."""
    image = grid_map.cells.astype(np.int8).copy()
    if covered is not None:
        image[covered & (grid_map.cells == Cell.FREE)] = 3
    ax.imshow(image, cmap=MAP_COLOURS, vmin=0, vmax=3, origin="lower", extent=_extent(grid_map), interpolation="none")
    x0, x1, y0, y1 = known_extent(grid_map)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")


def path_width(n_points: int) -> float:
    """Line width of a coverage path: thinner as it gets longer, so a long path stays a path, not a red
    area (1.4 pt up to about 300 positions, 0.3 pt from about 7,000)."""
    return float(np.clip(25.0 / np.sqrt(max(n_points, 1)), 0.3, 1.4))


def draw_morphology(
    ax: plt.Axes, morphology: Morphology, block_side_m: float, offset: tuple[float, float] = (0.0, 0.0)
) -> None:
    """The four blocks B1..B4 with their hinge order, shifted so the footprint's corner is `offset`."""
    blocks = all_corners(morphology, block_side_m)
    xs = [p[0] for b in blocks for p in b]
    ys = [p[1] for b in blocks for p in b]
    dx, dy = offset[0] - min(xs), offset[1] - min(ys)
    for n, (corners, colour) in enumerate(zip(blocks, BLOCK_COLOURS, strict=True)):
        pts = [(x + dx, y + dy) for x, y in corners]
        ax.add_patch(Polygon(pts, closed=True, facecolor=colour, edgecolor="black", alpha=0.75, lw=1))
        cx, cy = float(np.mean([p[0] for p in pts])), float(np.mean([p[1] for p in pts]))
        ax.text(cx, cy, f"B{n + 1}", ha="center", va="center", fontsize=8, color="white", weight="bold")
    ax.add_patch(
        Rectangle((offset[0], offset[1]), max(xs) - min(xs), max(ys) - min(ys), fill=False, ls="--", lw=1, ec="#555555")
    )


def plot_footprint(ax: plt.Axes, result: CoverageResult, morphology: Morphology, block_side_m: float, r: float) -> None:
    """Paper Figure 4a: the blocks, the footprint box w x l, and the cells of F."""
    l, w = result.footprint_cells
    draw_morphology(ax, morphology, block_side_m)
    ax.set_xlim(-0.05, max(result.footprint_m[0], w * r) + 0.05)
    ax.set_ylim(-0.05, max(result.footprint_m[1], l * r) + 0.05)
    ax.set_aspect("equal")
    ax.set_title(
        f"θ = {angles_text(result.theta)}\n"
        f"footprint {result.footprint_m[0]:.3f} × {result.footprint_m[1]:.3f} m, F {l} × {w} cells",
        fontsize=9,
    )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def draw_coverage(
    ax: plt.Axes, result: CoverageResult, grid_map: Map, morphology: Morphology, block_side_m: float, tiles: bool = True
) -> None:
    """The map with the covered area, (optionally) the tile grid, the coverage path and the robot at its start."""
    draw_map(ax, grid_map, result.covered)
    if not (result.feasible and result.placements is not None and len(result.placements)):
        return
    r = grid_map.resolution_m
    l, w = result.footprint_cells
    x0, x1, y0, y1 = _extent(grid_map)
    row0, col0 = (int(v) for v in result.placements[0])
    if tiles and grid_map.width <= MAX_GRID_LINES * w and grid_map.height <= MAX_GRID_LINES * l:
        # the lattice the path moves on (the paper's tiles start at the map's corner); left out when it
        # would grey a large map over
        for x in np.arange(x0 + (col0 % w) * r, x1 + 1e-9, w * r):
            ax.axvline(x, color="#4a90d9", lw=0.4, alpha=0.5)
        for y in np.arange(y0 + (row0 % l) * r, y1 + 1e-9, l * r):
            ax.axhline(y, color="#4a90d9", lw=0.4, alpha=0.5)
    pts = path_points_m(result, grid_map)
    ax.set_facecolor("#ececec")  # beyond the map's edge: not to be read as free floor
    (xa, xb), (ya, yb) = ax.get_xlim(), ax.get_ylim()  # the paper's planner may stand the robot past the map's edge:
    ax.set_xlim(min(xa, pts[:, 0].min() - w * r / 2), max(xb, pts[:, 0].max() + w * r / 2))  # its whole path shows
    ax.set_ylim(min(ya, pts[:, 1].min() - l * r / 2), max(yb, pts[:, 1].max() + l * r / 2))
    ax.plot(pts[:, 0], pts[:, 1], "-", color=PATH_COLOUR, lw=path_width(len(pts)), label="coverage path")
    ax.plot(pts[0, 0], pts[0, 1], "o", color="#ffd700", mec="black", mew=1.2, ms=9, zorder=5, label="start")
    draw_morphology(ax, morphology, block_side_m, (x0 + col0 * r, y0 + row0 * r))


def plot_coverage(
    result: CoverageResult, grid_map: Map, morphology: Morphology, block_side_m: float, out: str | Path
) -> Path:
    """Paper Figures 4 and 6: the footprint beside the map with covered area, tiles and path."""
    fig, (ax_fp, ax_map) = plt.subplots(1, 2, figsize=(11, 5.2), gridspec_kw={"width_ratios": [1, 2]})
    plot_footprint(ax_fp, result, morphology, block_side_m, grid_map.resolution_m)
    draw_coverage(ax_map, result, grid_map, morphology, block_side_m)
    map_key(ax_map, covered=True)
    status = "" if result.feasible else "  (infeasible: blocks overlap)"
    ax_map.set_title(
        f"{grid_map.name}: P_c = {result.P_c:.2f} %, free covered = {result.coverage_free_pct:.2f} %, "
        f"P_len = {result.P_len} ({result.path_length_m:.1f} m){status}",
        fontsize=9,
    )
    return _save(fig, out)


def plot_top_morphologies(
    items: list[tuple[str, CoverageResult, Morphology]], grid_map: Map, block_side_m: float, out: str | Path
) -> Path:
    """Paper Figure 6: the best morphologies side by side, each with its coverage and path on the map."""
    n = max(1, len(items))
    cols = min(n, 4)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.4 * rows), squeeze=False)
    for ax in axes.flat[len(items) :]:
        ax.axis("off")
    for ax, (label, result, morphology) in zip(axes.flat, items, strict=False):
        draw_coverage(ax, result, grid_map, morphology, block_side_m, tiles=False)
        ax.set_title(f"{label}: {angles_text(result.theta)}\nP_c {result.P_c:.2f} %, P_len {result.P_len}", fontsize=9)
    fig.suptitle(f"Top morphologies on {grid_map.name}", fontsize=11)
    return _save(fig, out)


FEW_POINTS = 20
"""A curve of fewer points is drawn with a dot at each: a line through one point draws nothing."""


def plot_learning_curves(
    curves: dict[str, dict[str, list[float]]], out: str | Path, optimum_r1: float | None = None,
    title: str | None = None, kept_steps: float | None = None,
) -> Path:  # fmt: skip
    """Mean episode return, the iteration's best R1 and the greedy policy's settled R1 (the evaluation protocol;
    the stochastic final-shape R1 beside it) against env steps (paper Figure 5), under `title` (the run), the
    policy a run ends on marked at `kept_steps` where it is not the last.

    `curves[label]` has lists `env_steps`, `episode_return_mean`, `best_R1` and optionally `eval_R1`, `final_R1`."""
    panels = [("episode_return_mean", "mean episode return"), ("best_R1", "best R1 of the episodes in each iteration"),
              ("eval_R1", "greedy settled R1, mean over the fixed starts")]  # fmt: skip
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.4))
    for ax, (key, heading) in zip(axes, panels, strict=True):
        for label, c in curves.items():
            if key in c:
                x, y = np.asarray(c["env_steps"], dtype=float), np.asarray(c[key], dtype=float)
                ok = np.isfinite(y)
                dots = key == "eval_R1" or ok.sum() < FEW_POINTS  # a short run's one or two points show as dots
                (line,) = ax.plot(x[ok], y[ok], lw=1.4, marker="o" if dots else None, ms=3, label=label)
                final = np.asarray(c.get("final_R1", []), dtype=float) if key == "eval_R1" else np.zeros(0)
                seen = np.isfinite(final) if len(final) == len(x) else np.zeros(0, dtype=bool)
                if seen.any():  # no entry in the legend for a curve with nothing to draw
                    ax.plot(x[seen], final[seen], lw=0.8, alpha=0.4, color=line.get_color(),
                            marker="o" if seen.sum() < FEW_POINTS else None, ms=2,
                            label=f"{label}: stochastic final-shape R1")  # fmt: skip
        if optimum_r1 is not None and key != "episode_return_mean":
            ax.axhline(optimum_r1, color="black", ls="--", lw=1, label=f"optimum {optimum_r1:.2f}")
            ax.axhline(0.99 * optimum_r1, color="grey", ls=":", lw=1, label="99 % of optimum")
        if kept_steps is not None and key == "eval_R1":
            ax.axvline(kept_steps, color="#2ca02c", ls="-.", lw=1, label=f"policy kept ({kept_steps:,.0f} env steps)")
        ax.set_title(heading, fontsize=10)
        _steps_axis(ax)
        if ax.get_legend_handles_labels()[0]:  # a panel with nothing drawn (evaluation off) has no legend
            ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, out)


def _steps_axis(ax: plt.Axes) -> None:
    """Env steps in thousands, five ticks at most: 200,000-step runs' full numbers ran into one another."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1000:g}k"))
    ax.set_xlabel("env steps")
    ax.grid(alpha=0.3)


TRANSFER_COLOURS = {"fine-tune": "#1f77b4", "scratch": "#ff7f0e"}


def plot_transfer_curves(
    maps: dict[str, dict[str, list[tuple[list[float], list[float]]]]], out: str | Path, equal_steps: int = 0
) -> Path:
    """Table 5's curves: one panel per held-out map, the greedy median gap to the exact optimum against env steps,
    a thin line per seed coloured by mode (fine-tuned, from scratch), the table's comparison point dashed. One
    legend of the modes: a line per run in the legend (18 runs) covered the panels."""
    cols = max(1, min(3, len(maps)))
    rows = max(1, -(-len(maps) // cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.6 * rows), squeeze=False)
    for ax in axes.ravel()[len(maps) :]:
        ax.set_axis_off()
    for ax, (name, modes) in zip(axes.ravel(), maps.items(), strict=False):
        for mode, runs in modes.items():
            colour = TRANSFER_COLOURS.get(mode, "grey")
            for n, (steps, gaps) in enumerate(runs):
                x, y = np.asarray(steps, dtype=float), np.asarray(gaps, dtype=float)
                ok = np.isfinite(y)
                ax.plot(x[ok], y[ok], color=colour, lw=1.1, alpha=0.8, marker="o" if ok.sum() < FEW_POINTS else None,
                        ms=2.5, label=f"{mode} ({counted(len(runs), 'seed')})" if n == 0 else None)  # fmt: skip
        ax.axhline(0.0, color="black", lw=0.8)
        if equal_steps:
            ax.axvline(equal_steps, color="grey", ls="--", lw=0.9, label=f"compared at {equal_steps:,}")
        ax.set_title(name, fontsize=10)
        ax.set_ylabel("greedy median gap to R1* (R1)")
        _steps_axis(ax)
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=len(handles), fontsize=8,
                   frameon=False, title="fine-tuned against from scratch on each held-out map (a line per seed)",
                   title_fontsize=10)  # fmt: skip
    return _save(fig, out)


def plot_sweep_curves(
    groups: dict[str, dict[str, dict[str, Any]]], out: str | Path, optima: dict[str, float] | None = None
) -> Path:
    """A sweep's Figure 5: per map set (columns), mean episode return and the greedy settled R1 (rows) against env
    steps, one line per algorithm and hyperparameters: the mean over seeds, shaded over its 95 % bootstrap band; a
    map set's exact optimum (`optima`, by its label) and 99 % of it on the settled R1 (a plateau 7 R1 below the
    optimum read as converged)."""
    cols = max(1, len(groups))
    crowded = max((len(lines) for lines in groups.values()), default=0) > 6  # legend beside the plots
    panels = [("episode_return_mean", "mean episode return"),
              ("eval_R1", "greedy settled R1 (fixed starts; band: 95 % bootstrap over seeds)")]  # fmt: skip
    if any("design_gap_mean" in c for lines in groups.values() for c in lines.values()):
        panels.append(("design_gap", "designer's median gap on the evaluated maps (% of R1*)"))
    fig, axes = plt.subplots(len(panels), cols, figsize=(6 * cols + (5 if crowded else 0), 4 * len(panels)),
                             squeeze=False)  # fmt: skip
    if not groups:  # the curves are over finished trials only
        for ax in axes[:, 0]:
            ax.text(0.5, 0.5, "no finished trial yet\n(sweep.md lists the unfinished ones)", ha="center", va="center")
            ax.set_axis_off()
    for col, (maps, lines) in enumerate(groups.items()):
        for row, (key, title) in enumerate(panels):
            ax = axes[row][col]
            for label, c in lines.items():
                if f"{key}_mean" not in c:
                    continue
                dots = "o" if len(c["env_steps"]) < FEW_POINTS else None
                (drawn,) = ax.plot(c["env_steps"], c[f"{key}_mean"], lw=1.4, marker=dots, ms=3, label=label)
                ax.fill_between(c["env_steps"], c[f"{key}_lo"], c[f"{key}_hi"], color=drawn.get_color(), alpha=0.15)
            if key == "eval_R1" and optima and maps in optima:
                ax.axhline(optima[maps], color="black", ls="--", lw=1, label=f"optimum {optima[maps]:.2f}")
                ax.axhline(0.99 * optima[maps], color="grey", ls=":", lw=1, label="99 % of optimum")
            ax.set_title(f"{maps}: {title}", fontsize=10)
            _steps_axis(ax)
            if not ax.get_legend_handles_labels()[0]:
                continue
            if crowded:
                ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
            else:
                ax.legend(fontsize=7)
    return _save(fig, out)


def _draw_replay_frame(ax: plt.Axes, grid_map: Map, frame: dict[str, Any], title: str) -> None:
    """One recorded step: the map (with the area its morphology covers, where the frame has it), the coverage path
    of the step's morphology, its four blocks at the path start."""
    ax.clear()
    draw_map(ax, grid_map, frame.get("covered"))
    path = frame["path"]
    if len(path):
        ax.plot(path[:, 0], path[:, 1], "-", color=PATH_COLOUR, lw=1.3)
    for n, ((x, y, yaw, side), colour) in enumerate(zip(frame["blocks"], BLOCK_COLOURS, strict=True)):
        c, s = np.cos(yaw), np.sin(yaw)
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * side / 2
        pts = local @ np.array([[c, s], [-s, c]]) + [x, y]
        ax.add_patch(Polygon(pts, closed=True, facecolor=colour, edgecolor="black", alpha=0.8, lw=1))
        ax.text(x, y, f"B{n + 1}", ha="center", va="center", fontsize=6, color="white", weight="bold")
    ax.set_title(title, fontsize=9)


def plot_replay(grid_map: Map, frames: list[dict[str, Any]], titles: list[str], out: str | Path) -> Path:
    """Recorded steps side by side (the paper's Figure 6 for one episode): map, covered area, path and blocks of
    each, their colours named below."""
    fig, axes = plt.subplots(1, len(frames), figsize=(5.2 * len(frames), 5.2), squeeze=False)
    for ax, frame, title in zip(axes[0], frames, titles, strict=True):
        _draw_replay_frame(ax, grid_map, frame, title)
        map_key(ax, covered=frame.get("covered") is not None)
    return _save(fig, out)


def animate_replay(grid_map: Map, frames: list[dict[str, Any]], titles: list[str], out: str | Path,
                   fps: int = 6, progress: Callable[[int, int], None] | None = None) -> Path:  # fmt: skip
    """A GIF of the morphology changing over the episode, one recorded step a frame; `progress(done, total)` after
    each frame drawn (a long episode's GIF takes a while)."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    fig, ax = plt.subplots(figsize=(5.6, 5.6))
    fig.tight_layout()
    anim = FuncAnimation(fig, lambda i: _draw_replay_frame(ax, grid_map, frames[i], titles[i]), frames=len(frames))
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(path) as tmp:  # a full disk leaves the old file or none, never half a GIF
            drawn = None if progress is None else (lambda i, n: progress(i + 1, n))
            anim.save(str(tmp), writer=PillowWriter(fps=fps), dpi=90, progress_callback=drawn)
    except Exception as exc:  # a stop before the first frame: the writer's finish fails on no frames (IndexError)
        if isinstance(exc.__context__, KeyboardInterrupt):
            raise KeyboardInterrupt from None
        raise
    finally:
        plt.close(fig)
    return path


def plot_planners(
    rows: list[tuple[Map, Morphology, list[CoverageResult]]], block_side_m: float, out: str | Path
) -> Path:
    """One row per map, one column per planner: the same shape's covered area and path (README figure)."""
    n_cols = max(len(results) for _, _, results in rows)
    fig, axes = plt.subplots(len(rows), n_cols, figsize=(5.2 * n_cols, 5.0 * len(rows)), squeeze=False)
    for (grid_map, morphology, results), ax_row in zip(rows, axes, strict=True):
        for result, ax in zip(results, ax_row, strict=False):
            draw_coverage(ax, result, grid_map, morphology, block_side_m, tiles=False)
            title = f"{grid_map.name}, {angles_text(morphology.angles)}, planner {result.planner}"
            ax.set_title(f"{title}\nfree covered {result.coverage_free_pct:.1f} %, P_len {result.P_len}", fontsize=9)
    return _save(fig, out)


def plot_map_grid(maps: list[Map], titles: list[str], cols: int, out: str | Path) -> Path:
    """Several maps in a grid of `cols` columns, each with its title (docs/floors.png)."""
    rows = -(-len(maps) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.2 * rows), squeeze=False)
    for ax, grid_map, title in zip(axes.flat, maps, titles, strict=False):
        draw_map(ax, grid_map)
        ax.set_title(title, fontsize=8)
    for ax in list(axes.flat)[len(maps) :]:
        ax.axis("off")
    return _save(fig, out)


def map_key(ax: plt.Axes, covered: bool = False) -> None:
    """A legend below the axes naming the map's colours (and the lines drawn on it): what was grey or white, and
    over the map, hiding cells."""
    from matplotlib.patches import Patch
    from matplotlib.transforms import ScaledTranslation

    free, occupied, unknown, covered_colour = CELL_COLOURS
    names = [("covered", covered_colour)] if covered else []
    names += [("free, not covered" if covered else "free", free), ("occupied", occupied), ("unknown", unknown)]
    handles, labels = ax.get_legend_handles_labels()
    handles += [Patch(facecolor=c, edgecolor="#555555", lw=0.6) for _, c in names]
    labels += [n for n, _ in names]
    below = ax.transAxes + ScaledTranslation(0, -0.5, ax.figure.dpi_scale_trans)  # under the x label, any height
    ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=below,
              ncol=min(len(labels), 6), fontsize=8, frameon=False)  # fmt: skip


def plot_map(grid_map: Map, out: str | Path) -> Path:
    """The map alone, zoomed to its known cells: its grid, the known area's size and its share of free floor in the
    title (the grid's size and occupied share included the unknown margin drawn only in part)."""
    fig, ax = plt.subplots(figsize=(6, 6.4))
    draw_map(ax, grid_map)
    x0, x1, y0, y1 = known_extent(grid_map, margin_m=0.0)
    free, occupied = grid_map.counts[Cell.FREE], grid_map.counts[Cell.OCCUPIED]
    ax.set_title(f"{grid_map.name}: {grid_map.width} × {grid_map.height} cells at {grid_map.resolution_m:g} m\n"
                 f"known area {x1 - x0:.1f} × {y1 - y0:.1f} m, {100 * free / max(free + occupied, 1):.1f} % of it "
                 "free", fontsize=9)  # fmt: skip
    map_key(ax)
    return _save(fig, out)


def _save(fig: plt.Figure, out: str | Path) -> Path:
    """Lay out, write the PNG (making its folder) and free the figure."""
    fig.tight_layout()
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(path) as tmp:  # a full disk leaves the old file or none, never half a PNG
            fig.savefig(tmp, dpi=120, format="png", bbox_inches="tight")  # equal-aspect panels: labels kept whole
    finally:
        plt.close(fig)
    return path


BEST_MARKERS = (("*", 170), ("P", 110), ("X", 110), ("D", 70), ("^", 90), ("v", 90), ("s", 70), ("p", 100))
"""Each method's best-R1 marker and size; earlier methods' drawn larger, so where they coincide all show."""


def plot_pareto(
    methods: dict[str, tuple[np.ndarray, np.ndarray]],
    out: str | Path,
    title: str,
    front: tuple[np.ndarray, np.ndarray] | None = None,
    best: dict[str, tuple[float, float]] | None = None,
) -> Path:
    """P_c against P_len (paper Figure 7): each method's non-dominated points, the exact front as a
    step line, and each method's best-R1 shape as a star."""
    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    if front is not None:
        ax.step(front[0], front[1], where="post", color="black", lw=1.2, label="exact front", zorder=1)
    for n, (label, (p_len, p_c)) in enumerate(methods.items()):
        colour = f"C{n}"
        ax.scatter(p_len, p_c, s=22, color=colour, alpha=0.85, label=label, zorder=2)
        if best and label in best:  # a marker of its own each: methods' bests often fall on one shape
            marker, size = BEST_MARKERS[n % len(BEST_MARKERS)]
            ax.scatter(*best[label], s=size + 60 * (len(best) - n - 1), marker=marker, facecolor=colour,
                       edgecolor="black", alpha=0.9, zorder=3 + n, label=f"{label}: best R1")  # fmt: skip
    ax.set_xlabel("P_len (tile moves)")
    ax.set_ylabel("P_c (%)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right", ncol=2 if best and len(methods) > 2 else 1, markerscale=0.7)
    return _save(fig, out)


def plot_gap_curves(curves: dict[str, list[tuple[list[float], list[float]]]], out: str | Path) -> Path:
    """The greedy policy's median gap to the exact optimum against env steps: per label the mean over seeds
    on a common grid, shaded over its 95 % bootstrap band."""
    from smorphi_rl.stats import band

    fig, ax = plt.subplots(figsize=(9, 5))
    for label, runs in curves.items():
        end = min(max(x) for x, _ in runs if x)
        grid = np.linspace(0, end, 60)
        ys = np.array([np.interp(grid, x, y, left=np.nan) for x, y in runs if x])
        mean, lo, hi = band(ys)
        (line,) = ax.plot(grid, mean, lw=1.5, label=f"{label} ({counted(len(runs), 'seed')})")
        ax.fill_between(grid, lo, hi, color=line.get_color(), alpha=0.15)
    ax.axhline(0, color="black", lw=0.8)
    ax.set_xlabel("env steps")
    ax.set_ylabel("median gap to the exact optimum (R1 points)")
    ax.set_title("Greedy settled gap from 20 fixed starts (mean over seeds, 95 % bootstrap band)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, out)

"""Figures that summarise seeds: they are written and shade the interval of the mean."""

import os
import subprocess
import sys

import numpy as np
import pytest

from smorphi_rl.plots import plot_gap_curves


@pytest.fixture
def saved(monkeypatch):
    """The figures the plots write, kept open for a test to read, each still written to its file."""
    from smorphi_rl import plots

    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, out: (figures.append(fig), real_save(fig, out))[1])
    return figures


def test_gap_curves_are_written_for_several_seeds_and_for_one(tmp_path, monkeypatch):
    """Each label's mean over seeds, shaded by a band that holds it; one seed's band is its own line."""
    from smorphi_rl import plots

    runs = [([0.0, 10.0, 20.0], [4.0, 3.0, 2.0]), ([0.0, 10.0, 20.0], [5.0, 3.0, 1.0]), ([0.0, 10.0], [4.0, 2.0])]
    out = plot_gap_curves({"PPO level": runs, "one seed": runs[:1]}, tmp_path / "gaps.png")
    assert out.is_file() and out.stat().st_size > 5_000
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, out: figures.append(fig) or out)
    plot_gap_curves({"PPO level": runs, "one seed": runs[:1]}, tmp_path / "again.png")
    (ax,) = figures[0].axes
    lines = {line.get_label(): line for line in ax.lines if not line.get_label().startswith("_")}
    assert set(lines) == {"PPO level (3 seeds)", "one seed (1 seed)"}
    bands = ax.collections
    assert len(bands) == 2
    for band, line in zip(bands, lines.values(), strict=True):
        ys = band.get_paths()[0].vertices[:, 1]
        mean = np.asarray(line.get_ydata(), float)
        assert np.nanmin(ys) <= np.nanmin(mean) and np.nanmax(ys) >= np.nanmax(mean)
    several = bands[0].get_paths()[0].vertices[:, 1]
    assert np.ptp(several) > np.ptp(np.asarray(lines["PPO level (3 seeds)"].get_ydata(), float))  # a band, not a line


def test_a_sweep_without_a_finished_trial_draws_a_figure_that_says_so(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from smorphi_rl.plots import plot_sweep_curves

    texts: list[str] = []
    original = plt.Axes.text
    monkeypatch.setattr(plt.Axes, "text", lambda self, x, y, s, **kw: texts.append(s) or original(self, x, y, s, **kw))
    out = plot_sweep_curves({}, tmp_path / "sweep_curves.png")
    assert out.is_file() and texts and all("no finished trial yet" in t for t in texts)


def test_a_name_with_dollar_signs_is_drawn_as_text_not_tex(tmp_path):
    """A map file `map_$1_$2.yaml` once raised matplotlib's mathtext error in every command that draws."""
    import numpy as np

    from smorphi_rl.maps import Map
    from smorphi_rl.plots import plot_map

    grid = Map(np.zeros((20, 20), dtype=np.uint8), 0.1, name="map_$1_$2")
    assert plot_map(grid, tmp_path / "m.png").stat().st_size > 0


def test_a_run_of_one_or_two_reports_draws_its_points(tmp_path, monkeypatch):
    """A transfer at a small budget drew two of its three panels empty: a line through one point draws nothing."""
    from smorphi_rl import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, out: figures.append(fig) or out)
    curves = {"fine-tuned": {"env_steps": [2000.0], "episode_return_mean": [1.0], "best_R1": [80.0]}}
    plots.plot_learning_curves(curves, tmp_path / "curves.png")
    sweep = {"map-1": {"ppo": {"env_steps": [2000.0], "episode_return_mean_mean": [1.0], "episode_return_mean_lo":
                               [0.5], "episode_return_mean_hi": [1.5]}}}  # fmt: skip
    plots.plot_sweep_curves(sweep, tmp_path / "sweep.png")
    drawn = [line for fig in figures for ax in fig.axes for line in ax.lines]
    lines = [line for line in drawn if line.get_label() in ("fine-tuned", "ppo")]
    assert len(lines) == 3 and all(line.get_marker() == "o" for line in lines)


def test_a_curve_with_nothing_to_draw_has_no_legend_entry(tmp_path, monkeypatch):
    """A short run on a real floor listed "PPO: stochastic final-shape R1" in the legend with no such line drawn."""
    from smorphi_rl import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, out: figures.append(fig) or out)
    steps = [2000.0, 4000.0, 6000.0]
    curve = {"env_steps": steps, "episode_return_mean": [1.0] * 3, "best_R1": [80.0] * 3, "eval_R1": [81.0] * 3}
    plots.plot_learning_curves({"PPO": curve | {"final_R1": [float("nan")] * 3}}, tmp_path / "a.png")
    plots.plot_learning_curves({"PPO": curve | {"final_R1": [79.0, float("nan"), 80.0]}}, tmp_path / "b.png")
    labels = [[t.get_text() for t in fig.axes[2].get_legend().get_texts()] for fig in figures]
    assert labels == [["PPO"], ["PPO", "PPO: stochastic final-shape R1"]]


def test_a_gif_stopped_before_its_first_frame_is_a_stop_not_a_writer_error(tmp_path, monkeypatch):
    """The GIF writer's finish read its first frame, which a stop had prevented: an IndexError hid the Ctrl-C."""
    import pytest

    from smorphi_rl import plots
    from smorphi_rl.maps import Map

    def stopped(*args, **kwargs):  # the Ctrl-C lands as the first frame is drawn
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "_draw_replay_frame", stopped)
    grid = Map(np.zeros((20, 20), dtype=np.uint8), 0.1, name="room")
    with pytest.raises(KeyboardInterrupt):
        plots.animate_replay(grid, [{}, {}], ["a", "b"], tmp_path / "r.gif")
    assert not list(tmp_path.iterdir())  # no GIF, and no temporary left


def test_matplotlib_keeps_one_folder_of_its_own_where_it_cannot_write_in_home(tmp_path):
    """With HOME unwritable (a container run as another user) matplotlib made a fresh temp folder each run, built
    its font cache there again and printed two lines about it amid a command's output."""
    home = tmp_path / "home-is-a-file"
    home.write_text("")
    env = {k: v for k, v in os.environ.items() if k not in ("MPLCONFIGDIR", "XDG_CONFIG_HOME", "XDG_CACHE_HOME")}
    env |= {"HOME": str(home), "TMPDIR": str(tmp_path)}
    code = "import os, smorphi_rl.plots, matplotlib; print(matplotlib.get_cachedir())"
    for _ in range(2):  # the second run finds the first's folder
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=tmp_path)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr
        assert proc.stdout.strip() == str(tmp_path / f"smorphi-rl-matplotlib-{os.getuid()}")
    env["MPLCONFIGDIR"] = str(tmp_path / "mine")  # the user's choice stands
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=tmp_path)
    assert proc.stdout.strip() == str(tmp_path / "mine")


def test_transfer_curves_take_a_panel_a_map_and_a_legend_entry_a_mode(tmp_path, saved):
    """With 18 runs in one figure the legend (a line per run) covered the panels and colours repeated."""
    import matplotlib.pyplot as plt

    from smorphi_rl import plots

    runs = [([10_000.0, 20_000.0, 30_000.0], [5.0, 2.0, float("nan")])] * 3
    maps = {f"m{k}": {"fine-tune": runs, "scratch": runs} for k in range(4)}
    out = plots.plot_transfer_curves(maps, tmp_path / "t.png", 20_000)
    assert out.stat().st_size > 10_000
    (fig,) = saved
    drawn = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    assert [ax.get_title() for ax in drawn] == ["m0", "m1", "m2", "m3"]
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["fine-tune (3 seeds)", "scratch (3 seeds)",
                                                          "compared at 20,000"]  # fmt: skip
    plt.close(fig)


def test_each_methods_best_shape_shows_and_is_named_where_they_coincide(tmp_path, saved):
    """compare.png drew every method's best as a star of its colour: on one shape only the last showed, unnamed."""
    from smorphi_rl import plots

    points = (np.array([60.0, 69.0]), np.array([95.0, 97.3]))
    methods = {"PPO": points, "NSGA-II": points, "random": points}
    plots.plot_pareto(methods, tmp_path / "p.png", "t", front=points, best=dict.fromkeys(methods, (69.0, 97.3)))
    (ax,) = saved[0].axes
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"PPO: best R1", "NSGA-II: best R1", "random: best R1"} <= set(labels)
    bests = [c for c in ax.collections if c.get_label().endswith(": best R1")]
    assert len({c.get_paths()[0].vertices.tobytes() for c in bests}) == 3  # a marker shape each
    assert sorted(c.get_sizes()[0] for c in bests) == sorted({c.get_sizes()[0] for c in bests})  # no two one size


def test_a_coverage_plot_shows_the_whole_path_where_the_robot_stands_past_the_maps_edge(tmp_path, saved):
    """The paper's planner lets tiles overhang the map: on map-1 (95, 59, 103) 13 of 91 path points lay at y 5.2
    of a 5 m map, cut off by axes that stopped at its edge."""
    from pathlib import Path

    from smorphi_rl import plots
    from smorphi_rl.coverage import path_points_m
    from smorphi_rl.geometry import Morphology
    from smorphi_rl.maps import load_map
    from smorphi_rl.planning import Evaluator

    grid = load_map(Path(__file__).resolve().parents[1] / "maps" / "map-1.yaml")
    shape = Morphology.of((95, 59, 103))
    result = Evaluator(grid).plan(shape)
    plots.plot_coverage(result, grid, shape, 0.17, tmp_path / "e.png")
    pts = path_points_m(result, grid)
    assert pts[:, 1].max() > grid.origin[1] + grid.height * grid.resolution_m  # past the edge: the case at hand
    ax = saved[0].axes[1]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x0 <= pts[:, 0].min() and pts[:, 0].max() <= x1 and y0 <= pts[:, 1].min() and pts[:, 1].max() <= y1


def test_learning_curves_name_their_run_and_mark_the_policy_it_keeps(tmp_path, saved):
    """The figure had no title (which map, algorithm, seed?) and its last point read as the result, though the run
    keeps an earlier policy."""
    from smorphi_rl import plots

    curve = {"env_steps": [1e4, 2e4, 3e4], "episode_return_mean": [1.0, 2.0, 3.0], "best_R1": [80.0, 85.0, 90.0],
             "eval_R1": [84.0, 90.1, 88.0]}  # fmt: skip
    plots.plot_learning_curves({"PPO": curve}, tmp_path / "c.png", 90.4, "PPO on map-1, seed 0: run", 20_000)
    fig = saved[0]
    assert fig.get_suptitle() == "PPO on map-1, seed 0: run"
    labels = [t.get_text() for t in fig.axes[2].get_legend().get_texts()]
    assert "policy kept (20,000 env steps)" in labels


def test_sweep_curves_draw_each_single_maps_optimum_under_its_settled_r1(tmp_path, saved):
    """Without it a plateau 7 R1 below the optimum read as converged (sweep_groups.md: 0 of 2 converged)."""
    from smorphi_rl import plots

    steps = np.array([1e4, 2e4])
    line = {"env_steps": steps} | {f"{k}_{s}": np.array([80.0, 83.5]) for k in ("episode_return_mean", "eval_R1")
                                   for s in ("mean", "lo", "hi")}  # fmt: skip
    plots.plot_sweep_curves({"map-1": {"PPO": line}, "map-1+map-2": {"PPO": line}}, tmp_path / "s.png",
                            {"map-1": 90.42})  # fmt: skip
    legends = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in saved[0].axes[2:]]
    assert "optimum 90.42" in legends[0] and not any("optimum" in t for t in legends[1])  # a set has no one optimum


def test_a_maps_figure_sizes_its_known_area_and_names_its_colours(tmp_path, saved):
    """The title gave the grid's size and occupied share, the unknown margin included, though the figure shows the
    known area; nothing said what grey and white were."""
    from smorphi_rl import plots
    from smorphi_rl.maps import Cell, Map

    cells = np.full((40, 60), Cell.UNKNOWN, dtype=np.uint8)
    cells[10:20, 10:30] = Cell.FREE  # a 2 x 1 m known area, one cell in ten of it occupied
    cells[10, 10:30] = Cell.OCCUPIED
    plots.plot_map(Map(cells, 0.1, name="margin"), tmp_path / "m.png")
    (ax,) = saved[0].axes
    assert ax.get_title() == "margin: 60 × 40 cells at 0.1 m\nknown area 2.0 × 1.0 m, 90.0 % of it free"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["free", "occupied", "unknown"]

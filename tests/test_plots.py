"""Figures that summarise seeds: they are written and shade the interval of the mean."""

from smorphi_rl.plots import plot_gap_curves


def test_gap_curves_are_written_for_several_seeds_and_for_one(tmp_path):
    runs = [([0.0, 10.0, 20.0], [4.0, 3.0, 2.0]), ([0.0, 10.0, 20.0], [5.0, 3.0, 1.0]), ([0.0, 10.0], [4.0, 2.0])]
    out = plot_gap_curves({"PPO level": runs, "one seed": runs[:1]}, tmp_path / "gaps.png")
    assert out.is_file() and out.stat().st_size > 5_000


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

"""`training/run.py` without a run: the end-of-run text names every file a run wrote."""

from __future__ import annotations

from pathlib import Path

from smorphi_rl.training.run import RunSummary, format_summary


def test_the_summary_names_the_top_plot_of_every_map(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run = Path("logs") / "two-maps"
    files = {"top_md": run / "top_morphologies.md", "curves_png": run / "learning_curves.png"}
    files |= {f"top_png_{m}": run / f"top_morphologies_{m}.png" for m in ("map-1", "map-2")}
    summary = RunSummary(run, "ppo", 2000, 1, 8.0, False, None, {}, None, files)
    text = format_summary(summary)
    assert "top morphologies plot (map-1): logs/two-maps/top_morphologies_map-1.png" in text
    assert "top morphologies plot (map-2): logs/two-maps/top_morphologies_map-2.png" in text
    assert "learning curves: logs/two-maps/learning_curves.png" in text and "logs: logs/two-maps" in text

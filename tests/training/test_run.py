"""`training/run.py` without a run: the end-of-run text names every file a run wrote; the optima are checked first."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from smorphi_rl.env_config import EnvConfig
from smorphi_rl.errors import SmorphiError
from smorphi_rl.protocol import CACHE_ENV
from smorphi_rl.training.config import TrainConfig
from smorphi_rl.training.run import RunSummary, format_summary, training_optima


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


@pytest.mark.parametrize(
    ("steps", "budget", "said"),
    [
        (2000, 1, "(1 iteration, the last ending past the 1 asked)"),  # `--timesteps 1` trains a whole iteration
        (201_334, 200_000, "(50 iterations, the last ending past the 200,000 asked)"),
        (200_000, 200_000, "(50 iterations)"),
    ],
)
def test_the_summary_says_when_whole_iterations_ran_past_the_budget(steps, budget, said):
    iterations = 1 if steps == 2000 else 50
    summary = RunSummary(Path("r"), "ppo", steps, iterations, 8.0, False, None, {}, None, {}, budget=budget)
    assert format_summary(summary).splitlines()[0] == f"PPO trained for {steps:,} env steps in 8s {said}"


def test_the_summary_says_a_run_trained_on_a_cluster():
    """`search` said "on the Ray cluster at ..."; `train` never did, though its results came from there."""
    on = RunSummary(Path("r"), "ppo", 2000, 1, 8.0, False, None, {}, None, {}, address="127.0.0.1:6379")
    assert format_summary(on).splitlines()[0].endswith("(1 iteration) on the Ray cluster at 127.0.0.1:6379")
    assert json.loads(on.to_json())["address"] == "127.0.0.1:6379"
    here = RunSummary(Path("r"), "ppo", 2000, 1, 8.0, False, None, {}, None, {})
    assert "cluster" not in format_summary(here)


def test_an_optimum_cache_that_cannot_be_made_is_named_before_any_optimum_line(tmp_path, monkeypatch):
    """`sweep --log-dir` under a file printed "exact optimum of map-1 ..." and then the refusal: two lines."""
    monkeypatch.delenv(CACHE_ENV, raising=False)
    (tmp_path / "a-file").write_text("not a folder")
    cfg = TrainConfig(env=EnvConfig.from_dict({"maps": [str(Path(__file__).parents[2] / "maps" / "map-1.yaml")]}))
    out = io.StringIO()
    with pytest.raises(SmorphiError, match="cannot cache exact optima"):
        training_optima(cfg, tmp_path / "a-file" / "logs", out)
    assert out.getvalue() == ""


def test_a_run_that_finished_no_episode_says_so_and_still_names_the_optimum():
    """A budget shorter than an episode finishes none: the summary went from the step count to the policy."""
    from smorphi_rl.protocol import Optimum

    optimum = {"tb3_world": Optimum((85.0, 50.0, 12.0), 89.9, 97.0, 71)}
    summary = RunSummary(Path("r"), "ppo", 4000, 2, 15.0, False, None, optimum, None, {}, budget=4000)
    lines = format_summary(summary).splitlines()
    assert lines[1] == "best morphology: none (no episode finished within 4,000 env steps: raise --timesteps)"
    assert lines[2] == "exact optimum of tb3_world on the 1-degree lattice: (85, 50, 12) R1 89.90"
    stopped = RunSummary(Path("r"), "ppo", 2000, 1, 15.0, True, None, optimum, None, {}, budget=200_000)
    assert (
        format_summary(stopped).splitlines()[1] == "best morphology: none (the run stopped before any episode finished)"
    )


def test_the_progress_line_shows_the_policy_of_its_step_not_the_one_the_run_keeps():
    """The last row reports the kept policy (an earlier one) and, under `trained`, the policy of the budget's
    step: the bar beside that step count shows the latter (a walk-through read 4.83 from 2,000 steps at 20,000)."""
    from smorphi_rl.protocol import EVAL_KEY, TRAINED_KEY
    from smorphi_rl.training.result_keys import STEPS
    from smorphi_rl.training.run import _Progress

    out = io.StringIO()
    progress = _Progress(TrainConfig(timesteps=20_000), out)
    kept = {"median_gap": 4.83, "share_within_1pct": 0.0, "policy_env_steps": 2_000}
    trained = {"median_gap": 18.99, "share_within_1pct": 0.05, "settled_R1_mean": 70.0}
    progress.on_result({STEPS: 2_000, EVAL_KEY: dict(kept)})
    progress.on_result({STEPS: 20_000, EVAL_KEY: kept | {TRAINED_KEY: trained}})
    first, last = out.getvalue().splitlines()
    assert "2,000/20,000" in first and "greedy: gap 4.83, 0 % within 1 %" in first
    assert "20,000/20,000" in last and "greedy: gap 18.99, 5 % within 1 %" in last
    assert progress.last_eval["median_gap"] == 4.83  # the summary still reads the kept policy


def test_an_optimum_in_the_cache_is_said_to_be_read_not_searched(tmp_path, monkeypatch):
    """Each of a transfer's runs said "exact optimum of val-1 (every 1-degree shape; ...)", searched once."""
    monkeypatch.delenv(CACHE_ENV, raising=False)
    cfg = TrainConfig(env=EnvConfig(maps=(str(Path(__file__).resolve().parents[2] / "maps" / "map-1.yaml"),)))
    first, again = io.StringIO(), io.StringIO()
    found = training_optima(cfg, tmp_path, first)
    assert "exact optimum of map-1 (every 1-degree shape; cached under" in first.getvalue()
    assert training_optima(cfg, tmp_path, again) == found
    assert again.getvalue() == f"exact optimum of map-1: read from {tmp_path / '.cache'}\n"


def test_a_terminal_sees_the_run_starting_before_its_first_bar():
    """On a floor of millions of cells the first bar came after 52 s of nothing: it read as a hang."""
    import io

    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.run import _Progress

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    for out, shown in ((Terminal(), True), (io.StringIO(), False)):  # a log file gets the bars alone
        _Progress(TrainConfig(timesteps=4000), out).starting()
        said = out.getvalue()
        assert said.startswith("\rPPO starting: the trial, 2 env runners, their floors") if shown else said == ""


def test_a_training_map_left_out_of_the_evaluation_still_has_its_warnings_said(tmp_path):
    """Only the evaluated maps' warnings were said: a training map outside --eval-maps read unknown space as free
    floor in silence."""
    import numpy as np
    import yaml
    from PIL import Image

    pixels = np.full((60, 60), 254, dtype=np.uint8)
    pixels[:8] = 205  # map_saver's unknown, read as free under free_thresh 0.25
    pixels[[8, -1], :] = pixels[:, [0, -1]] = 0
    Image.fromarray(pixels).save(tmp_path / "grey.pgm")
    meta = {"image": "grey.pgm", "resolution": 0.1, "origin": [0, 0, 0], "negate": 0, "occupied_thresh": 0.65,
            "free_thresh": 0.25}  # fmt: skip
    (tmp_path / "grey.yaml").write_text(yaml.safe_dump(meta))
    map_1 = str(Path(__file__).resolve().parents[2] / "maps" / "map-1.yaml")
    cfg = TrainConfig(env=EnvConfig(maps=(str(tmp_path / "grey.yaml"), map_1)), eval_maps=(map_1,))
    out = io.StringIO()
    training_optima(cfg, tmp_path / "logs", out)
    assert "grey: 464 cells of grey 205, which map_saver writes for unknown space" in out.getvalue()

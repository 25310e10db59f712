"""Our TensorBoard logger writes what Tune's writes: the same scalar tags, steps and values, histograms too."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from ray.tune.logger.tensorboardx import TBXLoggerCallback
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from smorphi_rl.training.tensorboard import TensorBoardLogger


class _Trial:
    """What Tune's logger reads off a trial."""

    def __init__(self, path: Path) -> None:
        self.local_path = str(path)
        self.evaluated_params: dict[str, Any] = {"lr": 0.001}
        self.trial_id = "t0"

    def init_local_path(self) -> None:
        Path(self.local_path).mkdir(parents=True, exist_ok=True)


def _results() -> list[dict[str, Any]]:
    return [
        {
            "training_iteration": i,
            "timestamp": 1.0,
            "time_total_s": 2.0 * i,
            "config": {"lr": 0.001},
            "env_runners": {"episode_return_mean": 0.5 * i, "num_episodes": np.int64(3 + i), "nan": float("nan")},
            "learners": {"default_policy": {"entropy": np.float32(1.0 / i), "flag": True}},
            "returns": [1.0, 2.0, float(i)],
            "label": "text, skipped",
        }
        for i in (1, 2, 3)
    ]


def _written(callback: TBXLoggerCallback, path: Path) -> EventAccumulator:
    trial = _Trial(path)
    for i, result in enumerate(_results(), start=1):
        callback.log_trial_result(i, trial, result)
    callback.log_trial_end(trial, failed=False)
    acc = EventAccumulator(str(path), size_guidance={"scalars": 0, "histograms": 0})
    acc.Reload()
    return acc


def test_one_event_per_result_holds_what_tunes_logger_writes(tmp_path):
    tune, ours = _written(TBXLoggerCallback(), tmp_path / "tune"), _written(TensorBoardLogger(), tmp_path / "ours")
    tags = tune.Tags()["scalars"]
    assert sorted(tags) == sorted(ours.Tags()["scalars"])
    assert "ray/tune/env_runners/episode_return_mean" in tags and "ray/tune/env_runners/nan" not in tags
    for tag in tags:
        assert [(e.step, e.value) for e in tune.Scalars(tag)] == [(e.step, e.value) for e in ours.Scalars(tag)]
    assert tune.Tags()["histograms"] == ours.Tags()["histograms"] == ["ray/tune/returns"]
    steps = [[e.step for e in acc.Histograms("ray/tune/returns")] for acc in (tune, ours)]
    assert steps[0] == steps[1] == [1, 2, 3]


def test_the_eval_series_follow_the_trained_policy_to_their_last_point():
    """A run's last result reports the policy it ends on (2,000 steps old) under eval/: the curve of a run at gap
    7.74 dropped to 6.54 at its last point, a false improvement."""
    from smorphi_rl.training.tensorboard import split_scalars

    row = {"timesteps_total": 12_000, "training_iteration": 6, "eval": {
        "median_gap": 6.54, "policy_env_steps": 2_000, "map-2": {"median_gap": 6.54},
        "trained": {"median_gap": 7.74, "share_within_1pct": 0.0}}}  # fmt: skip
    scalars, _ = split_scalars(row)
    assert scalars["ray/tune/eval/median_gap"] == 7.74 and scalars["ray/tune/eval/share_within_1pct"] == 0.0
    assert scalars["ray/tune/eval/kept/median_gap"] == 6.54 and scalars["ray/tune/eval/kept/map-2/median_gap"] == 6.54
    assert "ray/tune/eval/map-2/median_gap" not in scalars and not any("trained" in tag for tag in scalars)
    plain = {"timesteps_total": 2_000, "training_iteration": 1, "eval": {"median_gap": 6.54}}
    assert split_scalars(plain)[0]["ray/tune/eval/median_gap"] == 6.54  # every other row as it was


def test_a_resumed_runs_results_are_filed_under_the_algorithms_own_iteration():
    """A resumed run's Tune counts its iterations from 1 again: TensorBoard drew its curves back to the start."""
    from smorphi_rl.training import result_keys as keys
    from smorphi_rl.training.tensorboard import step_of

    assert step_of({"training_iteration": 1, keys.ALGO_ITERATION: 16}) == 16
    assert step_of({"training_iteration": 3}) == 3  # a result of Tune's alone

"""Tune's TensorBoard logger, writing each result's scalars as one event instead of one event per scalar.

Tune's `TBXLoggerCallback` calls tensorboardX's `add_scalar` once per scalar: about 70 us each, 9 ms for the
125 scalars of one of our results, and the trial waits that long for its next `train` call (Tune processes a
result before it asks for the next). One event whose summary holds every value is what TensorFlow's own
writers emit: TensorBoard reads the same tags, steps and values. Lists and arrays (histograms, images) and the
hyperparameters at the end are still Tune's. One change of view: `eval/...` follow the trained policy to the last
point, where the policy the run ends on is `eval/kept/...` (`trained_series`).
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

from ray.air.constants import TRAINING_ITERATION
from ray.tune.logger.tensorboardx import VALID_SUMMARY_TYPES, TBXLoggerCallback
from ray.tune.result import TIME_TOTAL_S, TIMESTEPS_TOTAL
from ray.tune.utils import flatten_dict

from smorphi_rl import rllib_compat
from smorphi_rl.protocol import EVAL_KEY, TRAINED_KEY
from smorphi_rl.training import result_keys as keys

NOT_LOGGED = ("config", "pid", "timestamp", TIME_TOTAL_S, TRAINING_ITERATION)
"""Result keys Tune's logger leaves out of TensorBoard (as it does)."""
PREFIX = "ray/tune/"
"""Tune's prefix of every tag."""


def trained_series(flat: dict[str, Any]) -> dict[str, Any]:
    """`eval/...` as the policy of each point's env steps throughout: a run's last result reports the policy it ends
    on (an earlier one it evaluated better) under `eval/...` and the trained one under `eval/trained/...`, and the
    curves would jump to the earlier policy at their last point. There the trained figures take `eval/...`, and the
    kept policy's move to `eval/kept/...`."""
    trained = f"{EVAL_KEY}/{TRAINED_KEY}/"
    if not any(k.startswith(trained) for k in flat):
        return flat
    view = {k: v for k, v in flat.items() if not k.startswith(f"{EVAL_KEY}/")}
    for key, value in flat.items():
        if key.startswith(trained):
            view[f"{EVAL_KEY}/{key.removeprefix(trained)}"] = value
        elif key.startswith(f"{EVAL_KEY}/"):
            view[f"{EVAL_KEY}/kept/{key.removeprefix(f'{EVAL_KEY}/')}"] = value
    return view


def split_scalars(result: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the TensorBoard scalars of a result, by tag, as Tune's logger picks them, `eval/...` always the trained
    policy's (`trained_series`); the rest of the result, flat, with its step as the iteration, so that Tune's logger
    writes the rest at the same step)."""
    flat = trained_series(flatten_dict({k: v for k, v in result.items() if k not in NOT_LOGGED}, delimiter="/"))
    kinds: tuple[type[SupportsFloat], ...] = tuple(VALID_SUMMARY_TYPES)
    scalars = {k: v for k, v in flat.items() if isinstance(v, kinds) and not math.isnan(float(v))}
    rest = {k: v for k, v in flat.items() if k not in scalars and k != TIMESTEPS_TOTAL}
    rest[TRAINING_ITERATION] = step_of(result)
    return {PREFIX + k: v for k, v in scalars.items()}, rest


def step_of(result: dict[str, Any]) -> Any:
    """The step Tune's logger files a result under: the algorithm's own iteration, which a resumed run (`train
    --resume`, `sweep --resume`) continues where Tune's `training_iteration` starts again from 1."""
    return result.get(TIMESTEPS_TOTAL) or result.get(keys.ALGO_ITERATION) or result[TRAINING_ITERATION]


class TensorBoardLogger(TBXLoggerCallback):  # type: ignore[misc]  # Tune's classes are untyped
    """`TBXLoggerCallback` with every scalar of a result in one event (same tags, step and values)."""

    def log_trial_result(self, iteration: int, trial: Any, result: dict[str, Any]) -> None:
        from tensorboardX.proto.summary_pb2 import Summary
        from tensorboardX.summary import scalar

        writer = rllib_compat.tune_trial_writer(self, trial)
        scalars, rest = split_scalars(result)
        if scalars:
            values = [value for tag, x in scalars.items() for value in scalar(tag, x).value]
            rllib_compat.summary_file_writer(writer).add_summary(Summary(value=values), step_of(result))
        super().log_trial_result(iteration, trial, rest)  # anything else, then Tune's flush
        last = rllib_compat.tune_last_scalars(self, trial)  # the hyperparameters' metrics at the trial's end
        last.update(scalars | dict(last))

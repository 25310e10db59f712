"""RLlib callbacks: our episode metrics for TensorBoard and each episode's best shape for the top-k table.

Runs inside the env runners (`on_episode_end`) and the trial process (`on_algorithm_init`,
`on_train_result`).
"""

from __future__ import annotations

import json
import os
from typing import Any

from ray.rllib.callbacks.callbacks import RLlibCallback
from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS

WINDOW = 50
"""Episodes each mean is taken over (RLlib's own episode_return_mean uses 100)."""
EPISODE_BEST_KEY = "smorphi_episode_best"
"""Result key holding, as a JSON string, the best shape of each episode finished this iteration:
[map, t1, t2, t3, P_c, P_len, R1]. A string, so TensorBoard skips it and the driver parses it."""
METRIC_PREFIX = "smorphi"


def _step_infos(episode: Any, chunks: list[Any] | None) -> list[dict[str, Any]]:
    """The info of every step of the whole episode (it may arrive as several chunks)."""
    infos: list[dict[str, Any]] = []
    for chunk in [*(chunks or []), episode]:
        infos.extend(chunk.get_infos()[1:])  # [0] is the observation the chunk starts from
    return infos


class MorphologyCallbacks(RLlibCallback):
    """Episode mean and best P_c, P_len, R1, the R1 of the shape the episode ends on, and the best shape's angles."""

    def on_algorithm_init(self, *, algorithm: Any, **kwargs: Any) -> None:
        import torch

        torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))

    def on_episode_end(
        self,
        *,
        episode: Any,
        prev_episode_chunks: list[Any] | None = None,
        metrics_logger: Any = None,
        **kwargs: Any,
    ) -> None:
        infos = _step_infos(episode, prev_episode_chunks)
        if not infos or metrics_logger is None:
            return
        last = infos[-1]
        n = len(infos)
        values = {
            "P_c_mean": sum(i["P_c"] for i in infos) / n,
            "P_len_mean": sum(i["P_len"] for i in infos) / n,
            "R1_mean": sum(i["R1"] for i in infos) / n,
            "R1_final": last["R1"],
            "best_P_c": last["best_P_c"],
            "best_P_len": last["best_P_len"],
            "best_R1": last["best_R1"],
            "best_theta1": last["best_theta"][0],
            "best_theta2": last["best_theta"][1],
            "best_theta3": last["best_theta"][2],
        }
        for name, value in values.items():
            metrics_logger.log_value((METRIC_PREFIX, name), float(value), reduce="mean", window=WINDOW)
        metrics_logger.log_value((METRIC_PREFIX, "best_R1_max"), float(last["best_R1"]), reduce="max", window=WINDOW)
        theta = [float(t) for t in last["best_theta"]]
        best = [str(last["map"]), *theta, float(last["best_P_c"]), int(last["best_P_len"]), float(last["best_R1"])]
        metrics_logger.log_value(EPISODE_BEST_KEY, best, reduce="item_series")

    def on_train_result(self, *, algorithm: Any, result: dict[str, Any], **kwargs: Any) -> None:
        runners = result.get(ENV_RUNNER_RESULTS, {})
        bests = runners.pop(EPISODE_BEST_KEY, None)
        if not isinstance(bests, list | tuple):  # no episode ended this iteration (RLlib reports NaN)
            bests = []
        result[EPISODE_BEST_KEY] = json.dumps([list(b) for b in bests if isinstance(b, list | tuple) and len(b) == 7])

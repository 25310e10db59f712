"""Keep RLlib's deprecation chatter and Tune's banners out of our output (driver and workers alike)."""

from __future__ import annotations

import logging
import os

TRIAL_ERROR_LOGGERS = ("ray.tune.execution.tune_controller", "ray.tune.execution.experiment_state", "ray.tune.tune")
"""Tune's loggers that print a failed trial's traceback (and a failed state save) on the driver."""
NOISY_LOGGERS = ("ray", "ray.rllib", "ray.tune", "ray._common.deprecation", "ray.rllib.algorithms.algorithm_config")


def quiet() -> None:
    """Errors only from Ray's loggers; Tune's old reporter, which at verbose=0 prints nothing.

    Also the worker_process_setup_hook of every Ray worker a run starts."""
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # the new reporter prints a banner even at verbose=0
    for name in NOISY_LOGGERS:
        logging.getLogger(name).setLevel(logging.ERROR)
    for name in TRIAL_ERROR_LOGGERS:  # a failed trial: our one line says why and where its full error is
        logging.getLogger(name).setLevel(logging.CRITICAL)

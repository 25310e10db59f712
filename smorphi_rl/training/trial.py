"""The one Ray Tune trainable of the project: `train` runs it as a one-trial experiment, `sweep` as many.

A trial builds the RLlib algorithm for its TrainConfig, continues from our own state file when a sweep
is resumed (`resume.py`: nothing unpickled but numbers and arrays), trains to the budget or the sweep's
stop criteria, and reports every iteration (checkpointing every `checkpoint_every` iterations and at
the end). It asks for 1 CPU plus 0.5 per env runner, so Tune queues trials to fit the machine or the
cluster.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from smorphi_rl.errors import SmorphiError
from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.checkpoints import STAGING_PREFIX
from smorphi_rl.training.config import (
    CPUS_FOR_TRIAL,
    CPUS_PER_ENV_RUNNER,
    TrainConfig,
    algorithm_config,
    recording_settings,
    register_env,
)
from smorphi_rl.training.resume import ELAPSED, KEPT, STATE_KEYS, check_fits, load_state, save_state
from smorphi_rl.training.runners import push_module_to_runners, reseed_runners
from smorphi_rl.training.stopping import stop_requested


def resources(cfg: TrainConfig) -> Any:
    """What one trial asks Tune for: a bundle for the trial (learner and driver of sampling), one per env runner."""
    from ray import tune

    bundles = [{"CPU": CPUS_FOR_TRIAL}] + [{"CPU": CPUS_PER_ENV_RUNNER}] * cfg.env_runners
    return tune.PlacementGroupFactory(bundles)


def stop_reached(stop: dict[str, float], iteration: int, steps: int, elapsed_s: float) -> bool:
    """Whether any of a sweep's stop criteria (`sweep_config.STOP_METRICS`: threshold) is met; the trial checks
    them itself, counted across resumes (Tune's own counters start again in a resumed trial)."""
    now = {keys.ITERATION: iteration, keys.TIME_TOTAL: elapsed_s, keys.STEPS: steps, keys.TIMESTEPS_TOTAL: steps}
    return any(now[k] >= v for k, v in stop.items())


class RunnersFailed(SmorphiError):
    """No env runner could be started."""


RUNNERS_FAILED = (
    "no env runner started: each failed as it built its env (on a cluster: a map file missing on a node, or "
    "smorphi-rl not installed there); each node's Ray worker logs (/tmp/ray/session_latest/logs) hold its error"
)


def no_runner_started(exc: IndexError) -> bool:
    """Whether RLlib's IndexError is its reading of the spaces from the first env runner when none is alive: the
    runners' own errors stay in their workers' logs, and the trial's line read "list index out of range"."""
    frames = []
    tb = exc.__traceback__
    while tb is not None:
        frames.append(tb.tb_frame.f_code.co_name)
        tb = tb.tb_next
    return bool(frames) and frames[-1] == "get_spaces"


def run_trial(
    cfg: TrainConfig, callbacks: type | None = None, recording_dir: Path | None = None,
    resume_from: Path | None = None, stop: dict[str, float] | None = None, resumable: bool = False,
    stop_name: str | None = None,
) -> None:  # fmt: skip
    """Inside a Tune trial: build the algorithm, continue from `resume_from`'s state (a resumed sweep), train to
    the budget or `stop` (`stop_reached`), or until the driver asks the run `stop_name` to end (`stopping.py`).

    `callbacks`: the RLlib callbacks class (evaluation, fine-tuning), default ours; `recording_dir`: where the
    MCAP episodes go (default the trial's folder), when `cfg.record_every` is set; `resumable`: every checkpoint
    also holds our state file, for `sweep --resume`."""
    from ray import tune
    from ray.rllib.core import DEFAULT_MODULE_ID
    from ray.tune.result import AUTO_RESULT_KEYS

    from smorphi_rl.training.callbacks import end_run, kept_policy, restore_kept, trained_weights, updates_paused

    register_env()
    trial_dir = Path(tune.get_context().get_trial_dir())
    run_dir = recording_dir or trial_dir
    config = algorithm_config(cfg, callbacks, recording_settings(cfg, run_dir, run_dir.name))
    # The trial's own storage: an Algorithm built without one makes itself a folder under ~/ray_results
    try:
        algo = config.algo_class(config=config, storage=tune.get_context().get_storage())
    except IndexError as exc:
        if not no_runner_started(exc):
            raise
        raise RunnersFailed(RUNNERS_FAILED) from None
    elapsed = 0.0
    try:
        if resume_from is not None:
            state = load_state(resume_from)
            check_fits(state, algo.learner_group.get_weights()[DEFAULT_MODULE_ID], resume_from)
            algo.set_state({k: state[k] for k in STATE_KEYS})
            elapsed = state[ELAPSED]
            restore_kept(algo, state.get(KEPT))  # the policy it would end on, if none beats it
            push_module_to_runners(algo)  # RLlib's own sync after a restore may be dropped (the notes)
            reseed_runners(algo, algo.iteration)  # fresh start shapes, not a replay of the first iterations
        while True:
            t0 = time.monotonic()
            result = algo.train()
            elapsed += time.monotonic() - t0
            steps = int(result.get(keys.STEPS) or 0)
            done = (steps >= cfg.timesteps or (cfg.max_iterations is not None and algo.iteration >= cfg.max_iterations)
                    or stop_reached(stop or {}, algo.iteration, steps, elapsed)
                    or (stop_name is not None and stop_requested(stop_name)))  # fmt: skip
            if done:  # ended by a stop criterion too: evaluated and its policy chosen as at the budget's end
                end_run(algo, result)
            metrics = {k: v for k, v in result.items() if k not in AUTO_RESULT_KEYS and k != "config"}
            metrics[keys.ALGO_ITERATION] = algo.iteration
            metrics[keys.TRIAL_DONE] = done
            if done or algo.iteration % cfg.checkpoint_every == 0:
                with tempfile.TemporaryDirectory(prefix=STAGING_PREFIX, dir=trial_dir) as path:
                    with updates_paused(algo):  # IMPALA's and APPO's thread: both files of one update
                        algo.save_to_path(path)
                        if resumable:
                            save_state(algo, Path(path), elapsed, kept_policy(algo), trained_weights(algo))
                    tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(path))
            else:
                tune.report(metrics)
            if done:
                return
    finally:
        algo.stop()

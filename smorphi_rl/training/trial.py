"""The one Ray Tune trainable of the project: `train` runs it as a one-trial experiment, `sweep` as many.

A trial builds the RLlib algorithm for its TrainConfig, restores Tune's checkpoint when the
experiment is resumed, trains to the budget, and reports every iteration (checkpointing every
`checkpoint_every` iterations and at the end). It asks for 1 CPU plus 0.5 per env runner, so Tune
queues trials to fit the machine or the cluster.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from smorphi_rl.training import result_keys as keys
from smorphi_rl.training.config import (
    CPUS_FOR_TRIAL,
    CPUS_PER_ENV_RUNNER,
    TrainConfig,
    algorithm_config,
    recording_settings,
    register_env,
)
from smorphi_rl.training.runners import push_module_to_runners, reseed_runners


def resources(cfg: TrainConfig) -> Any:
    """What one trial asks Tune for: a bundle for the trial (learner and driver of sampling), one per env runner."""
    from ray import tune

    bundles = [{"CPU": CPUS_FOR_TRIAL}] + [{"CPU": CPUS_PER_ENV_RUNNER}] * cfg.env_runners
    return tune.PlacementGroupFactory(bundles)


def run_trial(cfg: TrainConfig, callbacks: type | None = None, recording_dir: Path | None = None) -> None:
    """Inside a Tune trial: build the algorithm, restore Tune's checkpoint if resuming, train to the budget.

    `callbacks`: the RLlib callbacks class (evaluation, fine-tuning), default ours; `recording_dir`: where the
    MCAP episodes go (default the trial's folder), when `cfg.record_every` is set."""
    from ray import tune
    from ray.tune.result import AUTO_RESULT_KEYS

    register_env()
    trial_dir = Path(tune.get_context().get_trial_dir())
    run_dir = recording_dir or trial_dir
    config = algorithm_config(cfg, callbacks, recording_settings(cfg, run_dir, run_dir.name))
    # The trial's own storage: an Algorithm built without one makes itself a folder under ~/ray_results
    algo = config.algo_class(config=config, storage=tune.get_context().get_storage())
    try:
        resume = tune.get_checkpoint()
        if resume is not None:
            with resume.as_directory() as path:
                algo.restore_from_path(path)
            push_module_to_runners(algo)  # RLlib's own sync after a restore may be dropped (the notes)
            reseed_runners(algo, algo.iteration)  # fresh start shapes, not a replay of the first iterations
        while True:
            result = algo.train()
            steps = int(result.get(keys.STEPS) or 0)
            done = steps >= cfg.timesteps or (cfg.max_iterations is not None and algo.iteration >= cfg.max_iterations)
            metrics = {k: v for k, v in result.items() if k not in AUTO_RESULT_KEYS and k != "config"}
            metrics[keys.ALGO_ITERATION] = algo.iteration
            if done or algo.iteration % cfg.checkpoint_every == 0:
                with tempfile.TemporaryDirectory() as path:
                    algo.save_to_path(path)
                    tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(path))
            else:
                tune.report(metrics)
            if done:
                return
    finally:
        algo.stop()

"""The keys of RLlib's and Tune's training results that the project reads: one home for the strings.

They equal RLlib's and Tune's own constants (`tests/training/test_result_keys.py` checks), but are
spelled here so that readers of `result.json` (reports, plots, transfer) need not import RLlib,
whose package import takes seconds.
"""

ENV_RUNNERS = "env_runners"
"""ray.rllib.utils.metrics.ENV_RUNNER_RESULTS: the env runners' metrics of an iteration."""
EPISODE_RETURN_MEAN = "episode_return_mean"
"""ray.rllib.utils.metrics.EPISODE_RETURN_MEAN, under ENV_RUNNERS."""
STEPS = "num_env_steps_sampled_lifetime"
"""ray.rllib.utils.metrics.NUM_ENV_STEPS_SAMPLED_LIFETIME: env steps sampled so far (the budget's clock)."""
ITERATION = "training_iteration"
"""ray.tune.result.TRAINING_ITERATION."""
TIME_TOTAL = "time_total_s"
"""ray.tune.result.TIME_TOTAL_S."""
TIMESTEPS_TOTAL = "timesteps_total"
"""ray.tune.result.TIMESTEPS_TOTAL."""
METRIC_PREFIX = "smorphi"
"""Ours: the env runners' results group our episode metrics under this key (TensorBoard: env_runners/smorphi/)."""
ALGO_ITERATION = "smorphi_iteration"
"""Ours: the algorithm's own iteration count, reported by every trial; unlike ITERATION it survives a resume."""
TRIAL_DONE = "smorphi_done"
"""Ours: true in a trial's last row, once it reached its budget or its stop criteria (`sweep --resume` skips it)."""

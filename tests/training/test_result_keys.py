"""Our spelling of result keys is RLlib's and Tune's."""

from ray.rllib.utils import metrics
from ray.tune import result

from smorphi_rl.training import result_keys as keys


def test_keys_are_rllib_and_tune_constants():
    assert keys.ENV_RUNNERS == metrics.ENV_RUNNER_RESULTS
    assert keys.EPISODE_RETURN_MEAN == metrics.EPISODE_RETURN_MEAN
    assert keys.STEPS == metrics.NUM_ENV_STEPS_SAMPLED_LIFETIME
    assert keys.ITERATION == result.TRAINING_ITERATION
    assert keys.TIME_TOTAL == result.TIME_TOTAL_S
    assert keys.TIMESTEPS_TOTAL == result.TIMESTEPS_TOTAL


def test_the_resume_state_names_rllibs_components():
    from ray.rllib.algorithms.algorithm import TRAINING_ITERATION
    from ray.rllib.core import (
        COMPONENT_ENV_RUNNER,
        COMPONENT_EVAL_ENV_RUNNER,
        COMPONENT_LEARNER_GROUP,
        COMPONENT_METRICS_LOGGER,
    )

    from smorphi_rl.training.resume import LEFT_OUT, STATE_KEYS

    assert STATE_KEYS == (COMPONENT_LEARNER_GROUP, COMPONENT_METRICS_LOGGER, TRAINING_ITERATION)
    assert LEFT_OUT == (COMPONENT_ENV_RUNNER, COMPONENT_EVAL_ENV_RUNNER)

"""The learners' fused optimiser step: the same arithmetic as RLlib's tensor-by-tensor one."""

from __future__ import annotations

import pytest
import torch
from ray.rllib.utils.torch_utils import clip_gradients

from smorphi_rl.training.learners import all_finite, clip_each_tensor


def _grads() -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(3)
    return {
        "small": torch.randn(4, 5, generator=generator) * 0.1,
        "large": torch.randn(7, generator=generator) * 100.0,
        "exactly": torch.full((4,), 5.0),  # norm 10: not over the clip, left alone
        "nan": torch.tensor([float("nan"), 1.0]),
    }


def test_fused_clipping_equals_rllibs_per_tensor_clipping():
    ours, theirs = _grads(), _grads()
    clip_each_tensor(ours, grad_clip=10.0, grad_clip_by="norm")
    clip_gradients(theirs, grad_clip=10.0, grad_clip_by="norm")
    for key in ours:
        assert torch.allclose(ours[key], theirs[key], equal_nan=True), key
    assert abs(float(ours["large"].norm()) - 10.0) < 1e-4


def test_other_clipping_modes_are_rllibs():
    ours, theirs = _grads(), _grads()
    del ours["nan"], theirs["nan"]
    clip_each_tensor(ours, grad_clip=1.0, grad_clip_by="value")
    clip_gradients(theirs, grad_clip=1.0, grad_clip_by="value")
    assert all(torch.equal(ours[k], theirs[k]) for k in ours)


def test_one_non_finite_entry_anywhere_is_seen():
    grads = _grads()
    assert not all_finite(list(grads.values()))
    del grads["nan"]
    assert all_finite(list(grads.values()))
    grads["inf"] = torch.tensor([0.0, float("inf")])
    assert not all_finite(list(grads.values()))


@pytest.mark.slow
def test_a_failure_in_the_learner_thread_fails_the_update_instead_of_freezing_it():
    """APPO learns in a thread of its learner; an exception there comes back at the trial's next update."""
    import time

    from ray.rllib.core.learner.training_data import TrainingData
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    from smorphi_rl import cluster
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env
    from smorphi_rl.training.learners import LearnerThreadError

    def failing_loss(**kwargs):
        raise ValueError("a broken loss")

    register_env()
    cfg = TrainConfig(algo="appo", env=EnvConfig.from_dict({"max_steps": 20}), seed=3, envs_per_runner=8)
    config = algorithm_config(cfg)
    with cluster.ray_session(None):  # the learner thread puts its state in Ray's object store
        runner = SingleAgentEnvRunner(config=config)
        learner = config.build_learner(env=runner.env)
        learner.build()
        learner.compute_loss_for_module = failing_loss
        timesteps = {"num_env_steps_sampled_lifetime": 400}
        learner.update(training_data=TrainingData(episodes=runner.sample(num_timesteps=400)), timesteps=timesteps)
        deadline = time.monotonic() + 60
        while learner._thread_error is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert learner._learner_thread.is_alive()  # still taking batches off its queue: nothing blocks
        with pytest.raises(LearnerThreadError, match="ValueError: a broken loss"):
            learner.update(training_data=TrainingData(episodes=runner.sample(num_timesteps=400)), timesteps=timesteps)
        runner.stop()

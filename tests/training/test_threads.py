"""Acting on one torch thread: the count inside the block, and the count given back after it."""

from __future__ import annotations

import pytest
import torch

from smorphi_rl.training.threads import one_torch_thread


@pytest.fixture
def two_threads():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def test_one_thread_inside_and_the_count_given_back(two_threads):
    with one_torch_thread():
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2
    with pytest.raises(RuntimeError), one_torch_thread():
        raise RuntimeError("a failing step")
    assert torch.get_num_threads() == 2


def test_the_lean_runner_samples_on_one_thread_and_learns_on_two(two_threads, monkeypatch):
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.callbacks import MorphologyCallbacks
    from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env
    from smorphi_rl.vector_env import MorphologyVectorEnv

    seen: list[int] = []
    step = MorphologyVectorEnv.step

    def counting_step(self, actions):  # type: ignore[no-untyped-def]
        seen.append(torch.get_num_threads())
        return step(self, actions)

    monkeypatch.setattr(MorphologyVectorEnv, "step", counting_step)
    register_env()
    config = algorithm_config(TrainConfig(env=EnvConfig.from_dict({"max_steps": 20}), seed=3, envs_per_runner=4),
                              MorphologyCallbacks)  # fmt: skip
    runner = config.env_runner_cls(config=config)
    try:
        runner.sample(num_timesteps=40)
    finally:
        runner.stop()
    assert seen and set(seen) == {1}
    assert torch.get_num_threads() == 2

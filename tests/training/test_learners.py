"""The learners' fused optimiser step: the same arithmetic as RLlib's tensor-by-tensor one."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import ray
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


@contextmanager
def _async_learner(algo: str, **overrides: float) -> Iterator[tuple[Any, Any]]:
    """(env runner, learner) of one real IMPALA or APPO config (Preset `overrides` applied), in a Ray session (the
    learner thread puts its state in Ray's object store); the learner's thread is stopped before Ray is: a live one
    would start another Ray at its next put."""
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    from smorphi_rl import cluster
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.training.config import TrainConfig, algorithm_config, register_env

    register_env()
    cfg = TrainConfig(algo=algo, env=EnvConfig.from_dict({"max_steps": 20}), seed=3, envs_per_runner=8,
                      overrides=overrides)  # fmt: skip
    config = algorithm_config(cfg)
    with cluster.ray_session(None):
        runner = SingleAgentEnvRunner(config=config)
        learner = config.build_learner(env=runner.env)  # built, its thread started
        try:
            yield runner, learner
        finally:
            learner.shutdown()
            runner.stop()


@pytest.mark.slow
def test_a_failure_in_the_learner_thread_fails_the_update_instead_of_freezing_it():
    """APPO learns in a thread of its learner; an exception there comes back at the trial's next update."""
    import time

    from ray.rllib.core.learner.training_data import TrainingData

    from smorphi_rl.training.learners import LearnerThreadError

    def failing_loss(**kwargs):
        raise ValueError("a broken loss")

    with _async_learner("appo") as (runner, learner):
        learner.compute_loss_for_module = failing_loss
        timesteps = {"num_env_steps_sampled_lifetime": 400}
        learner.update(training_data=TrainingData(episodes=runner.sample(num_timesteps=400)), timesteps=timesteps)
        deadline = time.monotonic() + 60
        while learner._thread_error is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert learner._learner_thread.is_alive()  # still taking batches off its queue: nothing blocks
        with pytest.raises(LearnerThreadError, match="ValueError: a broken loss"):
            learner.update(training_data=TrainingData(episodes=runner.sample(num_timesteps=400)), timesteps=timesteps)


def _vtrace_inputs(seed: int = 0) -> dict[str, torch.Tensor]:
    """Time-major v-trace inputs: 7 steps of 5 trajectories."""
    g = torch.Generator().manual_seed(seed)
    t, b = 7, 5
    return {
        "target_action_log_probs": -torch.rand(t, b, generator=g),
        "behaviour_action_log_probs": -torch.rand(t, b, generator=g),
        "discounts": torch.full((t, b), 0.99),
        "rewards": torch.randn(t, b, generator=g) * 30 + 5,
        "values": torch.randn(t, b, generator=g) * 10,
        "bootstrap_values": torch.randn(b, generator=g),
    }


def test_normalised_vtrace_is_rllibs_with_the_advantages_standardised():
    from ray.rllib.algorithms.impala.torch.vtrace_torch_v2 import vtrace_torch

    from smorphi_rl.training.learners import normalised_vtrace

    inputs = _vtrace_inputs()
    targets, advantages = vtrace_torch(**inputs)
    ours_targets, ours_advantages = normalised_vtrace(**inputs)  # at the default lambda, 1
    assert torch.allclose(ours_targets, targets, atol=1e-5)  # the critic's targets as RLlib computes them
    expected = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    assert torch.allclose(ours_advantages, expected, atol=1e-6)
    assert abs(float(advantages.std()) - 1) > 0.5  # RLlib's own are not standardised: the wrap does something


def test_vtrace_lambda_is_rllibs_at_1_and_one_step_td_at_0():
    from ray.rllib.algorithms.impala.torch.vtrace_torch_v2 import vtrace_torch

    from smorphi_rl.training.learners import vtrace_lambda

    inputs = _vtrace_inputs()
    for ours, theirs in zip(vtrace_lambda(lambda_=1.0, **inputs), vtrace_torch(**inputs), strict=True):
        assert torch.allclose(ours, theirs, atol=1e-5)
    targets, _ = vtrace_lambda(lambda_=0.0, **inputs)
    v, r, d = inputs["values"], inputs["rewards"], inputs["discounts"]
    rhos = torch.exp(inputs["target_action_log_probs"] - inputs["behaviour_action_log_probs"]).clamp(max=1.0)
    next_v = torch.cat([v[1:], inputs["bootstrap_values"].unsqueeze(0)])
    assert torch.allclose(targets, v + rhos * (r + d * next_v - v), atol=1e-5)
    half, _ = vtrace_lambda(lambda_=0.5, **inputs)
    assert not torch.allclose(half, targets) and not torch.allclose(half, vtrace_torch(**inputs)[0])


def test_pg_lambda_at_lambda_gives_gae_on_policy_and_at_1_impalas_advantage():
    from smorphi_rl.training.learners import vtrace_lambda

    inputs = _vtrace_inputs()
    inputs["behaviour_action_log_probs"] = inputs["target_action_log_probs"]  # on-policy: every rho is 1
    values, rewards, discounts = inputs["values"], inputs["rewards"], inputs["discounts"]
    next_values = torch.cat([values[1:], inputs["bootstrap_values"].unsqueeze(0)])
    deltas = rewards + discounts * next_values - values
    gae, acc = torch.zeros_like(values), torch.zeros_like(values[0])
    for t in reversed(range(len(values))):  # GAE(0.5), as PPO computes it
        acc = deltas[t] + discounts[t] * 0.5 * acc
        gae[t] = acc
    _, advantages = vtrace_lambda(lambda_=0.5, pg_lambda=0.5, **inputs)
    assert torch.allclose(advantages, gae, atol=1e-4)
    targets, impala = vtrace_lambda(lambda_=0.5, **inputs)  # pg_lambda 1: the next state's whole v-trace target
    assert torch.allclose(impala[:-1], rewards[:-1] + discounts[:-1] * targets[1:] - values[:-1], atol=1e-4)
    assert not torch.allclose(impala, gae, atol=1e-2)


def test_the_async_losses_run_at_the_lambda_their_config_names_on_the_learnable_steps():
    from types import SimpleNamespace

    from ray.rllib.core.columns import Columns

    from smorphi_rl.training import learners

    seen = []

    def loss(self, *, batch, **kw):
        seen.append((learners._TRACE.get(), batch[Columns.LOSS_MASK]))

    wrapped = learners.with_trace_settings(loss)
    mask = torch.tensor([True, True, False, True, True, False, True])  # two chunks end in extra steps, one is cut
    for settings in ({learners.TRACE_LAMBDA_KEY: 0.3, learners.PG_LAMBDA_KEY: 0.2}, {}):
        config = SimpleNamespace(learner_config_dict=settings, get_rollout_fragment_length=lambda: 2)
        wrapped(None, module_id="m", config=config, batch={Columns.LOSS_MASK: mask}, fwd_out={})
    assert [(trace.lambda_, trace.pg_lambda) for trace, _ in seen] == [(0.3, 0.2), (1.0, 1.0)]
    assert learners._TRACE.get() is None  # for the loss only
    assert seen[0][1].tolist() == [True, True, False, True, True, False, False]  # the cut chunk's step is dropped
    assert seen[0][0].mask.tolist() == [[1.0, 0.0, 1.0, 0.0], [1.0, 1.0, 0.0, 0.0]]  # time-major, padded


def test_vtrace_bootstraps_each_chunk_from_its_extra_step_where_rllibs_wipes_it():
    """RLlib adds one masked step after every episode chunk to hold the bootstrap value; unmasked, its TD error
    -rho V cancels that bootstrap. With the mask, the last real step's one-step target is r + gamma V(extra)."""
    from ray.rllib.algorithms.impala.torch.vtrace_torch_v2 import vtrace_torch

    from smorphi_rl.training.learners import vtrace_lambda

    # one row of 4 steps: 2 real steps of chunk A, A's extra step (masked), 1 real step of chunk B
    inputs = {
        "target_action_log_probs": torch.zeros(4, 1),
        "behaviour_action_log_probs": torch.zeros(4, 1),
        "discounts": torch.tensor([[0.9], [0.9], [0.0], [0.9]]),  # RLlib: gamma x loss mask
        "rewards": torch.tensor([[1.0], [1.0], [0.0], [1.0]]),
        "values": torch.tensor([[5.0], [6.0], [40.0], [7.0]]),
        "bootstrap_values": torch.tensor([8.0]),
    }
    mask = torch.tensor([[1.0], [1.0], [0.0], [1.0]])
    theirs, _ = vtrace_torch(**inputs)
    assert float(theirs[1, 0]) == pytest.approx(1.0)  # the bootstrap 0.9 x 40 is gone
    ours, _ = vtrace_lambda(lambda_=0.0, mask=mask, **inputs)
    assert float(ours[1, 0]) == pytest.approx(1.0 + 0.9 * 40.0) and float(ours[2, 0]) == 40.0


def test_normalised_advantages_are_standardised_over_the_learnable_steps_only():
    from smorphi_rl.training import learners

    inputs = _vtrace_inputs()
    mask = torch.ones(7, 5)
    mask[3, :] = 0.0
    token = learners._TRACE.set(learners.TraceSettings(0.5, mask=mask))
    try:
        _, advantages = learners.normalised_vtrace(**inputs)
    finally:
        learners._TRACE.reset(token)
    kept = advantages[mask > 0]
    assert abs(float(kept.mean())) < 1e-5 and abs(float(kept.std()) - 1) < 1e-4 and not advantages[3].any()


def _ppo_learner(learner_class=None):
    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.training.config import TrainConfig, algorithm_config

    env = MorphologyEnv()
    spaces = {"__env__": (env.observation_space, env.action_space)}
    spaces["default_policy"] = spaces["__env__"]
    config = algorithm_config(TrainConfig(timesteps=10_000))
    if learner_class is not None:
        config.training(learner_class=learner_class)
    learner = config.build_learner(spaces=spaces)
    learner.build()
    return learner


def test_the_fused_optimiser_step_is_rllibs_step_and_schedule():
    """Clipping per tensor, Adam and the learning-rate schedule, step for step, against RLlib's own learner."""
    from ray.rllib.algorithms.ppo.torch.ppo_torch_learner import PPOTorchLearner
    from ray.rllib.utils.metrics import NUM_ENV_STEPS_SAMPLED_LIFETIME

    ours, theirs = _ppo_learner(), _ppo_learner(PPOTorchLearner)
    assert type(theirs) is PPOTorchLearner and type(ours) is not PPOTorchLearner
    theirs.module.set_state(ours.module.get_state())
    ours_params = list(ours.module["default_policy"].parameters())
    theirs_params = list(theirs.module["default_policy"].parameters())
    g = torch.Generator().manual_seed(1)
    start = [p.detach().clone() for p in ours_params]
    for step, timestep in enumerate((0, 4_000, 9_000)):
        noise = [torch.randn(p.shape, generator=g) * (50.0 if i % 3 == 0 else 0.1) for i, p in enumerate(ours_params)]
        for learner, params in ((ours, ours_params), (theirs, theirs_params)):
            grads = {learner.get_param_ref(p): n.clone() for p, n in zip(params, noise, strict=True)}
            learner.apply_gradients(learner.postprocess_gradients(grads))
            learner.after_gradient_based_update(timesteps={NUM_ENV_STEPS_SAMPLED_LIFETIME: timestep})
        for a, b in zip(ours_params, theirs_params, strict=True):
            assert torch.allclose(a, b, rtol=1e-5, atol=1e-7), step
        lrs = [opt.param_groups[0]["lr"] for lr_learner in (ours, theirs)
               for _, opt in lr_learner.get_optimizers_for_module("default_policy")]  # fmt: skip
        assert abs(float(lrs[0]) - float(lrs[1])) < 1e-9, (step, lrs)
    assert float(lrs[0]) < 1e-3  # the schedule moved the rate down from its start
    assert any(not torch.equal(a, b) for a, b in zip(start, ours_params, strict=True))  # the steps moved the weights


def test_a_learner_whose_updates_are_held_keeps_its_weights():
    """At a run's end the learner's updates are held (`snapshot.hold_updates`): a step then changes nothing, as an
    asynchronous learner's thread would otherwise go on stepping after the last evaluation."""
    from smorphi_rl.training.snapshot import hold_updates, updates_held

    learner = _ppo_learner()
    params = list(learner.module["default_policy"].parameters())

    def step() -> list[torch.Tensor]:
        before = [p.detach().clone() for p in params]
        learner.apply_gradients({learner.get_param_ref(p): torch.ones_like(p) for p in params})
        return before

    before = step()
    assert any(not torch.equal(a, b) for a, b in zip(before, params, strict=True))  # a step moves the weights
    assert not updates_held(learner)
    hold_updates(learner)
    before = step()
    assert updates_held(learner) and all(torch.equal(a, b) for a, b in zip(before, params, strict=True))


@pytest.mark.parametrize("algo", ["impala", "appo"])
def test_one_update_of_the_async_learners_moves_the_weights(algo):
    """IMPALA and APPO learn in their learner's thread: one update's batch changes the module's weights."""
    import time

    from ray.rllib.core.learner.training_data import TrainingData

    with _async_learner(algo) as (runner, learner):
        before = [p.detach().clone() for p in learner.module["default_policy"].parameters()]
        learner.update(training_data=TrainingData(episodes=runner.sample(num_timesteps=400)),
                       timesteps={"num_env_steps_sampled_lifetime": 400})  # fmt: skip
        deadline = time.monotonic() + 60
        params = list(learner.module["default_policy"].parameters())
        while all(torch.equal(a, b) for a, b in zip(before, params, strict=True)) and time.monotonic() < deadline:
            time.sleep(0.05)
    assert any(not torch.equal(a, b) for a, b in zip(before, params, strict=True))


@pytest.mark.slow
def test_the_async_learners_hand_over_the_weights_of_the_update_they_waited_for():
    """The weights APPO's update hands the algorithm to broadcast are those after the batch it just trained on
    (RLlib's are one batch older), so the env runners sample with the learner's latest policy."""
    from ray.rllib.core import COMPONENT_RL_MODULE
    from ray.rllib.core.learner.training_data import TrainingData

    from smorphi_rl import rllib_compat

    # Each batch trained once: with the circular buffer's replays (RLlib's 8 batches, 2 passes) the thread may train
    # again after the update returns, and the module read below would race it.
    with _async_learner("appo", circular_buffer_batches=1, circular_buffer_passes=1) as (runner, learner):
        handed = []
        for _ in range(3):
            data = TrainingData(episodes=runner.sample(num_timesteps=400))
            result = learner.update(training_data=data, timesteps={"num_env_steps_sampled_lifetime": 400},
                                    return_state=True)  # fmt: skip
            state = result[rllib_compat.LEARNER_STATE_KEY][COMPONENT_RL_MODULE]
            handed.append(ray.get(state) if isinstance(state, ray.ObjectRef) else state)
        now = learner.module["default_policy"].get_state(inference_only=True)
    last = handed[-1]["default_policy"]
    assert last.keys() == now.keys()
    assert all(np.array_equal(last[k], now[k]) for k in now)
    earlier = handed[-2]["default_policy"]
    assert any(not np.array_equal(earlier[k], now[k]) for k in now)


def test_appos_frozen_critic_is_the_critic_at_the_last_target_refresh_and_feeds_vtrace():
    """`frozen_critic`: v-trace reads the critic as copied when APPO last refreshed its target policy, so a
    batch's advantages and value targets stay fixed over its passes while the critic trains (PPO's GAE)."""
    from ray.rllib.core.columns import Columns
    from ray.rllib.utils.metrics import NUM_ENV_STEPS_SAMPLED_LIFETIME, NUM_ENV_STEPS_TRAINED_LIFETIME

    from smorphi_rl.env import MorphologyEnv
    from smorphi_rl.training import learners
    from smorphi_rl.training.config import TrainConfig, algorithm_config

    env = MorphologyEnv()
    spaces = {"__env__": (env.observation_space, env.action_space)}
    spaces["default_policy"] = spaces["__env__"]
    plain = algorithm_config(TrainConfig(algo="appo", timesteps=10_000)).build_learner(spaces=spaces)
    try:  # off by default: nothing is copied
        plain.after_gradient_based_update(timesteps={NUM_ENV_STEPS_SAMPLED_LIFETIME: 0})
        assert not getattr(plain, "_frozen", {})
    finally:
        plain.shutdown()
    config = algorithm_config(TrainConfig(algo="appo", timesteps=10_000, overrides={"frozen_critic": 1}))
    learner = config.build_learner(spaces=spaces)
    try:
        module = learner.module["default_policy"].unwrapped()
        obs, _ = env.reset(seed=0)
        batch = {Columns.OBS: {k: torch.as_tensor(v)[None] for k, v in obs.items()}}
        assert learner.frozen_values("default_policy", batch) is None  # nothing frozen before the first update

        def update(trained: int) -> None:
            learner.after_gradient_based_update(
                timesteps={NUM_ENV_STEPS_SAMPLED_LIFETIME: 0, NUM_ENV_STEPS_TRAINED_LIFETIME: trained}
            )

        update(0)
        before = module.compute_values(batch).detach()
        with torch.no_grad():  # both nets learn between refreshes
            for p in [*module.value_net().parameters(), *module._pi.parameters()]:
                p.add_(0.05)
        update(1)  # no refresh of the target policy: the copy stays
        assert torch.allclose(learner.frozen_values("default_policy", batch), before)
        assert not torch.allclose(module.compute_values(batch), before)
        update(10**9)  # APPO refreshes its target policy: the copy follows the critic
        assert torch.allclose(learner.frozen_values("default_policy", batch), module.compute_values(batch).detach())

        seen = []
        wrapped = learners.with_trace_settings(lambda self, **kw: seen.append(learners._TRACE.get()))
        mask = torch.tensor([True])
        wrapped(learner, module_id="default_policy", config=learner.config,
                batch={**batch, Columns.LOSS_MASK: mask}, fwd_out={})  # fmt: skip
        frozen = learner.frozen_values("default_policy", batch)
        assert seen[0].values is not None and torch.allclose(seen[0].values.flatten()[:1], frozen)  # time-major
    finally:
        learner.shutdown()

"""`HingeCategorical` computes what RLlib's MultiCategorical does, bit for bit: PPO's loss terms and their
gradients, with 1 and 2 torch threads, on batches of the sizes training uses."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import pytest
import torch
from ray.rllib.core.distribution.torch.torch_distribution import TorchMultiCategorical

from smorphi_rl.training.distribution import HingeCategorical

SPACE = gym.spaces.MultiDiscrete([3, 3, 3])
RLLIB = TorchMultiCategorical.get_partial_dist_cls(space=SPACE, input_lens=[3, 3, 3])
OURS = HingeCategorical.get_partial_dist_cls(space=SPACE, input_lens=[3, 3, 3])


def _ppo_terms(cls: Any, logits: torch.Tensor, batch: dict[str, torch.Tensor]) -> list[torch.Tensor]:
    """PPO's use of the distributions (RLlib's `compute_loss_for_module`, in its order), and the logits' gradient."""
    logits = logits.clone().requires_grad_(True)
    current, previous = cls.from_logits(logits), cls.from_logits(batch["previous"])
    logp = current.logp(batch["actions"])
    ratio = torch.exp(logp - batch["old_logp"])
    kl = previous.kl(current)
    entropy = current.entropy()
    surrogate = torch.min(batch["advantages"] * ratio, batch["advantages"] * torch.clamp(ratio, 0.8, 1.2))
    total = torch.mean(-surrogate - 0.01 * entropy) + 0.2 * kl.mean()
    total.backward()
    assert logits.grad is not None
    return [total.detach(), logp.detach(), kl.detach(), entropy.detach(), logits.grad]


@pytest.mark.parametrize("threads", [1, 2])
def test_ppo_terms_and_gradients_are_rllibs_bit_for_bit(threads):
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for seed, rows in enumerate([1, 7, 500, 504, 2016]):
            g = torch.Generator().manual_seed(seed)
            logits = torch.randn(rows, 9, generator=g) * 3
            logits[:, 0] = -1e30 if seed % 2 else logits[:, 0]  # a move of probability 0
            batch = {
                "previous": logits + 0.1 * torch.randn(rows, 9, generator=g),
                "actions": torch.randint(0, 3, (rows, 3), generator=g),
                "old_logp": torch.randn(rows, generator=g) * 0.1 - 3,
                "advantages": torch.randn(rows, generator=g),
            }
            for ours, rllib in zip(_ppo_terms(OURS, logits, batch), _ppo_terms(RLLIB, logits, batch), strict=True):
                assert torch.equal(ours, rllib)
    finally:
        torch.set_num_threads(before)


def test_sampling_and_greedy_moves_go_through_rllibs_categoricals():
    logits = torch.randn(16, 9, generator=torch.Generator().manual_seed(0))
    ours, rllib = OURS.from_logits(logits), RLLIB.from_logits(logits)
    assert isinstance(ours, HingeCategorical) and isinstance(ours, TorchMultiCategorical)
    torch.manual_seed(1)
    drawn = ours.sample()
    torch.manual_seed(1)
    assert torch.equal(drawn, rllib.sample())
    assert torch.equal(ours.to_deterministic().sample(), rllib.to_deterministic().sample())


def test_unequal_hinges_fall_back_to_rllibs_per_hinge_arithmetic():
    logits = torch.randn(5, 7, generator=torch.Generator().manual_seed(2))
    ours = HingeCategorical.from_logits(logits, input_lens=[3, 4])
    rllib = TorchMultiCategorical.from_logits(logits, input_lens=[3, 4])
    actions = torch.tensor([[0, 3], [2, 1], [1, 0], [0, 2], [2, 3]])
    assert torch.equal(ours.logp(actions), rllib.logp(actions))
    assert torch.equal(ours.entropy(), rllib.entropy())

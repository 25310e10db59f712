"""The learners' fused optimiser step: the same arithmetic as RLlib's tensor-by-tensor one."""

from __future__ import annotations

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

"""IMPALA and APPO learners whose v-trace policy-gradient advantages are normalised per batch.

PPO standardises its GAE advantages in every minibatch; RLlib's IMPALA and APPO do not, so their policy
step scales with the return's units and the critic's error, and on this env they drifted instead of
learning. These learners standardise v-trace's `pg_advantages` (zero mean, unit spread over the batch)
and leave the value targets alone. RLlib computes both inside `compute_loss_for_module` with no hook
between them, so the loss is run with its module's `vtrace_torch` wrapped for the duration of the call.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import torch
from ray.rllib.algorithms.appo.torch.appo_torch_learner import APPOTorchLearner
from ray.rllib.algorithms.impala.torch.impala_torch_learner import IMPALATorchLearner

ADVANTAGE_EPS = 1e-8


def _normalising(vtrace: Callable[..., tuple[torch.Tensor, torch.Tensor]]) -> Callable[..., Any]:
    """`vtrace` whose policy-gradient advantages come back standardised over the batch."""

    def wrapped(**kwargs: Any) -> tuple[torch.Tensor, torch.Tensor]:
        targets, advantages = vtrace(**kwargs)
        centred = advantages - advantages.mean()
        return targets, centred / (centred.std() + ADVANTAGE_EPS)

    return wrapped


def _loss_with_normalised_advantages(learner: Any, parent: Any, kwargs: dict[str, Any]) -> Any:
    """Run `parent`'s loss with the `vtrace_torch` its module calls standardising the advantages."""
    module = inspect.getmodule(parent.compute_loss_for_module)
    original = module.vtrace_torch  # type: ignore[union-attr]
    module.vtrace_torch = _normalising(original)  # type: ignore[union-attr]
    try:
        return parent.compute_loss_for_module(learner, **kwargs)
    finally:
        module.vtrace_torch = original  # type: ignore[union-attr]


class NormalisedIMPALALearner(IMPALATorchLearner):
    """IMPALA with per-batch standardised v-trace advantages."""

    def compute_loss_for_module(self, **kwargs: Any) -> Any:
        return _loss_with_normalised_advantages(self, IMPALATorchLearner, kwargs)


class NormalisedAPPOLearner(APPOTorchLearner):
    """APPO with per-batch standardised v-trace advantages."""

    def compute_loss_for_module(self, **kwargs: Any) -> Any:
        return _loss_with_normalised_advantages(self, APPOTorchLearner, kwargs)


LEARNERS: dict[str, type] = {"impala": NormalisedIMPALALearner, "appo": NormalisedAPPOLearner}
"""The learner class each asynchronous algorithm trains with (PPO keeps RLlib's own)."""

"""Learners: PPO whose critic learns from longer returns than its policy, and IMPALA and APPO whose v-trace
policy-gradient advantages are normalised per batch.

PPO computes its advantages and the critic's targets with one GAE lambda. A small lambda keeps the
advantages' noise down but makes the critic a slow fixed-point iteration: each full fit shrinks its error
only by the factor gamma (1 - lambda) / (1 - gamma lambda) (0.99 at gamma 0.995, lambda 0.5), so after a
run's few hundred fits it still sees a fraction of the future. `TwoLambdaPPOLearner` takes the critic's
targets with `value_lambda` (near 1: returns measured over the rest of the episode) and the advantages
with PPO's own lambda. Off by default: it brings the critic's values 3-4x closer to the true ones, but
did not by itself improve where the greedy policy settles (README, "Learning").

PPO standardises its GAE advantages in every minibatch; RLlib's IMPALA and APPO do not, so their policy
step scales with the return's units and the critic's error, and on this env they drifted instead of
learning. These learners standardise v-trace's `pg_advantages` (zero mean, unit spread over the batch)
and leave the value targets alone. RLlib computes both inside `compute_loss_for_module` with no hook
between them, so the loss is run with its module's `vtrace_torch` wrapped for the duration of the call.

Every learner ends its connector pipeline with `PackMaps`, which hands the module the batch's maps as
int64 words: RLlib's per-epoch shuffle then moves a quarter of the time's bytes-as-bytes work.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import torch
from ray.rllib.algorithms.appo.torch.appo_torch_learner import APPOTorchLearner
from ray.rllib.algorithms.impala.torch.impala_torch_learner import IMPALATorchLearner
from ray.rllib.algorithms.ppo.torch.ppo_torch_learner import PPOTorchLearner
from ray.rllib.connectors.connector_v2 import ConnectorV2
from ray.rllib.connectors.learner import GeneralAdvantageEstimation
from ray.rllib.core.columns import Columns
from ray.rllib.evaluation.postprocessing import Postprocessing

from smorphi_rl.training.module import MAP_KEY, pack_maps

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


class PackMaps(ConnectorV2):
    """The learner pipeline's last piece: every module's map observations as int64 words (`pack_maps`).

    RLlib shuffles the whole train batch row by row once an epoch; indexing 2,000 uint8 maps of 2 x 64 x 64
    took 17 ms, the same rows as 1,024 int64 words each 4 ms (15 % of PPO's learner time before). The
    module reads either layout."""

    def __call__(self, *, batch: dict[str, Any], **kwargs: Any) -> Any:
        for column in batch.values():
            obs = column.get(Columns.OBS) if isinstance(column, dict) else None
            if isinstance(obs, dict) and isinstance(obs.get(MAP_KEY), torch.Tensor):
                obs[MAP_KEY] = pack_maps(obs[MAP_KEY])
        return batch


def _end_with_pack_maps(learner: Any) -> None:
    """Append `PackMaps` to a built learner's connector pipeline (after RLlib's own pieces)."""
    if learner._learner_connector is not None:
        learner._learner_connector.append(PackMaps())


class NormalisedIMPALALearner(IMPALATorchLearner):
    """IMPALA with per-batch standardised v-trace advantages."""

    def build(self) -> None:
        super().build()
        _end_with_pack_maps(self)

    def compute_loss_for_module(self, **kwargs: Any) -> Any:
        return _loss_with_normalised_advantages(self, IMPALATorchLearner, kwargs)


class NormalisedAPPOLearner(APPOTorchLearner):
    """APPO with per-batch standardised v-trace advantages."""

    def build(self) -> None:
        super().build()
        _end_with_pack_maps(self)

    def compute_loss_for_module(self, **kwargs: Any) -> Any:
        return _loss_with_normalised_advantages(self, APPOTorchLearner, kwargs)


VALUE_LAMBDA_KEY = "value_lambda"
"""The `learner_config_dict` key that carries the critic's GAE lambda to `TwoLambdaPPOLearner`."""


class TwoLambdaGAE(GeneralAdvantageEstimation):
    """GAE whose advantages use `lambda_` and whose value targets use `value_lambda` (one critic pass).

    RLlib computes both from one `compute_value_targets` call inside `__call__`; for the duration of the
    call that function is wrapped to also compute the `value_lambda` targets, which then replace the
    batch's value targets (single-agent: one module)."""

    def __init__(self, *args: Any, value_lambda: float, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.value_lambda = value_lambda

    def __call__(self, **kwargs: Any) -> Any:
        module = inspect.getmodule(GeneralAdvantageEstimation)
        original = module.compute_value_targets  # type: ignore[union-attr]
        critic_targets: list[Any] = []

        def both(**args: Any) -> Any:
            critic_targets.append(original(**(args | {"lambda_": self.value_lambda})))
            return original(**args)

        module.compute_value_targets = both  # type: ignore[union-attr]
        try:
            batch = super().__call__(**kwargs)
        finally:
            module.compute_value_targets = original  # type: ignore[union-attr]
        columns = [b for b in batch.values() if Postprocessing.VALUE_TARGETS in b]
        for column, targets in zip(columns, critic_targets, strict=True):
            old = column[Postprocessing.VALUE_TARGETS]
            column[Postprocessing.VALUE_TARGETS] = torch.as_tensor(targets, dtype=old.dtype, device=old.device)
        return batch


class TwoLambdaPPOLearner(PPOTorchLearner):
    """PPO whose critic's targets use `learner_config_dict["value_lambda"]` (advantages keep `lambda_`)."""

    def build(self) -> None:
        super().build()
        if self._learner_connector is None:
            return
        value_lambda = self.config.learner_config_dict.get(VALUE_LAMBDA_KEY)
        if value_lambda is not None:
            self._learner_connector.remove("GeneralAdvantageEstimation")
            self._learner_connector.append(
                TwoLambdaGAE(gamma=self.config.gamma, lambda_=self.config.lambda_, value_lambda=value_lambda)  # type: ignore[attr-defined]
            )
        _end_with_pack_maps(self)


LEARNERS: dict[str, type] = {
    "ppo": TwoLambdaPPOLearner,
    "impala": NormalisedIMPALALearner,
    "appo": NormalisedAPPOLearner,
}
"""The learner class each algorithm trains with."""

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

Every learner ends its connector pipeline with `CompactMaps`, which hands the module the batch's maps as
numbers in the module's table of distinct maps (or, when they are mostly distinct, as int64 words): RLlib's
per-epoch shuffle and minibatch slicing then move 4 bytes a row instead of each row's map.

Every learner also takes its optimiser step through `FusedStep`: the same clipping, nan handling and Adam
update as RLlib's, each done in one pass over all of a net's tensors instead of one call per tensor.

IMPALA's and APPO's learner threads are guarded (`GuardedLearnerThread`): an exception there fails the trial
with its cause instead of freezing it.
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


class CompactMaps(ConnectorV2):
    """The learner pipeline's last piece: every module's map observations in index form (the module's
    `index_maps`: each row's number in its table of distinct maps), else as int64 words (`pack_maps`).

    RLlib shuffles the whole train batch row by row once an epoch: 2,000 uint8 maps of 2 x 64 x 64 took
    17 ms, as int64 words 4 ms, and as map numbers next to nothing; the module then runs its CNN once per
    distinct map of a minibatch and gathers. The module reads every layout."""

    def __call__(self, *, batch: dict[str, Any], rl_module: Any = None, **kwargs: Any) -> Any:
        for module_id, column in batch.items():
            obs = column.get(Columns.OBS) if isinstance(column, dict) else None
            if not (isinstance(obs, dict) and isinstance(obs.get(MAP_KEY), torch.Tensor)):
                continue
            module = rl_module[module_id] if rl_module is not None and module_id in rl_module else None
            index_maps = getattr(module, "index_maps", None)
            indexed = index_maps(obs[MAP_KEY]) if index_maps is not None else None
            obs[MAP_KEY] = indexed if indexed is not None else pack_maps(obs[MAP_KEY])
        return batch


def clip_each_tensor(gradients_dict: dict[Any, torch.Tensor | None], *, grad_clip: float, grad_clip_by: str) -> None:
    """RLlib's `clip_gradients` in one fused pass for `grad_clip_by="norm"` (each tensor whose L2 norm is over
    `grad_clip` is scaled down to it; a nan norm leaves its tensor alone); other modes go to RLlib's."""
    from ray.rllib.utils.torch_utils import clip_gradients

    grads = [g for g in gradients_dict.values() if g is not None]
    if grad_clip_by != "norm" or not grads:
        clip_gradients(gradients_dict, grad_clip=grad_clip, grad_clip_by=grad_clip_by)  # type: ignore[arg-type]
        return
    norms = torch.stack(torch._foreach_norm(grads))
    coefficients = torch.where(norms > grad_clip, grad_clip / norms, torch.ones_like(norms))
    torch._foreach_mul_(grads, list(coefficients.unbind()))


def all_finite(grads: list[torch.Tensor]) -> bool:
    """Whether every entry of every tensor is finite (one reduction: a sum of squares is finite only then)."""
    return bool(torch.isfinite(torch.stack(torch._foreach_norm(grads))).all())


class FusedStep:
    """A TorchLearner mixin: Adam with torch's multi-tensor (`foreach`) update, per-tensor clipping in one pass
    (`clip_each_tensor`), and one finiteness check for all gradients before the step.

    RLlib's TorchLearner clips, checks for nan and checks again tensor by tensor (about 70 small calls an
    update for our two nets) and builds a single-tensor Adam on CPU; the arithmetic is the same. A step with
    a non-finite gradient, a torch lr scheduler or a grad scaler goes through RLlib's own `apply_gradients`
    (which zeroes nan gradients and warns)."""

    def configure_optimizers_for_module(self, module_id: Any, config: Any = None) -> None:
        params = self.get_parameters(self._module[module_id])  # type: ignore[attr-defined]
        self.register_optimizer(  # type: ignore[attr-defined]
            module_id=module_id, optimizer=torch.optim.Adam(params, foreach=True), params=params,
            lr_or_lr_schedule=config.lr,
        )  # fmt: skip

    @staticmethod
    def _get_clip_function() -> Callable[..., Any]:
        return clip_each_tensor

    @staticmethod
    def _set_optimizer_lr(optimizer: torch.optim.Optimizer, lr: Any) -> None:
        for group in optimizer.param_groups:  # a float: the foreach Adam on CPU takes no tensor rate
            group["lr"] = float(lr)

    def apply_gradients(self, gradients_dict: dict[Any, torch.Tensor]) -> None:
        grads = [g for g in gradients_dict.values() if g is not None]
        plain = self._lr_scheduler_classes is None and self._grad_scalers is None  # type: ignore[attr-defined]
        if not (plain and grads and all_finite(grads)):
            super().apply_gradients(gradients_dict)  # type: ignore[misc]
            return
        params = self._params  # type: ignore[attr-defined]
        for pid, grad in gradients_dict.items():
            params[pid].grad = grad
        for module_id, names in self._module_optimizers.items():  # type: ignore[attr-defined]
            for name in names:
                self.get_optimizer(module_id, name).step()  # type: ignore[attr-defined]


def _end_with_compact_maps(learner: Any) -> None:
    """Append `CompactMaps` to a built learner's connector pipeline (after RLlib's own pieces)."""
    if learner._learner_connector is not None:
        learner._learner_connector.append(CompactMaps())


class LearnerThreadError(RuntimeError):
    """IMPALA's or APPO's learner thread failed; the trial fails with it instead of waiting forever."""


class GuardedLearnerThread:
    """IMPALA and APPO learn in a thread of their learner. In RLlib an exception there ends the thread silently,
    and the trial then waits forever on the thread's queue (a frozen run). The guard catches it in the thread,
    which goes on taking batches off its queue without learning from them, so nothing blocks, and raises it in
    the trial's next `update`: the run fails, naming the cause."""

    _thread_error: Exception | None = None

    def build(self) -> None:
        super().build()  # type: ignore[misc]  # a mixin of a Learner
        thread = getattr(self, "_learner_thread", None)
        if thread is not None and hasattr(thread, "_update_method"):  # set before any batch is queued
            thread._update_method = self._guarded(thread._update_method)

    def _guarded(self, update: Callable[..., Any]) -> Callable[..., Any]:
        def guarded(**kwargs: Any) -> Any:
            if self._thread_error is not None:
                return None  # drain: the trial raises at its next update
            try:
                return update(**kwargs)
            except Exception as exc:  # kept, and raised in the trial's thread
                self._thread_error = exc
                return None

        return guarded

    def update(self, *args: Any, **kwargs: Any) -> Any:
        error = self._thread_error
        if error is not None:
            raise LearnerThreadError(f"the learner thread failed: {type(error).__name__}: {error}") from error
        return super().update(*args, **kwargs)  # type: ignore[misc]  # a mixin of a Learner


class NormalisedIMPALALearner(GuardedLearnerThread, FusedStep, IMPALATorchLearner):  # type: ignore[misc]  # RLlib's own bases disagree
    """IMPALA with per-batch standardised v-trace advantages."""

    def build(self) -> None:
        super().build()
        _end_with_compact_maps(self)

    def compute_loss_for_module(self, **kwargs: Any) -> Any:
        return _loss_with_normalised_advantages(self, IMPALATorchLearner, kwargs)


class NormalisedAPPOLearner(GuardedLearnerThread, FusedStep, APPOTorchLearner):  # type: ignore[misc]  # RLlib's own bases disagree
    """APPO with per-batch standardised v-trace advantages."""

    def build(self) -> None:
        super().build()
        _end_with_compact_maps(self)

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


class TwoLambdaPPOLearner(FusedStep, PPOTorchLearner):
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
        _end_with_compact_maps(self)


LEARNERS: dict[str, type] = {
    "ppo": TwoLambdaPPOLearner,
    "impala": NormalisedIMPALALearner,
    "appo": NormalisedAPPOLearner,
}
"""The learner class each algorithm trains with."""

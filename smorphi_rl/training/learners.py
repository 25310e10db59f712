"""Learners: RLlib's PPO, and IMPALA and APPO whose v-trace policy-gradient advantages are normalised per batch.

PPO standardises its GAE advantages in every minibatch; RLlib's IMPALA and APPO do not, so their policy
step scales with the return's units and the critic's error, and on this env they drifted instead of
learning. These learners standardise v-trace's `pg_advantages` (zero mean, unit spread over the batch)
and leave the value targets alone. RLlib computes both inside `compute_loss_for_module` with no hook
between them, so the loss is RLlib's own with `vtrace_torch` resolved to a normalising one
(`rllib_compat.with_globals`: a copy of the method; RLlib's module is left as it is). That v-trace also takes
the IMPALA paper's lambda (`vtrace_lambda`), which RLlib's lacks, the advantage's form (`pg_lambda`) and, for
APPO, a critic frozen at each target refresh (`FrozenCritic`), from the config's `learner_config_dict`.

Every learner ends its connector pipeline with `CompactMaps`, which hands the module the batch's maps as
numbers in the module's table of distinct maps (or, when they are mostly distinct, as int64 words): RLlib's
per-epoch shuffle and minibatch slicing then move 4 bytes a row instead of each row's map.

Every learner also takes its optimiser step through `FusedStep`: the same clipping, nan handling and Adam
update as RLlib's, each done in one pass over all of a net's tensors instead of one call per tensor, through
the Learner's public methods (`configure_optimizers_for_module`, `postprocess_gradients_for_module`,
`apply_gradients`), written whole.

IMPALA's and APPO's learner threads are guarded (`GuardedLearnerThread`): an exception there fails the trial
with its cause instead of freezing it; the env runners get the weights of the learner's latest update
(`LatestWeights`).
"""

from __future__ import annotations

import contextvars
import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from ray.rllib.algorithms.appo.torch.appo_torch_learner import APPOTorchLearner
from ray.rllib.algorithms.impala.torch.impala_torch_learner import IMPALATorchLearner
from ray.rllib.algorithms.ppo.torch.ppo_torch_learner import PPOTorchLearner
from ray.rllib.connectors.connector_v2 import ConnectorV2
from ray.rllib.core.columns import Columns
from ray.rllib.utils.metrics import NUM_ENV_STEPS_SAMPLED_LIFETIME
from ray.rllib.utils.schedules.scheduler import Scheduler
from ray.rllib.utils.torch_utils import clip_gradients

from smorphi_rl import rllib_compat
from smorphi_rl.training.module import MAP_KEY, pack_maps
from smorphi_rl.training.snapshot import release_after_failure, update_lock, updates_held

ADVANTAGE_EPS = 1e-8
TRACE_LAMBDA_KEY = "vtrace_lambda"
"""The key of v-trace's lambda in the AlgorithmConfig's public `learner_config_dict` (config.py sets it)."""
FROZEN_CRITIC_KEY = "vtrace_frozen_critic"
"""The key that makes APPO's v-trace read the critic as frozen at its target policy's last refresh (`FrozenCritic`)."""
PG_LAMBDA_KEY = "vtrace_pg_lambda"
"""The key of the policy-gradient advantage's `pg_lambda` (`vtrace_lambda`) in the same dict."""


@dataclass(frozen=True)
class TraceSettings:
    """What the v-trace of the loss being computed in this thread needs beyond RLlib's arguments."""

    lambda_: float = 1.0
    pg_lambda: float = 1.0
    mask: torch.Tensor | None = None
    """Time-major, 1.0 on the steps the loss learns from; None: every step."""
    values: torch.Tensor | None = None
    """Time-major state values v-trace reads in place of RLlib's (the critic being trained); None: RLlib's."""


_TRACE: contextvars.ContextVar[TraceSettings | None] = contextvars.ContextVar("vtrace", default=None)
"""Set around RLlib's loss by `with_trace_settings` (None: RLlib's v-trace settings, lambda 1 and no mask)."""


def vtrace_lambda(
    *, lambda_: float = 1.0, pg_lambda: float = 1.0, mask: torch.Tensor | None = None, **kwargs: Any
) -> tuple[torch.Tensor, torch.Tensor]:
    """V-trace with the IMPALA paper's lambda (Espeholt et al. 2018, remark 1): traces cut by
    `c_s = lambda min(1, rho_s)`, as GAE's lambda cuts returns. At lambda 1 and no mask it is RLlib's
    `vtrace_torch`; at 0 the targets are one-step TD (both by test). RLlib's has no lambda: its advantages ride on
    every later random move of the episode, the noise that kept PPO at GAE lambda 0.95 from settling (presets.py).

    `mask` (time-major, 0 on the steps the loss ignores): those steps add no TD error and cut the trace, so the
    step before them is bootstrapped from their value. RLlib's has no mask and gives the extra timestep it adds
    after every episode chunk (to hold the bootstrap value) a TD error of `-rho V`: the bootstrap of every chunk
    that does not end a row is wiped (the last real step's target becomes its reward alone).

    `pg_lambda`: how much of the next state's correction `v_(s+1) - V(x_(s+1))` the policy-gradient advantage
    takes, `A_s = rho_s (r_s + gamma (V(x_(s+1)) + pg_lambda (v_(s+1) - V(x_(s+1)))) - V(x_s))`. At 1 it is
    IMPALA's (every later step's TD error enters at full weight from the first); at `lambda_` and on-policy
    it is GAE's advantage at that lambda, PPO's (by test)."""
    rhos = torch.exp(kwargs["target_action_log_probs"] - kwargs["behaviour_action_log_probs"])
    discounts, rewards, values = kwargs["discounts"], kwargs["rewards"], kwargs["values"]
    bootstrap = kwargs["bootstrap_values"]
    clip_rho, clip_pg = kwargs.get("clip_rho_threshold", 1.0), kwargs.get("clip_pg_rho_threshold", 1.0)
    clipped_rhos = rhos if clip_rho is None else torch.clamp(rhos, max=clip_rho)
    cs = lambda_ * torch.clamp(rhos, max=1.0)
    pg_rhos = rhos if clip_pg is None else torch.clamp(rhos, max=clip_pg)
    if mask is not None:
        clipped_rhos, cs, pg_rhos = clipped_rhos * mask, cs * mask, pg_rhos * mask
    next_values = torch.cat([values[1:], bootstrap.unsqueeze(0)], dim=0)
    deltas = clipped_rhos * (rewards + discounts * next_values - values)
    acc = torch.zeros_like(bootstrap)
    corrections = []
    for t in reversed(range(len(discounts))):
        acc = deltas[t] + discounts[t] * cs[t] * acc
        corrections.append(acc)
    vs = torch.stack(corrections[::-1]) + values
    next_vs = torch.cat([vs[1:], bootstrap.unsqueeze(0)], dim=0)
    pg_next = next_values + pg_lambda * (next_vs - next_values)
    return vs.detach(), (pg_rhos * (rewards + discounts * pg_next - values)).detach()


def normalised_vtrace(**kwargs: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """V-trace (`vtrace_lambda`, with the settings of the loss being computed) whose policy-gradient advantages
    come back standardised over the steps the loss learns from (the others stay 0)."""
    trace = _TRACE.get() or TraceSettings()
    if trace.values is not None:  # bootstrapped as RLlib does: from the next row's first value
        kwargs = {**kwargs, "values": trace.values,
                  "bootstrap_values": torch.cat([trace.values[0][1:], trace.values[0][0:1]])}  # fmt: skip
    targets, advantages = vtrace_lambda(lambda_=trace.lambda_, pg_lambda=trace.pg_lambda, mask=trace.mask, **kwargs)
    kept = torch.ones_like(advantages, dtype=torch.bool) if trace.mask is None else trace.mask > 0
    mean, std = advantages[kept].mean(), advantages[kept].std()
    return targets, torch.where(kept, (advantages - mean) / (std + ADVANTAGE_EPS), torch.zeros_like(advantages))


def learnable_steps(loss_mask: torch.Tensor) -> torch.Tensor:
    """The loss mask of a (mini)batch less the steps after its last masked-out one: RLlib ends every episode
    chunk with a masked extra timestep holding the bootstrap value, so steps after the last one belong to a
    chunk cut by the minibatch, whose last step RLlib would bootstrap from the minibatch's first state (another
    env's). A batch without any masked step is left as it is."""
    masked = torch.nonzero(~loss_mask.bool())
    if len(masked) == 0:
        return loss_mask
    kept = loss_mask.clone()
    kept[int(masked[-1]) + 1 :] = False
    return kept


def with_trace_settings(loss: Callable[..., Any]) -> Callable[..., Any]:
    """RLlib's loss method `loss` (a copy calling `normalised_vtrace`) on the batch's learnable steps
    (`learnable_steps`), at the lambda its config names."""

    def compute_loss_for_module(self: Any, *, module_id: Any, config: Any, batch: Any, fwd_out: Any) -> Any:
        settings = config.learner_config_dict or {}
        lambda_, pg_lambda = float(settings.get(TRACE_LAMBDA_KEY, 1.0)), float(settings.get(PG_LAMBDA_KEY, 1.0))
        mask = learnable_steps(batch[Columns.LOSS_MASK])
        batch = {**batch, Columns.LOSS_MASK: mask}
        steps = config.get_rollout_fragment_length()
        by_time = rllib_compat.time_major(mask.float(), steps, batch.get("seq_lens"))
        frozen = getattr(self, "frozen_values", None)
        values = frozen(module_id, batch) if frozen is not None and settings.get(FROZEN_CRITIC_KEY) else None
        if values is not None:
            values = rllib_compat.time_major(values, steps, batch.get("seq_lens"))
        token = _TRACE.set(TraceSettings(lambda_, pg_lambda, mask=by_time, values=values))
        try:
            return loss(self, module_id=module_id, config=config, batch=batch, fwd_out=fwd_out)
        finally:
            _TRACE.reset(token)

    compute_loss_for_module.__doc__ = loss.__doc__
    compute_loss_for_module.__wrapped__ = loss  # type: ignore[attr-defined]  # functools' convention
    return compute_loss_for_module


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
    grads = [g for g in gradients_dict.values() if g is not None]
    if grad_clip_by != "norm" or not grads:
        clip_gradients(gradients_dict, grad_clip=grad_clip, grad_clip_by=grad_clip_by)  # type: ignore[arg-type]
        return
    norms = rllib_compat.tensor_norms(grads)
    rllib_compat.scale_each_(grads, torch.where(norms > grad_clip, grad_clip / norms, torch.ones_like(norms)))


def all_finite(grads: list[torch.Tensor]) -> bool:
    """Whether every entry of every tensor is finite (one reduction: a sum of squares is finite only then)."""
    return bool(torch.isfinite(rllib_compat.tensor_norms(grads)).all())


class FusedStep:
    """A TorchLearner mixin: Adam with torch's multi-tensor (`foreach`) update, per-tensor clipping in one pass
    (`clip_each_tensor`), and one finiteness check for all gradients before the step.

    RLlib's TorchLearner clips, checks for nan and checks again tensor by tensor (about 70 small calls an
    update for our two nets) and builds a single-tensor Adam on CPU; the arithmetic is the same. A step with a
    non-finite gradient goes through RLlib's own `apply_gradients` (which zeroes nan gradients and warns); a
    learning-rate schedule moves the rate as RLlib's does; torch lr schedulers and grad scalers (RLlib's
    experimental settings, which our configs never set) are not supported. Steps are taken under the learner's
    update lock and skipped once a run's end holds its updates (`snapshot.hold_updates`)."""

    def configure_optimizers_for_module(self, module_id: Any, config: Any = None) -> None:
        params = self.get_parameters(self.module[module_id])  # type: ignore[attr-defined]
        # The rate is a float set here and moved by us: the foreach Adam on CPU takes no tensor rate, which
        # RLlib's own scheduling sets. RLlib's Scheduler computes it, as RLlib's scheduling would.
        rate = Scheduler(fixed_value_or_schedule=config.lr, framework="torch")
        optimizer = torch.optim.Adam(params, lr=float(rate.get_current_value()), foreach=True)
        self.register_optimizer(  # type: ignore[attr-defined]
            module_id=module_id, optimizer=optimizer, params=params, lr_or_lr_schedule=None
        )
        if rate.use_schedule:
            self._rates = [*getattr(self, "_rates", []), (optimizer, rate)]

    def after_gradient_based_update(self, *, timesteps: dict[str, Any]) -> None:
        for optimizer, rate in getattr(self, "_rates", []):  # as RLlib moves a scheduled rate, before it logs it
            value = float(rate.update(timestep=timesteps.get(NUM_ENV_STEPS_SAMPLED_LIFETIME, 0)))
            for group in optimizer.param_groups:
                group["lr"] = value
        super().after_gradient_based_update(timesteps=timesteps)  # type: ignore[misc]

    def postprocess_gradients_for_module(
        self, *, module_id: Any, config: Any = None, module_gradients_dict: dict[Any, torch.Tensor]
    ) -> dict[Any, torch.Tensor]:
        if not config.grad_clip or config.grad_clip_by != "norm" or config.log_gradients:
            return super().postprocess_gradients_for_module(  # type: ignore[misc, no-any-return]
                module_id=module_id, config=config, module_gradients_dict=module_gradients_dict
            )
        clipped = {}
        for _, optimizer in self.get_optimizers_for_module(module_id):  # type: ignore[attr-defined]
            grads = self.filter_param_dict_for_optimizer(module_gradients_dict, optimizer)  # type: ignore[attr-defined]
            clip_each_tensor(grads, grad_clip=config.grad_clip, grad_clip_by="norm")
            clipped.update(grads)
        return clipped

    def apply_gradients(self, gradients_dict: dict[Any, torch.Tensor]) -> None:
        with update_lock(self):  # a run's end holds the updates (`snapshot.hold_updates`): none applies after it
            if not updates_held(self):
                self._apply_gradients(gradients_dict)

    def _apply_gradients(self, gradients_dict: dict[Any, torch.Tensor]) -> None:
        grads = [g for g in gradients_dict.values() if g is not None]
        if not (grads and all_finite(grads)):  # RLlib's step zeroes nan gradients and warns
            super().apply_gradients(gradients_dict)  # type: ignore[misc]
            return
        for module_id in self.module.keys():  # type: ignore[attr-defined]  # noqa: SIM118  # a MultiRLModule
            for _, optimizer in self.get_optimizers_for_module(module_id):  # type: ignore[attr-defined]
                for group in optimizer.param_groups:
                    for param in group["params"]:
                        param.grad = gradients_dict.get(self.get_param_ref(param))  # type: ignore[attr-defined]
                optimizer.step()


def _end_with_compact_maps(learner: Any) -> None:
    """Append `CompactMaps` to a built learner's connector pipeline (after RLlib's own pieces)."""
    pipeline = rllib_compat.learner_pipeline(learner)
    if pipeline is not None:
        pipeline.append(CompactMaps())


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
        rllib_compat.guard_learner_thread(self, self._guarded)  # before any batch is queued

    def _guarded(self, update: Callable[..., Any]) -> Callable[..., Any]:
        def guarded(**kwargs: Any) -> Any:
            if self._thread_error is not None:
                return None  # drain: the trial raises at its next update
            try:
                return update(**kwargs)
            except Exception as exc:  # kept, and raised in the trial's thread
                release_after_failure(self)  # a step that raised keeps its lock: checkpoints would wait for it
                self._thread_error = exc
                return None

        return guarded

    def update(self, *args: Any, **kwargs: Any) -> Any:
        error = self._thread_error
        if error is not None:
            raise LearnerThreadError(f"the learner thread failed: {type(error).__name__}: {error}") from error
        return super().update(*args, **kwargs)  # type: ignore[misc]  # a mixin of a Learner


class LatestWeights:
    """An IMPALA/APPO learner mixin: `update` hands the algorithm the weights after the update it waited for
    (`rllib_compat.latest_learner_state`), where RLlib's hands those of the update before. On 2 env runners with a
    plain learner queue (`learner_queue` 1) APPO's behaviour policy trailed its target by 2.4 train batches
    (probability ratio 1.23, variance 0.26), with these by 1.4 (1.03, 0.05)."""

    def update(self, *args: Any, **kwargs: Any) -> Any:
        result = super().update(*args, **kwargs)  # type: ignore[misc]  # a mixin of a Learner
        if kwargs.get("return_state") and isinstance(result, dict):  # the weights the algorithm broadcasts
            latest = rllib_compat.latest_learner_state(self)  # after the update this call waited for
            if latest is not None:
                result[rllib_compat.LEARNER_STATE_KEY] = latest
        return result


class NormalisedIMPALALearner(GuardedLearnerThread, LatestWeights, FusedStep, IMPALATorchLearner):  # type: ignore[misc]  # RLlib's own bases disagree
    """IMPALA with per-batch standardised v-trace advantages."""

    def build(self) -> None:
        super().build()
        _end_with_compact_maps(self)

    compute_loss_for_module = with_trace_settings(
        rllib_compat.with_globals(IMPALATorchLearner.compute_loss_for_module, vtrace_torch=normalised_vtrace)
    )


class FrozenCritic:
    """An APPO learner mixin: a copy of each module's critic taken whenever APPO refreshes the module's target
    policy, for v-trace's advantages and value targets (`frozen_values`). PPO computes its advantages and value
    targets once per batch, before its epochs; RLlib's APPO recomputes them every minibatch with the critic
    it is training on that very batch, so by the later passes the critic has fit the returns and the
    standardised advantages are mostly noise. A refresh is seen as a change of the target policy's weights
    (APPO copies the policy there), so the copy is taken after the update that refreshed them."""

    def frozen_values(self, module_id: Any, batch: dict[str, Any]) -> torch.Tensor | None:
        module = self.module[module_id].unwrapped()  # type: ignore[attr-defined]  # a mixin of a Learner
        frozen = getattr(self, "_frozen", {}).get(module_id)  # only modules with a `value_net` get one
        if frozen is None:
            return None
        with torch.no_grad():
            return module.compute_values_with(frozen[0], batch)

    def after_gradient_based_update(self, *, timesteps: dict[str, Any]) -> None:
        super().after_gradient_based_update(timesteps=timesteps)  # type: ignore[misc]  # refreshes target nets
        if not (self.config.learner_config_dict or {}).get(FROZEN_CRITIC_KEY):  # type: ignore[attr-defined]
            return
        store = self.__dict__.setdefault("_frozen", {})
        for module_id, wrapped in self.module.items():  # type: ignore[attr-defined]
            module = wrapped.unwrapped()
            if not hasattr(module, "value_net") or not hasattr(module, "get_target_network_pairs"):
                continue
            mark = next(iter(module.get_target_network_pairs()[0][1].parameters())).detach()
            held = store.get(module_id)
            if held is None or not torch.equal(held[1], mark):  # the target policy was refreshed (or first)
                store[module_id] = (copy.deepcopy(module.value_net()), mark.clone())


class NormalisedAPPOLearner(GuardedLearnerThread, LatestWeights, FrozenCritic, FusedStep, APPOTorchLearner):  # type: ignore[misc]  # RLlib's own bases disagree
    """APPO with per-batch standardised v-trace advantages."""

    def build(self) -> None:
        super().build()
        _end_with_compact_maps(self)

    compute_loss_for_module = with_trace_settings(
        rllib_compat.with_globals(APPOTorchLearner.compute_loss_for_module, vtrace_torch=normalised_vtrace)
    )


class CompactPPOLearner(FusedStep, PPOTorchLearner):
    """RLlib's PPO with the fused optimiser step and `CompactMaps` at the end of its connector pipeline."""

    def build(self) -> None:
        super().build()
        _end_with_compact_maps(self)


LEARNERS: dict[str, type] = {
    "ppo": CompactPPOLearner,
    "impala": NormalisedIMPALALearner,
    "appo": NormalisedAPPOLearner,
}
"""The learner class each algorithm trains with."""

"""RLlib callbacks: our episode metrics for TensorBoard and each episode's best shape for the top-k table.

Runs inside the env runners (`on_episode_end`) and the trial process (`on_algorithm_init`,
`on_train_result`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

from ray.rllib.callbacks.callbacks import RLlibCallback
from ray.rllib.core import DEFAULT_MODULE_ID
from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME

from smorphi_rl.policy_file import MAX_WEIGHT
from smorphi_rl.protocol import EVAL_KEY, TRAINED_FIGURES, TRAINED_KEY
from smorphi_rl.training.heap import settle_heap
from smorphi_rl.training.result_keys import METRIC_PREFIX
from smorphi_rl.training.runners import push_module_to_runners
from smorphi_rl.training.snapshot import hold_updates, snapshot_module, update_lock
from smorphi_rl.training.topk import EPISODE_BEST_KEY, EpisodeBest, encode_bests
from smorphi_rl.vector_env import SEED_KEY, action_seed

LEARNER_THREADS = 2
"""Torch threads of PPO's learner (IMPALA and APPO take 1): a fixed number, not the machine's cores."""
WINDOW = 50
"""Episodes each mean is taken over (RLlib's own episode_return_mean uses 100)."""


def _step_infos(episode: Any, chunks: list[Any] | None) -> list[dict[str, Any]]:
    """The info of every step of the whole episode (it may arrive as several chunks)."""
    infos: list[dict[str, Any]] = []
    for chunk in [*(chunks or []), episode]:
        infos.extend(chunk.get_infos()[1:])  # [0] is the observation the chunk starts from
    return infos


class MorphologyCallbacks(RLlibCallback):
    """Episode mean and best P_c, P_len, R1, the R1 of the shape the episode ends on, and the best shape's angles;
    every `eval_every` iterations (and the first), the evaluation protocol's greedy roll-outs (`with_evaluation`)."""

    eval_every: int = 0
    eval_final_steps: int = 0
    eval_starts: tuple[tuple[float, float, float], ...] = ()
    eval_optima: dict[str, Any] = {}  # noqa: RUF012 (set per run by with_evaluation)
    select_starts: tuple[tuple[float, float, float], ...] = ()
    """Other seeded starts on which the run chooses the policy it ends on (none: it ends on its last)."""
    eval_maps: tuple[str, ...] = ()
    """The maps evaluated on (none: the training maps)."""
    design_budget: int = 0
    """Planner evaluations of the designer's figures at each evaluation (`policy.DesignEvaluation`; 0: none)."""
    _design: Any = None
    _evaluation: Any = None
    """The GreedyRollouts this run's evaluations reuse (its envs keep their scored shapes), made at the first:
    the protocol's starts, then the selection starts, rolled out together (one forward pass a step for both)."""
    _kept: Any = None
    """(selection score, env steps, module state, protocol evaluation, designer's figures) of the best policy
    evaluated so far (after a resume: its evaluation None and figures empty, rolled out again if it is put back)."""
    _ended: bool = False
    """Whether the run's last iteration has been evaluated (by its budget, or `end_run`)."""
    _trained: Any = None
    """The module state the learner trained to, where the run's end put the kept policy back in its place (a run
    stopped early goes on from it when resumed, not from the policy it ended on); None otherwise."""
    _snapshot: Any = None
    """((iteration, env steps), (evaluations, weights)) of the latest evaluation: `end_run` on an iteration just
    evaluated reuses it where no learner thread has stepped since."""

    def on_environment_created(self, *, env: Any, env_context: Any, **kwargs: Any) -> None:
        """Tell our vector env which env runner it is in (RLlib's vector entry point loses the index), and give a
        remote runner's action sampling its own stream (`vector_env.action_seed`) in place of RLlib's
        `seed + worker_index` (RLlib makes a runner's env once, when it builds the runner). The trial process's
        runner keeps the run's seed: its torch generator is the learner's too."""
        worker = int(getattr(env_context, "worker_index", 0) or 0)
        if hasattr(env, "set_worker_index"):
            env.set_worker_index(worker)
        run_seed = env_context.get(SEED_KEY) if hasattr(env_context, "get") else None
        if worker > 0 and run_seed is not None:
            import torch

            torch.manual_seed(action_seed(int(run_seed), worker))

    def on_algorithm_init(self, *, algorithm: Any, **kwargs: Any) -> None:
        """Torch threads of the trial's learner, and its garbage collector settled (`heap`). PPO samples, then
        learns: its learner has the machine to itself and takes LEARNER_THREADS (fixed, so a seeded run's bits do
        not depend on the machine's cores). IMPALA and APPO learn while their
        env runners sample, so a second thread only contends with them; on 2 cores IMPALA trained 5,208 ->
        6,644 env steps/s and APPO 5,008 -> 6,187 with one."""
        import torch

        torch.set_num_threads(1 if _is_async(algorithm) else LEARNER_THREADS)
        _on_learner_itself(algorithm, lambda learner: update_lock(learner) and None)  # before the first step
        settle_heap()  # the built algorithm's objects live as long as the trial: out of the collector's way

    def on_episode_end(
        self,
        *,
        episode: Any,
        prev_episode_chunks: list[Any] | None = None,
        metrics_logger: Any = None,
        **kwargs: Any,
    ) -> None:
        infos = _step_infos(episode, prev_episode_chunks)
        if not infos or metrics_logger is None:
            return
        last = infos[-1]
        n = len(infos)
        values = {
            "P_c_mean": sum(i["P_c"] for i in infos) / n,
            "P_len_mean": sum(i["P_len"] for i in infos) / n,
            "R1_mean": sum(i["R1"] for i in infos) / n,
            "R1_final": last["R1"],
            "best_P_c": last["best_P_c"],
            "best_P_len": last["best_P_len"],
            "best_R1": last["best_R1"],
            "best_theta1": last["best_theta"][0],
            "best_theta2": last["best_theta"][1],
            "best_theta3": last["best_theta"][2],
        }
        for name, value in values.items():
            metrics_logger.log_value((METRIC_PREFIX, name), float(value), reduce="mean", window=WINDOW)
        metrics_logger.log_value((METRIC_PREFIX, "best_R1_max"), float(last["best_R1"]), reduce="max", window=WINDOW)
        t1, t2, t3 = (float(t) for t in last["best_theta"])
        best = EpisodeBest(str(last["map"]), (t1, t2, t3), float(last["best_P_c"]), int(last["best_P_len"]),
                           float(last["best_R1"]))  # fmt: skip
        metrics_logger.log_value(EPISODE_BEST_KEY, best.to_row(), reduce="item_series")

    def on_train_result(self, *, algorithm: Any, result: dict[str, Any], **kwargs: Any) -> None:
        steps = int(result.get(NUM_ENV_STEPS_SAMPLED_LIFETIME) or 0)
        bad = _on_learner_itself(algorithm, lambda learner: diverged(learner.module[DEFAULT_MODULE_ID]))
        if bad:  # the runners would sample from NaN and fail, restarted by RLlib for ever: end the run now
            raise DivergedError(f"the policy diverged after {steps:,} env steps: weight {bad} holds values beyond "
                                f"{MAX_WEIGHT:g} or not numbers (a learning rate or step size too large; a resume "
                                "would repeat it)")  # fmt: skip
        runners = result.get(ENV_RUNNER_RESULTS, {})
        bests = runners.pop(EPISODE_BEST_KEY, None)
        if not isinstance(bests, list | tuple):  # no episode ended this iteration (RLlib reports NaN)
            bests = []
        result[EPISODE_BEST_KEY] = encode_bests(bests)
        self._evaluate(algorithm, result, bool(self.eval_final_steps and steps >= self.eval_final_steps))

    def end_run(self, *, algorithm: Any, result: dict[str, Any]) -> None:
        """The run ends at this iteration before its budget (a sweep's stop criterion, `max_iterations`): what the
        budget's last iteration does, once; the iteration's `result` gains the final evaluation."""
        if not self._ended:
            self._evaluate(algorithm, result, True)

    def _evaluate(self, algorithm: Any, result: dict[str, Any], last: bool) -> None:
        """Every `eval_every` iterations, the first and the `last`: the protocol's greedy roll-outs (and the
        designer's figures) on one snapshot of the weights, into `result`; at the last, an asynchronous learner's
        updates held first and the kept policy put back if it beat the trained one (`_select`)."""
        iteration = int(getattr(algorithm, "iteration", 0) or 0)
        if last:  # an asynchronous learner's thread would go on stepping: the checkpoint holds what is evaluated
            self._ended = True
            _on_learner_itself(algorithm, hold_updates)
        if self.eval_every and self.eval_starts and (iteration <= 1 or iteration % self.eval_every == 0 or last):
            steps = int(result.get(NUM_ENV_STEPS_SAMPLED_LIFETIME) or 0)
            if self._evaluation is None:
                self._evaluation = self._protocol(algorithm, self.eval_starts + self.select_starts)
            if self.design_budget and self._design is None:
                self._design = self._design_evaluation(algorithm)
            calls = [self._evaluation, *([self._design] if self.design_budget else [])]
            if self._snapshot is not None and self._snapshot[0] == (iteration, steps) and not _is_async(algorithm):
                (both, *design), state = self._snapshot[1]  # this iteration's, evaluated already: the same weights
            else:
                (both, *design), state = _on_snapshot(algorithm, calls)
            self._snapshot = ((iteration, steps), ((both, *design), state))
            n = len(self.eval_starts)
            trained = [replace(e, outcomes=e.outcomes[:n]) for e in both]
            protocol, policy_steps, policy_design = trained, steps, design
            if self.select_starts:
                selection = [replace(e, outcomes=e.outcomes[n:]) for e in both]
                protocol, policy_steps, policy_design = self._select(algorithm, steps, last, selection, trained,
                                                                     state, design)  # fmt: skip
            result[EVAL_KEY] = evaluation_metrics(protocol) | {"policy_env_steps": policy_steps}
            for figures in policy_design:  # the designer's figures of the policy the row reports
                result[EVAL_KEY] |= figures
            if protocol is not trained:  # the run ends on an earlier policy; the curves keep the trained one's
                figures = evaluation_metrics(trained)
                result[EVAL_KEY][TRAINED_KEY] = {k: figures[k] for k in TRAINED_FIGURES}
                for designed in design:
                    result[EVAL_KEY][TRAINED_KEY] |= designed

    def _protocol(self, algorithm: Any, starts: Any) -> Any:
        """The protocol's greedy roll-outs from `starts` on every evaluated map (a GreedyRollouts)."""
        import numpy as np

        from smorphi_rl.env_config import EnvConfig
        from smorphi_rl.protocol import Optimum
        from smorphi_rl.training.policy import GreedyRollouts

        known = set(EnvConfig.__dataclass_fields__)
        raw = {k: v for k, v in dict(algorithm.config.env_config).items() if k in known}
        env = EnvConfig.from_dict(raw)
        env = replace(env, maps=self.eval_maps or env.map_files)  # a generated floor has no optimum: files only
        optima = {name: Optimum(**o) for name, o in self.eval_optima.items()}
        return GreedyRollouts(env, np.array(starts, dtype=np.float64), optima)

    def _design_evaluation(self, algorithm: Any) -> Any:
        """The designer's figures on the evaluated maps (a DesignEvaluation)."""
        from smorphi_rl.protocol import Optimum
        from smorphi_rl.training.policy import DesignEvaluation

        env = self._protocol(algorithm, ()).env_config
        return DesignEvaluation(env, {name: Optimum(**o) for name, o in self.eval_optima.items()}, self.design_budget)

    def _select(
        self, algorithm: Any, steps: int, last: bool, selection: list[Any], protocol: list[Any],
        state: dict[str, Any], design: list[dict[str, Any]],
    ) -> tuple[list[Any], int, list[dict[str, Any]]]:  # fmt: skip
        """Rank the evaluated policy (weights `state`) by its `selection` evaluation and keep it if it is the best
        so far (ties: the later); at the run's last iteration, put the kept policy back if it beat the last one.
        The protocol evaluation, env steps and designer's figures (`design`) of the policy the learner now holds
        (greedy roll-outs and designs are deterministic, so the kept policy's stand for it)."""
        score = selection_score(selection)
        kept = self._kept
        if kept is None or score >= kept[0]:
            self._kept = (score, steps, state, protocol, design)
            return protocol, steps, design
        if not last:
            return protocol, steps, design
        self._trained = state
        _on_live_learner(algorithm, lambda module: module.load_state_dict(kept[2]))
        push_module_to_runners(algorithm)  # the checkpoint's runners hold the policy its learner holds
        evaluation, kept_design = kept[3], kept[4]
        if evaluation is None:  # kept before a resume, which keeps its weights only: its roll-outs are repeated
            calls = [self._evaluation, *([self._design] if self.design_budget else [])]
            (both, *kept_design), _ = _on_snapshot(algorithm, calls)
            evaluation = [replace(e, outcomes=e.outcomes[: len(self.eval_starts)]) for e in both]
        return evaluation, int(kept[1]), kept_design

    def kept_policy(self) -> dict[str, Any] | None:
        """The kept policy as numbers and arrays (a resumable sweep's state file holds it): its selection score,
        env steps and weights; None when none is kept."""
        if self._kept is None or not math.isfinite(self._kept[0][1]):  # a NaN never ranks: nothing to keep
            return None
        (within, gap), steps, state, *_ = self._kept
        return {"score": [int(within), float(gap)], "env_steps": int(steps), "weights": _as_arrays(state)}

    def trained_weights(self) -> dict[str, Any] | None:
        """The weights the learner trained to, as numpy arrays, where the run's end put the kept policy in their
        place (a resumable state file holds them as the learner's); None where the learner holds them still."""
        return None if self._trained is None else _as_arrays(self._trained)

    def restore_kept(self, kept: dict[str, Any]) -> None:
        """Keep the policy `kept_policy` gave before a resume, as if this run had evaluated it."""
        import torch

        within, gap = kept["score"]
        weights = {name: torch.from_numpy(value.copy()) for name, value in kept["weights"].items()}
        self._kept = ((int(within), float(gap)), int(kept["env_steps"]), weights, None, [])


def _as_arrays(state: dict[str, Any]) -> dict[str, Any]:
    """A module state's tensors as numpy arrays, by name (what a resumable state file holds)."""
    return {name: value.detach().cpu().numpy() for name, value in state.items()}


def _is_async(algorithm: Any) -> bool:
    """Whether the algorithm's learner steps in a thread of its own, beside its env runners (IMPALA, APPO)."""
    from ray.rllib.algorithms.impala import IMPALA  # APPO is an IMPALA

    return isinstance(algorithm, IMPALA)


def ours(algorithm: Any) -> list[MorphologyCallbacks]:
    """The algorithm's callbacks objects of this module's class (RLlib keeps one object, or a list of them)."""
    callbacks = algorithm.callbacks if isinstance(algorithm.callbacks, list) else [algorithm.callbacks]
    return [c for c in callbacks if isinstance(c, MorphologyCallbacks)]


def end_run(algorithm: Any, result: dict[str, Any]) -> None:
    """Tell the run's callbacks that this iteration (`result`) is its last; a no-op where the budget's last
    iteration has been evaluated already."""
    for callback in ours(algorithm):
        callback.end_run(algorithm=algorithm, result=result)


def kept_policy(algorithm: Any) -> dict[str, Any] | None:
    """The policy the run keeps so far, as a resumable state file holds it (`MorphologyCallbacks.kept_policy`)."""
    return next((k for c in ours(algorithm) if (k := c.kept_policy()) is not None), None)


def trained_weights(algorithm: Any) -> dict[str, Any] | None:
    """The weights the run trained to where its end put the kept policy back (`MorphologyCallbacks.trained_weights`);
    None where the learner holds them."""
    return next((w for c in ours(algorithm) if (w := c.trained_weights()) is not None), None)


def restore_kept(algorithm: Any, kept: dict[str, Any] | None) -> None:
    """Put back the policy `kept_policy` gave before a resume (None: none was kept)."""
    if kept is None:
        return
    for callback in ours(algorithm):
        callback.restore_kept(kept)


def _on_snapshot(algorithm: Any, calls: list[Any]) -> tuple[list[Any], dict[str, Any]]:
    """Each `call(module)` on one snapshot of the learner's module (the local learner, or the first remote one): a
    copy holding one update's weights, never the module an asynchronous learner's thread may be writing
    (`snapshot`); with the snapshot's weights, which a run keeps as the policy these calls measured."""

    def run(learner: Any) -> tuple[list[Any], dict[str, Any]]:
        twin = snapshot_module(learner)
        return [call(twin) for call in calls], twin.state_dict()

    return _on_learner_itself(algorithm, run)  # type: ignore[no-any-return]


def _on_live_learner(algorithm: Any, call: Any) -> Any:
    """`call(module)` on the learner's own module (to change it)."""
    return _on_learner_itself(algorithm, lambda learner: call(learner.module[DEFAULT_MODULE_ID]))


class DivergedError(RuntimeError):
    """A run's weights overflowed: nothing more can be learnt, sampling from them fails, no loader reads them."""


def diverged(module: Any) -> str:
    """The first of `module`'s parameters holding a NaN, an infinity or a value beyond MAX_WEIGHT (whose forward pass
    overflows, and which no loader reads), or '' (one pass over the weights: a few milliseconds)."""
    for name, p in module.named_parameters():
        if p.numel() and not float(p.detach().abs().max()) <= MAX_WEIGHT:  # one pass: a NaN compares false
            return name
    return ""


def _on_learner_itself(algorithm: Any, call: Any) -> Any:
    (first, *_) = list(algorithm.learner_group.foreach_learner(call))
    return first.get()


@contextmanager
def updates_paused(algorithm: Any) -> Iterator[None]:
    """No optimizer step of the learner while the block runs (an asynchronous learner's thread waits at its next
    one): a checkpoint written inside holds the weights and optimizer state of one update. The learner is the
    driver's own (`num_learners=0`, training/config.py), so the lock itself comes back to be held here."""
    with _on_learner_itself(algorithm, update_lock):
        yield


def selection_score(evaluations: list[Any]) -> tuple[int, float]:
    """How a policy ranks on the selection starts: starts within 1 % of the optimum, then the smaller median gap,
    on the maps with an exact optimum; on none, the higher mean settled R1 (a NaN would never rank)."""
    import numpy as np

    measured = [e for e in evaluations if e.measured]
    if not measured:
        return 0, float(np.mean([e.mean_R1 for e in evaluations]))
    return sum(e.within for e in measured), -float(np.median(np.concatenate([e.gaps for e in measured])))


def evaluation_metrics(evaluations: list[Any]) -> dict[str, Any]:
    """The eval/... figures: every map's summary under its name, and the medians and shares over the maps with an
    exact optimum (NaN when none has one: not measured, which is not 0 %)."""
    import numpy as np

    measured = [e for e in evaluations if e.measured]
    gaps = np.concatenate([e.gaps for e in measured]) if measured else np.array([])
    out: dict[str, Any] = {e.map: e.summary() for e in evaluations}
    out |= {"median_gap": float(np.median(gaps)) if gaps.size else math.nan,
            "share_within_1pct": sum(e.within for e in measured) / gaps.size if gaps.size else math.nan,
            "starts": sum(len(e.outcomes) for e in evaluations), "measured_starts": int(gaps.size),
            "settled_R1_mean": float(np.mean([e.mean_R1 for e in evaluations]))}  # fmt: skip
    return out


def with_evaluation(
    base: type[MorphologyCallbacks], every: int, starts: Any, optima: dict[str, Any], final_steps: int = 0,
    selection: Any = (), maps: tuple[str, ...] = (), design_budget: int = 0,
) -> type:  # fmt: skip
    """`base` with the periodic evaluation switched on: `starts` (n x 3), each evaluated map's Optimum, and the
    env-step budget (the iteration that reaches it is evaluated too); `selection` (m x 3), other starts on
    which the run chooses the evaluated policy it ends on (empty: the last); `maps`, the maps evaluated on
    (empty: the training maps that are files); `design_budget`, the designer's figures at that many planner
    evaluations (0: off)."""
    from dataclasses import asdict

    evaluations = design_budget

    class EvaluatingCallbacks(base):  # type: ignore[valid-type, misc]
        eval_every = every
        eval_final_steps = final_steps
        eval_starts = tuple(tuple(float(t) for t in row) for row in starts)
        eval_optima = {name: asdict(o) for name, o in optima.items()}  # noqa: RUF012
        select_starts = tuple(tuple(float(t) for t in row) for row in selection)
        eval_maps = tuple(maps)
        design_budget = evaluations

    return EvaluatingCallbacks

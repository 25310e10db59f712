"""How a run ranks its evaluated policies when it chooses the one it ends on."""

from __future__ import annotations

from pathlib import Path

import pytest

from smorphi_rl.protocol import MapEvaluation, Optimum, Outcome
from smorphi_rl.training.callbacks import selection_score

OPTIMUM = Optimum((0.0, 0.0, 0.0), 90.0, 100.0, 1)
ROOT = Path(__file__).resolve().parents[2]


def _evaluation(*settled_R1: float) -> list[MapEvaluation]:
    outcomes = tuple(Outcome((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), r, 100.0, 1, 1) for r in settled_R1)
    return [MapEvaluation("map-1", "policy", OPTIMUM, outcomes)]


def _without_a_learner(monkeypatch, on_snapshot) -> None:
    """The callbacks' learner calls answered by `on_snapshot(algorithm, calls)` alone, with no learner to change."""
    from smorphi_rl.training import callbacks

    monkeypatch.setattr(callbacks, "_on_snapshot", on_snapshot)
    monkeypatch.setattr(callbacks, "_on_learner_itself", lambda algorithm, call: None)
    monkeypatch.setattr(callbacks, "_on_live_learner", lambda algorithm, call: None)
    monkeypatch.setattr(callbacks, "push_module_to_runners", lambda algorithm: None)


def _loading_learner(monkeypatch) -> list:
    """The callbacks' learner calls answered with no learner, but for the live module's `load_state_dict`: what it
    is given is appended to the returned list (the policy a run's end puts back)."""
    from types import SimpleNamespace

    from smorphi_rl.training import callbacks

    loaded: list = []
    monkeypatch.setattr(callbacks, "_on_learner_itself", lambda algorithm, call: None)
    monkeypatch.setattr(callbacks, "_on_live_learner",
                        lambda algorithm, call: call(SimpleNamespace(load_state_dict=loaded.append)))  # fmt: skip
    monkeypatch.setattr(callbacks, "push_module_to_runners", lambda algorithm: None)
    return loaded


def _train_results(hooks, iterations) -> list[dict]:
    """The result rows of `iterations`, 1,000 env steps each, as the callbacks leave them."""
    from types import SimpleNamespace

    rows = []
    for i in iterations:
        result = {"num_env_steps_sampled_lifetime": 1000 * i, "env_runners": {}}
        hooks.on_train_result(algorithm=SimpleNamespace(iteration=i), result=result)
        rows.append(result)
    return rows


def test_more_starts_within_one_percent_rank_first_then_the_smaller_median_gap():
    three_in = selection_score(_evaluation(89.9, 89.5, 89.2, 80.0))  # 89.2 is within 1 % of 90 (band 89.1)
    two_in_close = selection_score(_evaluation(90.0, 89.95, 89.0, 89.0))
    two_in_far = selection_score(_evaluation(89.5, 89.2, 85.0, 85.0))
    assert three_in > two_in_close > two_in_far
    assert selection_score(_evaluation(90.0, 80.0)) == (1, -5.0)


def test_evaluation_snapshots_are_never_torn_by_a_learner_thread_stepping_the_optimizer():
    """A learner thread steps an optimizer that sets every weight to k, one tensor at a time with a pause
    between (an update under way), for k = 1, 2, ...: a plain copy often holds two updates' weights; a
    snapshot never does."""
    import threading
    import time

    import torch
    from ray.rllib.core import DEFAULT_MODULE_ID

    from smorphi_rl.training.snapshot import snapshot_module, snapshot_state, update_lock

    class SlowStep(torch.optim.Optimizer):
        def __init__(self, params):
            super().__init__(params, {})
            self.k = 0

        @torch.no_grad()
        def step(self, closure=None):
            self.k += 1
            for group in self.param_groups:
                for p in group["params"]:
                    p.fill_(float(self.k))
                    time.sleep(0.0005)

    module = torch.nn.Sequential(torch.nn.Linear(8, 8), torch.nn.Linear(8, 8), torch.nn.Linear(8, 2))
    with torch.no_grad():  # one value throughout, as after a whole step: only a copy taken mid-step is torn (random
        for p in module.parameters():  # initial weights read as torn, before a slow thread's first step)
            p.fill_(0.0)
    optimizer = SlowStep(module.parameters())

    class Learner:
        def __init__(self):
            self.module = {DEFAULT_MODULE_ID: module}

        def get_optimizers_for_module(self, module_id):
            return [("default_optimizer", optimizer)]

    learner = Learner()
    update_lock(learner)  # as the callbacks do before training starts
    stop = threading.Event()

    def learn() -> None:
        while not stop.is_set():
            optimizer.step()
            time.sleep(0.002)

    def torn(state: dict) -> bool:
        return len({float(v.flatten()[0]) for v in state.values()}) > 1

    thread = threading.Thread(target=learn, daemon=True)
    thread.start()
    deadline = time.monotonic() + 60  # a hang guard: each loop ends on what it waits for, however busy the cores
    try:
        plain: list[bool] = []
        while not any(plain) and time.monotonic() < deadline:  # until an unguarded copy is torn
            plain.append(torn({k: v.clone() for k, v in module.state_dict().items()}))
            time.sleep(0.0002)
        snapshots: list[bool] = []
        k0 = optimizer.k
        while (optimizer.k < k0 + 10 or len(snapshots) < 100) and time.monotonic() < deadline:
            snapshots.append(torn(snapshot_state(learner)))  # while the learner takes 10 steps or more
            time.sleep(0.0002)
        twin = snapshot_module(learner)
    finally:
        stop.set()
        thread.join()
    assert any(plain)  # the test can fail: unguarded copies are torn
    assert optimizer.k >= k0 + 10 and len(snapshots) >= 100  # the learner kept learning while snapshots were taken
    assert not any(snapshots)
    assert twin is not module and not torn(twin.state_dict())


def test_no_optimizer_step_lands_while_a_checkpoint_is_written():
    """A checkpoint of IMPALA or APPO read the learner's weights and Adam state from the driver while the learner
    thread stepped: two updates' weights in one checkpoint, the state file of a third."""
    import threading
    import time

    import torch
    from ray.rllib.core import DEFAULT_MODULE_ID
    from ray.rllib.utils.actor_manager import RemoteCallResults, ResultOrError

    from smorphi_rl.training.callbacks import updates_paused
    from smorphi_rl.training.snapshot import update_lock

    module = torch.nn.Linear(4, 2)
    optimizer = torch.optim.SGD(module.parameters(), lr=0.1)

    class Learner:  # the learner's two parts the lock reads; RLlib's local LearnerGroup hands it to the call
        def __init__(self):
            self.module = {DEFAULT_MODULE_ID: module}

        def get_optimizers_for_module(self, module_id):
            return [("default_optimizer", optimizer)]

    class LocalGroup:
        def __init__(self, learner):
            self.learner = learner

        def foreach_learner(self, call):  # as LearnerGroup.foreach_learner with num_learners=0
            results = RemoteCallResults()
            results.add_result(None, ResultOrError(result=call(self.learner)), None)
            return results

    class Algorithm:
        learner_group = LocalGroup(Learner())

    update_lock(Algorithm.learner_group.learner)
    steps, stop = [0], threading.Event()

    def learn() -> None:
        while not stop.is_set():
            optimizer.step()
            steps[0] += 1
            time.sleep(0.001)

    thread = threading.Thread(target=learn, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while steps[0] < 5 and time.monotonic() < deadline:
            time.sleep(0.001)
        with updates_paused(Algorithm):
            paused = steps[0]
            time.sleep(0.2)  # a checkpoint being written
            during = steps[0] - paused
        while steps[0] < paused + 5 and time.monotonic() < deadline:
            time.sleep(0.001)
    finally:
        stop.set()
        thread.join()
    assert during <= 1 and steps[0] >= paused + 5  # at most the step already past its lock; learning went on after


def test_a_step_that_raises_in_the_learner_thread_leaves_the_lock_free():
    """torch runs no post-hook when a step raises: the learner thread kept the update lock, and the next checkpoint
    (or evaluation snapshot) waited on it for ever while the thread went on draining its queue."""
    import threading

    import torch
    from ray.rllib.core import DEFAULT_MODULE_ID

    from smorphi_rl.training.snapshot import release_after_failure, update_lock

    class Failing(torch.optim.SGD):
        def step(self, closure=None):
            raise FloatingPointError("a step that fails")

    class Learner:
        def __init__(self):
            self.module = {DEFAULT_MODULE_ID: torch.nn.Linear(2, 2)}
            self.optimizer = Failing(self.module[DEFAULT_MODULE_ID].parameters(), lr=0.1)

        def get_optimizers_for_module(self, module_id):
            return [("default_optimizer", self.optimizer)]

    for release in (False, True):
        learner = Learner()
        lock = update_lock(learner)

        def learn(learner=learner, release=release) -> None:
            try:
                learner.optimizer.step()
            except FloatingPointError:
                if release:
                    release_after_failure(learner)

        thread = threading.Thread(target=learn)
        thread.start()
        thread.join()
        free = lock.acquire(timeout=0.5)
        if free:
            lock.release()
        assert free is release  # held for ever without the release: the test can fail


def test_a_run_that_ends_on_an_earlier_policy_keeps_its_trained_curve_for_convergence(monkeypatch):
    """Evaluations 20 %, 100 %, 20 %, 20 % of the starts within 1 %: the run ends on the 100 % policy, whose
    figures its last row reports, but the curves (and so convergence) read the policy training ended with."""

    from smorphi_rl.protocol import EVAL_KEY
    from smorphi_rl.training import callbacks
    from smorphi_rl.training.convergence import convergence
    from smorphi_rl.training.sweep_report import result_curve

    poor, good = (80.0, 80.0, 80.0, 80.0, 89.9), (89.9, 89.9, 89.9, 89.9, 89.9)
    shares = [poor, good, poor, poor]  # each policy's protocol starts, then its selection starts alike

    def on_snapshot(algorithm, calls):
        return [_evaluation(*shares[0], *shares.pop(0))], {"weights": len(shares)}

    _without_a_learner(monkeypatch, on_snapshot)
    starts = [(0.0, 0.0, 0.0)] * 5
    evaluating = callbacks.with_evaluation(callbacks.MorphologyCallbacks, 1, starts, {"map-1": OPTIMUM}, 4000,
                                           selection=starts)  # fmt: skip
    hooks = evaluating()
    hooks._evaluation = object()
    rows = _train_results(hooks, range(1, 5))
    last = rows[-1][EVAL_KEY]
    assert last["share_within_1pct"] == 1.0 and last["policy_env_steps"] == 2000  # the policy it ends on
    assert last["trained"]["share_within_1pct"] == 0.2 and "trained" not in rows[1][EVAL_KEY]
    assert result_curve(rows)["eval_within"] == [0.2, 1.0, 0.2, 0.2]
    assert convergence(result_curve(rows))[0] is None  # with the chosen policy's figures it read 4,000


def test_a_map_without_an_exact_optimum_is_not_measured_rather_than_0_percent():
    """A map too large to enumerate has no R1*: its share is NaN (not measured), and the pooled figures are over the
    maps that have one, so it cannot hold the run under 90 % for ever."""
    import math

    from smorphi_rl.protocol import NO_OPTIMUM, POOLED_KEYS
    from smorphi_rl.training.callbacks import evaluation_metrics

    (large,) = _evaluation(50.0, 60.0)
    large = MapEvaluation("large", "policy", NO_OPTIMUM, large.outcomes)
    both = evaluation_metrics([*_evaluation(89.9, 89.9, 80.0, 89.5), large])
    assert both["share_within_1pct"] == 0.75 and math.isclose(both["median_gap"], 0.3) and both["starts"] == 6
    assert both["measured_starts"] == 4 and math.isnan(both["large"]["share_within_1pct"])
    assert set(both) - {"map-1", "large"} <= set(POOLED_KEYS)  # a map may not take a pooled figure's name
    alone = evaluation_metrics([large])
    assert math.isnan(alone["share_within_1pct"]) and math.isnan(alone["median_gap"])


def test_policies_rank_by_settled_r1_where_no_map_has_an_exact_optimum():
    """A NaN score never ranks (nan >= nan is False): selection would keep the first policy for ever."""
    from smorphi_rl.protocol import NO_OPTIMUM
    from smorphi_rl.training.callbacks import selection_score

    def blind(*r1: float) -> list[MapEvaluation]:
        (e,) = _evaluation(*r1)
        return [MapEvaluation("large", "policy", NO_OPTIMUM, e.outcomes)]

    assert selection_score(blind(60.0, 70.0)) > selection_score(blind(50.0, 60.0))
    assert selection_score(blind(50.0, 60.0)) >= selection_score(blind(50.0, 60.0))
    score = selection_score([*_evaluation(89.9, 89.9), *blind(50.0)])
    assert score[0] == 2 and abs(score[1] + 0.1) < 1e-9


def test_the_designers_figures_a_run_reports_are_those_of_the_policy_it_ends_on(monkeypatch):
    """Evaluations 20 %, 100 %, 20 % with design gaps 3, 1 and 2 %: the last row reports the kept policy's 1 % (it
    reported the last policy's 2 % beside the kept one's protocol figures), the curve the trained one's 2 %."""

    from smorphi_rl.protocol import EVAL_KEY
    from smorphi_rl.training import callbacks
    from smorphi_rl.training.sweep_report import result_curve

    poor, good = (80.0, 80.0, 80.0, 80.0, 89.9), (89.9, 89.9, 89.9, 89.9, 89.9)
    shares, gaps = [poor, good, poor], [3.0, 1.0, 2.0]

    def on_snapshot(algorithm, calls):
        assert len(calls) == 2  # the protocol and the designer, on the same snapshot
        return [_evaluation(*shares[0], *shares.pop(0)), {"design_median_gap_pct": gaps.pop(0)}], {}

    _without_a_learner(monkeypatch, on_snapshot)
    starts = [(0.0, 0.0, 0.0)] * 5
    evaluating = callbacks.with_evaluation(callbacks.MorphologyCallbacks, 1, starts, {"map-1": OPTIMUM}, 3000,
                                           selection=starts, design_budget=10)  # fmt: skip
    hooks = evaluating()
    hooks._evaluation, hooks._design = object(), object()
    rows = _train_results(hooks, range(1, 4))
    last = rows[-1][EVAL_KEY]
    assert last["share_within_1pct"] == 1.0 and last["design_median_gap_pct"] == 1.0
    assert last["trained"]["design_median_gap_pct"] == 2.0
    assert result_curve(rows)["design_gap"] == [3.0, 1.0, 2.0]


@pytest.mark.parametrize("design_budget", [0, 10])
def test_a_resumed_run_still_ends_on_the_policy_it_kept_before_the_interruption(monkeypatch, design_budget):
    """Evaluations 20 %, 100 %, an interruption, a resume from the state file's kept policy, then 20 %, 20 %: the
    run ends on the 100 % policy kept before the resume; its weights are put back and, as only its weights are
    kept, its protocol roll-outs (and its designs) are repeated for the figures."""
    from types import SimpleNamespace

    import torch

    from smorphi_rl.protocol import EVAL_KEY
    from smorphi_rl.training import callbacks

    poor, good = (80.0, 80.0, 80.0, 80.0, 89.9), (89.9, 89.9, 89.9, 89.9, 89.9)
    shares = [poor, good, poor, poor, good]  # the last: the kept policy's roll-outs, repeated

    def on_snapshot(algorithm, calls):
        design = [{"design_median_gap_pct": 1.0 if shares[0] is good else 3.0}] if len(calls) == 2 else []
        return [_evaluation(*shares[0], *shares.pop(0)), *design], {"w": torch.tensor([float(len(shares))])}

    loaded = _loading_learner(monkeypatch)
    monkeypatch.setattr(callbacks, "_on_snapshot", on_snapshot)
    starts = [(0.0, 0.0, 0.0)] * 5
    evaluating = callbacks.with_evaluation(callbacks.MorphologyCallbacks, 1, starts, {"map-1": OPTIMUM}, 4000,
                                           selection=starts, design_budget=design_budget)  # fmt: skip

    def run(hooks, iterations):
        hooks._evaluation, hooks._design = object(), object()
        for i in iterations:
            result = {"num_env_steps_sampled_lifetime": 1000 * i, "env_runners": {}}
            hooks.on_train_result(algorithm=SimpleNamespace(iteration=i), result=result)
        return result[EVAL_KEY]

    before = evaluating()
    run(before, (1, 2))
    kept = before.kept_policy()
    assert kept["score"][0] == 5 and kept["env_steps"] == 2000 and kept["weights"]["w"].tolist() == [3.0]
    after = evaluating()
    after.restore_kept(kept)
    last = run(after, (3, 4))
    assert last["share_within_1pct"] == 1.0 and last["policy_env_steps"] == 2000
    assert last["trained"]["share_within_1pct"] == 0.2
    assert [w["w"].tolist() for w in loaded] == [[3.0]] and not shares
    if design_budget:  # the kept policy's designs are repeated with its roll-outs, on its own weights
        assert last["design_median_gap_pct"] == 1.0 and last["trained"]["design_median_gap_pct"] == 3.0
    else:
        assert "design_median_gap_pct" not in last


def test_a_run_that_ends_on_its_kept_policy_sets_the_weights_it_trained_aside_for_a_resume(monkeypatch):
    """Evaluations 100 %, then 20 % at the end: the learner is given the kept policy's weights, and the weights it
    trained to stay at hand (`trained_weights`), for the state file a stopped run resumes from; a run whose last
    policy is its best has none set aside."""
    from types import SimpleNamespace

    import torch

    from smorphi_rl.training import callbacks

    poor, good = (80.0, 80.0, 80.0, 80.0, 89.9), (89.9, 89.9, 89.9, 89.9, 89.9)
    loaded = _loading_learner(monkeypatch)
    starts = [(0.0, 0.0, 0.0)] * 5
    evaluating = callbacks.with_evaluation(callbacks.MorphologyCallbacks, 1, starts, {"map-1": OPTIMUM}, 2000,
                                           selection=starts)  # fmt: skip

    def run(shares):
        def on_snapshot(algorithm, calls):
            return [_evaluation(*shares[0], *shares.pop(0))], {"w": torch.tensor([float(len(shares))])}

        monkeypatch.setattr(callbacks, "_on_snapshot", on_snapshot)
        hooks = evaluating()
        hooks._evaluation = object()
        for i in (1, 2):
            hooks.on_train_result(algorithm=SimpleNamespace(iteration=i),
                                  result={"num_env_steps_sampled_lifetime": 1000 * i, "env_runners": {}})  # fmt: skip
        return hooks

    ended = run([good, poor])
    assert [w["w"].tolist() for w in loaded] == [[1.0]]  # the kept policy, into the learner
    assert ended.trained_weights()["w"].tolist() == [0.0]  # the last trained weights, set aside
    algorithm = SimpleNamespace(callbacks=[ended])
    assert callbacks.trained_weights(algorithm)["w"].tolist() == [0.0]
    assert run([poor, good]).trained_weights() is None and len(loaded) == 1


def test_a_run_ending_early_on_an_evaluated_iteration_is_not_rolled_out_twice(monkeypatch):
    """A stop criterion met on an iteration the protocol has just evaluated: `end_run` chooses the policy on that
    evaluation (a learner that steps only inside `train()` has not changed since), rolling nothing out again."""
    from types import SimpleNamespace

    import torch

    from smorphi_rl.protocol import EVAL_KEY
    from smorphi_rl.training import callbacks

    good = (89.9, 89.9, 89.9, 89.9, 89.9)
    calls = []

    def on_snapshot(algorithm, work):
        calls.append(algorithm.iteration)
        return [_evaluation(*good, *good)], {"w": torch.zeros(1)}

    monkeypatch.setattr(callbacks, "_on_snapshot", on_snapshot)
    monkeypatch.setattr(callbacks, "_on_learner_itself", lambda algorithm, call: None)
    starts = [(0.0, 0.0, 0.0)] * 5
    hooks = callbacks.with_evaluation(callbacks.MorphologyCallbacks, 5, starts, {"map-1": OPTIMUM}, 10**6,
                                      selection=starts)()  # fmt: skip
    hooks._evaluation = object()
    for i in range(1, 6):
        result = {"num_env_steps_sampled_lifetime": 1000 * i, "env_runners": {}}
        hooks.on_train_result(algorithm=SimpleNamespace(iteration=i), result=result)
    hooks.end_run(algorithm=SimpleNamespace(iteration=5), result=result)
    hooks.end_run(algorithm=SimpleNamespace(iteration=5), result=result)  # once only
    assert calls == [1, 5] and result[EVAL_KEY]["policy_env_steps"] == 5000 and "trained" not in result[EVAL_KEY]


def test_the_protocol_runs_on_the_training_maps_that_are_files_never_on_a_generator():
    """A run on a map file and generated floors, with no evaluation maps named, is evaluated on the file alone
    (a generated floor has no exact optimum to look up)."""
    from types import SimpleNamespace

    from smorphi_rl.training import callbacks

    maps = [str(ROOT / "maps" / "map-1.yaml"), "generate:mixed"]
    hooks = callbacks.with_evaluation(callbacks.MorphologyCallbacks, 1, [(90.0, 90.0, 90.0)], {"map-1": OPTIMUM})()
    rollouts = hooks._protocol(SimpleNamespace(config=SimpleNamespace(env_config={"maps": maps})), [(90.0,) * 3])
    assert [Path(m).name for m in rollouts.env_config.maps] == ["map-1.yaml"]


def test_weights_that_overflowed_or_are_not_numbers_are_named():
    """What ends a diverged run before its runners sample from it (they would fail, and RLlib restart them for ever)."""
    import torch

    from smorphi_rl.training.callbacks import diverged

    net = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    assert diverged(net) == ""
    with torch.no_grad():
        net[1].bias[0] = 2e6  # beyond MAX_WEIGHT: its forward pass overflows, and no loader reads it
    assert diverged(net) == "1.bias"
    with torch.no_grad():
        net[1].bias[0] = 0.0
        net[0].weight[2, 1] = float("nan")
    assert diverged(net) == "0.weight"

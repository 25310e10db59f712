"""Consistent copies of a learner's module, for evaluating while an asynchronous learner trains.

IMPALA's and APPO's learner thread steps the optimizer while the driver evaluates the policy; a copy taken
during a step holds two updates' weights. Every optimizer of the learner's module gets a lock held for the
length of its step (torch's public `register_step_pre_hook` / `register_step_post_hook`), and a snapshot is
copied under that lock, so it holds the weights of one update. The evaluation then runs on a copy of the
module, never on the module the thread writes. PPO learns in the driver's thread: the lock is never contended.

At the end of a run the learner's updates are held (`hold_updates`): the thread goes on draining its queue, but
no step changes the weights, so the final checkpoint holds the policy the last evaluation measured.
"""

from __future__ import annotations

import copy
import threading
import weakref
from typing import Any

from ray.rllib.core import DEFAULT_MODULE_ID

_LOCKS: weakref.WeakKeyDictionary[Any, threading.RLock] = weakref.WeakKeyDictionary()
_HOLDS: weakref.WeakKeyDictionary[Any, list[threading.local]] = weakref.WeakKeyDictionary()
_HELD: weakref.WeakSet[Any] = weakref.WeakSet()


def update_lock(learner: Any) -> threading.RLock:
    """The lock held while any optimizer of the learner's module steps; hooks registered on first use (call it
    before training starts: a step already under way when the hooks arrive releases nothing it did not take)."""
    lock = _LOCKS.get(learner)
    if lock is not None:
        return lock
    lock = _LOCKS[learner] = threading.RLock()  # re-entered by a step taken under it (`FusedStep`)
    holds = _HOLDS[learner] = []
    for _, optimizer in learner.get_optimizers_for_module(DEFAULT_MODULE_ID):
        held = threading.local()
        holds.append(held)

        def before(*_: Any, held: Any = held) -> None:
            lock.acquire()
            held.on = True

        def after(*_: Any, held: Any = held) -> None:
            if getattr(held, "on", False):
                held.on = False
                lock.release()

        optimizer.register_step_pre_hook(before)
        optimizer.register_step_post_hook(after)
    return lock


def release_after_failure(learner: Any) -> None:
    """Release the update lock a step that raised in this thread still holds: torch runs no post-hook then, and a
    checkpoint or snapshot waiting on the lock would wait for ever (the learner thread goes on, draining)."""
    lock = _LOCKS.get(learner)
    for held in _HOLDS.get(learner, ()):
        if lock is not None and getattr(held, "on", False):
            held.on = False
            lock.release()


def snapshot_state(learner: Any) -> dict[str, Any]:
    """A copy of the learner module's weights, taken while no optimizer step is under way."""
    module = learner.module[DEFAULT_MODULE_ID]
    with update_lock(learner):
        return {name: value.detach().clone() for name, value in module.state_dict().items()}


def snapshot_module(learner: Any) -> Any:
    """A copy of the learner's module holding `snapshot_state(learner)`: evaluated without touching the live one."""
    state = snapshot_state(learner)
    twin = copy.deepcopy(learner.module[DEFAULT_MODULE_ID])
    twin.load_state_dict(state)
    return twin


def hold_updates(learner: Any) -> None:
    """From now on the learner's updates leave its weights as they are (`updates_held`); set under the update
    lock, so a step under way finishes first and none starts after."""
    with update_lock(learner):
        _HELD.add(learner)


def updates_held(learner: Any) -> bool:
    """Whether `hold_updates` was called on the learner: its optimizer steps are skipped (read under the lock)."""
    return learner in _HELD

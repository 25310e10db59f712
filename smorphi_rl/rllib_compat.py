"""The one module that uses names Ray, RLlib, Tune, tensorboardX, torch and numpy keep private.

Everything else in the package customises those libraries through what they offer publicly (an RLModule and its
distribution, ConnectorV2 pieces with the default pipelines switched off, Learner methods written whole, an env
runner class set through config, Tune callbacks). What is here has no public way, each entry says why, and each
was written against ray 2.60.0, torch 2.13.0, tensorboardX 2.6 and numpy 2.x (`training.versions.TESTED`).
`tests/test_rllib_compat.py` fails when one of them changes underneath: a name gone, a signature changed, an
override no longer taking effect; `tests/test_private_names.py` fails when such a name appears anywhere else.

Nothing here assigns into another package's module or swaps an object's class, with one exception said below
(Ray's `ConsolePopen`, for the length of `ray.init`).
"""

from __future__ import annotations

import sys
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from smorphi_rl.errors import SmorphiError


class LibraryChanged(SmorphiError):
    """A private name this module relies on is gone or has changed: the installed library is not the tested one
    (the CLI prints it in one line)."""


def with_globals(function: Callable[..., Any], **names: Any) -> Callable[..., Any]:
    """A copy of a library `function` in which the global `names` resolve to ours.

    The library's module is left as it is (nothing is assigned into it), so the copy is safe beside other threads
    and every other caller still gets the original. Raises LibraryChanged at once if `function` no longer refers
    to one of `names` (the replacement would silently not take effect)."""
    code = function.__code__
    missing = sorted(set(names) - set(code.co_names))
    if missing:
        raise LibraryChanged(
            f"{function.__module__}.{function.__qualname__} no longer calls {', '.join(missing)}: this Ray is not "
            "the one smorphi-rl's RLlib layer is tested with (training/versions.py)"
        )
    copy = types.FunctionType(code, {**function.__globals__, **names}, function.__name__, None, function.__closure__)
    copy.__defaults__ = function.__defaults__
    copy.__kwdefaults__ = function.__kwdefaults__
    copy.__qualname__ = function.__qualname__
    copy.__doc__ = function.__doc__
    return copy


def _private(owner: Any, name: str) -> Any:
    """`owner.name`, or LibraryChanged naming it when the library no longer has it."""
    try:
        return getattr(owner, name)
    except AttributeError:
        raise LibraryChanged(
            f"{type(owner).__module__}.{type(owner).__qualname__} has no {name} any more: this library is not the "
            "one smorphi-rl is tested with (training/versions.py)"
        ) from None


# -- RLlib's env runner (ray.rllib.env.single_agent_env_runner, 2.60) ---------------------------------------


def treeless_sample(unbatch: Callable[[Any], list[Any]]) -> Callable[..., Any]:
    """RLlib's `SingleAgentEnvRunner._sample` with `unbatch` (what splits each step's batched observations and
    actions by env) resolved to ours. `_sample` is the runner's private step loop; the public `sample` only wraps
    it, and RLlib offers no hook for how a step's batch is split, which with its tree utilities costs about 25 us
    per env and step here."""
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    return with_globals(SingleAgentEnvRunner._sample, unbatch=unbatch)


def runner_mixin(unbatch: Callable[[Any], list[Any]]) -> type:
    """A SingleAgentEnvRunner subclass that samples with `treeless_sample(unbatch)` and makes no per-env, per-step
    `on_episode_step` callback when no callback overrides it (RLlib makes one for every env and step, through its
    private `_make_on_episode_callback`; there is no setting for it)."""
    from ray.rllib.callbacks.callbacks import RLlibCallback
    from ray.rllib.env.single_agent_env_runner import SingleAgentEnvRunner

    class RunnerInternals(SingleAgentEnvRunner):  # type: ignore[misc]  # RLlib's bases are untyped
        _sample = treeless_sample(unbatch)
        _step_callbacks: bool | None = None

        def _make_on_episode_callback(self, which: str, idx: int, episodes: list[Any]) -> None:
            if which == "on_episode_step":
                if self._step_callbacks is None:
                    base = RLlibCallback.on_episode_step
                    objects = self._callbacks or []
                    self._step_callbacks = bool(self.config.callbacks_on_episode_step) or any(
                        getattr(type(c), which, base) is not base for c in objects
                    )
                if not self._step_callbacks:
                    return
            SingleAgentEnvRunner._make_on_episode_callback(self, which, idx, episodes)  # no super(): Ray ships
            # this class's methods to remote runners by value, where a zero-argument super() names another class

    return RunnerInternals


# -- RLlib's learners (ray.rllib.core.learner, ray.rllib.algorithms.impala, 2.60) ----------------------------


def learner_pipeline(learner: Any) -> Any:
    """A built learner's connector pipeline (None when aggregator actors run it). RLlib's own learners extend it in
    `build()` through this private attribute; the config's public `learner_connector` puts custom pieces first,
    and ours (`CompactMaps`) must come after RLlib's."""
    return _private(learner, "_learner_connector")


def guard_learner_thread(learner: Any, guard: Callable[[Callable[..., Any]], Callable[..., Any]]) -> None:
    """Wrap the update that IMPALA's and APPO's learner thread runs (`Learner.update`, held by the thread) in
    `guard`. In RLlib an exception there ends the thread without a word and the trial then waits forever on its
    queue; the thread is private and takes no callback."""
    thread = _private(learner, "_learner_thread")
    thread._update_method = guard(_private(thread, "_update_method"))


LEARNER_STATE_KEY = "_rl_module_state_after_update"
"""Where IMPALA's `Learner.update` hands the algorithm the module state it broadcasts to the env runners."""


def latest_learner_state(learner: Any) -> Any | None:
    """The module state IMPALA's and APPO's learner thread queued after its latest finished update, taken off its
    queue (None when it queued none since the last take). RLlib's `update` takes the queued state before it
    waits for the thread's update to finish and broadcasts that one, so the env runners sample with weights one
    train batch older than the learner's; the queue and its lock are private and no setting returns the newer."""
    from queue import Empty

    states = _private(learner, "_learner_state_queue")
    with _private(learner, "_learner_state_lock"):
        try:
            state = states.get_nowait()
        except Empty:
            return None
        learner._learner_state = state  # where RLlib's next `update` looks for it when the queue is empty
    return state


def time_major(tensor: Any, trajectory_len: int, seq_lens: Any = None) -> Any:
    """A [B * T] tensor laid out [T, B] by the helper RLlib's v-trace losses lay their own tensors out with
    (`vtrace_torch_v2.make_time_major`, an unannotated function, not public API): the learnable-steps mask and the
    frozen critic's values line up with the loss's tensors whatever layout RLlib picks."""
    from ray.rllib.algorithms.impala.torch.vtrace_torch_v2 import make_time_major

    return make_time_major(tensor, trajectory_len=trajectory_len, recurrent_seq_len=seq_lens)


def tensor_norms(tensors: list[Any]) -> Any:
    """The L2 norm of each tensor, in one fused call (torch's `_foreach_norm`: no public multi-tensor norm)."""
    import torch

    return torch.stack(torch._foreach_norm(tensors))


def scale_each_(tensors: list[Any], factors: Any) -> None:
    """Multiply each tensor in place by its factor, in one fused call (torch's `_foreach_mul_`)."""
    import torch

    torch._foreach_mul_(tensors, list(factors.unbind()))


def tensor_version(tensor: Any) -> int:
    """torch's in-place version counter of a tensor: bumped by every optimiser step and load, so a cached result
    computed from the tensor is stale once it moves. torch keeps it private and offers nothing else for it."""
    return int(tensor._version)


# -- Ray and Tune ------------------------------------------------------------------------------------------


@contextmanager
def daemons_in_their_own_session() -> Iterator[None]:
    """Start a local Ray's daemons (GCS, raylet and the workers they spawn) in a session of their own.

    `timeout` and batch schedulers send SIGTERM to the whole process group; Ray's daemons would die at once and
    the driver could no longer stop its trials and write their summary. In their own session they get no group
    signal; they still die with the driver (Ray's kill-on-parent-death fate sharing). Ray starts them through
    `ray._private.services.ConsolePopen` and offers no setting for their session: this is the one assignment
    into another package's module (for the length of `ray.init`, undone after)."""
    from ray._private import services

    original = services.ConsolePopen

    class _Detached(original):  # type: ignore[valid-type, misc]
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            if sys.platform != "win32":
                kwargs.setdefault("start_new_session", True)
            super().__init__(*args, **kwargs)

    services.ConsolePopen = _Detached  # type: ignore[misc]
    try:
        yield
    finally:
        services.ConsolePopen = original  # type: ignore[misc]


def submitted_with_working_dir() -> bool:
    """Whether this driver runs as a `ray job submit` job whose runtime env has a working_dir. Ray hands a job its
    config in an environment variable named only in `ray._private`, and merges `ray.init`'s runtime env into it,
    refusing a second working_dir ("Failed to merge the Job's runtime env")."""
    import json
    import os

    from ray._private.runtime_env.constants import RAY_JOB_CONFIG_JSON_ENV_VAR

    try:
        config = json.loads(os.environ.get(RAY_JOB_CONFIG_JSON_ENV_VAR) or "null")
    except ValueError:
        return False
    runtime_env = config.get("runtime_env") if isinstance(config, dict) else None
    return isinstance(runtime_env, dict) and bool(runtime_env.get("working_dir"))


def tune_trial_writer(callback: Any, trial: Any) -> Any:
    """The tensorboardX SummaryWriter Tune's `TBXLoggerCallback` keeps for `trial` (opened by its public
    `log_trial_start` if none is yet); Tune keeps the writers private."""
    writers = _private(callback, "_trial_writer")
    if trial not in writers:
        callback.log_trial_start(trial)
    return writers[trial]


def tune_last_scalars(callback: Any, trial: Any) -> dict[str, Any]:
    """The scalars of `trial`'s last result that `TBXLoggerCallback` writes as hyperparameter metrics at its end
    (a private dict; ours are written apart, so they are added to it)."""
    last: dict[str, Any] = _private(callback, "_trial_result")[trial]
    return last


def summary_file_writer(writer: Any) -> Any:
    """tensorboardX's file writer behind a SummaryWriter: the only way to add one Summary holding many values."""
    return _private(writer, "_get_file_writer")()


# -- pickle's and numpy's pickling helpers ------------------------------------------------------------------


def python_unpickler() -> type:
    """The standard library's pure-Python unpickler (`pickle._Unpickler`): unlike the C one, a subclass can check
    what each BUILD opcode hands an object's `__setstate__` (its `dispatch` table, `load_build`)."""
    import pickle

    unpickler: type = pickle._Unpickler  # type: ignore[attr-defined]
    return unpickler


def numpy_unpickle_helpers() -> dict[tuple[str, str], Any]:
    """The private (module, name) pairs numpy's own pickles of arrays and Generators name, for the checkpoint
    loader's exact allowlist (numpy 1.x spells the array helpers `numpy.core`, 2.x `numpy._core`)."""
    import numpy as np
    from numpy.random import _pickle as random_pickle
    from numpy.random import bit_generator

    core = getattr(np, "_core", None) or np.core
    seed_sequence = "__pyx_unpickle_SeedSequence"  # a Cython helper: spelled as a string
    helpers: dict[tuple[str, str], Any] = {
        ("numpy.random.bit_generator", seed_sequence): getattr(bit_generator, seed_sequence),
        ("numpy.random._pickle", "__generator_ctor"): random_pickle.__generator_ctor,
        ("numpy.random._pickle", "__bit_generator_ctor"): random_pickle.__bit_generator_ctor,
    }
    for prefix in ("numpy._core", "numpy.core"):
        helpers[(f"{prefix}.multiarray", "_reconstruct")] = core.multiarray._reconstruct
        helpers[(f"{prefix}.numeric", "_frombuffer")] = core.numeric._frombuffer
    return helpers

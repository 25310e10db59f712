"""`train`'s first Ctrl-C (or SIGTERM) ends the run at its trial's next iteration as its budget's end would: the final
policy chosen, evaluated and checkpointed. Ray Tune's own handler stops the trial at its next report instead, before
the policy the summary names is saved. A second signal stops the run at once.

The driver asks by creating a named Ray actor (from a watcher thread: a signal handler only flips state); the trial
looks the name up after every iteration (`stop_requested`), wherever on a `HOST:PORT` cluster it runs (the training
jobs refuse Ray Client, `ray://`, under which Tune would run the experiment on the head).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

from smorphi_rl import interrupts

NAMESPACE = "smorphi-rl"
"""The Ray namespace of the stop requests (the driver's and its trials' alike)."""
TUNE_SIGINT = "TUNE_DISABLE_SIGINT_HANDLER"
"""Ray Tune installs its own SIGINT handler in `fit` unless this is set (ray/tune/tune.py)."""
ASK_TIMEOUT_S = 30
"""How long asking the trials may take (a new Ray worker process for the actor) before the request is given up."""


@contextmanager
def tune_stop_seen(stopped: threading.Event) -> Iterator[None]:
    """Around `Tuner.fit()` under Tune's own SIGINT handler (no graceful stop): Tune puts back the handler it found
    only when a stop fires, and leaves its own installed on a normal return, where a later Ctrl-C would set a flag
    nothing reads (a job's next run would train on). On leaving, a stop Tune took is set in `stopped`, and the
    handler found is back either way."""
    if threading.current_thread() is not threading.main_thread() or os.environ.get(TUNE_SIGINT) == "1":
        yield
        return
    before = signal.getsignal(signal.SIGINT)
    try:
        yield
    finally:
        if signal.getsignal(signal.SIGINT) is before:  # Tune's handler fired, and put `before` back
            stopped.set()
        signal.signal(signal.SIGINT, before)


def stop_requested(name: str) -> bool:
    """Inside a trial: whether the driver asked the run `name` to end (`GracefulStop`); a lookup that fails (no such
    actor, or the cluster's directory slow to answer) is no request, never a failed trial."""
    import ray

    try:
        ray.get_actor(name, namespace=NAMESPACE)
    except Exception:
        return False
    return True


class GracefulStop:
    """Driver side: while `catching(reported)`, the first SIGINT or SIGTERM asks the trials to end (once `reported()`
    says a trial has reported; before that the run stops at once, and nothing is kept); the next stops it at once."""

    def __init__(self, out: TextIO | None = None) -> None:
        self.name = f"stop-{uuid.uuid4().hex}"
        self.reported: Callable[[], bool] = lambda: False
        self.out = out or sys.stderr
        self.requested = threading.Event()
        self._closing = threading.Event()
        self._wake = threading.Event()
        self._asked: list[Any] = []  # the actor, held so that it lives as long as the run

    def _on_signal(self, signum: int, frame: Any) -> None:
        """Flips state only: no output, thread or Ray call inside a signal handler (`_watch` does the asking)."""
        if not self.reported():  # nothing to keep yet: out of Tune's loop at once (Ray's shutdown ends the trial),
            interrupts.raise_when_safe(frame)  # or once out of an import (Tune imports as it starts)
            return
        signal.signal(signal.SIGINT, interrupts.interrupt)  # the next one stops at once
        self.requested.set()
        self._wake.set()

    def _watch(self) -> None:
        """The watcher thread: once a stop is asked for while the run still goes, says so and asks the trials by
        creating the named actor (`catching` waits for it before Ray can be shut down under it)."""
        self._wake.wait()
        if self._closing.is_set() or not self.requested.is_set():
            return
        self.out.write("\nstopping: the run ends after this iteration, its final policy evaluated and checkpointed "
                       "(Ctrl-C again to stop at once)\n")  # fmt: skip
        self.out.flush()
        import ray

        @ray.remote(num_cpus=0)
        class _Stop:
            def ping(self) -> bool:
                return True

        try:
            actor = _Stop.options(name=self.name, namespace=NAMESPACE).remote()  # type: ignore[attr-defined]
            ray.get(actor.ping.remote(), timeout=ASK_TIMEOUT_S)
        except Exception as exc:  # Ray not answering: the next Ctrl-C stops the run at once
            self.out.write(f"stopping: the run could not be asked to end ({type(exc).__name__}); Ctrl-C stops it at "
                           "once\n")  # fmt: skip
            return
        self._asked.append(actor)

    @contextmanager
    def catching(self, reported: Callable[[], bool]) -> Iterator[GracefulStop]:
        """SIGINT handled here rather than by Tune for the block (only the main thread may set handlers; SIGTERM
        follows SIGINT's handler, `interrupts.install`). On leaving, the watcher is waited for, so that no Ray call
        of its is left running when the caller shuts Ray down."""
        self.reported = reported
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        before, env = signal.getsignal(signal.SIGINT), os.environ.get(TUNE_SIGINT)
        watcher = threading.Thread(target=self._watch, name="smorphi-rl-stop", daemon=True)
        try:
            watcher.start()
            os.environ[TUNE_SIGINT] = "1"
            signal.signal(signal.SIGINT, self._on_signal)
            yield self
        finally:
            signal.signal(signal.SIGINT, before)
            self._closing.set()
            self._wake.set()
            watcher.join(ASK_TIMEOUT_S + 5)
            if env is None:
                os.environ.pop(TUNE_SIGINT, None)
            else:
                os.environ[TUNE_SIGINT] = env

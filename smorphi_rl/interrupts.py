"""SIGTERM handled like Ctrl-C: what `timeout`, `kill` and cluster schedulers send must not lose a run.

At the moment SIGTERM arrives it does what SIGINT would: while `train` runs, its graceful stop
(`training/stopping.py`: the run ends at its next iteration as at its budget's end); while a sweep or transfer
runs, Ray Tune's own handler (trials stop at their next report; checkpoints, tables and the summary are
written); a KeyboardInterrupt otherwise. Ray's core installs a C++ handler for SIGTERM in `ray.init` that
prints raw stack lines and exits, so `install()` is called again once Ray has started.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from typing import Any


def _sigterm_as_sigint(signum: int, frame: Any) -> None:
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler):
        handler(signal.SIGINT, frame)
    else:
        raise KeyboardInterrupt


def install() -> None:
    """Route SIGTERM to the current SIGINT behaviour, and honour SIGINT in a command a script started in the
    background (its shell set SIGINT to be ignored; Ray Tune's handler honours it once training runs, so it is
    honoured throughout). Only the main thread may set handlers."""
    if threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, _sigterm_as_sigint)


@contextmanager
def stop_requests(stop: threading.Event | None = None, again: bool = False) -> Iterator[threading.Event]:
    """While a long computation runs, Ctrl-C and SIGTERM set an event (`stop`, or a new one) instead of raising
    wherever the main thread happens to be (a KeyboardInterrupt raised as a compiled kernel returns crashed the
    process); the computation checks the event between chunks and stops there. With `again`, a stop once the event
    is set raises KeyboardInterrupt: a second Ctrl-C stops at once (no compiled kernel runs there). Outside the main
    thread, nothing is changed."""
    stop = stop if stop is not None else threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def request(*_: Any) -> None:
        if again and stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    handlers = {sig: signal.signal(sig, request) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


@contextmanager
def writes_held(stop: threading.Event | None = None) -> Iterator[threading.Event]:
    """Writing a job's results once Ray has shut down: stops set `stop` (or a new event) and wait for the writes,
    since Ray's shutdown may have reset SIGTERM's handler to its default (a kill); a second stop raises at once. On
    leaving, however it is left, SIGTERM is Ctrl-C again (`install`)."""
    try:
        with stop_requests(stop, again=True) as event:
            yield event
    finally:
        install()


@contextmanager
def results_held(stop: threading.Event, held: ExitStack) -> Iterator[None]:
    """`writes_held`, for a run whose `held` already holds stops in `stop` since its training ended."""
    with held, writes_held(stop):
        yield

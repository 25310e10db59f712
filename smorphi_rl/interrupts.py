"""SIGTERM handled like Ctrl-C: what `timeout`, `kill` and cluster schedulers send must not lose a run.

At the moment SIGTERM arrives it does what SIGINT would: while `train` runs, its graceful stop
(`training/stopping.py`: the run ends at its next iteration as at its budget's end); while a sweep or transfer
runs, Ray Tune's own handler (trials stop at their next report; checkpoints, tables and the summary are
written); a KeyboardInterrupt otherwise. Ray's core installs a C++ handler for SIGTERM in `ray.init` that
prints raw stack lines and exits, so `install()` is called again once Ray has started.

Python raises a KeyboardInterrupt at whatever line runs when the signal comes. Raised inside an import, it aborted
the process (matplotlib's compiled font module); raised in a callback (llvmlite's, as numba loaded a kernel; a
garbage-collector callback), Python printed "Exception ignored" and dropped it, and the command ran on to exit 0,
or the compiled code the callback served went on without its answer. `interrupt`, the SIGINT handler `install`
sets, raises only outside imports and llvmlite and asks again 50 ms later otherwise; a stop Python drops is asked
again the same way.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager, suppress
from types import FrameType
from typing import Any

RETRY_S = 0.05
"""How soon a stop that came where it cannot be raised is asked again."""
_HELD_IN = ("importlib._bootstrap", "_frozen_importlib", "_frozen_importlib_external", "llvmlite")
"""Modules (and their submodules) inside which a stop waits: imports (a second or two at most: Ray's, torch's; the
bootstrap is `_frozen_importlib` until `importlib` is first imported) and llvmlite, whose callbacks serve compiled
code as numba loads a kernel (numba's own Python, a compile of seconds on a first run, stops at once)."""


class _State:
    """The stop machinery's state: plain attributes, never a lock. A handler runs on the main thread between any
    two bytecodes, also inside a `threading.Event`'s own method, whose lock it would then wait on for ever."""

    pending = False
    """A stop has come and waits to be raised."""
    retry = False
    """The next call of the SIGINT handler is a waiting stop asked again, not a new one."""
    settled = True
    """No command runs (`install` starts one, `settle` ends it): nothing is asked again."""
    pid = 0
    """The process whose retry thread `wake` reaches (a forked child has none)."""
    wake = -1
    """The write end of the retry thread's pipe: a handler asks for a retry with one `os.write`."""
    whole = False
    """The command's output is flushed (`exiting`): a stop in the teardown says so."""


_unraisable_before: list[Any] = []
"""The `sys.unraisablehook` `install` found (what anything but a dropped stop goes to)."""


def _held(frame: FrameType | None) -> bool:
    """Whether the main thread is inside an import or llvmlite (any frame of its stack)."""
    while frame is not None:
        name = str(frame.f_globals.get("__name__", ""))
        if any(name == held or name.startswith(f"{held}.") for held in _HELD_IN):
            return True
        frame = frame.f_back
    return False


def _retrier(read_end: int) -> None:
    """The retry thread: for each request, RETRY_S later, the waiting stop handed to whatever handles SIGINT now
    (Tune's, a hold's, `interrupt`) as a signal to the main thread, which also wakes it from a blocking wait."""
    while os.read(read_end, 1):
        time.sleep(RETRY_S)
        if not _State.pending or _State.settled:
            continue  # raised meanwhile, or the command has ended
        if signal.getsignal(signal.SIGINT) is interrupt:
            _State.retry = True
        else:
            _State.pending = False
        signal.pthread_kill(threading.main_thread().ident or 0, signal.SIGINT)


def _later() -> None:
    """Ask the retry thread to hand the stop on RETRY_S from now (one `os.write`: safe inside a handler)."""
    if _State.settled or sys.is_finalizing() or os.getpid() != _State.pid:
        return
    _State.pending = True
    with suppress(OSError):  # a full pipe: retries are queued already
        os.write(_State.wake, b"r")


def _disarm() -> bool:
    """No stop waits any longer (a queued retry finds nothing to do); whether one did."""
    waited = _State.pending
    _State.pending = _State.retry = False
    return waited


def raise_when_safe(frame: FrameType | None) -> None:
    """A stop's KeyboardInterrupt: raised now outside imports and llvmlite, else asked again once the main thread
    is out of them (for every SIGINT handler that raises one: `interrupt`, `train`'s before its first report)."""
    if _held(frame) and not _State.settled and os.getpid() == _State.pid:  # a retry thread to ask again
        _later()
        return
    _disarm()
    raise KeyboardInterrupt


def interrupt(signum: int, frame: FrameType | None) -> None:
    """The SIGINT handler: a KeyboardInterrupt, raised at once outside imports and llvmlite, else once the main
    thread is out of them; a second stop while one waits raises at once (the user insists)."""
    retry, _State.retry = _State.retry, False
    if _State.pending and not retry:
        _disarm()
        raise KeyboardInterrupt
    raise_when_safe(frame)


def _unraisable(unraisable: Any) -> None:
    """`sys.unraisablehook`: a KeyboardInterrupt Python would print as "Exception ignored" and drop (raised in a
    callback) is asked again once the callback has returned, while a command runs; anything else, and anything once
    it has ended, goes to the hook that was there."""
    ours = not (_State.settled or sys.is_finalizing()) and os.getpid() == _State.pid  # (not a forked child's)
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and ours:
        _later()
    else:
        (_unraisable_before[-1] if _unraisable_before else sys.__unraisablehook__)(unraisable)


def settle() -> bool:
    """At a command's end: whether a stop still waits to be raised (it came too late to end the work). It is
    dropped, and nothing is asked again after."""
    _State.settled = True
    if sys.unraisablehook is _unraisable and _unraisable_before:
        sys.unraisablehook = _unraisable_before[-1]
    return _disarm()


EXIT_STOPPED = 130
"""The exit status of a stopped command (the CLI's EXIT_INTERRUPTED, and the entry point's before the CLI loads)."""


def _exiting(signum: int, frame: Any) -> None:
    with suppress(OSError):  # stderr a closed pipe (`2>&1 | head`): the exit all the same
        os.write(2, b"smorphi-rl: interrupted as it exited" + (b" (its output is whole)\n" if _State.whole else b"\n"))
    os._exit(EXIT_STOPPED)


def exiting(whole: bool = False) -> None:
    """Once a command has ended (before its last output is flushed, and again, `whole`, after): a stop in the flush
    or Python's teardown (its exit callbacks, the release of torch and the rest) ends the process at once with exit
    130 and one line, not a traceback, an "Exception ignored" and exit 0, nor the default handlers' death by signal
    Python puts back late in the teardown."""
    _State.whole = whole
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _exiting)


def _sigterm_as_sigint(signum: int, frame: Any) -> None:
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler):
        handler(signal.SIGINT, frame)
    else:
        raise KeyboardInterrupt


def install() -> None:
    """Route SIGTERM to the current SIGINT behaviour; put `interrupt` in place of Python's SIGINT handler, also in a
    command a script started in the background (its shell set SIGINT to be ignored; Ray Tune's handler honours it
    once training runs, so it is honoured throughout); hook dropped stops. Only the main thread may set handlers."""
    if threading.current_thread() is threading.main_thread():
        if _State.pid != os.getpid():  # the retry thread, started here: never inside a handler
            read_end, _State.wake = os.pipe()
            os.set_blocking(_State.wake, False)
            threading.Thread(target=_retrier, args=(read_end,), name="smorphi-rl-stops", daemon=True).start()
            _State.pid = os.getpid()
        _State.settled = False
        # `_exiting`: left by a command run before in this process
        if signal.getsignal(signal.SIGINT) in (signal.SIG_IGN, signal.default_int_handler, _exiting):
            signal.signal(signal.SIGINT, interrupt)
        signal.signal(signal.SIGTERM, _sigterm_as_sigint)
        if sys.unraisablehook is not _unraisable:
            _unraisable_before[:] = [sys.unraisablehook]
            sys.unraisablehook = _unraisable


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
        if stop.is_set():  # (`is_set` takes no lock: a second signal inside the first one's `set` would wait on it)
            if again:
                raise KeyboardInterrupt
            return
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

"""Stops raised only where Python can raise them: not inside an import or llvmlite's callbacks, never dropped."""

from __future__ import annotations

import signal
import sys
import time

import pytest
from conftest import stop_inside_llvmlite

from smorphi_rl import interrupts


def test_a_stop_inside_an_import_is_raised_once_the_import_is_done(installed, tmp_path, monkeypatch):
    """Raised inside an import, a KeyboardInterrupt aborted Python (matplotlib's compiled font module)."""
    (tmp_path / "stopped_import.py").write_text(
        "import signal\nsignal.raise_signal(signal.SIGINT)\nLOADED = True\n", encoding="utf-8"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(KeyboardInterrupt):
        import stopped_import  # noqa: F401

        time.sleep(5)  # the stop, asked again, wakes the sleep
    assert sys.modules.pop("stopped_import").LOADED  # the import ran to its end
    assert not interrupts.settle()


def test_a_stop_python_would_drop_in_a_callback_is_raised_after_it(installed):
    """A KeyboardInterrupt raised in a callback (llvmlite's as numba loaded a kernel, a garbage-collector callback)
    was printed "Exception ignored" and dropped: the command ran on and exited 0."""

    class StoppedAsItGoes:
        def __del__(self) -> None:
            signal.raise_signal(signal.SIGINT)

    slept = []
    with pytest.raises(KeyboardInterrupt):
        StoppedAsItGoes()
        time.sleep(60)
        slept.append(True)
    assert not slept  # raised as the sleep ran, not once it ended (nor dropped)
    assert not interrupts.settle()


def test_a_second_stop_while_the_first_waits_is_raised_at_once(installed, tmp_path, monkeypatch):
    """The user who presses Ctrl-C again is not kept waiting for an import (or a long first compile) to end."""
    (tmp_path / "stopped_twice.py").write_text(
        "import signal\nsignal.raise_signal(signal.SIGINT)\nsignal.raise_signal(signal.SIGINT)\nLOADED = True\n",
        encoding="utf-8",
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(KeyboardInterrupt):
        import stopped_twice  # noqa: F401
    assert "stopped_twice" not in sys.modules
    time.sleep(3 * interrupts.RETRY_S)  # the first stop's retry, due meanwhile, raises nothing more
    assert not interrupts.settle()


def test_a_stop_in_an_import_before_importlib_is_loaded_waits_too():
    """Until `import importlib` renames it, the bootstrap runs as `_frozen_importlib` (a plain install's first
    imports): a stop there was raised inside the import."""
    for name in ("_frozen_importlib", "_frozen_importlib_external", "importlib._bootstrap", "llvmlite.binding"):
        frame = eval("sys._getframe()", {"__name__": name, "sys": sys})
        assert interrupts._held(frame), name
    assert not interrupts._held(sys._getframe())


def test_after_the_command_ends_nothing_is_asked_again(installed):
    """A stop dropped in an exit callback was asked again in the next one, cutting each short in turn."""
    hook = interrupts._unraisable_before[-1]
    interrupts.settle()
    assert sys.unraisablehook is hook  # dropped stops go to the hook that was there
    interrupts._later()
    time.sleep(3 * interrupts.RETRY_S)  # nothing raised
    assert not interrupts.settle()


def test_a_stop_that_finds_the_work_done_is_dropped_and_reported(installed):
    """A stop that came inside llvmlite (numba loading a kernel) and still waits as the command ends is not raised
    in Python's teardown; `settle` says it came, so that the command exits as stopped."""
    stop_inside_llvmlite()  # returns: the stop waits
    assert interrupts.settle()
    time.sleep(3 * interrupts.RETRY_S)  # nothing raised
    assert not interrupts.settle()


def test_a_stop_in_pythons_teardown_exits_130_at_once_with_one_line():
    """Ray's exit callback ran with the stop handler in place: "Exception ignored in atexit callback", exit 0; a
    moment later Python's default handlers killed the process by the signal, without a word."""
    import subprocess

    script = (
        "import atexit, os, signal, time\n"
        "from smorphi_rl import interrupts\n"
        "interrupts.install()\n"
        "atexit.register(lambda: print('the other exit callbacks are skipped'))\n"
        "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(5)))  # a stop as Ray shuts down\n"
        "print('done', flush=True)\n"
        "interrupts.settle()\n"
        "interrupts.exiting(whole=True)\n"
    )
    ran = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert (ran.returncode, ran.stdout) == (130, "done\n")
    assert ran.stderr == "smorphi-rl: interrupted as it exited (its output is whole)\n"


def test_a_stop_in_the_teardown_exits_130_with_stderr_a_closed_pipe():
    """`cmd 2>&1 | head`: the line could not be written, the handler raised BrokenPipeError in an exit callback, and
    the process exited 0."""
    import os
    import subprocess

    script = (
        "import atexit, os, signal, time\n"
        "from smorphi_rl import interrupts\n"
        "interrupts.install()\n"
        "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(5)))\n"
        "interrupts.settle()\n"
        "interrupts.exiting(whole=True)\n"
    )
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader has gone
    try:
        ran = subprocess.run([sys.executable, "-c", script], stderr=write_end, timeout=60)
    finally:
        os.close(write_end)
    assert ran.returncode == 130

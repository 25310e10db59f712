"""`train`'s graceful stop: a first signal asks the trials to end, a second stops at once, and neither may leave a Ray
call running when Ray shuts down (a quick second Ctrl-C once crashed the process in Ray's core, exit 1)."""

from __future__ import annotations

import subprocess
import sys

from cli_runs import ray_env

SCRIPT = """
import os, signal, sys, time
from smorphi_rl import cluster, interrupts
from smorphi_rl.training.stopping import GracefulStop, stop_requested
interrupts.install()
gap = float(sys.argv[1])
try:
    with cluster.ray_session(None):
        stop = GracefulStop(sys.stderr)
        with stop.catching(reported=lambda: True):
            os.kill(os.getpid(), signal.SIGTERM)  # the first: a scheduler's, routed as Ctrl-C
            if gap < 0:  # one signal: the trials are asked
                deadline = time.monotonic() + 60
                while not stop_requested(stop.name) and time.monotonic() < deadline:
                    time.sleep(0.1)
                print("asked" if stop_requested(stop.name) else "not asked", flush=True)
                sys.exit(0)
            time.sleep(gap)
            os.kill(os.getpid(), signal.SIGINT)  # the second
            time.sleep(60)
except KeyboardInterrupt:
    print("stopped at once", flush=True)
    sys.exit(130)
"""


def stop_script(gap: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", SCRIPT, str(gap)], capture_output=True, text=True, env=ray_env(),
                          timeout=300)  # fmt: skip


def test_a_first_signal_asks_the_trials_and_says_so():
    proc = stop_script(-1)
    assert proc.returncode == 0 and proc.stdout.strip() == "asked", proc.stderr[-2000:]
    assert "stopping: the run ends after this iteration" in proc.stderr


def test_a_quick_second_signal_stops_at_once_without_crashing_ray():
    for gap in (0.0, 0.05):
        proc = stop_script(gap)
        assert proc.returncode == 130 and proc.stdout.strip() == "stopped at once", (gap, proc.stderr[-2000:])
        assert "core worker has already been shutdown" not in proc.stderr


def test_a_stop_tunes_own_handler_took_is_seen_and_its_handler_never_outlives_fit(monkeypatch):
    """Tune puts back the SIGINT handler it found only when a stop fires: a stop after a run's last report ended
    `fit` as usual (a transfer trained its next run), and on a normal return Tune's handler stayed, swallowing the
    next Ctrl-C."""
    import signal
    import threading

    from smorphi_rl.training.stopping import TUNE_SIGINT, tune_stop_seen

    monkeypatch.delenv(TUNE_SIGINT, raising=False)
    before = signal.getsignal(signal.SIGINT)

    def tunes_fit(fire: bool) -> None:  # what `tune.run`'s _setup_signal_catching does
        found = signal.getsignal(signal.SIGINT)
        signal.signal(signal.SIGINT, lambda *_: signal.signal(signal.SIGINT, found))
        if fire:
            signal.raise_signal(signal.SIGINT)

    for fire in (True, False):
        stopped = threading.Event()
        with tune_stop_seen(stopped):
            tunes_fit(fire)
        assert stopped.is_set() is fire and signal.getsignal(signal.SIGINT) is before


def test_a_stop_before_the_first_report_waits_for_an_import_to_end(installed, tmp_path, monkeypatch):
    """`train`'s handler raised at once before a trial reported, also inside an import (Tune imports as it starts),
    where a KeyboardInterrupt aborted Python."""
    import time

    import pytest

    from smorphi_rl import interrupts
    from smorphi_rl.training.stopping import GracefulStop

    (tmp_path / "stopped_in_tune.py").write_text("import signal\nsignal.raise_signal(signal.SIGINT)\nLOADED = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(KeyboardInterrupt), GracefulStop().catching(reported=lambda: False):
        import stopped_in_tune  # noqa: F401

        time.sleep(5)  # the stop, asked again once the import is done, wakes the sleep
    assert sys.modules.pop("stopped_in_tune").LOADED
    assert not interrupts.settle()

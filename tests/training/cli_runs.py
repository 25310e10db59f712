"""`smorphi-rl` in a subprocess for the Ray tests: run plainly, or stopped by Ctrl-C after its first checkpoint; and
what a finished trial's files must hold."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest


def ray_env() -> dict[str, str]:
    """The environment without RAY_ADDRESS, so each run starts its own local Ray."""
    return {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}


PROMPT_ROWS = {"TUNE_GLOBAL_CHECKPOINT_S": "1"}
"""Tune stages a trial's result rows away from the run's folder and copies them there at its experiment saves, every
10 s or more: a short run could end before a test that waits for its rows sees them. With this, every second."""


def cli(*argv: str, cwd: Path, timeout: float = 400, home: Path | None = None,
        drop: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:  # fmt: skip
    """`smorphi-rl ARGV` in `cwd`; `home`: the HOME it runs with (default the test's own); `drop`: environment
    variables it runs without."""
    env = {k: v for k, v in ray_env().items() if k not in drop} | ({"HOME": str(home)} if home is not None else {})
    return subprocess.run([sys.executable, "-m", "smorphi_rl.cli", *argv], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=timeout)  # fmt: skip


def fresh_home(home: Path) -> list[Path]:
    """Make `home` a user's home where the libraries' own caches already exist (matplotlib writes its font cache
    there by design on first import); returns what it holds, for a test to compare with after a run."""
    env = ray_env() | {"HOME": str(home)}
    subprocess.run([sys.executable, "-c", "import matplotlib.pyplot"], env=env, check=True, timeout=120)
    return sorted(home.rglob("*"))


def ctrl_c_after_checkpoint(argv: list[str], cwd: Path, checkpoints: Path, pattern: str,
                            ready: Callable[[], bool] = lambda: True) -> tuple[int, str, str]:  # fmt: skip
    """Start the command; SIGINT once `checkpoints.glob(pattern)` finds a checkpoint and `ready()` holds (what the
    test reads afterwards is written: polled, not a fixed wait, as a machine under load writes it later);
    (exit code, stdout, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "smorphi_rl.cli", *argv], cwd=cwd, env=ray_env() | PROMPT_ROWS,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and not list(checkpoints.glob(pattern)):
        time.sleep(0.5)
    if not list(checkpoints.glob(pattern)):
        proc.kill()
        raise AssertionError(f"no checkpoint matching {pattern} under {checkpoints} within 240 s")
    while time.monotonic() < deadline and not ready():
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=180)
    return proc.returncode, out, err


def holds_the_reported_policy(trial: Path) -> None:
    """The trial's final checkpoint, rolled out greedily from the protocol's starts, settles where its last
    evaluation (result.json) says: a run ends on the policy it reports."""
    from smorphi_rl.protocol import Optimum, eval_starts
    from smorphi_rl.training.checkpoints import find_checkpoint, load_module
    from smorphi_rl.training.policy import env_config_of, evaluate_policy

    last = json.loads((trial / "result.json").read_text().splitlines()[-1])
    reported = last["eval"]
    assert 0 <= reported["policy_env_steps"] <= last["num_env_steps_sampled_lifetime"]
    module = load_module(find_checkpoint(trial))
    config = env_config_of(module, None)
    unused = Optimum((0.0, 0.0, 0.0), math.inf, 100.0, 1)  # the settled shapes do not depend on it
    optima = dict.fromkeys((Path(m).stem for m in config.map_files), unused)
    evaluations = evaluate_policy(module, config, eval_starts(reported["starts"] // len(optima)), optima)
    mean = sum(e.mean_R1 for e in evaluations) / len(evaluations)
    assert mean == pytest.approx(reported["settled_R1_mean"], abs=1e-9)

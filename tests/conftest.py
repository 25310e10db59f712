"""Shared fixtures: the golden maps of docs/spec/fbcpp.md section 8 and hypothesis settings."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from smorphi_rl.maps import Cell, Map

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from _cluster import local_ray_cluster as ray_cluster

__all__ = ["ray_cluster"]

settings.register_profile(
    "ci", max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("ci")

ROOM12 = """
............
............
...##.......
...##.......
............
.......###..
.......###..
............
..#.........
..#.........
............
............
"""

CORRIDOR = """
##############
#............#
#.##########.#
#.#........#.#
#.#.######.#.#
#...#....#...#
######..######
######..######
"""

WALLED = """
################
#......#.......#
#......#.......#
#..............#
#..............#
#.....???......#
#.....???......#
#..............#
#....####......#
#..............#
################
"""
"""docs/fbcpp-fit.md section 8: a walled room with an unknown patch."""

GOLDEN_THETAS = [(0, 0, 0), (0, 180, 0), (90, 90, 90), (95, 59, 103), (15, 15, 39)]


_RAY_TMP = "SMORPHI_RL_TEST_RAY_TMPDIR"
"""Set (to the folder) in the process that made the suite's Ray folder; the workers inherit both variables."""


def pytest_configure(config: pytest.Config) -> None:
    """The Rays the suite starts (about a hundred, 1 MB of logs each) keep their session folders in one folder of
    the suite's own, removed at its end, rather than pile up in /tmp/ray. A RAY_TMPDIR the user set is kept."""
    if "RAY_TMPDIR" not in os.environ:
        # under /tmp, short: Ray's socket paths must fit 107 bytes
        os.environ["RAY_TMPDIR"] = os.environ[_RAY_TMP] = tempfile.mkdtemp(prefix="smorphi-test-", dir="/tmp")


def pytest_unconfigure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput"):  # an xdist worker: the process that made the folder removes it
        return
    if (made := os.environ.get(_RAY_TMP)) and os.environ.get("RAY_TMPDIR") == made:
        shutil.rmtree(made, ignore_errors=True)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Files that hold a slow (Ray) test run first: on `make test`'s 2 workers the longest files start early, rather
    than leave one worker running them alone at the end. Within a file, and among the rest, the order stays."""
    slow = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow)


@pytest.fixture(scope="session")
def room12() -> Map:
    return Map.from_text(ROOM12, 0.1, name="room12")


@pytest.fixture(scope="session")
def corridor() -> Map:
    return Map.from_text(CORRIDOR, 0.1, name="corridor")


@pytest.fixture(scope="session")
def walled() -> Map:
    return Map.from_text(WALLED, 0.1, name="walled")


def _realmaps() -> Path:
    """The workplace's shared/realmaps: $SMORPHI_RL_REALMAPS, else the nearest `shared/realmaps` above the tests."""
    if "SMORPHI_RL_REALMAPS" in os.environ:
        return Path(os.environ["SMORPHI_RL_REALMAPS"])
    here = Path(__file__).resolve()
    found = [p / "shared" / "realmaps" for p in here.parents if (p / "shared" / "realmaps").is_dir()]
    return found[0] if found else here.parents[2] / "shared" / "realmaps"


REALMAPS = _realmaps()
"""Real ROS maps recorded by robots (used from where the workplace keeps them; not copied into the project)."""


def realmap(name: str) -> Path:
    """The map_server YAML of a real map, or skip the test where the shared maps are not beside the project."""
    path = REALMAPS / f"{name}.yaml"
    if not path.is_file():
        pytest.skip(f"real map {path} not found (set SMORPHI_RL_REALMAPS)")
    return path


def random_map(rng: np.random.Generator, h: int, w: int, p_occupied: float, p_unknown: float = 0.0) -> Map:
    """A map of independent random cells with at least one free cell."""
    u = rng.random((h, w))
    cells = np.where(u < p_occupied, Cell.OCCUPIED, Cell.FREE).astype(np.uint8)
    cells[(u >= p_occupied) & (u < p_occupied + p_unknown)] = Cell.UNKNOWN
    cells[rng.integers(h), rng.integers(w)] = Cell.FREE
    return Map(cells, 0.1, name="random")


@pytest.fixture
def installed() -> Iterator[None]:
    """`interrupts.install` as the CLI calls it, with Python's handlers back afterwards."""
    import signal

    from smorphi_rl import interrupts

    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    hook = sys.unraisablehook
    signal.signal(signal.SIGINT, signal.default_int_handler)
    interrupts.install()
    try:
        yield
    finally:
        interrupts.settle()
        for sig, handler in before.items():
            signal.signal(sig, handler)
        sys.unraisablehook = hook


def stop_inside_llvmlite() -> None:
    """A Ctrl-C as if it came while llvmlite served numba a kernel: `interrupts.interrupt` called from a frame of
    llvmlite's (the stop then waits for a safe place)."""
    import signal

    from smorphi_rl import interrupts

    names = {"__name__": "llvmlite.binding.executionengine", "interrupts": interrupts, "signal": signal, "sys": sys}
    exec("interrupts.interrupt(signal.SIGINT, sys._getframe())", names)


@pytest.fixture(autouse=True, scope="session")
def _shared_optimum_cache(tmp_path_factory):
    """Every training run in the suite shares one cache of exact optima (each costs ~10 s to compute)."""
    import os

    os.environ["SMORPHI_RL_CACHE_DIR"] = str(tmp_path_factory.mktemp("optimum-cache"))
    yield


@contextmanager
def optima_under(log_dir: Path) -> Iterator[None]:
    """For a command run without $SMORPHI_RL_CACHE_DIR (so a test sees where it caches exact optima): the suite's
    optima copied into `log_dir`'s own cache first, and what the command adds copied back for later tests."""
    shared, own = Path(os.environ["SMORPHI_RL_CACHE_DIR"]), log_dir / ".cache"
    shutil.copytree(shared, own, dirs_exist_ok=True)
    yield
    shutil.copytree(own, shared, dirs_exist_ok=True)


@pytest.fixture
def small_disk(tmp_path):
    """A 4 MB tmpfs to fill (mounting one needs root: skipped otherwise); `fill(left)` leaves `left` bytes free."""
    import shutil
    import subprocess

    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4M", "tmpfs", str(disk)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip("mounting a small tmpfs needs root")
    yield disk
    shutil.rmtree(disk, ignore_errors=True)
    subprocess.run(["umount", "-l", str(disk)], check=False)


def fill_disk(disk: Path, left: int) -> None:
    """Fill `disk` until about `left` bytes are free."""
    import shutil

    free = shutil.disk_usage(disk).free
    (disk / "filler").write_bytes(b"\0" * max(0, free - left))


def printed_command(text: str, prog: str = "smorphi-rl") -> list[str]:
    """The `smorphi-rl ...` command a hint in `text` tells the user to run (in backticks or parentheses, or after
    a semicolon inside them), as the argv for `python -m smorphi_rl.cli`: tests run hints exactly as printed."""
    import re
    import shlex
    import sys

    found = re.search(rf"(?:[`(]|; )({re.escape(prog)} [^`)]+)[`)]", text)
    assert found, f"no `{prog} ...` hint in: {text[-2000:]}"
    return [sys.executable, "-m", "smorphi_rl.cli", *shlex.split(found.group(1))[1:]]

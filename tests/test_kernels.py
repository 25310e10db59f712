"""The compiled kernels load wherever the package is installed: numba's cache falls back to a temp folder where
it can write neither beside the package nor in the user's cache."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from smorphi_rl import _kernels

PACKAGE = Path(_kernels.__file__).parent


def test_the_cache_stays_numbas_own_where_it_can_write(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    assert _kernels.cache_fallback(tmp_path / "pkg", blocked / "user") is None  # beside the package
    assert _kernels.cache_fallback(blocked / "pkg", tmp_path / "user") is None  # the user's cache
    fallback = _kernels.cache_fallback(blocked / "pkg", blocked / "user")
    assert fallback is not None and Path(fallback).name == f"smorphi-rl-numba-{os.getuid()}"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert _kernels.cache_fallback(blocked / "pkg", blocked / "user") is None  # the user's choice


def test_a_read_only_install_with_no_writable_home_loads_the_kernels(tmp_path):
    """Both unwritable (a shared install, a container run as another user): `@njit(cache=True)` raised "cannot
    cache function '_poses': no locator available" at import, in a traceback, on every planning command."""
    copy = tmp_path / "site" / "smorphi_rl"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "__pycache__").write_text("")  # numba cannot cache beside the kernels (as root, no mode stops it)
    home = tmp_path / "home-is-a-file"
    home.write_text("")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env |= {"HOME": str(home), "PYTHONPATH": str(copy.parent), "TMPDIR": str(tmp_path)}
    code = "import os, smorphi_rl._kernels as k; print(k.__file__); print(os.environ['NUMBA_CACHE_DIR'])"
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    loaded, cache = proc.stdout.split()
    assert Path(loaded).parent == copy and Path(cache).parent == tmp_path


def _on_a_terminal(code: str, env: dict[str, str]) -> tuple[str, str]:
    """(stdout, stderr) of `python -c code` whose stderr is a terminal (a pseudo-terminal)."""
    terminal, other_end = os.openpty()
    try:
        proc = subprocess.run([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=other_end,
                              text=True, timeout=120)  # fmt: skip
        os.close(other_end)
        chunks = []
        while True:
            try:
                chunk = os.read(terminal, 4096)
            except OSError:  # the other end closed: all was read
                break
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(terminal)
    return proc.stdout, b"".join(chunks).decode()


def test_a_compile_is_announced_on_a_terminal_once_and_a_cached_kernel_is_not(tmp_path):
    """A fresh install's first plan was silent for about 40 s. Numba's compile event says so once a process; a
    kernel loaded from the cache raises none; a log or a pipe hears nothing."""
    env = os.environ | {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    code = ("import numpy as np, smorphi_rl._kernels as k; print(k._popcount(np.uint64(5)), k._ctz(np.uint64(8)), "
            "k._popcount(np.uint64(7)))")  # fmt: skip
    out, said = _on_a_terminal(code, env)
    assert out.split() == ["2", "3", "3"] and said.strip() == _kernels.COMPILE_NOTICE  # two kernels: one line
    out, said = _on_a_terminal(code, env)
    assert out.split() == ["2", "3", "3"] and said == ""  # both loaded from the cache
    proc = subprocess.run([sys.executable, "-c", code], env=os.environ | {"NUMBA_CACHE_DIR": str(tmp_path / "b")},
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.stdout.split() == ["2", "3", "3"] and proc.stderr == ""  # compiled, off a terminal

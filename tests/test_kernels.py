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


def test_the_index_file_a_compile_leaves_is_where_compiled_before_looks():
    """`compiled_before` reads numba's own file names: a numba that names them otherwise fails here, not by a
    notice on every run (or none)."""
    import numpy as np

    side = _kernels.buffer_side(0.17, 0.1)
    assert _kernels.footprint_keys(np.full((1, 3), 90.0), 0.17, 0.1, side).shape == (1, 2)  # compiled or loaded
    assert _kernels._index_file(_kernels.footprint_keys).is_file()
    assert _kernels.compiled_before()


def test_a_first_compile_is_announced_on_a_terminal_and_nowhere_else(tmp_path):
    """A fresh install's first plan was silent for about half a minute."""
    env = os.environ | {"NUMBA_CACHE_DIR": str(tmp_path / "empty-cache")}
    code = "import smorphi_rl._kernels as k; print(k.compiled_before())"
    terminal, other_end = os.openpty()
    try:
        proc = subprocess.run([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=other_end,
                              text=True, timeout=120)  # fmt: skip
        os.close(other_end)
        said = os.read(terminal, 4096).decode()
    finally:
        os.close(terminal)
    assert proc.stdout.strip() == "False" and said.strip() == _kernels.COMPILE_NOTICE
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() == "False" and proc.stderr == ""  # a log file or a pipe: nothing said

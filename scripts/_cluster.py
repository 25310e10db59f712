"""A Ray cluster of its own on this machine, for the benchmarks and the tests that attach to one."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def local_ray_cluster(num_cpus: int, nodes: int = 1) -> Iterator[str]:
    """A Ray cluster of its own (`ray start --head` on a free loopback port, its own temp folder; `nodes` - 1 more
    nodes joined to it, the CPUs shared out) for the block; yields its address. Only its own processes are stopped
    afterwards (`ray stop` would stop every Ray here)."""
    import shutil
    import signal
    import socket
    import subprocess
    import sys
    import tempfile
    import time

    with socket.socket() as s, socket.socket() as c:  # the client server's too: Ray's fixed 10001 is one per machine
        s.bind(("127.0.0.1", 0))
        c.bind(("127.0.0.1", 0))
        port, client_port = int(s.getsockname()[1]), int(c.getsockname()[1])
    ray = shutil.which("ray", path=str(Path(sys.executable).parent)) or "ray"
    temp_dir = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # short: Ray's socket paths must fit 107 bytes
    # Without auth, whatever token file a Ray on this machine may have left in ~/.ray (the client sets none).
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {"RAY_AUTH_MODE": "disabled"}
    # On loopback alone: Ray would advertise the node on the host's routable address.
    each = num_cpus // nodes
    start = [ray, "start", "--head", "--node-ip-address=127.0.0.1", f"--num-cpus={num_cpus - each * (nodes - 1)}",
             f"--port={port}", "--include-dashboard=false", f"--ray-client-server-port={client_port}",
             "--disable-usage-stats", f"--temp-dir={temp_dir}"]  # fmt: skip
    subprocess.run(start, check=True, capture_output=True, env=env, timeout=120)
    for _ in range(nodes - 1):  # another node on this machine: the same files, its own raylet and object store
        join = [ray, "start", f"--address=127.0.0.1:{port}", "--node-ip-address=127.0.0.1", f"--num-cpus={each}",
                "--disable-usage-stats", f"--temp-dir={temp_dir}"]  # fmt: skip
        subprocess.run(join, check=True, capture_output=True, env=env, timeout=120)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            pids = []
            for entry in Path("/proc").iterdir():
                try:
                    if entry.name.isdigit() and temp_dir in (entry / "cmdline").read_bytes().decode(errors="replace"):
                        pids.append(int(entry.name))
                except OSError:
                    continue
            for pid in pids:
                with contextlib.suppress(OSError):
                    os.kill(pid, sig)
            if not pids:
                break
            time.sleep(3)
        shutil.rmtree(temp_dir, ignore_errors=True)

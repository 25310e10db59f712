"""Starting a local Ray for one run, or attaching to an existing cluster, with a clear error if it is not there."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import socket
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from smorphi_rl import interrupts
from smorphi_rl.errors import SmorphiError
from smorphi_rl.words import counted, verb

CONNECT_TIMEOUT_S = 3.0
MIN_LOCAL_CPUS = 2
"""A trial asks for 2 CPUs (1 for its own process, 0.5 per env runner); a 1-core machine still runs it."""


CLIENT_SCHEME = "ray://"
"""Ray Client's scheme: the driver's work runs on the cluster's head, and only what it returns comes back here."""


class ClusterError(SmorphiError):
    """The Ray cluster named by --address cannot be reached."""


def _host_port(address: str, named: str = "--address") -> tuple[str, int] | None:
    """(host, port) of a `host:port` or `ray://host:port` address; None for `auto`. Any other scheme (http://,
    grpc://) is refused: Ray would take it for a job server or fail inside its client. `named`: where the address
    came from, as the refusal names it."""
    if address == "auto":
        return None
    given = address
    address = address.removeprefix(CLIENT_SCHEME)
    host, sep, port = address.rpartition(":")
    if "://" in host:
        sep = ""  # another scheme: refused below
    if host.startswith("[") and host.endswith("]"):  # an IPv6 literal, [::1]:6379
        host = host[1:-1]
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ClusterError(f"{named} must be HOST:PORT, 'auto' or ray://HOST:PORT, got {given!r}")
    return host, int(port)


RAY_CURRENT_CLUSTER = "ray_current_cluster"
"""The file in Ray's temp folder (`ray_temp_dir`) where `ray start --head` leaves the address that `--address auto`
attaches to (Ray 2.60), unless RAY_ADDRESS names one."""


def ray_temp_dir() -> str:
    """The folder `ray start` writes its session and address into when given no --temp-dir, as Ray 2.60 picks it:
    `ray` under RAY_TMPDIR, else under TMPDIR on Linux, else under /tmp."""
    if "RAY_TMPDIR" in os.environ:
        base = os.environ["RAY_TMPDIR"]
    elif sys.platform.startswith("linux") and "TMPDIR" in os.environ:
        base = os.environ["TMPDIR"]
    elif sys.platform.startswith(("linux", "darwin")):
        base = "/tmp"
    else:
        base = tempfile.gettempdir()
    return os.path.join(base, "ray")


SOCKET_PATH_MAX = 103 if sys.platform.startswith("darwin") else 107
"""The longest Unix socket path Ray accepts, in bytes (sun_path less its terminating zero)."""

SOCKET_TAIL = len("/session_2026-12-07_08-54-13_647655_4194304/sockets/plasma_store")
"""What a local Ray adds to its temp folder for its longest socket's path (Ray 2.60; a pid of up to 7 digits)."""


def check_local_ray() -> None:
    """Refuse at once a temp folder a local Ray cannot start in: a relative one (an empty or relative TMPDIR left
    Ray's start-up to time out after 30 s in a traceback, its folder in the current one) or one too long for the
    socket paths Ray makes inside it (refused by Ray only as it starts, after any exact optimum is computed)."""
    folder = ray_temp_dir()
    named = next((v for v in ("RAY_TMPDIR", "TMPDIR") if v in os.environ), None)
    said = f"{named}={os.environ[named]!r}" if named else "the temp folder"
    if not os.path.isabs(folder):  # only a variable set to a relative path makes it so
        raise ClusterError(f"{said} is not an absolute folder: a local Ray would keep its sessions in {folder!r}, "
                           f"under the current folder, and time out starting: give an absolute folder or unset "
                           f"{named}")  # fmt: skip
    if len(os.fsencode(folder)) + SOCKET_TAIL > SOCKET_PATH_MAX:
        room = SOCKET_PATH_MAX - SOCKET_TAIL - len(os.sep + "ray")  # ray_temp_dir adds /ray
        raise ClusterError(f"{said}: a local Ray's socket paths under {folder} would pass the limit of "
                           f"{SOCKET_PATH_MAX} bytes: set RAY_TMPDIR to a folder of at most {room} bytes, such as "
                           "/tmp")  # fmt: skip


def _recorded_path() -> str:
    return os.path.join(ray_temp_dir(), RAY_CURRENT_CLUSTER)


def auto_address() -> str | None:
    """What `--address auto` attaches to: RAY_ADDRESS, else the address the latest `ray start` on this machine
    recorded; None when neither exists. (Ray itself would also attach to any Ray running here, such as another
    run's private local Ray, and fail inside it: not a cluster to share.)"""
    if os.environ.get("RAY_ADDRESS", "").strip() not in ("", "auto"):
        return os.environ["RAY_ADDRESS"].strip()
    try:
        with open(_recorded_path()) as fh:
            return fh.read().strip() or None
    except OSError:
        return None


def auto_source() -> str:
    """Where `auto_address` found its address, as a message names it."""
    if os.environ.get("RAY_ADDRESS", "").strip() not in ("", "auto"):
        return "RAY_ADDRESS"
    return f"{_recorded_path()} (left by the latest `ray start` here)"


def check_reachable(address: str | None, client: bool = True) -> None:
    """Fail fast, before Ray starts (and before any optimum is computed), when the cluster an address names does
    not answer, or, given none, when a local Ray could not start in its temp folder (`check_local_ray`); `auto` is
    resolved first (`auto_address`). `client` False (the training jobs) refuses Ray Client:
    under `ray://` Tune runs the whole experiment on the head, so no result, progress or stop request reaches this
    process, and its files are written on the head's disk."""
    if address is None:
        check_local_ray()
        return
    given = address
    if address == "auto":
        resolved = auto_address()
        if resolved is None:
            raise ClusterError(f"--address auto: no Ray cluster started on this machine (RAY_ADDRESS names none "
                               f"and `ray start --head` has left no address in {_recorded_path()}, as `ray start "
                               "--temp-dir DIR` leaves it in DIR): start one, or give its HOST:PORT")  # fmt: skip
        address = resolved
    if not client and address.startswith(CLIENT_SCHEME):
        said = given if given == address else f"{given} ({address})"
        raise ClusterError(f"--address {said}: training runs Tune from this process, and under Ray Client (ray://) "
                           "Tune would run on the cluster's head with its results there: give the cluster's "
                           "HOST:PORT (the GCS port `ray start --head --port` printed) from a machine of the "
                           "cluster")  # fmt: skip
    target = _host_port(address, "--address" if given == address else f"--address auto's {auto_source()}")
    if target is None:
        return
    found = "" if given == address else f", which --address auto found in {auto_source()}"
    try:
        with socket.create_connection(target, timeout=CONNECT_TIMEOUT_S) as sock:
            answers = _answers_grpc(sock) if not _tls() else True  # under TLS a plain preface is no question
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ClusterError(
            f"cannot reach a Ray cluster at {address}{found} ({reason}): start one there (`ray start --head "
            "--port=PORT`), or leave --address out to run on a Ray of this machine's own"
        ) from None
    if not answers:  # Ray itself would retry for a minute and more, printing its C++ core's log lines
        raise ClusterError(f"{address} answers, but not as a Ray cluster (no gRPC reply within {CONNECT_TIMEOUT_S:g} "
                           "s): give the port `ray start --head --port` printed")  # fmt: skip


GRPC_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
"""HTTP/2's client preface and an empty SETTINGS frame: a gRPC server (Ray's GCS, its client server) answers with
a SETTINGS frame of its own."""


def _answers_grpc(sock: socket.socket) -> bool:
    """Whether the server on `sock` answers HTTP/2's preface with a SETTINGS frame, as every gRPC server does."""
    sock.settimeout(CONNECT_TIMEOUT_S)
    sock.sendall(GRPC_PREFACE)
    head = b""
    try:
        while len(head) < 9:
            chunk = sock.recv(9 - len(head))
            if not chunk:
                break
            head += chunk
    except (TimeoutError, ConnectionError):
        return False
    return len(head) == 9 and head[3] == 4  # a frame header: length (3 bytes), then its type, 4 for SETTINGS


def _tls() -> bool:
    """Whether Ray speaks TLS here (RAY_USE_TLS), so a cleartext preface tells nothing."""
    return os.environ.get("RAY_USE_TLS", "0").strip().lower() in ("1", "true")


_OPEN: list[str | None] = []
"""The addresses of the sessions this process holds open, outermost first."""


@contextmanager
def ray_session(address: str | None) -> Iterator[None]:
    """A local Ray started for this run (address None), or a connection to an existing cluster. Inside a session
    of the same address (a job of many runs, such as `transfer`), the runs share it: Ray starts and stops once."""
    import ray

    if address == "auto":
        address = auto_address() or address  # the recorded cluster, not whichever Ray Ray's own "auto" finds
    if _OPEN and _OPEN[-1] == address and ray.is_initialized():
        yield
        return
    if address is None:
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # a private, local-only Ray
    # Attaching leaves RAY_AUTH_MODE / RAY_AUTH_TOKEN to the user: forcing token mode against a
    # cluster started without a token aborts the process inside Ray's C++ core.
    empty = _empty_working_dir()
    runtime_env: dict[str, Any] = {"worker_process_setup_hook": "smorphi_rl.quiet.quiet"}
    if empty is not None:
        runtime_env["working_dir"] = empty.name
    kwargs: dict[str, Any] = {
        "include_dashboard": False,
        "log_to_driver": False,
        "logging_level": logging.ERROR,
        "runtime_env": runtime_env,
    }
    if address is None:
        kwargs["num_cpus"] = local_cpus()
    # Ctrl-C during ray.init could vanish inside Ray's start-up (the run then trained its whole budget), and Ray's
    # init replaces the SIGTERM handler with exit(15): both are only noted while Ray starts, and acted on after.
    sigterm = False  # Ray's own start-up handler took it: set after the hold (a signal inside `set` would wait)
    with interrupts.stop_requests() as stop:
        try:
            if address is None:
                from smorphi_rl import rllib_compat

                with rllib_compat.daemons_in_their_own_session():  # "local": a new Ray, never a running one
                    ray.init(address="local", **kwargs)  # (Ray's default attaches to a `ray start` of this machine)
            else:
                ray.init(address=address, **kwargs)
        except Exception as exc:  # Ray's start-up raises plain Exceptions too (a node that timed out starting)
            where = "a local Ray" if address is None else f"the Ray cluster at {address}"
            raise ClusterError(f"cannot start or reach {where}: {ray_error_line(exc)}") from None
        except SystemExit as exc:
            if exc.code != signal.SIGTERM:
                raise
            sigterm = True  # SIGTERM reached Ray's own start-up handler
        finally:
            if empty is not None:
                empty.cleanup()
    interrupts.install()  # Ray's init replaced our SIGTERM handler with its exit(15)
    if stop.is_set() or sigterm:
        ray.shutdown()
        raise KeyboardInterrupt
    _OPEN.append(address)
    try:
        yield
    finally:
        _OPEN.pop()
        ray.shutdown()


def _empty_working_dir() -> tempfile.TemporaryDirectory[str] | None:
    """An empty folder for the job's runtime env to name as its working_dir, or None for a job submitted with its
    own (Ray refuses two). Without one Ray puts the driver's working folder first on every worker's sys.path: a
    `tensorflow.py` in the folder a run starts from ran in every env runner. Ray packs it at `ray.init`, so it goes
    at once after; the workers start in Ray's unpacked copy."""
    from smorphi_rl import rllib_compat

    if rllib_compat.submitted_with_working_dir():
        return None
    try:
        return tempfile.TemporaryDirectory(prefix="smorphi-rl-ray-")
    except OSError as exc:
        raise ClusterError(f"cannot make the empty folder Ray's workers start in: {exc}") from None


def ray_error_line(exc: BaseException) -> str:
    """Ray's error in one line: its first line, or all of a version mismatch's (which names both versions)."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    if not lines:
        return type(exc).__name__
    if lines[0].startswith("Version mismatch"):
        return " ".join(lines).replace(" Ray:", " Ray").replace(" Python:", " Python")
    return lines[0]


def local_cpus() -> int:
    """The CPUs a local Ray started for a run gets."""
    return max(MIN_LOCAL_CPUS, usable_cpus())


def usable_cpus() -> int:
    """The cores this process may run on: its CPU affinity (`taskset`, a batch job's cpuset) within a container's
    CPU quota (cgroup), not every core of the machine; a job given 4 cores of 128 forked 128 planners."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # no affinity here (macOS)
        cores = os.cpu_count() or 1
    quota = _cgroup_quota()
    return max(1, min(cores, math.ceil(quota)) if quota else cores)


def _cgroup_quota(root: Path = Path("/sys/fs/cgroup"), own: Path = Path("/proc/self/cgroup")) -> float | None:
    """The CPUs the cgroup quotas allow this process (cgroup v2's cpu.max on its own group and every group above it,
    the least; else v1's CFS quota), None where unlimited or not Linux. `own`: the file naming the process's group
    (a systemd unit's CPUQuota, a container started in the host's cgroup namespace lie below the top)."""
    try:
        group = next((line[3:].strip() for line in own.read_text().splitlines() if line.startswith("0::")), "/")
    except OSError:
        group = "/"
    here = Path(os.path.normpath(root / group.lstrip("/")))
    quotas = []
    for level in (here, *here.parents):
        if not level.is_relative_to(root):
            break
        try:
            quota, period = (level / "cpu.max").read_text().split()[:2]
            if quota != "max":
                quotas.append(int(quota) / int(period))
        except (OSError, ValueError):
            continue
    if quotas:
        return min(quotas)
    try:
        v1 = root / "cpu"
        quota_us = int((v1 / "cpu.cfs_quota_us").read_text())
        return None if quota_us <= 0 else quota_us / int((v1 / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None


def check_capacity(cpus: float, env_runners: int, address: str | None, fix: str = "use fewer --env-runners") -> None:
    """Refuse, before any trial starts, a layout the Ray in use cannot place (it would wait forever), saying `fix`.
    For a local Ray this needs no Ray at all; for a cluster, call it once connected."""
    if address is None:
        have = float(local_cpus())
    else:
        import ray

        have = float(ray.cluster_resources().get("CPU", 0.0))
    if cpus > have + 1e-9:
        where = "this machine's local Ray" if address is None else f"the Ray cluster at {address}"
        raise ClusterError(
            f"{counted(env_runners, 'env runner')} {verb(env_runners, 'needs', 'need')} {cpus:g} CPUs (1 for the "
            f"trial, 0.5 per runner) and {where} has {have:g}: {fix}"
        )


SHARED_CHECK_TIMEOUT_S = 60.0
"""How long each node of a cluster may take to say whether it sees a run's folder (`check_shared_folder`)."""


def _sees(path: str) -> bool:
    """On a node: whether the file `path` is there."""
    return os.path.isfile(path)


def check_shared_folder(folder: Path, address: str | None) -> None:
    """On a cluster of several machines, refuse in one line, before any trial starts, a run folder that some node
    does not see at the same path: Tune saves a trial's checkpoints from the node it runs on (Ray 2.60 fails at the
    first one, perhaps hours in) and its env runners record episodes there. Call it once connected."""
    if address is None:
        return
    import uuid

    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [node for node in ray.nodes() if node.get("Alive")]
    if len(nodes) < 2:
        return
    from smorphi_rl.rundir import rel, write_text_atomic

    marker = folder / f".seen-from-every-node-{uuid.uuid4().hex}"
    write_text_atomic(marker, "")
    try:
        sees: Any = ray.remote(num_cpus=0)(_sees)
        asked = {sees.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False))
                 .remote(str(marker)): node for node in nodes}  # fmt: skip
        answered, late = ray.wait(list(asked), num_returns=len(asked), timeout=SHARED_CHECK_TIMEOUT_S)
        for ref in late:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        blind, silent = [], [str(asked[ref].get("NodeManagerAddress")) for ref in late]
        for ref in answered:
            try:
                seen = bool(ray.get(ref))
            except ray.exceptions.RayError:  # a node gone since it was listed, or one that cannot run our code
                silent.append(str(asked[ref].get("NodeManagerAddress")))
                continue
            if not seen:
                blind.append(str(asked[ref].get("NodeManagerAddress")))
    finally:
        marker.unlink(missing_ok=True)
    if blind:
        raise ClusterError(unshared_line(folder, blind, len(nodes)))
    if silent:
        raise ClusterError(f"{_nodes(silent, len(nodes))} did not say within {SHARED_CHECK_TIMEOUT_S:.0f} s whether "
                           f"{rel(folder)} is there (a node gone, or one without smorphi-rl); a run on several "
                           "machines needs --log-dir seen from every node")  # fmt: skip


def _nodes(addresses: list[str], n_nodes: int) -> str:
    """`2 nodes of the cluster's 3 (127.0.0.2, 127.0.0.9)`: at most three addresses named."""
    more = ", ..." if len(addresses) > 3 else ""
    return f"{counted(len(addresses), 'node')} of the cluster's {n_nodes} ({', '.join(sorted(addresses)[:3])}{more})"


def unshared_line(folder: Path, blind: list[str], n_nodes: int) -> str:
    """What `check_shared_folder` says of a run folder the nodes at `blind` (addresses) do not see."""
    from smorphi_rl.rundir import rel

    return (
        f"{rel(folder)} is not seen from {_nodes(blind, n_nodes)}: on a cluster of several machines each trial "
        "saves its checkpoints from the node it runs on, so --log-dir must be a folder every node sees at the "
        "same path (NFS, a mounted bucket)"
    )

"""`--address auto` attaches to RAY_ADDRESS or the cluster `ray start` recorded, and is refused in one line, before
any work, when there is none or it does not answer."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import ray

from smorphi_rl import cluster
from smorphi_rl.cluster import ClusterError, check_reachable


@pytest.fixture
def no_ray_here(tmp_path, monkeypatch):
    """An empty Ray temp folder, as `ray start` with RAY_TMPDIR=tmp_path would use it."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setenv("RAY_TMPDIR", str(tmp_path))
    (tmp_path / "ray").mkdir()
    return tmp_path / "ray"


@pytest.mark.parametrize(
    "env", [{}, {"TMPDIR": "/scratch/t"}, {"RAY_TMPDIR": "/scratch/r"}, {"RAY_TMPDIR": "/r", "TMPDIR": "/t"}]
)
def test_the_temp_folder_is_the_one_ray_start_writes_its_address_into(env, monkeypatch):
    """`--address auto` read RAY_TMPDIR/ray_current_cluster, where `ray start` writes RAY_TMPDIR/ray/..., and
    ignored TMPDIR: with either set it never found the cluster. Fails when Ray picks its folder otherwise."""
    from ray._common.utils import get_default_ray_temp_dir  # the function `ray start` calls (Ray 2.60)

    for name in ("RAY_TMPDIR", "TMPDIR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert cluster.ray_temp_dir() == get_default_ray_temp_dir()


def test_auto_with_no_cluster_on_the_machine_is_refused(no_ray_here):
    with pytest.raises(ClusterError, match="--address auto: no Ray cluster started on this machine"):
        check_reachable("auto")


@pytest.mark.parametrize(("value", "said"), [("junk", "'junk'"), ("ray://", "'ray://'")])
def test_a_ray_address_auto_follows_that_is_no_address_is_named_as_the_variable(no_ray_here, monkeypatch, value, said):
    """The refusal named --address, which the user had given as `auto`, and `ray://` as ''."""
    monkeypatch.setenv("RAY_ADDRESS", value)
    with pytest.raises(ClusterError, match=rf"^--address auto's RAY_ADDRESS must be HOST:PORT, .* got {said}$"):
        check_reachable("auto")


def test_auto_says_where_it_looked_for_the_address(no_ray_here):
    """A cluster started with `ray start --temp-dir` records its address in that folder, where neither Ray's own
    `auto` nor this one looks: the line says where it looked."""
    with pytest.raises(ClusterError, match=r"no address in .*/ray/ray_current_cluster, as `ray start --temp-dir DIR`"):
        check_reachable("auto")


def test_auto_follows_ray_address(no_ray_here, monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(
        ClusterError,
        match=r"cannot reach a Ray cluster at 127\.0\.0\.1:1, which --address auto found in RAY_ADDRESS \(",
    ):
        check_reachable("auto")


def test_auto_follows_the_address_ray_start_recorded(no_ray_here):
    """The line named an address the user never typed without saying where it came from."""
    (no_ray_here / cluster.RAY_CURRENT_CLUSTER).write_text("127.0.0.1:1\n")
    with pytest.raises(
        ClusterError,
        match=r"127\.0\.0\.1:1, which --address auto found in .*ray_current_cluster \(left by the latest `ray start`",
    ):
        check_reachable("auto")


def test_an_ipv6_literal_is_tried_as_an_address_not_looked_up_as_a_name():
    """`[::1]:PORT` read "Name or service not known": the brackets went to the resolver."""
    with pytest.raises(ClusterError, match=r"cannot reach a Ray cluster at \[::1\]:1 \(") as refused:
        check_reachable("[::1]:1")
    assert "not known" not in str(refused.value)


def test_a_port_where_something_else_listens_is_refused_in_one_line_not_retried(tmp_path, capsys):
    """An HTTP server, or a listener that never speaks, on the given port: Ray retried for over a minute, printing
    its C++ core's log lines, where a gRPC probe answers within seconds."""
    import socket
    import threading

    from smorphi_rl.cli import main

    def http_once(server: socket.socket) -> None:
        conn, _ = server.accept()
        with conn:
            conn.recv(64)
            conn.sendall(b"HTTP/1.0 400 Bad request\r\n\r\n")

    with socket.create_server(("127.0.0.1", 0)) as silent, socket.create_server(("127.0.0.1", 0)) as http:
        threading.Thread(target=http_once, args=(http,), daemon=True).start()
        for server in (http, silent):
            address = f"127.0.0.1:{server.getsockname()[1]}"
            with pytest.raises(ClusterError, match=f"{address} answers, but not as a Ray cluster"):
                check_reachable(address)
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        assert main(["search", "random", "--samples", "5", "--address", address, "--log-dir", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "answers, but not as a Ray cluster" in err[0] and not list(tmp_path.iterdir())


def test_a_port_that_answers_as_grpc_passes_the_probe():
    """A server that answers HTTP/2's preface with a SETTINGS frame, as Ray's GCS and client server do."""
    import socket
    import threading

    def settings_once(server: socket.socket) -> None:
        conn, _ = server.accept()
        with conn:
            conn.recv(64)
            conn.sendall(bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))
            conn.recv(64)

    for prefix in ("", "ray://"):
        with socket.create_server(("127.0.0.1", 0)) as server:
            threading.Thread(target=settings_once, args=(server,), daemon=True).start()
            check_reachable(f"{prefix}127.0.0.1:{server.getsockname()[1]}")


def test_train_with_auto_and_no_cluster_writes_nothing(no_ray_here, tmp_path, capsys):
    from smorphi_rl.cli import main

    assert main(["train", "--address", "auto", "--log-dir", str(tmp_path / "logs")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--address auto: no Ray cluster" in err[0] and not (tmp_path / "logs").exists()


def test_a_version_mismatch_with_a_cluster_is_one_line_naming_both_versions():
    from ray._private.utils import check_version_info

    from smorphi_rl.cluster import ray_error_line

    metadata = {"ray_version": "2.50.0", "python_version": "3.11.0"}
    with pytest.raises(RuntimeError) as exc:  # Ray's own check, with the message Ray prints
        check_version_info(metadata, "127.0.0.1")
    line = ray_error_line(exc.value)
    assert "\n" not in line and line.startswith("Version mismatch")
    assert "Ray 2.50.0" in line and f"Ray {ray.__version__}" in line
    assert ray_error_line(RuntimeError("first\nsecond")) == "first" and ray_error_line(RuntimeError()) == "RuntimeError"


def test_a_session_inside_one_of_the_same_address_shares_its_ray(monkeypatch, tmp_path):
    """A job of many runs starts Ray once: a run's session inside it neither starts nor stops Ray. Without --address
    the run's Ray is its own even where RAY_ADDRESS (or a `ray start` of this machine) names another: Ray's default
    attached to that one, and a dead one refused the run ("num_cpus and num_gpus must not be provided").
    A module in the folder a run starts from is not the workers' to import: Ray put that folder first on their
    sys.path, and a `tensorflow.py` there ran in every env runner (RLlib tries that import)."""
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    (tmp_path / "smorphi_planted.py").write_text(f"open({str(tmp_path / 'ran')!r}, 'w').close()\n")
    monkeypatch.chdir(tmp_path)
    with cluster.ray_session(None):
        node = ray.get_runtime_context().get_node_id()

        @ray.remote
        def planted() -> tuple[bool, list[str]]:
            import importlib.util
            import sys

            return importlib.util.find_spec("smorphi_planted") is not None, sys.path

        found, path = ray.get(planted.remote())
        assert not found and str(tmp_path) not in path
        # the socket paths `check_local_ray` foresees: fails when Ray names them longer
        sockets = list(Path(cluster.ray_temp_dir()).glob(f"session_*_{os.getpid()}/sockets/*"))
        assert sockets and max(len(os.fsencode(p)) for p in sockets) - len(os.fsencode(cluster.ray_temp_dir())) <= (
            cluster.SOCKET_TAIL - (7 - len(str(os.getpid())))  # SOCKET_TAIL holds a 7-digit pid
        )
        with cluster.ray_session(None):
            assert ray.get_runtime_context().get_node_id() == node
        assert ray.is_initialized()
    assert not ray.is_initialized()


@pytest.mark.parametrize(
    ("files", "quota"),
    [
        ({"cpu.max": "max 100000\n"}, None),
        ({"cpu.max": "150000 100000\n"}, 1.5),
        ({"cpu/cpu.cfs_quota_us": "400000\n", "cpu/cpu.cfs_period_us": "100000\n"}, 4.0),
        ({"cpu/cpu.cfs_quota_us": "-1\n", "cpu/cpu.cfs_period_us": "100000\n"}, None),
        ({}, None),
    ],
)
def test_a_containers_cpu_quota_is_read_from_cgroup_v2_or_v1(tmp_path, files, quota):
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(text)
    assert cluster._cgroup_quota(tmp_path, tmp_path / "no-such-file") == quota


def test_a_quota_on_the_processs_own_cgroup_below_the_top_counts(tmp_path):
    """Only the top group's cpu.max was read: a systemd unit's CPUQuota (or a container in the host's cgroup
    namespace) lies on the process's own group, below it. The least quota on the way up holds."""
    (tmp_path / "cpu.max").write_text("max 100000\n")
    (tmp_path / "jobs.slice" / "job-7.scope").mkdir(parents=True)
    (tmp_path / "jobs.slice" / "cpu.max").write_text("400000 100000\n")
    (tmp_path / "jobs.slice" / "job-7.scope" / "cpu.max").write_text("150000 100000\n")
    own = tmp_path / "cgroup"
    own.write_text("0::/jobs.slice/job-7.scope\n")
    assert cluster._cgroup_quota(tmp_path, own) == 1.5
    own.write_text("0::/jobs.slice/other.scope\n")  # a group with no file of its own: the one above
    assert cluster._cgroup_quota(tmp_path, own) == 4.0
    own.write_text("0::/../../etc\n")  # nothing above the top is read
    assert cluster._cgroup_quota(tmp_path, own) is None


def test_the_usable_cores_are_within_the_machines_and_the_quota(monkeypatch):
    assert 1 <= cluster.usable_cpus() <= (os.cpu_count() or 1)
    monkeypatch.setattr(cluster, "_cgroup_quota", lambda: 0.5)
    assert cluster.usable_cpus() == 1 and cluster.local_cpus() == cluster.MIN_LOCAL_CPUS


@pytest.mark.parametrize(
    ("env", "said"),
    [
        ({"TMPDIR": ""}, "TMPDIR='' is not an absolute folder: a local Ray would keep its sessions in 'ray'"),
        ({"RAY_TMPDIR": "rt", "TMPDIR": "/tmp"}, "RAY_TMPDIR='rt' is not an absolute folder"),
        ({"TMPDIR": "/" + "t" * 39}, "socket paths under /tttt"),
    ],
)
@pytest.mark.parametrize("job", [["train", "--timesteps", "2000"], ["reproduce", "--budget", "tiny"]])
def test_a_temp_folder_a_local_ray_cannot_start_in_is_one_line_before_anything_is_written(
    env, said, job, tmp_path, monkeypatch, capsys
):
    """An empty TMPDIR (a batch script's unset variable) timed out Ray's start-up after 30 s in a 34-line
    traceback and left a `ray` folder in the current one; one too long failed as Ray started, after the optimum.
    `reproduce` did not look: it made its folder, waited 30 s and left Ray's folder in the current one."""
    from smorphi_rl.cli import main

    for name in ("RAY_TMPDIR", "TMPDIR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    monkeypatch.chdir(tmp_path)
    assert main([*job, "--log-dir", "logs"]) != 0
    err = capsys.readouterr().err
    assert said in err and len(err.splitlines()) == 1 and not list(tmp_path.iterdir())


def test_a_temp_folder_at_the_socket_limit_is_taken_and_one_byte_over_refused(monkeypatch):
    room = cluster.SOCKET_PATH_MAX - cluster.SOCKET_TAIL - len("/ray")
    monkeypatch.delenv("TMPDIR", raising=False)
    monkeypatch.setenv("RAY_TMPDIR", "/" + "t" * (room - 1))
    cluster.check_local_ray()
    monkeypatch.setenv("RAY_TMPDIR", "/" + "t" * room)
    with pytest.raises(ClusterError, match=f"a folder of at most {room} bytes"):
        cluster.check_local_ray()

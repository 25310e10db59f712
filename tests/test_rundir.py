"""Run folders: names that stay inside --log-dir, atomic claims under races, atomic result files."""

from __future__ import annotations

import errno
import multiprocessing as mp
import os
from pathlib import Path

import numpy as np
import pytest

from smorphi_rl.cli import main
from smorphi_rl.errors import SmorphiError
from smorphi_rl.rundir import (
    MARKER,
    RunDirError,
    check_run_name,
    prepare_run_dir,
    safe_name,
    shell_path,
    write_atomic,
)
from smorphi_rl.search.results import load as load_result

ROOT = Path(__file__).resolve().parents[1]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


@pytest.mark.parametrize("name", ["../../etc", "..", ".", "/abs/path", "a/b", ".hidden", "", "x" * 129, "a b", "a\\b"])
def test_names_that_leave_the_log_dir_are_refused(name):
    with pytest.raises(RunDirError, match="not a plain folder name"):
        check_run_name(name)


def test_default_names_from_odd_map_files_are_made_safe():
    assert check_run_name(safe_name("random-my map (copy)-seed0")) == "random-my_map_copy_-seed0"
    assert check_run_name(safe_name("..")).startswith("run_")
    long = safe_name("random-" + "L" * 300 + "-seed12")  # the seed was cut off: every seed's run had one name
    assert check_run_name(long) == long and len(long) == 128 and long.endswith("-seed12")
    assert safe_name("ppo-" + "m" * 300 + "-20261206-034303") != safe_name("ppo-" + "m" * 300 + "-20261206-034304")


def test_an_existing_run_is_never_reused(tmp_path):
    first = prepare_run_dir(tmp_path, "run")
    assert (first / MARKER).is_file()
    with pytest.raises(RunDirError, match="already exists"):
        prepare_run_dir(tmp_path, "run")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(RunDirError, match="already exists"):
        prepare_run_dir(tmp_path, "mine")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def _claim(args: tuple[str, str]) -> str:
    root, name = args
    try:
        prepare_run_dir(root, name)
        return "won"
    except RunDirError:
        return "refused"


def test_racing_processes_exactly_one_wins(tmp_path):
    with mp.get_context("spawn").Pool(6) as pool:
        for round_ in range(3):
            outcomes = pool.map(_claim, [(str(tmp_path), f"same-{round_}")] * 6)
            assert outcomes.count("won") == 1 and outcomes.count("refused") == 5


def test_atomic_write_leaves_no_temporary_behind(tmp_path):
    target = tmp_path / "out.bin"
    write_atomic(target, b"x" * 1000)
    write_atomic(target, b"y")
    assert target.read_bytes() == b"y" and [p.name for p in tmp_path.iterdir()] == ["out.bin"]


@pytest.mark.parametrize("name", ["../../escape", "{tmp}/abs-escape", "a/b"])
def test_search_with_a_traversing_name_writes_nothing_outside(tmp_path, capsys, name):
    log_dir = tmp_path / "logs"
    name = name.format(tmp=tmp_path)  # an absolute path of this test's own: nothing left behind can fail a later run
    code = main(["search", "random", "--map", MAP_1, "--samples", "5", "--name", name, "--log-dir", str(log_dir)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "not a plain folder name" in err[0]
    assert not (log_dir / name).resolve().exists()  # where the name leads: tmp_path's parent, tmp_path, logs/a
    assert not log_dir.exists() or not any(log_dir.rglob("*.npz"))


def test_racing_searches_one_result_intact(tmp_path):
    """Two `search random` processes on one name: one wins, the other says so, the result loads."""
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "smorphi_rl.cli", "search", "random", "--map", MAP_1, "--samples", "200",
           "--name", "same", "--log-dir", str(tmp_path)]  # fmt: skip
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(3)]
    results = [(p.wait(timeout=120), p.stderr.read()) for p in procs]  # type: ignore[union-attr]
    assert sorted(code for code, _ in results) == [0, 1, 1]
    assert all("already exists" in err for code, err in results if code == 1)
    loaded = load_result(tmp_path / "same")
    assert len(loaded.thetas) == 200 and np.isfinite(loaded.P_c).all()


def test_a_write_killed_midway_leaves_the_old_file_or_the_new_one(tmp_path):
    """Every output goes through write_atomic: SIGKILL at any moment leaves one whole version, never a mix."""
    import signal
    import subprocess
    import sys
    import time

    target = tmp_path / "summary.json"
    size = 4 << 20
    code = (f"from pathlib import Path\nfrom smorphi_rl.rundir import write_text_atomic\np = Path({str(target)!r})\n"
            f"i = 0\nwhile True:\n    write_text_atomic(p, 'ab'[i % 2] * {size})\n    i += 1\n")  # fmt: skip
    for delay in (0.0, 0.01, 0.02, 0.04, 0.08):  # a 4 MB version takes some 10-50 ms to write
        before = target.stat().st_mtime_ns if target.exists() else None
        proc = subprocess.Popen([sys.executable, "-c", code])
        deadline = time.monotonic() + 60  # the writer's first version: however long its start takes on a busy machine
        while time.monotonic() < deadline and (not target.exists() or target.stat().st_mtime_ns == before):
            time.sleep(0.005)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        if target.exists():
            text = target.read_text()
            assert len(text) == size and text in ("a" * size, "b" * size)
    assert target.exists()


def test_a_folder_claimed_by_a_dead_process_is_reused_and_a_live_one_is_not(tmp_path, capsys):
    import subprocess
    import sys

    from smorphi_rl.rundir import MARKER, RunDirError, prepare_run_dir

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / MARKER).write_text(f"pid {int(dead.stdout)} at 2026-01-01T00:00:00\n")
    assert prepare_run_dir(tmp_path, "x") == (tmp_path / "x").resolve()
    assert "died before writing anything: reusing it" in capsys.readouterr().err
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        (tmp_path / "y").mkdir()
        (tmp_path / "y" / MARKER).write_text(f"pid {live.pid} at 2026-01-01T00:00:00\n")
        with pytest.raises(RunDirError, match="already exists"):
            prepare_run_dir(tmp_path, "y")
    finally:
        live.kill()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="a process's start is read from Linux's /proc")
def test_a_process_given_a_dead_claimants_pid_again_is_not_the_claimant(tmp_path):
    """A claim named its pid alone: after a reboot, or once pids wrapped, whatever process holds that pid now kept
    the folder "in use" for ever. A claim now says which process it was (its start in ticks since boot, the boot),
    read from counters a clock step does not move."""
    import socket
    import subprocess
    import sys

    from smorphi_rl.rundir import MARKER, claim_line, cut_short, in_use_by, process_identity

    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        ticks, boot = process_identity(live.pid)
        claims = {"itself": f"started {ticks} boot {boot}", "pid-reused": f"started {ticks - 1} boot {boot}",
                  "other-boot": f"started {ticks} boot not-{boot}", "older": ""}  # fmt: skip
        for name, identity in claims.items():
            (tmp_path / name).mkdir()
            line = f"pid {live.pid} at 2026-12-07T11:00:00+0000 on {socket.gethostname()} {identity}"
            (tmp_path / name / MARKER).write_text(line.rstrip() + "\n")
        for name in ("itself", "older"):  # a claim written before identities were: its pid alone, as before
            assert in_use_by(tmp_path / name) == str(live.pid) and not cut_short(tmp_path / name), name
        for name in ("pid-reused", "other-boot"):
            assert in_use_by(tmp_path / name) is None and cut_short(tmp_path / name), name
    finally:
        live.kill()
        live.wait()
    assert claim_line().rstrip().endswith(f" started {process_identity(os.getpid())[0]} boot {boot}")
    (tmp_path / "mine").mkdir()  # this process's pid in a claim another process wrote (a container's pid 1, say)
    (tmp_path / "mine" / MARKER).write_text(claim_line())
    assert not cut_short(tmp_path / "mine")  # this process's own claim
    me = process_identity(os.getpid())[0]
    (tmp_path / "mine" / MARKER).write_text(claim_line().replace(f" started {me} ", f" started {me + 1} "))
    assert cut_short(tmp_path / "mine")


def test_a_run_killed_before_it_finished_is_named_so_when_its_name_or_its_files_are_asked_for(tmp_path):
    """SIGKILLed mid-run (a job's time limit), a search left results.npz without summary.json: the same command said
    only "already exists", and `compare` "not a readable search summary (FileNotFoundError)"."""
    import subprocess
    import sys

    from smorphi_rl.rundir import MARKER, RunDirError, prepare_run_dir

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / MARKER).write_text(f"pid {int(dead.stdout)} at 2026-01-01T00:00:00\n")
    (cut / "results.npz").write_bytes(b"")
    with pytest.raises(RunDirError, match=r"left by a run that stopped before it finished .* move it away"):
        prepare_run_dir(tmp_path, "cut")
    with pytest.raises(SmorphiError, match=r"no search summary: the run stopped before it finished and wrote it"):
        load_result(cut)
    for finished in ("summary.json", "transfer.md"):  # a run that finished (a transfer job: its table): only taken
        (cut / finished).write_text("{}")
        with pytest.raises(RunDirError, match=r"cut already exists: choose another --name$"):
            prepare_run_dir(tmp_path, "cut")
        (cut / finished).unlink()
    with pytest.raises(SmorphiError, match=r"no such file"):  # not a run's folder at all
        load_result(tmp_path)


def test_a_run_is_claimed_again_only_when_the_process_that_ran_it_is_gone(tmp_path):
    """`--resume` claims the folder again; while the process that ran it still runs, the two would mix their files."""
    import os
    import subprocess
    import sys

    from smorphi_rl.rundir import claim_again

    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        (tmp_path / "job").mkdir()
        (tmp_path / "job" / MARKER).write_text(f"pid {live.pid} at 2026-01-01T00:00:00\n")
        with pytest.raises(RunDirError, match=f"in use by process {live.pid}"):
            claim_again(tmp_path / "job")
    finally:
        live.kill()
        live.wait()
    claim_again(tmp_path / "job")
    assert (tmp_path / "job" / MARKER).read_text().startswith(f"pid {os.getpid()} ")
    assert sorted(p.name for p in (tmp_path / "job").iterdir()) == [MARKER]  # no lock or temporary left


def test_a_run_cut_short_is_renamed_beside_itself_never_deleted(tmp_path):
    from smorphi_rl.rundir import rename_cut_run

    for k in (1, 2):
        (tmp_path / "run").mkdir()
        (tmp_path / "run" / "summary.json").write_text(str(k))
        assert rename_cut_run(tmp_path / "run") == tmp_path / f"run.cut-{k}"
    assert [(tmp_path / f"run.cut-{k}" / "summary.json").read_text() for k in (1, 2)] == ["1", "2"]


def test_a_taken_name_is_refused_with_the_folder_as_the_user_named_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    prepare_run_dir("logs", "run")
    with pytest.raises(RunDirError) as refused:
        prepare_run_dir("logs", "run")
    assert str(refused.value) == "run directory logs/run already exists: choose another --name"


@pytest.mark.parametrize("where", ["file", "missing", "folder", "deep"])
def test_a_folder_holding_a_link_is_refused_before_a_resume_writes_into_it(tmp_path, where):
    """A handed-over sweep folder whose tuner.pkl, result.json or episodes linked elsewhere: the resume wrote there."""
    from smorphi_rl.rundir import refuse_links

    root, elsewhere = tmp_path / "exp", tmp_path / "victim"
    (root / "trial" / "checkpoint_000000").mkdir(parents=True)
    (root / "trial" / "params.json").write_text("{}")
    elsewhere.mkdir()
    (elsewhere / "f").write_text("keep")
    refuse_links(root)  # a folder without links is accepted
    trial = root / "trial"
    link = {"file": root / "tuner.pkl", "missing": trial / "result.json", "folder": trial / "episodes",
            "deep": trial / "checkpoint_000000" / "x.pkl"}[where]  # fmt: skip
    target = {"missing": elsewhere / "new", "folder": elsewhere}.get(where, elsewhere / "f")
    link.symlink_to(target)
    with pytest.raises(RunDirError, match=f"{link.name}: a link inside .*resume only folders you ran"):
        refuse_links(root)
    assert (elsewhere / "f").read_text() == "keep" and sorted(p.name for p in elsewhere.iterdir()) == ["f"]


def test_a_fifo_inside_a_folder_a_resume_reads_is_refused_before_it_is_opened(tmp_path):
    """A handed-over sweep folder whose params.json was a FIFO: `sweep --resume` blocked on it for ever."""
    import os

    from smorphi_rl.rundir import refuse_links

    trial = tmp_path / "exp" / "trial"
    trial.mkdir(parents=True)
    os.mkfifo(trial / "params.json")
    with pytest.raises(RunDirError, match=r"params\.json: a FIFO, socket or device inside .*reading one never ends"):
        refuse_links(tmp_path / "exp")


def test_a_name_that_is_a_link_is_refused_so_nothing_lands_outside_the_log_dir(tmp_path, capsys, monkeypatch):
    """A link under --log-dir named as the run: every file of the run went where it pointed."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "lnk").symlink_to(elsewhere)
    with pytest.raises(RunDirError, match=r"lnk is a link to .*elsewhere: a run writes only into a folder of its own"):
        prepare_run_dir(tmp_path / "logs", "lnk")
    code = main(["search", "random", "--samples", "5", "--name", "lnk", "--log-dir", str(tmp_path / "logs")])
    assert code == 1 and capsys.readouterr().err.count("\n") == 1 and not list(elsewhere.iterdir())
    from smorphi_rl.rundir import refuse_links

    with pytest.raises(RunDirError, match="is a link to"):  # a resumed sweep's or transfer job's own folder
        refuse_links(tmp_path / "logs" / "lnk")
    (tmp_path / "logs" / ".cache").symlink_to(elsewhere)
    from smorphi_rl.errors import SmorphiError
    from smorphi_rl.protocol import CACHE_ENV, optimum_cache

    monkeypatch.delenv(CACHE_ENV, raising=False)  # the suite shares one cache through it
    with pytest.raises(SmorphiError, match=r"\.cache is a link: exact optima are cached only under"):
        optimum_cache(tmp_path / "logs")


def test_a_discarded_run_removes_only_a_folder_it_made(tmp_path):
    """A run stopped before its first report removed the user's own empty folder it had been given."""
    from smorphi_rl.rundir import discard_run_dir

    (tmp_path / "mine").mkdir()
    kept = prepare_run_dir(tmp_path, "mine")
    (kept / "config.json").write_text("{}")
    discard_run_dir(kept)
    assert kept.is_dir() and not list(kept.iterdir())
    made = prepare_run_dir(tmp_path, "new")
    discard_run_dir(made)
    assert not made.exists()


def test_a_path_in_a_printed_command_is_quoted_for_the_shell(tmp_path, monkeypatch):
    """`train --log-dir "my logs"` printed `tensorboard --logdir my logs/run`, which runs on the wrong folders."""
    import shlex

    monkeypatch.chdir(tmp_path)
    assert shell_path(tmp_path / "logs" / "run") == "logs/run"
    assert shlex.split(f"replay {shell_path(tmp_path / 'my logs' / 'rün')}") == ["replay", "my logs/rün"]
    assert shell_path("/elsewhere/it's") == "'/elsewhere/it'\"'\"'s'"


def test_a_job_running_in_the_folder_asked_for_is_named_not_offered_a_resume(tmp_path, capsys):
    """The second of two `sweep`s (or `transfer`s) of one name was told "or add --resume", which the folder, in use by
    the first, then refused."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    config = tmp_path / "tiny.yaml"
    config.write_text(f"algorithms: [ppo]\nmaps: [{root / 'maps' / 'map-1.yaml'}]\nseeds: [0]\n")
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        (tmp_path / "logs" / "tiny").mkdir(parents=True)
        (tmp_path / "logs" / "tiny" / MARKER).write_text(f"pid {live.pid} at 2026-01-01T00:00:00\n")
        capsys.readouterr()
        assert main(["sweep", str(config), "--log-dir", str(tmp_path / "logs")]) == 1
        err = capsys.readouterr().err
        assert f"is in use by process {live.pid}, a sweep running now: wait for it to finish" in err, err
        assert "--resume" not in err
    finally:
        live.kill()
        live.wait()


def test_a_folder_that_cannot_be_made_is_named_for_what_failed(tmp_path, monkeypatch):
    """A full disk or a virtual file system is not a permission: the line names the folder and the reason."""

    def full(path, *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(Path, "mkdir", full)
    with pytest.raises(RunDirError, match=r"cannot create the run directory .*run-1 \(No space left on device\)"):
        prepare_run_dir(tmp_path / "logs", "run-1")


def test_a_cache_folder_another_user_could_plant_is_used_only_when_it_is_ours(tmp_path, monkeypatch):
    """The fallback cache folder has a fixed name in the shared temp folder, and numba unpickles its cache index:
    one made first by another user (or a link to one) would have run their code."""
    import tempfile

    from smorphi_rl.rundir import own_temp_folder

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    ours = tmp_path / f"smorphi-rl-numba-{os.getuid()}"
    assert own_temp_folder("numba") == str(ours) and ours.stat().st_mode & 0o777 == 0o700
    ours.chmod(0o777)  # writable by others: not used
    other = Path(own_temp_folder("numba"))
    assert other != ours and other.parent == tmp_path and other.name.startswith("smorphi-rl-numba-")
    ours.chmod(0o700)
    ours.rename(tmp_path / "elsewhere")
    ours.symlink_to(tmp_path / "elsewhere")  # a link planted under the name: not followed
    assert own_temp_folder("numba") != str(ours)


def test_another_machines_claim_is_taken_as_alive_on_a_shared_log_folder(tmp_path):
    """Claims named a pid alone: on a log folder shared between machines, a run writing there from another one was
    taken for dead here; its folder was reused under it, or called cut short."""
    import socket
    import subprocess
    import sys

    from smorphi_rl.rundir import MARKER, RunDirError, claim_again, claim_line, cut_short, in_use_by, prepare_run_dir

    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)  # fmt: skip
    there = tmp_path / "there"
    there.mkdir()
    (there / MARKER).write_text(f"pid {dead} at 2026-01-01T00:00:00 on not-{socket.gethostname()}\n")
    with pytest.raises(RunDirError, match="already exists: choose another --name"):  # not reused, nor cut short
        prepare_run_dir(tmp_path, "there")
    assert in_use_by(there).startswith(f"{dead} on not-{socket.gethostname()} (another machine's, or an earlier "
                                       "container's: if nothing runs there now, remove ")  # fmt: skip
    assert not cut_short(there)
    with pytest.raises(RunDirError, match=f"in use by process {dead} on not-"):
        claim_again(there)
    (there / MARKER).write_text(f"pid {dead} at 2026-01-01T00:00:00 on {socket.gethostname()}\n")  # this machine's
    assert in_use_by(there) is None and cut_short(there)
    assert f" on {socket.gethostname()}" in claim_line()


def test_two_runs_started_within_one_second_take_two_stamped_names(tmp_path):
    """`train` names a run by the second it starts: the second of two started together was refused a name its user
    never gave ("already exists: choose another --name")."""
    from smorphi_rl.rundir import RunDirError, prepare_run_dir, prepare_stamped_run_dir

    first = prepare_stamped_run_dir(tmp_path, "ppo-map-1-20261207-102613")
    second = prepare_stamped_run_dir(tmp_path, "ppo-map-1-20261207-102613")
    assert (first.name, second.name) == ("ppo-map-1-20261207-102613", "ppo-map-1-20261207-102613-2")
    with pytest.raises(RunDirError, match="already exists"):  # a name the user gave stays theirs alone
        prepare_run_dir(tmp_path, "ppo-map-1-20261207-102613")
    (tmp_path / "file").write_text("")
    with pytest.raises(RunDirError, match="not a folder"):  # refused for another reason: said as it is
        prepare_stamped_run_dir(tmp_path / "file", "x")

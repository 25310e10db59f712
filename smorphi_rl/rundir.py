"""Run directories under --log-dir: one validated name, claimed atomically, never overwritten.

A run name names exactly one folder directly under the log directory (no separators, no '.' or
'..', nothing hidden), so nothing a command writes can land outside the folder the user named.
The folder is claimed by creating a marker file with O_EXCL: of several processes racing for one
name exactly one wins, and the others are refused before they write anything.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import re
import shlex
import shutil
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from smorphi_rl.errors import SmorphiError

RUN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,127}")
MARKER = ".smorphi-run"
"""Created first in every run directory: the claim (and the write test); says which process made it."""

DEFAULT_LOG_DIR = "logs"
"""Where run directories go unless the user names another root (`--log-dir`)."""


class RunDirError(SmorphiError):
    """The run directory cannot be used."""


def rel(path: str | Path) -> str:
    """`path` as a message shows it: relative to the working directory when it lies below it, as given or with links
    resolved (as the README shows it), else as given; a newline, carriage return or tab in it shown escaped (\\n), so a
    folder's name cannot forge a line of the output (the CLI's stream escapes every other control)."""
    return _relative(path).replace("\n", "\\n").replace("\r", "\\r").replace("\t", "\\t")


def _relative(path: str | Path) -> str:
    """`rel`'s path, its characters as they are."""
    for resolve in (False, True):
        try:
            here = Path(path).resolve() if resolve else Path(path).absolute()
            return str(here.relative_to(Path.cwd().resolve() if resolve else Path.cwd()))
        except (ValueError, OSError, RuntimeError):
            continue
    return str(path)


def shell_path(path: str | Path) -> str:
    """`rel(path)` as a command a hint prints takes it: quoted for the shell where it holds spaces or the like."""
    return shlex.quote(_relative(path))  # quoted, not escaped: the command runs as printed


def check_run_name(name: str, what: str = "run name") -> str:
    """`name` if it names one plain folder; RunDirError otherwise."""
    if not isinstance(name, str) or not RUN_NAME.fullmatch(name):
        raise RunDirError(
            f"{what} {name!r} is not a plain folder name: use ASCII letters, digits and _ . + - (not first), "
            "at most 128 characters, no / or .."
        )
    return name


MAX_DEFAULT_NAME = 128
"""Characters of a default run name; a longer one is cut in its middle, keeping its end (a seed, a time stamp)."""


def safe_name(text: str) -> str:
    """A default run name built from free text (a map's file name): every other character becomes '_'."""
    name = re.sub(r"[^A-Za-z0-9_.+-]+", "_", text)
    name = name if RUN_NAME.match(name[:1]) else f"run_{name}"  # '..', '-x': a plain name's first character
    if len(name) > MAX_DEFAULT_NAME:  # cut at the end, every run of a long map name had one name, refused as taken
        keep = MAX_DEFAULT_NAME // 3
        name = f"{name[: MAX_DEFAULT_NAME - keep - 1]}_{name[-keep:]}"
    return name


def claim_line() -> str:
    """What a claim holds: this process's pid, the time and the machine (a log folder shared between machines holds
    claims whose pids mean nothing here) and, on Linux, which process that pid was (`process_identity`)."""
    import socket

    me = process_identity(os.getpid())
    known = "" if me is None else f" started {me[0]} boot {me[1]}"
    return f"pid {os.getpid()} at {time.strftime(CLAIM_TIME)} on {socket.gethostname()}{known}\n"


CLAIM_TIME = "%Y-%m-%dT%H:%M:%S%z"
"""A claim's time, for the reader: with its UTC offset."""


def process_identity(pid: int) -> tuple[int, str] | None:
    """(start time in clock ticks since boot, the boot's id) of process `pid`, from Linux's /proc: the same pid with
    either different is another process (the pid given again, or a reboot since). Read from counters, never from the
    wall clock, which a clock step (NTP, a VM resumed) moves. None where /proc does not tell."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            ticks = int(fh.read().rsplit(b")", 1)[1].split()[19])  # field 22, after the name in parentheses
        with open("/proc/sys/kernel/random/boot_id") as fh:
            boot = fh.read().strip()
    except (OSError, ValueError, IndexError):
        return None
    return (ticks, boot) if boot and " " not in boot else None


def _claim(run_dir: Path) -> tuple[int, str, tuple[int, str] | None]:
    """(pid, machine, identity) a run directory's claim names: pid 0 when it names none or cannot be read, machine ''
    where the claim names none (written before machines were recorded: taken as this one), identity None where it
    names none (written before they were, or where /proc does not tell)."""
    try:
        with (run_dir / MARKER).open(errors="replace") as fh:
            words = fh.read(256).split()  # "pid N at TIME on HOST started T boot B": no more of a marker grown huge
        pid = int(words[1]) if len(words) > 1 and words[0] == "pid" else 0
    except (OSError, ValueError):
        return 0, "", None
    host = words[5] if len(words) > 5 and words[4] == "on" else ""
    try:
        identity = (int(words[7]), words[9]) if len(words) > 9 and (words[6], words[8]) == ("started", "boot") else None
    except ValueError:
        identity = None
    return pid, host, identity


def _here(host: str) -> bool:
    import socket

    return not host or host == socket.gethostname()


def _alive(pid: int) -> bool:
    """Whether process `pid` (another than this one) is running."""
    if pid <= 0 or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def _gone(run_dir: Path) -> bool:
    """Whether the process `run_dir`'s claim names is known to have ended: one of this machine, not running. Another
    machine's is never known to have ended (its pid means nothing here): its run may be writing there now."""
    pid, host, identity = _claim(run_dir)
    if pid <= 0 or not _here(host):
        return False
    if pid == os.getpid():  # this process's claim, unless it names another process that had this pid (a container's)
        return identity is not None and process_identity(pid) not in (None, identity)
    return not _claimant_alive(pid, identity)


def _claimant_alive(pid: int, identity: tuple[int, str] | None) -> bool:
    """Whether the process that wrote a claim of this machine still runs: `pid` runs and, where the claim says which
    process it was, is that one (a reused pid, or one of a later boot, is not)."""
    if not _alive(pid):
        return False
    now = None if identity is None else process_identity(pid)
    return identity is None or now is None or now == identity


def in_use_by(run_dir: Path) -> str | None:
    """The process whose claim `run_dir` holds while it may run (another job writing there now): its pid, with its
    machine where that is another; None if none."""
    pid, host, identity = _claim(run_dir)
    if pid > 0 and not _here(host):  # a container's name changes with each container: the way out is said
        return (f"{pid} on {host} (another machine's, or an earlier container's: if nothing runs there now, remove "
                f"{rel(run_dir / MARKER)})")  # fmt: skip
    return str(pid) if _claimant_alive(pid, identity) else None


FINISHED_FILES = ("summary.json", "report.md", "transfer.md", "sweep.md")
"""What a run writes once its results are whole (train, search: summary.json; compare: report.md; a transfer job
and a sweep: their tables)."""


def cut_short(run_dir: Path) -> bool:
    """Whether `run_dir` is a run stopped before it finished (killed, out of memory, a job's time limit): it holds
    the claim of a process no longer running and none of FINISHED_FILES."""
    return _gone(run_dir) and not any((run_dir / name).exists() for name in FINISHED_FILES)


def _abandoned(run_dir: Path) -> bool:
    """A folder holding nothing but the claim of a process that is no longer alive (a run killed before it wrote
    anything): it may be claimed again."""
    try:
        if sorted(p.name for p in run_dir.iterdir()) != [MARKER]:
            return False
    except OSError:
        return False
    return _gone(run_dir)


def claim_again(run_dir: Path) -> None:
    """Claim a run directory an earlier process made, to continue it (`--resume`): refused while the process
    its claim names still runs (two writers would mix their files), or may (another machine's)."""
    with _write_lock(run_dir / MARKER):
        if (pid := in_use_by(run_dir)) is not None:
            raise RunDirError(f"{rel(run_dir)} is in use by process {pid}: stop it first, or wait for it to finish")
        write_text_atomic(run_dir / MARKER, claim_line())


def refuse_links(root: Path) -> None:
    """Refuse a folder a resume writes into when it is a symbolic link or one lies anywhere below it: Tune, RLlib and
    our own writers would follow it and write wherever it points (a folder someone else handed over). A FIFO, socket
    or device below it is refused too: the resume reads the files there, and reading one never ends."""
    if root.is_symlink():
        raise RunDirError(outside_link(root))
    for folder, dirs, files in os.walk(root, followlinks=False):
        for name in (*dirs, *files):
            path = Path(folder) / name
            if path.is_symlink():
                raise RunDirError(
                    f"{rel(path)}: a link inside {rel(root)}, which the resume writes into (it would "
                    "write wherever the link points); resume only folders you ran, or remove the link"
                )
            with contextlib.suppress(OSError):  # gone meanwhile: nothing to read
                if not stat.S_ISREG(mode := path.lstat().st_mode) and not stat.S_ISDIR(mode):
                    raise RunDirError(f"{rel(path)}: a FIFO, socket or device inside {rel(root)}, whose files the "
                                      "resume reads (reading one never ends); resume only folders you ran")  # fmt: skip


def outside_link(path: Path) -> str:
    """The refusal of a run's folder that is a symbolic link: its files would land wherever it points, outside
    --log-dir."""
    return (f"{rel(path)} is a link to {os.readlink(path)}: a run writes only into a folder of its own under --log-dir "
            "(choose another --name, or give the link's target as --log-dir)")  # fmt: skip


def rename_cut_run(run_dir: Path) -> Path:
    """Rename a run that was cut short to the first free `<name>.cut-N` beside it (kept, never deleted), so its
    name is free for the run that replaces it."""
    k = 1
    while run_dir.with_name(f"{run_dir.name}.cut-{k}").exists():
        k += 1
    try:
        return run_dir.rename(run_dir.with_name(f"{run_dir.name}.cut-{k}"))
    except OSError as exc:
        raise RunDirError(f"cannot set {rel(run_dir)} aside ({exc.strerror or exc})") from None


def check_run_dir(log_dir: str | Path, name: str) -> Path:
    """Where the run would go, checked without creating anything (a valid name, not taken). A folder whose
    claiming process died before writing anything is taken again, with a line saying so."""
    try:
        run_dir = Path(log_dir).resolve() / check_run_name(name)
    except (RuntimeError, OSError) as exc:  # a symlink loop, an unreadable folder
        raise RunDirError(f"log directory {log_dir} cannot be used ({exc})") from None
    if run_dir.parent.exists() and not run_dir.parent.is_dir():
        raise RunDirError(f"log directory {log_dir} is not a folder")
    if run_dir.is_symlink():  # exists(), iterdir() and mkdir() would all follow it
        raise RunDirError(outside_link(run_dir))
    if run_dir.is_dir() and _abandoned(run_dir):
        import sys

        (run_dir / MARKER).unlink(missing_ok=True)
        print(f"smorphi-rl: {rel(run_dir)} held only the claim of a run that died before writing anything: reusing it",
              file=sys.stderr)  # fmt: skip
    if run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())):
        raise RunDirError(_taken(run_dir))
    return run_dir


def _taken(run_dir: Path) -> str:
    """The refusal of a taken name, the folder named as every message names it (`rel`); one a run was cut short in
    says so (a job killed at its time limit and queued again met only "already exists")."""
    if run_dir.is_dir() and cut_short(run_dir):
        resumable = ", add --resume to continue it (`train`)" if (run_dir / "config.json").is_file() else ""
        return (
            f"run directory {rel(run_dir)} already exists, left by a run that stopped before it finished (its "
            f"process is gone); its files stay there: choose another --name{resumable}, or move it away to use this "
            "one"
        )
    return f"run directory {rel(run_dir)} already exists: choose another --name"


_UNWRITABLE = (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR)


def prepare_run_dir(log_dir: str | Path, name: str) -> Path:
    """`log_dir/name`, created and claimed atomically; refused if it already holds anything or another
    process claimed it first."""
    run_dir = check_run_dir(log_dir, name)
    root = run_dir.parent
    try:
        root.mkdir(parents=True, exist_ok=True)
        try:
            run_dir.mkdir()
            _MADE.add(run_dir)
        except FileExistsError:  # the user's own empty folder: used, and never removed with a run discarded
            pass
        fd = os.open(run_dir / MARKER, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        raise RunDirError(_taken(run_dir)) from None
    except OSError as exc:  # a permission named as such; anything else (a full disk, /proc) as what failed
        if exc.errno in _UNWRITABLE:
            raise RunDirError(f"log directory {rel(root)} is not writable ({exc.strerror or exc})") from None
        raise RunDirError(f"cannot create the run directory {rel(run_dir)} ({exc.strerror or exc})") from None
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(claim_line())
    except OSError as exc:  # a full disk: the claim is taken back (a user's folder keeps whatever else is in it)
        (run_dir / MARKER).unlink(missing_ok=True)
        if run_dir in _MADE:
            _MADE.discard(run_dir)
            with contextlib.suppress(OSError):
                run_dir.rmdir()
        raise naming(exc, run_dir / MARKER) from None
    if sorted(p.name for p in run_dir.iterdir()) != [MARKER]:  # a user's folder that filled meanwhile
        (run_dir / MARKER).unlink(missing_ok=True)
        raise RunDirError(_taken(run_dir))
    return run_dir


def prepare_stamped_run_dir(log_dir: str | Path, name: str) -> Path:
    """`prepare_run_dir` for a name the command made from the time, to the second: where two runs started within
    one second took it, the first free `<name>-2`, `-3`, ... (the second run was refused a name its user never
    gave)."""
    for k in range(1, 100):
        candidate = name if k == 1 else f"{name}-{k}"
        try:
            return prepare_run_dir(log_dir, candidate)
        except RunDirError:
            if not (Path(log_dir).resolve() / candidate).exists():  # refused for another reason: said as it is
                raise
    return prepare_run_dir(log_dir, name)  # every one taken: the refusal names the first


_MADE: set[Path] = set()
"""Run folders this process made (`prepare_run_dir`); a folder the user made is emptied, never removed."""


def discard_run_dir(run_dir: Path) -> None:
    """Remove a run directory this process claimed and that holds no result (a run that never started); one the user
    made (empty when it was claimed) is emptied of what the run wrote and kept."""
    if run_dir.is_symlink() or not (run_dir / MARKER).is_file():
        return
    if run_dir in _MADE:
        _MADE.discard(run_dir)
        shutil.rmtree(run_dir, ignore_errors=True)
        return
    for child in run_dir.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


def make_writable(folder: Path) -> None:
    """Make `folder` if missing and make a file in it (removed at once); the OSError where either fails."""
    import tempfile

    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=folder):
        pass


def writable_folder(folder: Path) -> bool:
    """Whether a file can be made in `folder`, made first if missing (as the library that asks would make it)."""
    try:
        make_writable(folder)
    except OSError:
        return False
    return True


def own_temp_folder(library: str) -> str:
    """A folder of this user's in the temp folder for a `library`'s cache where the library's own places cannot be
    written (a read-only install, an unwritable HOME): kept across runs, unlike a library's own fallback. Another
    user could make that name first (numba unpickles its cache index): it is used only as a folder, not a link,
    owned by this user and written by no one else; otherwise a fresh folder of this run's own."""
    import stat
    import tempfile

    folder = Path(tempfile.gettempdir()) / f"smorphi-rl-{library}-{os.getuid()}"
    with contextlib.suppress(OSError):
        folder.mkdir(mode=0o700)
    try:
        st = folder.lstat()
        if stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return str(folder)
    except OSError:
        pass
    return tempfile.mkdtemp(prefix=f"smorphi-rl-{library}-")


def write_text_atomic(path: Path, text: str) -> None:
    """`write_atomic` of a text (UTF-8)."""
    write_atomic(path, text.encode())


@contextmanager
def atomic_text(path: Path) -> Iterator[io.StringIO]:
    """A text stream (for `csv.writer`) whose content replaces `path` atomically when the block ends well."""
    buffer = io.StringIO(newline="")
    yield buffer
    write_text_atomic(path, buffer.getvalue())


def naming(exc: OSError, path: Path) -> OSError:
    """`exc` as the error of `path`: a failed write (a full disk) names the file the user asked for, never a
    temporary name or a stream's missing one."""
    return OSError(exc.errno, exc.strerror or str(exc), str(path))


@contextmanager
def discarded_on_failure(run_dir: Path) -> Iterator[None]:
    """Within the block, any failure or interruption discards the run folder (`discard_run_dir`): a run with no
    whole result leaves its name free."""
    try:
        yield
    except BaseException:
        discard_run_dir(run_dir)
        raise


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary name beside `path` for a writer that needs a file name (a figure, an animation); renamed over
    `path` when the block ends without an error, removed otherwise: readers see the old file or the new one."""
    fd, tmp = _fresh_temporary(path, f".tmp{path.suffix}")  # the writer infers the format from the suffix
    os.close(fd)  # the writer opens it by name
    try:
        yield tmp
        os.replace(tmp, path)
        _remove_stale_temporaries(path, f".tmp{path.suffix}")
    except OSError as exc:  # a full disk: name the file the user asked for, not our temporary one
        if exc.filename is None or Path(exc.filename) == tmp:
            raise naming(exc, path) from None
        raise
    finally:
        tmp.unlink(missing_ok=True)


def _fresh_temporary(path: Path, suffix: str) -> tuple[int, Path]:
    """A new, empty file of an unpredictable name beside `path`, created exclusively (never a name another process
    or thread chose, nor a link planted in a shared folder), with the permissions the umask gives a new file (not
    mkstemp's owner-only ones), open for writing; a failure to create it names `path`."""
    import secrets

    for _ in range(100):
        tmp = path.with_name(f".{path.stem}.{os.getpid()}-{secrets.token_hex(6)}{suffix}")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue
        except OSError as exc:
            raise naming(exc, path) from None
    raise FileExistsError(errno.EEXIST, "no fresh temporary name beside it", str(path))


def write_atomic(path: Path, data: bytes) -> None:
    """Write `path` through a temporary file in the same folder and rename it: readers never see half a file.
    A failed write (a full disk) names `path` in its error."""
    fd, tmp = _fresh_temporary(path, ".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:  # the file created, never one a name might point to since
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        _remove_stale_temporaries(path, ".tmp")
    except OSError as exc:
        if exc.filename is None or Path(exc.filename) == tmp:
            raise naming(exc, path) from None
        raise
    finally:
        tmp.unlink(missing_ok=True)


STALE_TEMPORARY_S = 600
"""A temporary older than this whose writer is not running here is a killed writer's: writes take seconds."""


def _remove_stale_temporaries(path: Path, suffix: str) -> None:
    """Remove the temporaries beside `path` that writers no longer running left (`_fresh_temporary`'s names carry
    the writer's pid): a process killed mid-write (SIGKILL, out of memory) left its empty `.pareto.<hex>.tmp.png`
    for good. A live writer's stays, and so does a fresh one (another machine's writer, on a shared folder)."""
    import glob

    ours = re.compile(rf"\.{re.escape(path.stem)}\.(\d+)-[0-9a-f]{{12}}{re.escape(suffix)}")
    for stale in path.parent.glob(f".{glob.escape(path.stem)}.*-*{glob.escape(suffix)}"):
        # exactly `_fresh_temporary`'s name for this file: `room.json`'s is no `room.2024-01.json`'s
        if (m := ours.fullmatch(stale.name)) and int(m[1]) != os.getpid() and not _alive(int(m[1])):
            with contextlib.suppress(OSError):  # an old one only: on a shared folder the pid may be another machine's
                if time.time() - stale.lstat().st_mtime > STALE_TEMPORARY_S:
                    stale.unlink()


FORCE_HINT = "pass --force to overwrite it"
"""What a command that takes --force says when its output exists."""


@contextmanager
def claimed_files(paths: list[Path], force: bool = False, taken: str = FORCE_HINT) -> Iterator[None]:
    """`claim_files` for the length of a block that writes them: a claimed file still empty when the block fails
    (a full disk) is removed again, so nothing half-made is left behind. With `force`, a lock beside the first
    file is held instead, so two overwriting writers never mix their files: the second is refused."""
    if force:
        with _write_lock(paths[0]):
            yield
        return
    claim_files(paths, force, taken)
    try:
        yield
    except BaseException:
        for path in paths:
            with contextlib.suppress(OSError):
                if path.stat().st_size == 0:
                    path.unlink()
        raise


def _check_parent(path: Path) -> None:
    """The nearest existing folder above `path` is a folder (not a file or a device such as /dev/full)."""
    above = path.parent
    try:
        while not above.exists() and above != above.parent:
            above = above.parent
        ok = above.is_dir()
    except OSError:
        ok = False
    if not ok:
        raise RunDirError(f"cannot write {path}: {above} is not a folder")


@contextmanager
def _write_lock(path: Path) -> Iterator[None]:
    """`.NAME.lock` beside `path`, created with O_EXCL for the block and removed after it."""
    lock = path.with_name(f".{path.name}.lock")
    _check_parent(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        os.close(os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644))
    except FileExistsError:
        raise RunDirError(f"{path} is being written by another process (its lock {lock} exists; remove it if no "
                          "process is writing)") from None  # fmt: skip
    except OSError as exc:
        raise RunDirError(f"cannot write {path} ({exc.strerror or exc})") from None
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)


def claim_files(paths: list[Path], force: bool = False, taken: str = FORCE_HINT) -> None:
    """Claim new output files by creating each with O_EXCL (of two racing writers exactly one wins; the other is
    refused before it writes anything); `force`: overwrite whatever is there instead. The claimed files are
    empty until written (atomically) over."""
    if force:
        return
    made: list[Path] = []
    for path in paths:
        _check_parent(path)
    try:
        for path in paths:
            path.parent.mkdir(parents=True, exist_ok=True)
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644))
            made.append(path)
    except FileExistsError:
        for path in made:
            path.unlink(missing_ok=True)
        raise RunDirError(f"{path} exists; {taken}") from None
    except OSError as exc:
        for path in made:
            path.unlink(missing_ok=True)
        raise RunDirError(f"cannot write {path} ({exc.strerror or exc})") from None

"""Every file the package writes goes through `rundir`'s atomic helpers: a scan for writes that bypass them."""

from __future__ import annotations

import ast
import os
import time
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "smorphi_rl"
HELPERS = PACKAGE / "rundir.py"
"""The one home of plain writes: a temporary file, then a rename."""
WRITERS = {"write_text", "write_bytes", "savefig", "save", "savez", "savez_compressed", "dump", "copyfile", "copy2",
           "copytree", "move", "tofile", "to_csv"}  # fmt: skip
"""Method names that write a file given a path (`copy` without arguments copies an array and is left out)."""
IN_MEMORY_OR_TEMPORARY = {"buffer", "tmp"}
"""First arguments that are an in-memory buffer or `rundir.atomic_path`'s temporary name."""
ALLOWED = {
    ("recording/writer.py", "self.part.open('wb')"): "an MCAP recording streams into NAME.mcap.part, renamed when "
    "it finishes (docs/commands.md: recordings are atomic when they finish)",
    ("training/resume.py", "shutil.move(str(p), str(aside / p.name))"): "a rename into before-resume-N/, no content "
    "written",
}


def _writes(call: ast.Call) -> bool:
    func = call.func
    if isinstance(func, ast.Attribute) and func.attr in WRITERS:
        first = call.args[0] if call.args else None
        if isinstance(first, ast.Call) and isinstance(first.func, ast.Name) and first.func.id == "str" and first.args:
            first = first.args[0]  # str(tmp)
        return not (isinstance(first, ast.Name) and first.id in IN_MEMORY_OR_TEMPORARY)
    name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None
    if name == "open":
        modes = [k.value for k in call.keywords if k.arg == "mode"]
        modes += call.args[1:2] if isinstance(func, ast.Name) else call.args[:1]
        return any(isinstance(m, ast.Constant) and set(str(m.value)) & set("wax+") for m in modes)
    return False


def direct_writes() -> set[tuple[str, str]]:
    """(file, call) of every call in the package outside rundir.py that writes a file itself."""
    found = set()
    for path in PACKAGE.rglob("*.py"):
        if path == HELPERS:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and _writes(node):
                found.add((path.relative_to(PACKAGE).as_posix(), ast.unparse(node)))
    return found


def test_no_file_is_written_outside_the_atomic_helpers():
    assert direct_writes() - set(ALLOWED) == set()


def test_the_scan_finds_a_plain_write(tmp_path, monkeypatch):
    """The scan is not blind: each kind of plain write in a module is found."""
    fake = tmp_path / "smorphi_rl"
    fake.mkdir()
    (fake / "rundir.py").write_text("open(p, 'wb')\n")
    (fake / "bad.py").write_text(
        "p.write_text('x')\nopen(p, 'w')\np.open(mode='ab')\njson.dump(d, fh)\nfig.savefig(path)\nfig.savefig(tmp)\n"
        "open(p)\n"
    )
    monkeypatch.setattr(__import__(__name__), "PACKAGE", fake)
    monkeypatch.setattr(__import__(__name__), "HELPERS", fake / "rundir.py")
    assert {call for _, call in direct_writes()} == {
        "p.write_text('x')",
        "open(p, 'w')",
        "p.open(mode='ab')",
        "json.dump(d, fh)",
        "fig.savefig(path)",
    }


def test_every_allowed_write_still_exists():
    """An allowance whose call is gone is stale and would hide a new write of the same text."""
    assert set(ALLOWED) <= direct_writes()


def test_a_temporary_file_is_fresh_and_a_planted_link_is_never_followed(tmp_path):
    """The temporary name was `.NAME.PID.tmp`: in a folder others can write to, a link planted there redirected the
    write. Now each is created exclusively under a random name, with the permissions the umask gives."""
    import os

    from smorphi_rl.rundir import atomic_path, write_atomic

    victim = tmp_path / "victim"
    victim.write_text("kept")
    target = tmp_path / "summary.json"
    (tmp_path / f".{target.name}.{os.getpid()}.tmp").symlink_to(victim)  # the old name, planted
    write_atomic(target, b"{}")
    assert target.read_bytes() == b"{}" and victim.read_text() == "kept"
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    with atomic_path(tmp_path / "a.png") as one, atomic_path(tmp_path / "a.png") as two:
        assert one != two and one.suffix == ".png" and one.parent == tmp_path
        one.write_bytes(b"1")
        two.write_bytes(b"2")
    assert (tmp_path / "a.png").read_bytes() == b"1"  # the outer block ends last
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == [f".{target.name}.{os.getpid()}.tmp"]


def test_a_temporary_a_killed_writer_left_is_removed_by_the_next_write_and_a_live_ones_stays(tmp_path):
    """A search SIGKILLed as it drew its front left an empty `.pareto.<hex>.tmp.png` beside pareto.png for good."""
    import subprocess
    import sys

    from smorphi_rl.rundir import atomic_path, write_atomic

    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)  # fmt: skip
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        left = [tmp_path / f".pareto.{dead}-0123456789ab.tmp.png", tmp_path / f".summary.{dead}-0123456789ab.tmp"]
        kept = [
            tmp_path / f".pareto.{live.pid}-0123456789ab.tmp.png",
            tmp_path / ".pareto.notes.tmp.png",
            tmp_path / f".summary.2024-01.{dead}-0123456789ab.tmp",
        ]  # summary.2024-01.json's, not summary.json's
        fresh = tmp_path / f".pareto.{dead}-ba9876543210.tmp.png"  # a dead pid here: another machine's, maybe
        kept.append(fresh)
        for path in left + kept:
            path.write_bytes(b"")
            if path != fresh:
                os.utime(path, (time.time() - 3600, time.time() - 3600))
        with atomic_path(tmp_path / "pareto.png") as tmp:
            tmp.write_bytes(b"png")
        write_atomic(tmp_path / "summary.json", b"{}")
        assert not any(p.exists() for p in left) and all(p.exists() for p in kept)
        shown = sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith("."))
        assert shown == ["pareto.png", "summary.json"]
    finally:
        live.kill()

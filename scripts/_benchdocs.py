"""Each benchmark script writes its own section of docs/benchmarks.md (`--write-docs`): figures are never typed
by hand. A section lies between `<!-- BEGIN name -->` and `<!-- END name -->`; rewriting one leaves the rest
of the file as it was."""

from __future__ import annotations

import fcntl
import os
import platform
import shlex
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import NoReturn, TypeVar

T = TypeVar("T")

DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
HEADER = """# Benchmarks

Each section below is written by the benchmark script it names (`--write-docs`), with the machine, the
date and the exact command; rerun the command to refresh it. Nothing here is typed by hand.
"""


def machine() -> str:
    """The CPU model and core count (Linux /proc/cpuinfo), and the Python version."""
    model = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores, Python {platform.python_version()}"


def write_section(name: str, body: str) -> Path:
    """Replace (or append) the section `name` of docs/benchmarks.md with `body`, stamped with the command that
    produced it, the machine and the date; written through a temporary file and a rename."""
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    command = " ".join(shlex.quote(a) for a in [".venv/bin/python", *sys.argv])
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = f"{begin}\n{body.rstrip()}\n\n_Written by `{command}` on {stamp}, {machine()}._\n{end}"
    folder = os.open(DOCS.parent, os.O_RDONLY)
    try:
        fcntl.flock(folder, fcntl.LOCK_EX)  # two benchmarks ending together: each reads what the other wrote
        text = DOCS.read_text() if DOCS.exists() else HEADER
        if begin in text:
            head, rest = text.split(begin, 1)
            if end not in rest:  # appending would leave two sections, and the next rewrite swallow those between
                raise SystemExit(f"{DOCS}: its '{begin}' has no '{end}' after it; mend the file, then write again")
            text = head + section + rest.split(end, 1)[1]
        else:
            text = text.rstrip() + "\n\n" + section + "\n"
        tmp = DOCS.with_name(f".{DOCS.name}.{os.getpid()}.tmp")
        try:
            tmp.write_text(text)
            os.replace(tmp, DOCS)
        finally:
            tmp.unlink(missing_ok=True)
    finally:
        os.close(folder)  # the lock goes with it
    return DOCS


class _Tee:
    """Writes to the real stdout and keeps a copy."""

    def __init__(self, stream: object) -> None:
        self.stream, self.parts = stream, []  # type: ignore[var-annotated]

    def write(self, text: str) -> int:
        self.parts.append(text)
        return self.stream.write(text)  # type: ignore[attr-defined,no-any-return]

    def flush(self) -> None:
        self.stream.flush()  # type: ignore[attr-defined]


def whole(summary: T) -> T:
    """A training run's summary, or a stop where the run was cut short (Ctrl-C, SIGTERM: `train` then ends at the
    next report and returns): a benchmark's partial figures must never replace its section of docs/benchmarks.md."""
    if getattr(summary, "interrupted", False):
        raise KeyboardInterrupt
    return summary


def stop_interrupted() -> NoReturn:
    """End a benchmark that Ctrl-C, SIGTERM or a cut-short run (`whole`) stopped: one line, exit 130, and its section
    of docs/benchmarks.md as it was."""
    print(f"{Path(sys.argv[0]).name}: interrupted; docs/benchmarks.md left as it was", file=sys.stderr)
    raise SystemExit(130)


def check_at_least(*limits: tuple[str, int, int]) -> None:
    """Refuse in one line (a SmorphiError, as the CLI's) the first option whose value is under its least: each limit
    is (option, value, least), checked before anything runs or is written."""
    from smorphi_rl.errors import SmorphiError

    for name, value, least in limits:
        if value < least:
            raise SmorphiError(f"{name} {value}: at least {least}")


def run_documented(name: str, title: str, main: object) -> None:
    """Run a benchmark's `main()`; with `--write-docs` on the command line, its printed report becomes the
    section `name` of docs/benchmarks.md (the flag is taken off before the script parses its own)."""
    write = "--write-docs" in sys.argv
    if write:
        sys.argv.remove("--write-docs")
    from smorphi_rl.errors import SmorphiError

    tee = _Tee(sys.stdout)
    sys.stdout = tee  # type: ignore[assignment]
    try:
        main()  # type: ignore[operator]
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM, or a run `whole` found cut short: nothing written
        sys.stdout = tee.stream  # type: ignore[assignment]
        stop_interrupted()
    except SmorphiError as exc:  # a bad option or input: one line, as the CLI gives it, and nothing written
        sys.stdout = tee.stream  # type: ignore[assignment]
        print(f"{Path(sys.argv[0]).name}: error: {exc}", file=sys.stderr)
        raise SystemExit(1) from None
    finally:
        sys.stdout = tee.stream  # type: ignore[assignment]
    if write:
        report = "".join(tee.parts).rstrip()
        print(f"docs: {write_section(name, f'## {title}' + chr(10) * 2 + '```' + chr(10) + report + chr(10) + '```')}")

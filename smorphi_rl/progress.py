"""A progress bar on stderr for long counted work (searches, exact optima), with its rate and the time left."""

from __future__ import annotations

import math
import os
import shutil
import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

ETA_AFTER_S = 3.0
"""The time left is estimated from the rate since the first count reported, once that has run this long (the wait
for the first count holds the work's start-up, such as compiling the planner, and says nothing of its rate)."""


STATUS_WIDTH = 160
"""A status line rewritten in place is cut (and padded, so a shorter one clears it) to the terminal's width less one,
and to this many characters at most."""


def bar(fraction: float, width: int) -> str:
    """`[####------]`: `fraction` (clamped to 0..1) of `width` filled."""
    filled = int(width * min(1.0, max(0.0, fraction)))
    return "[" + "#" * filled + "-" * (width - filled) + "]"


class StatusLine:
    """One status line on a stream (stderr): rewritten in place on a terminal; elsewhere (a log file), or where the
    line is wider than the terminal (it would wrap, and every rewrite leave a row behind), a new line at most every
    `every_s` seconds, besides the ones forced. Pickled (Tune keeps its callbacks), it leaves the stream behind and
    writes to the stderr of the process that loads it."""

    def __init__(self, out: TextIO | None = None, every_s: float = 10.0) -> None:
        self.out = out or sys.stderr  # the stream of the moment, not the one at import
        self.tty = bool(getattr(self.out, "isatty", lambda: False)())
        self.every_s = every_s
        self._last = -math.inf
        self._open = False
        """A line in place is on the terminal, not yet ended."""
        self._wide = False
        """The last line was wider than the terminal: lines go on lines of their own, as off a terminal."""

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "out"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update({"_wide": False} | state, out=sys.stderr, _open=False,
                             tty=bool(getattr(sys.stderr, "isatty", lambda: False)()))  # fmt: skip

    def due(self, force: bool = False, now: float | None = None) -> bool:
        """Whether a line is to be written now (always on a terminal, or when forced); if so the clock restarts.
        `now`: the caller's own reading of the clock, when it has one."""
        now = time.monotonic() if now is None else now
        if (not self.tty or self._wide) and not force and now - self._last < self.every_s:
            return False
        self._last = now
        return True

    def width(self) -> int:
        """The characters a line in place may take: short of the terminal's width, since a line that wraps leaves
        its first row behind at every rewrite; at most `STATUS_WIDTH` (a wider line is written whole, on its own)."""
        try:
            columns = os.get_terminal_size(self.out.fileno()).columns
        except (AttributeError, OSError, ValueError):  # a stream with no terminal behind it
            columns = 0
        if columns <= 0:  # not known (a pty whose size was never set says 0): $COLUMNS, or the widest
            columns = shutil.get_terminal_size((STATUS_WIDTH + 1, 24)).columns
        return max(20, min(STATUS_WIDTH, columns - 1))

    def restart(self) -> None:
        """The next line is due at once (a new pass begins)."""
        self._last = -math.inf

    def note(self, line: str) -> None:
        """A line of its own that stays, below the status line on a terminal (which the next write redraws)."""
        self.out.write(("\n" if self._open else "") + line + "\n")
        self._open = False
        self.out.flush()

    def write(self, line: str, end: bool = False) -> None:
        """The line, in place on a terminal where it fits (ended there when `end`), else on a line of its own."""
        width = self.width() if self.tty else 0
        self._wide = self.tty and len(line) > width
        if self.tty and not self._wide:
            self.out.write("\r" + line.ljust(width) + ("\n" if end else ""))
            self._open = not end
        else:  # the line in place, if any, is cleared first: the whole line below it would read as its end
            self.out.write(("\r" + " " * width + "\r" if self._open else "") + line + "\n")
            self._open = False
        self.out.flush()

    def finish(self) -> None:
        """Leave the terminal's line: what follows starts on a line of its own."""
        if self._open:
            self.out.write("\n")
            self._open = False
            self.out.flush()


def progress_line(
    label: str | tuple[str, ...], hint: str = "", stream: TextIO | None = None
) -> Callable[[int, int], None]:
    """A progress bar on `stream` (stderr) with the rate and the time left: rewritten in place on a terminal, every
    5 s otherwise. Once the time left is known to exceed a minute, one line says so, with `hint` (how to cut it).
    Given several labels, a count that goes back down starts the next pass, under the next label."""
    labels = (label,) if isinstance(label, str) else label
    status = StatusLine(stream, every_s=5.0)
    t0 = [time.monotonic()]
    warned = [False]
    stage = [0, 0]  # pass, last count
    first: list[tuple[float, int] | None] = [None]  # (time, count) of the pass's first count above 0
    ended = [False]  # the pass's full bar is written: a caller reporting the end twice gets it once

    def show(done: int, total: int) -> None:
        now = time.monotonic()
        if done < stage[1] and stage[0] + 1 < len(labels):
            stage[0] += 1
            t0[0], warned[0], first[0], ended[0] = now, False, None, False
            status.restart()
        stage[1] = done
        if done >= total and ended[0]:
            return
        ended[0] = done >= total
        name = labels[stage[0]]
        elapsed = now - t0[0]
        if first[0] is None and done:
            first[0] = (now, done)
        since_t, since_n = first[0] if first[0] is not None else (t0[0], 0)
        if done > since_n and now > since_t:  # the pace since the first count: start-up (compiling) is not the work's
            per_s = (done - since_n) / (now - since_t)
        else:
            per_s = done / elapsed if done and elapsed > 0 else math.nan
        timed = done > since_n and now - since_t >= ETA_AFTER_S
        left = (total - done) / per_s if timed and per_s > 0 else math.inf
        if not warned[0] and done < total and math.isfinite(left) and left > 60:
            warned[0] = True
            status.note(f"{name}: about {left / 60:.0f} min more at this rate" + (f"; {hint}" if hint else ""))
        if not status.due(force=done >= total, now=now):
            return
        frac = done / total if total else 1.0  # nothing to do (a density of 0) is done
        rate = "-" if not math.isfinite(per_s) else f"{per_s:,.0f}/s" if per_s >= 10 else f"{per_s:.2g}/s"
        eta = f", {fmt_duration(left)} left" if done < total and math.isfinite(left) else ""
        status.write(f"{name} {bar(frac, 30)} {done:,}/{total:,} {elapsed:5.1f} s, {rate}{eta}", end=done >= total)

    return show


def fmt_duration(seconds: float) -> str:
    """A duration as the progress lines show it: 45s, 3m 07s, 1h 05m."""
    m, s = divmod(round(seconds), 60)
    if m >= 60:  # to the nearest minute
        h, m = divmod(round(seconds / 60), 60)
        return f"{h}h {m:02d}m"
    return f"{m}m {s:02d}s" if m else f"{s}s"


def optimum_progress(map_name: str, stream: TextIO | None = None) -> Callable[[int, int], None]:
    """The bar of an exact optimum's two passes on one map (`protocol.exact_optimum`'s `progress`)."""
    return progress_line((f"exact optimum of {map_name}: shapes keyed by footprint",
                          f"exact optimum of {map_name}: shapes settled"), stream=stream)  # fmt: skip

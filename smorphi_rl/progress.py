"""A progress bar on stderr for long counted work (searches, exact optima), with its rate and the time left."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import TextIO

ETA_AFTER_S = 3.0
"""The time left is estimated from the rate since the first count reported, once that has run this long (the wait
for the first count holds the work's start-up, such as compiling the planner, and says nothing of its rate)."""


def progress_line(
    label: str | tuple[str, ...], hint: str = "", stream: TextIO | None = None
) -> Callable[[int, int], None]:
    """A progress bar on `stream` (stderr) with the rate and the time left: rewritten in place on a terminal, every
    5 s otherwise. Once the time left is known to exceed a minute, one line says so, with `hint` (how to cut it).
    Given several labels, a count that goes back down starts the next pass, under the next label."""
    labels = (label,) if isinstance(label, str) else label
    out = stream or sys.stderr
    tty = out.isatty()
    t0 = [time.monotonic()]
    last = [-math.inf]
    warned = [False]
    stage = [0, 0]  # pass, last count
    first: list[tuple[float, int] | None] = [None]  # (time, count) of the pass's first count above 0
    ended = [False]  # the pass's full bar is written: a caller reporting the end twice gets it once

    def show(done: int, total: int) -> None:
        now = time.monotonic()
        if done < stage[1] and stage[0] + 1 < len(labels):
            stage[0] += 1
            t0[0], last[0], warned[0], first[0], ended[0] = now, -math.inf, False, None, False
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
            out.write(("\n" if tty else "") + f"{name}: about {left / 60:.0f} min more at this rate"
                      + (f"; {hint}" if hint else "") + "\n")  # fmt: skip
        if not tty and done < total and now - last[0] < 5:
            return
        last[0] = now
        frac = done / total if total else 1.0  # nothing to do (a density of 0) is done
        bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
        rate = "-" if not math.isfinite(per_s) else f"{per_s:,.0f}/s" if per_s >= 10 else f"{per_s:.2g}/s"
        eta = f", {left:,.0f} s left" if done < total and math.isfinite(left) else ""
        line = f"{name} [{bar}] {done:,}/{total:,} {elapsed:5.1f} s, {rate}{eta}"
        out.write(("\r" + line + ("\n" if done >= total else "")) if tty else line + "\n")
        out.flush()

    return show


def optimum_progress(map_name: str, stream: TextIO | None = None) -> Callable[[int, int], None]:
    """The bar of an exact optimum's two passes on one map (`protocol.exact_optimum`'s `progress`)."""
    return progress_line((f"exact optimum of {map_name}: shapes keyed by footprint",
                          f"exact optimum of {map_name}: shapes settled"), stream=stream)  # fmt: skip

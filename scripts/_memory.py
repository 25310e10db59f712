"""Peak memory of a benchmark's process tree (Linux /proc), shared by the benchmark scripts."""

from __future__ import annotations

import os
import threading


def _memory_kib(pid: int) -> tuple[int, int]:
    """(RSS, PSS) of one process in KiB: PSS splits shared pages (torch, Ray's libraries) among their users."""
    rss = pss = 0
    try:
        with open(f"/proc/{pid}/smaps_rollup") as fh:
            for line in fh:
                if line.startswith("Rss:"):
                    rss = int(line.split()[1])
                elif line.startswith("Pss:"):
                    pss = int(line.split()[1])
    except OSError:
        pass
    return rss, pss


def _tree_memory_bytes(root: int) -> tuple[int, int]:
    """Summed (RSS, PSS) of `root` and all its descendants (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(entry))
    rss = pss = 0
    stack = [root]
    while stack:
        pid = stack.pop()
        r, p = _memory_kib(pid)
        rss, pss = rss + r, pss + p
        stack.extend(children.get(pid, []))
    return rss * 1024, pss * 1024


class PeakMemory:
    """Samples the process tree's memory every 0.5 s in a thread; `.peak_pss` and `.peak_rss` in bytes."""

    def __init__(self) -> None:
        self.peak_pss = self.peak_rss = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            rss, pss = _tree_memory_bytes(os.getpid())
            self.peak_rss, self.peak_pss = max(self.peak_rss, rss), max(self.peak_pss, pss)
            self._stop.wait(0.5)

    def __enter__(self) -> PeakMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

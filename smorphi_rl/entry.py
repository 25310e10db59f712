"""The `smorphi-rl` command's entry point: imports the CLI (seconds of numpy, scipy, matplotlib) inside a guard,
so a Ctrl-C or SIGTERM that lands while it loads ends in one line, as one during any command does."""

from __future__ import annotations

import signal
import sys
from typing import Any

EXIT_INTERRUPTED = 130
"""cli.common's: importing it would load the whole CLI, which this module guards."""


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def main() -> int:
    """The console script: the CLI imported inside a Ctrl-C guard (its imports take seconds); SIGTERM is Ctrl-C
    meanwhile (the CLI's `interrupts.install` keeps it so)."""
    signal.signal(signal.SIGTERM, _interrupt)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # a script's `cmd &`: Ctrl-C is a stop from the start
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        from smorphi_rl.cli import main as cli_main
    except KeyboardInterrupt:
        print("smorphi-rl: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return cli_main()

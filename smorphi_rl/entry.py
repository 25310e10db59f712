"""The `smorphi-rl` command's entry point: imports the CLI (seconds of numpy, scipy, matplotlib) inside a guard,
so a Ctrl-C or SIGTERM that lands while it loads ends in one line, as one during any command does."""

from __future__ import annotations

import contextlib
import os
import sys

from smorphi_rl import interrupts  # the standard library only: the guard is up before anything heavy loads


def main() -> int:
    """The console script: the CLI imported and run inside a Ctrl-C guard (its imports take seconds); SIGTERM is
    Ctrl-C throughout (`interrupts.install`). A stop that came where it could not be raised and found the command
    already done is still a stop: exit 130."""
    interrupts.install()  # also honours Ctrl-C in a script's `cmd &`, whose shell starts it ignored
    code: int | None = None
    try:
        from smorphi_rl.cli import main as cli_main

        code = cli_main()
    except KeyboardInterrupt:
        pass
    finally:  # also as argparse's SystemExit (--help, a usage error) leaves
        waited = interrupts.settle()
    interrupts.exiting()  # a stop from here on (a flush a slow pipe holds, the teardown): exit 130 at once
    if code is None or (waited and code == 0):
        print("smorphi-rl: interrupted", file=sys.stderr)
        code = interrupts.EXIT_STOPPED
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BrokenPipeError:  # `| head` has closed it: what is left goes nowhere, not to a failed teardown flush
            with contextlib.suppress(OSError, ValueError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), stream.fileno())
        except (OSError, ValueError):  # closed
            pass
    interrupts.exiting(whole=True)
    return code

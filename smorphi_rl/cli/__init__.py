"""`smorphi-rl` command line: one module per command group, each command parse -> config -> job -> print.

Bad input ends with one line on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from smorphi_rl import interrupts
from smorphi_rl.cli import design, evaluate, maps, policy, search, train
from smorphi_rl.cli.common import (
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    PROG,
    Parser,
    default_map,
    name_choices,
    one_line,
    printable_output,
)
from smorphi_rl.errors import Interrupted, SmorphiError

__all__ = ["build_parser", "main"]


GROUPS = {
    evaluate: ("evaluate",),
    maps: ("maps",),
    train: ("train", "transfer", "sweep", "reproduce"),
    policy: ("replay", "evaluate-policy", "export-policy"),
    search: ("search", "compare"),
    design: ("design",),
}
"""Each command-group module and the commands it registers."""


def build_parser(command: str | None = None) -> Parser:
    """The whole command line; given the command about to run, only its group (the others' options import
    the training stack, which a one-shape `evaluate` does not need)."""
    parser = Parser(prog=PROG, description="Find the best Smorphi morphology for a floor map.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for group, commands in GROUPS.items():
        if command is None or command in commands:
            group.register(sub)
    name_choices(parser, sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; bad input is one line on stderr and exit 1 (2 for usage, 130 interrupted), never a traceback."""
    interrupts.install()
    with printable_output():
        return _run(argv)


def _run(argv: Sequence[str] | None) -> int:
    try:
        argv = list(sys.argv[1:] if argv is None else argv)
        known = {c for commands in GROUPS.values() for c in commands}
        args = build_parser(argv[0] if argv and argv[0] in known else None).parse_args(argv)
        if getattr(args, "map", "") is None and getattr(args, "map_default", None) is None:
            args.map = default_map()
        return int(args.func(args))
    except SmorphiError as exc:
        from smorphi_rl.cli.fields import flag_named

        print(f"{PROG}: error: {one_line(flag_named(str(exc), list(argv or ())))}", file=sys.stderr)
        return EXIT_INPUT
    except BrokenPipeError:  # output piped into `head` and the like (an OSError: caught first)
        sys.stderr.close()
        return 0
    except OSError as exc:
        print(one_line(f"{PROG}: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")), file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt as exc:
        said = f": {one_line(str(exc))}" if isinstance(exc, Interrupted) else ""
        print(f"{PROG}: interrupted{said}", file=sys.stderr)
        return EXIT_INTERRUPTED

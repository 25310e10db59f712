"""What every command shares: the one-line-error parser, exit codes, argument types and output helpers."""

from __future__ import annotations

import argparse
import math
import re
import sys
import unicodedata
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from smorphi_rl.cli.fields import finite_arg, option
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import angles_text
from smorphi_rl.inputs import MAX_SEED
from smorphi_rl.interrupts import EXIT_STOPPED
from smorphi_rl.maps import SHIPPED_DEFAULT_MAP
from smorphi_rl.rundir import DEFAULT_LOG_DIR

if TYPE_CHECKING:
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import Map
    from smorphi_rl.planning import Planning

PROG = "smorphi-rl"
DEFAULT_MAP = Path("maps") / SHIPPED_DEFAULT_MAP.name
"""The default map as the README shows it: maps/map-1.yaml in the working directory (else the shipped one)."""
EXIT_INPUT, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, EXIT_STOPPED


class Repeated(argparse.Action):
    """A list option (`nargs="+"`) that a repeated flag extends: `--random a --random b` is both runs, where argparse
    keeps only the last list and drops the others without a word. The first use replaces the default."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:  # fmt: skip
        held = getattr(namespace, self.dest, None)
        setattr(namespace, self.dest, [*(() if held is self.default or held is None else held), *values])


class Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line, like every other error, and refuses an empty value: every
    option names a file, a folder, a name or a number, and '' read as a path is the working directory."""

    def error(self, message: str) -> NoReturn:
        for dest, choices in self.subcommands.items():  # a missing subcommand by its choices, not argparse's dest
            message = message.replace(f"required: {dest}", f"required: {choices}").replace(f"argument {dest}: ", "")
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.named: dict[str, str] = {}  # each argument's dest, as argparse names the argument (before --help's)
        self.subcommands: dict[str, str] = {}  # each subcommand group's dest and its choices, `name_choices`
        super().__init__(*args, **kwargs)

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        return self._named(super().add_argument(*args, **kwargs))

    def add_one_of(self, required: bool = False) -> Any:
        """A mutually exclusive group whose arguments are named like the parser's own (an empty value refused)."""
        group = self.add_mutually_exclusive_group(required=required)
        add = group.add_argument
        group.add_argument = lambda *args, **kwargs: self._named(add(*args, **kwargs))  # type: ignore[method-assign]
        return group

    def _named(self, action: argparse.Action) -> argparse.Action:
        shown = action.metavar if isinstance(action.metavar, str) else action.dest  # a positional, as argparse says
        self.named[action.dest] = "/".join(action.option_strings) or shown
        return action

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        parsed, rest = super().parse_known_args(args, namespace)  # a value its type checks is named by its type
        for dest, value in vars(parsed).items():
            empty = value == "" or (isinstance(value, list) and "" in value)
            if empty and dest not in EMPTY_ALLOWED and dest in self.named:  # another parser's: its own check says
                self.error(f"argument {self.named[dest]}: expected a value, got an empty string")
        return parsed, rest


def name_choices(parser: Parser, sub: Any) -> None:
    """Have a missing subcommand of `parser` named by its choices, as `--help` lists them, not by its internal dest
    (a metavar would do it, but doubles the list in the invalid-choice message)."""
    parser.subcommands[sub.dest] = "{" + ",".join(sub.choices) + "}"


EMPTY_ALLOWED = ("command",)
"""Options whose empty value means something (export-policy's --command, by its default: none given)."""


def default_map() -> Path:
    """maps/map-1.yaml in the working directory, else the one shipped beside the package."""
    if DEFAULT_MAP.exists():
        return DEFAULT_MAP
    return SHIPPED_DEFAULT_MAP


def seed_arg(text: str) -> int:
    """argparse type of every --seed: a whole number in [0, 2^32-1], what numpy, torch, RLlib and Tune all take."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {value}")
    if value > MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected a seed of at most 2^32-1 = {MAX_SEED}, got {value}")
    return value


def nonempty(text: str) -> str:
    """argparse type of a name or a folder: anything but the empty string (which would mean "here" or "the
    default" without saying so)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a name, got an empty string")
    return text


def number(text: str, what: str) -> float:
    """A finite number from the command line, or an error naming `what`."""
    try:
        value = float(text)
    except ValueError:
        raise SmorphiError(f"{what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise SmorphiError(f"{what} {text!r} is not a finite number")
    return value


def map_paths(value: object) -> list[str]:
    """--map as a list of paths (one given, or several)."""
    return [str(v) for v in value] if isinstance(value, list) else [str(value)]


def scored_text(d: dict[str, object]) -> str:
    """A scored shape as the reports show it: angles, P_c, P_len and R1."""
    return f"{angles_text(d['theta'])} P_c {d['P_c']:.2f} %, P_len {d['P_len']}, R1 {d['R1']:.2f}"  # type: ignore[arg-type]


def weight_options(parser: argparse.ArgumentParser) -> None:
    """--w1 / --w2 / --path-term: the weights that rank shapes by R1 = w1 P_c - w2 P_len (the env's fields)."""
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.score import PATH_TERMS

    option(parser, EnvConfig, "w1", unset=True)
    option(parser, EnvConfig, "w2", unset=True)
    option(parser, EnvConfig, "path_term", unset=True, choices=PATH_TERMS)


def one_line(message: str) -> str:
    """Text as one line: a newline or another control character inside it (a path, a value or a recording's text
    holding one: an escape sequence would drive the terminal) is shown escaped, as \\n or \\x1b."""
    return "".join(c if c.isprintable() or c == " " else c.encode("unicode_escape").decode() for c in message)


_DRIVES_TERMINAL = re.compile(
    "[\x00-\x08\x0b\x0c\x0e-\x1f\x80-\x9f\u061c\u200b-\u200f\u2028-\u202e\u2060-\u2069\ufeff]"
)
"""Control characters that move or restyle a terminal (ESC starts its sequences, 0x9b is one; BEL, backspace, the
bidirectional overrides), but newline, carriage return and tab, which the output's own lines use. None is in JSON
that `json.dumps` writes (it escapes them all), so JSON lines pass unchanged."""


class PrintableStream:
    """A text stream that writes what it is given with every `_DRIVES_TERMINAL` character escaped, as `one_line`
    shows it (\x1b): a map named `x\x1b]0;title\a.yaml` printed in a result set the window's title."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        self.stream.write(_DRIVES_TERMINAL.sub(lambda m: m.group().encode("unicode_escape").decode(), text))
        return len(text)

    def __getattr__(self, name: str) -> Any:  # flush, isatty, fileno, encoding: the stream's own
        return getattr(self.stream, name)


@contextmanager
def printable_output() -> Iterator[None]:
    """For the block, stdout and stderr as `PrintableStream`s: no path, name or recorded text any command prints
    drives the terminal, however it reaches the output."""
    streams = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = PrintableStream(sys.stdout), PrintableStream(sys.stderr)  # type: ignore[assignment]
    try:
        yield
    finally:
        sys.stdout, sys.stderr = streams


def columns(text: str) -> int:
    """The terminal columns `text` takes: a wide East Asian character two, a combining mark none (`len` counts
    each one, so a map named in CJK pushed the columns after it out of line)."""
    return sum(0 if unicodedata.combining(ch) else 2 if unicodedata.east_asian_width(ch) in "WF" else 1 for ch in text)


def padded(text: str, width: int) -> str:
    """`text` filled with spaces to `width` terminal columns (`columns`)."""
    return text + " " * max(0, width - columns(text))


def say_warnings(grid_map: Map) -> None:
    """A map's warnings (`Map.warnings`: a sparse frame, unknown space read as free), each one line on stderr, said
    before the work they concern (stdout stays the command's report, or its JSON)."""
    for warning in grid_map.warnings():
        print(one_line(warning), file=sys.stderr)


def clipped(value: object, limit: int = 80) -> str:
    """A recorded value as text of at most about `limit` characters: a long one (a 10,000-character run name) keeps
    its start and end, and says how long it was, so one field cannot fill the screen."""
    text = str(value)
    if len(text) <= limit:
        return text
    tail = limit // 4
    return f"{text[: limit - tail]}...{text[-tail:]} ({len(text):,} characters)"


def planner_option(parser: argparse.ArgumentParser, *, start: bool = True, unset: bool = False) -> None:
    """--planner paper|fit: which coverage planner scores shapes; and (`start`) --start-xy X Y, where plans start
    (the env's fields; `unset`: the planner stays None when not given, for a checkpoint's to apply)."""
    from smorphi_rl.coverage import PLANNERS
    from smorphi_rl.env_config import EnvConfig

    option(parser, EnvConfig, "planner", unset=unset, choices=PLANNERS)
    if start:
        start_option(parser)


def start_option(parser: argparse.ArgumentParser) -> None:
    """--start-xy X Y: where plans start (the env's field; None when not given: the planner's own start)."""
    from smorphi_rl.env_config import EnvConfig

    option(parser, EnvConfig, "start_xy", unset=True, nargs=2, type=finite_arg, metavar=("X", "Y"),
           default_text="the planner's")  # fmt: skip


def planning_of(args: argparse.Namespace, grid_map: Map | None = None) -> Planning:
    """The Planning the --planner / --start-xy options ask for (checked on `grid_map` when given)."""
    from smorphi_rl.coverage import Planner
    from smorphi_rl.planning import Planning

    start = None if args.start_xy is None else (float(args.start_xy[0]), float(args.start_xy[1]))
    planning = Planning(planner=Planner(args.planner or Planner.PAPER.value), start_xy=start)
    if grid_map is not None:
        planning.start_on(grid_map)  # a start on a wall or outside the map fails here, naming the point
    return planning


def weights(args: argparse.Namespace) -> EnvConfig:
    """The env configuration with --w1 / --w2 applied (validated there, defaults from there)."""
    from smorphi_rl.env_config import EnvConfig

    return EnvConfig.from_dict({k: v for k in ("w1", "w2", "path_term") if (v := getattr(args, k)) is not None})


def run_options(parser: argparse.ArgumentParser, what: str = "run name: results go to LOG_DIR/NAME") -> None:
    """--name and --log-dir, as every command that writes a run directory takes them."""
    parser.add_argument("--name", type=nonempty, help=what)
    parser.add_argument(
        "--log-dir",
        type=nonempty,
        default=DEFAULT_LOG_DIR,
        help=f"root of the run directories (default: {DEFAULT_LOG_DIR})",
    )


def record_option(p: argparse.ArgumentParser) -> None:
    """--record-every N (TrainConfig's field)."""
    from smorphi_rl.training.config import TrainConfig

    option(p, TrainConfig, "record_every", metavar="N")

"""The one command-line framework of ``python -m plant_sim``, ``bridge`` and ``virtual_bus``.

A command is a module with ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int`` (the convention of ``plant_sim/commands/*.py``), and optionally
``DESCRIPTION`` (the paragraph of ``COMMAND --help``; ``HELP`` where there is none).
:func:`main` builds the parser from a package's command modules and runs the chosen one.
What every command gets:

* one way to fail on bad input: a single line ``PROG COMMAND: error: MESSAGE`` on stderr and
  exit status 2, whether argparse rejects an argument (:class:`Parser`), a command raises
  :class:`UsageError`, or a package's input error (bad file, bad value) reaches :func:`main`;
* one set of argument types: :func:`positive_float`, :func:`count`, :func:`node_id`,
  :func:`number_list` (``--kv 20,30`` and ``--kv 20 30`` alike), :func:`existing_file`,
  :func:`output_dir`, :func:`new_file`;
* ``--quiet`` on every command (:func:`add_quiet`; added when a command does not add it) for
  the progress of :mod:`cmdline.progress`.

It lives in :mod:`virtual_bus`, the lowest package (it imports nothing else of the project),
so ``plant_sim`` and ``bridge`` import it without a cycle. Standard library only.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import math
import os
import select
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import NoReturn, Protocol

#: Exit status of bad arguments or bad input files (one line on stderr).
EXIT_USAGE = 2
#: Exit status of a failure while running (device, bus, environment).
EXIT_FAILURE = 1
#: the reader of standard output went away (``| head``): 128 + SIGPIPE, what a shell reports
#: for a filter stopped the same way
EXIT_BROKEN_PIPE = 141


class UsageError(Exception):
    """An argument that passed argparse but is invalid (alone or with another one): exit 2."""


class Command(Protocol):
    """What a command module provides (checked structurally)."""

    NAME: str
    HELP: str

    def add_arguments(self, parser: argparse.ArgumentParser) -> None: ...

    def run(self, args: argparse.Namespace) -> int: ...


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage dump) and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {one_line(message)} (see --help)\n")


def one_line(message: object) -> str:
    """``message`` on one line (line breaks of a nested message become "; ")."""
    return "; ".join(part.strip() for part in str(message).splitlines() if part.strip())


def print_error(where: str, message: object, code: int = EXIT_USAGE) -> int:
    """Print ``WHERE: error: MESSAGE`` as one line on stderr; returns ``code``."""
    print(f"{where}: error: {one_line(message)}", file=sys.stderr)
    return code


@dataclass(frozen=True)
class Failure:
    """Exceptions of these types end a command with one line and ``code`` (1 or 2);
    ``label`` (optional) is put before the message, e.g. "CAN bus error"."""

    types: tuple[type[BaseException], ...]
    code: int = EXIT_USAGE
    label: str = ""


#: The console scripts pip installs (``[project.scripts]``) and the module each one runs: a
#: command started under one of these names says that name in its usage and errors.
CONSOLE_SCRIPTS = {
    "backlash-bridge": "python -m bridge",
    "backlash-hil": "python -m hil",
    "backlash-sim": "python -m plant_sim",
    "backlash-bus": "python -m virtual_bus",
}

#: Input errors every package shares: a file that is missing or unreadable is bad input.
FILE_ERRORS = Failure((FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError))


def started_as(prog: str) -> str:
    """``prog``, or the console script's name when the process was started by it."""
    name = Path(sys.argv[0]).name
    return name if CONSOLE_SCRIPTS.get(name) == prog else prog


def missing_extra(prog: str, modules: Sequence[str], extra: str) -> int | None:
    """One line and exit status 1 when a module an optional extra installs is missing (a
    bridge-only install runs ``python -m plant_sim``), else None."""
    absent = [m for m in modules if importlib.util.find_spec(m) is None]
    if not absent:
        return None
    return print_error(
        started_as(prog),
        f"{', '.join(absent)} not installed: this part of the project needs the '{extra}' "
        f"extra (pip install 'backlash-bridge[{extra}]')",
        EXIT_FAILURE,
    )


def load_commands(package: str, names: Sequence[str]) -> list[ModuleType]:
    """Import ``package.commands.NAME`` for each name (a module that is not installed is
    simply not offered)."""
    modules = []
    for name in names:
        target = f"{package}.commands.{name}"
        try:
            modules.append(importlib.import_module(target))
        except ModuleNotFoundError as exc:
            if exc.name != target:
                raise
    return modules


def build_parser(prog: str, description: str, commands: Sequence[ModuleType]) -> Parser:
    parser = Parser(prog=prog, description=description)
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=Parser
    )
    for module in commands:
        description = getattr(module, "DESCRIPTION", module.HELP)
        p = sub.add_parser(module.NAME, help=module.HELP, description=description)
        module.add_arguments(p)
        if not any(a.dest == "quiet" for a in p._actions):
            add_quiet(p)
        p.set_defaults(_command=module)
    return parser


def main(
    prog: str,
    description: str,
    commands: Sequence[ModuleType],
    argv: Sequence[str] | None,
    failures: Sequence[Failure] = (),
    defaults: Mapping[str, object] | None = None,
) -> int:
    """Parse ``argv``, run the chosen command, map errors to one line and an exit status.

    ``failures`` are tried in order after :class:`UsageError` (always exit 2) and before
    :data:`FILE_ERRORS`; ``defaults`` are set on the namespace of every command (injected
    collaborators of tests, e.g. a fake ``ip`` runner)."""
    if argv is None:
        prog = started_as(prog)
    parser = build_parser(prog, description, commands)
    if defaults:
        parser.set_defaults(**defaults)
    args = parser.parse_args(argv)
    where = f"{prog} {args.command}"
    try:
        return int(args._command.run(args))
    except UsageError as exc:
        return print_error(where, exc, EXIT_USAGE)
    except Exception as exc:
        if isinstance(exc, BrokenPipeError) and _stdout_gone():
            # nobody reads the rest: no error line, and no second failure when Python
            # flushes standard output at exit (the recipe of the `signal` module's docs)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return EXIT_BROKEN_PIPE
        for failure in (*failures, FILE_ERRORS):
            if isinstance(exc, failure.types):
                label = f"{failure.label}: " if failure.label else ""
                return print_error(where, f"{label}{exc}", failure.code)
        raise


def run_package(
    package: str,
    description: str,
    commands: Sequence[str],
    argv: Sequence[str] | None,
    failures: Sequence[Failure] = (),
    *,
    needs: Sequence[str] = (),
    extra: str = "sim",
    defaults: Mapping[str, object] | None = None,
) -> int:
    """The ``main`` of ``python -m PACKAGE``: one line and exit 1 when a module of ``needs``
    (what the optional ``extra`` installs) is missing (:func:`missing_extra`), else
    :func:`main` over ``PACKAGE.commands.NAME`` for each of ``commands``
    (:func:`load_commands`), with the package's ``failures`` and ``defaults``."""
    prog = f"python -m {package}"
    if needs and (code := missing_extra(prog, needs, extra)) is not None:
        return code
    return main(prog, description, load_commands(package, commands), argv, failures, defaults)


def _stdout_gone() -> bool:
    """Whether a broken pipe is standard output's (not a socket's or a child's pipe): the
    write end of a pipe whose reader has closed polls as an error."""
    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        events = poller.poll(0)
    except (OSError, ValueError, AttributeError):
        return False
    return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in events)


# --- argument types -----------------------------------------------------------------------------
def _number(
    text: str,
    allowed: Callable[[float], bool] = math.isfinite,
    rule: str = "must be a finite number",
) -> float:
    """``text`` as a float for which ``allowed`` holds; ArgumentTypeError saying ``rule``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not allowed(value):
        raise argparse.ArgumentTypeError(f"{text!r}: {rule}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return _number(text, lambda v: math.isfinite(v) and v > 0, "must be a finite number > 0")


def bounded_float(low: float, high: float) -> Callable[[str], float]:
    """A number in [low, high]."""

    def parse(text: str) -> float:
        value = _number(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text!r}: allowed {low:g}..{high:g}")
        return value

    return parse


def integer(text: str, low: int, high: int | None, rule: str) -> int:
    """``text`` as a whole number in [low, high] (``high`` None: no upper bound);
    ArgumentTypeError "is not an integer" or ``rule``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"{text!r}: {rule}")
    return value


def bounded_int(low: int, high: int) -> Callable[[str], int]:
    """A whole number in [low, high]."""

    def parse(text: str) -> int:
        return integer(text, low, high, f"allowed {low}..{high}")

    return parse


def count(text: str) -> int:
    """A whole number >= 1."""
    return integer(text, 1, None, "must be >= 1")


#: CiA 301: node-IDs 1..127.
NODE_ID_RANGE = (1, 127)


def node_id(text: str) -> int:
    """A CANopen node-ID, 1..127 (decimal or 0x hex)."""
    try:
        value = int(text, 0)
    except ValueError:
        value = -1
    if not NODE_ID_RANGE[0] <= value <= NODE_ID_RANGE[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: a CANopen node-ID is 1..127")
    return value


def positive_list(text: str) -> tuple[float, ...]:
    """Comma-separated numbers, each > 0 (one word of a :func:`number_list` option)."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected comma-separated numbers, e.g. 20,30 or 20 30"
        ) from None
    if not values or any(not (math.isfinite(v) and v > 0) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: every value must be a finite number > 0")
    return values


class _FlatList(argparse.Action):
    """Joins the words of ``--opt 20,30 40`` into one tuple (20, 30, 40)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        words = values if isinstance(values, list) else [values]
        setattr(namespace, self.dest, tuple(v for word in words for v in word))


def number_list(
    parser: argparse.ArgumentParser, flag: str, default: Sequence[float], help_text: str
) -> None:
    """Add ``flag`` taking positive numbers separated by commas or spaces, or both."""
    parser.add_argument(
        flag,
        nargs="+",
        type=positive_list,
        action=_FlatList,
        default=tuple(default),
        metavar="X",
        help=f"{help_text}; comma- or space-separated (default "
        + ",".join(f"{v:g}" for v in default)
        + ")",
    )


def existing_file(text: str) -> Path:
    """A path to an existing file."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: not a file")
    return path


def output_dir(text: str) -> Path:
    """A directory to write into: it may not exist yet (created by the command), but it must
    not be an existing file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(
            f"{text}: exists and is not a directory (--out takes a directory)"
        )
    return path


def new_file(text: str) -> Path:
    """A file to write: not a directory, and its directory exists."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory, expected a file path")
    if not path.parent.exists():
        raise argparse.ArgumentTypeError(f"{text}: directory {path.parent} does not exist")
    return path


def add_can_bus(
    parser: argparse.ArgumentParser, bitrate: int = 1_000_000, bitrate_help: str | None = None
) -> None:
    """``--interface``, ``--channel`` (both required) and ``--bitrate``: the one CAN bus a
    command opens (the fields of :class:`virtual_bus.BusConfig`)."""
    parser.add_argument("--interface", required=True, help="python-can interface, e.g. socketcan")
    parser.add_argument("--channel", required=True, help="CAN channel, e.g. can0")
    parser.add_argument(
        "--bitrate", type=int, default=bitrate, help=bitrate_help or f"bit/s (default {bitrate})"
    )


def add_output_dir(parser: argparse.ArgumentParser, help: str = "output directory") -> None:
    """``--out DIR`` (required): a directory the command writes into (:func:`output_dir`)."""
    parser.add_argument("--out", type=output_dir, required=True, help=help)


def add_inputs(
    parser: argparse.ArgumentParser, name: str, help: str, metavar: str | None = None
) -> None:
    """Positional ``name`` (zero or more paths): the files (or folders) a command reads; when
    none is given the command reads its documented default (``help`` says which)."""
    parser.add_argument(name, nargs="*", type=Path, metavar=metavar, help=help)


def add_dask(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` (local Dask worker processes, 0..256; 0: in this process, no Dask) and
    ``--scheduler ADDRESS`` (an existing Dask scheduler instead)."""
    parser.add_argument(
        "--workers",
        type=bounded_int(0, 256),
        default=2,
        help="local worker processes, 0..256 (default 2; 0: in this process, no Dask)",
    )
    parser.add_argument(
        "--scheduler",
        metavar="tcp://HOST:8786",
        help="an existing Dask scheduler instead of local workers",
    )


def add_quiet(parser: argparse.ArgumentParser) -> None:
    """``--quiet``/``-q``: no progress output (results and errors are still printed)."""
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="no progress output (results still printed)"
    )

"""``python -m plant_sim COMMAND``: the simulator's command line.

Each command lives in its own module under :mod:`plant_sim.commands` exposing
``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Bad arguments or bad
files end with a one-line message and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

from regulator.errors import RegulatorError

from .errors import PlantSimError

COMMANDS = (
    "paper",
    "sweep",
    "bench",
    "simulate",
    "identify",
    "diagnose",
    "drive",
    "monitor",
    "monitor_bench",
)


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error message (no usage dump) and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _parser() -> tuple[argparse.ArgumentParser, dict[str, object]]:
    parser = _Parser(
        prog="python -m plant_sim",
        description="Servo-axis simulator, paper reproduction and diagnosis "
        "(Mohammadiasl, 'Vibration Detection and Backlash Suppression in Machine Tools').",
    )
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=_Parser
    )
    modules: dict[str, object] = {}
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"plant_sim.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"plant_sim.commands.{name}":
                raise
            continue  # a command whose module is not installed is simply not offered
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        modules[module.NAME] = module
    return parser, modules


def main(argv: list[str] | None = None) -> int:
    parser, modules = _parser()
    args = parser.parse_args(argv)
    module = modules[args.command]
    try:
        return int(module.run(args))  # type: ignore[attr-defined]
    except RegulatorError as exc:
        axis = getattr(args, "axis", None)
        print(
            f"python -m plant_sim {args.command}: {axis}: the regulator cannot run on this "
            f"axis: {exc}",
            file=sys.stderr,
        )
        return 2
    except (PlantSimError, OSError) as exc:
        print(f"python -m plant_sim {args.command}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

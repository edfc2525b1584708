"""``python -m plant_sim COMMAND``: the simulator's command line.

Each command lives in its own module under :mod:`plant_sim.commands` exposing ``NAME``,
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``; :mod:`cmdline.cli` runs
them (the framework of every command line of the project). Bad arguments or bad files end
with a one-line message and exit code 2, never a traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from cmdline import cli
from virtual_bus.errors import RealTimeRefused
from virtual_bus.formats import FormatError

from .errors import PlantSimError

PROG = "python -m plant_sim"
COMMANDS = (
    "paper",
    "sweep",
    "bench",
    "identify",
    "emps",
    "xl330",
    "force_error",
    "drive",
    "fmu_axis",
)
DESCRIPTION = (
    "Servo-axis simulator and paper reproduction "
    "(Mohammadiasl, 'Vibration Detection and Backlash Suppression in Machine Tools')."
)


#: What ``pip install 'backlash-bridge[sim]'`` adds and every simulator command needs.
SIM_MODULES = ("numba", "matplotlib")


def main(argv: Sequence[str] | None = None) -> int:
    failures = (
        cli.Failure((RealTimeRefused,), cli.EXIT_FAILURE, "refused"),
        cli.Failure((PlantSimError, FormatError, OSError)),
    )
    return cli.run_package("plant_sim", DESCRIPTION, COMMANDS, argv, failures, needs=SIM_MODULES)


if __name__ == "__main__":
    sys.exit(main())

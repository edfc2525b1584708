"""``python -m diagnosis COMMAND``: models against recordings (console script
``backlash-diagnosis``).

Each command lives in its own module under :mod:`diagnosis.commands` (``NAME``, ``HELP``,
``add_arguments``, ``run``); :mod:`cmdline.cli` runs them. Bad arguments or files: one line,
exit 2.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from cmdline import cli
from plant_sim.errors import PlantSimError
from virtual_bus.formats import FormatError

from .errors import DiagnosisError

PROG = "python -m diagnosis"
COMMANDS = ("diagnose", "simulate", "matrix")
DESCRIPTION = (
    "Where a recording and its axis file differ, which physics the model leaves out, the "
    "fitted model and its proof on held-out data (docs/diagnosis.md)."
)
#: What ``pip install 'backlash-bridge[sim]'`` adds and every diagnosis command needs.
SIM_MODULES = ("numba", "matplotlib")


def main(argv: Sequence[str] | None = None) -> int:
    failures = (cli.Failure((DiagnosisError, PlantSimError, FormatError, OSError)),)
    return cli.run_package("diagnosis", DESCRIPTION, COMMANDS, argv, failures, needs=SIM_MODULES)


if __name__ == "__main__":
    sys.exit(main())

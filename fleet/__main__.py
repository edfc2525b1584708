"""``python -m fleet COMMAND``: condition monitoring of a fleet of axes (console script
``backlash-fleet``; docs/monitor.md).

Each command lives in its own module under :mod:`fleet.commands`; :mod:`cmdline.cli` runs
them. Bad arguments or files: one line, exit 2.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from cmdline import cli
from plant_sim.errors import PlantSimError
from virtual_bus.formats import FormatError

from .errors import FleetError

PROG = "python -m fleet"
COMMANDS = ("monitor", "monitor_bench")
DESCRIPTION = (
    "Condition monitoring of many axes' recordings: vibration episodes, eq. 13 verdicts, "
    "backlash trends, ranked axes, on Dask (docs/monitor.md)."
)
#: What ``pip install 'backlash-bridge[sim]'`` adds and the monitor needs.
SIM_MODULES = ("numba", "matplotlib", "distributed", "pyarrow")


def main(argv: Sequence[str] | None = None) -> int:
    failures = (cli.Failure((FleetError, PlantSimError, FormatError, OSError)),)
    return cli.run_package("fleet", DESCRIPTION, COMMANDS, argv, failures, needs=SIM_MODULES)


if __name__ == "__main__":
    sys.exit(main())

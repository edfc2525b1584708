"""``python -m hil COMMAND``: the bridge against the simulated drive (demo, bench) and its
commissioning on the simulated axis offline (tune, freqresp).

Each command is a module under :mod:`hil.commands` run by :mod:`cmdline.cli`, with the
same failures as ``python -m bridge`` (one line; 2 for bad input, 1 for a failing drive or
bus) plus the simulator's input errors.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from bridge.__main__ import FAILURES as BRIDGE_FAILURES
from bridge.__main__ import quiet_sdo_client_logging
from cmdline import cli
from plant_sim.__main__ import SIM_MODULES
from plant_sim.errors import PlantSimError
from regulator.errors import RegulatorError

PROG = "python -m hil"
COMMANDS = ("demo", "bench", "tune", "freqresp", "sweep", "contour", "plot")
DESCRIPTION = (
    "Hardware in the loop without hardware: the bridge (python -m bridge) closing the loop "
    "over CANopen against the simulated CiA 402 drive (python -m plant_sim drive)."
)
FAILURES = (*BRIDGE_FAILURES, cli.Failure((PlantSimError, RegulatorError)))


def main(argv: Sequence[str] | None = None) -> int:
    if (code := cli.missing_extra(PROG, SIM_MODULES, "sim")) is not None:
        return code  # before the SDO client's logging is touched
    quiet_sdo_client_logging()
    return cli.run_package("hil", DESCRIPTION, COMMANDS, argv, FAILURES)


if __name__ == "__main__":
    sys.exit(main())

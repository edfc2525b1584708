"""``python -m hil COMMAND``: the bridge's commissioning on the simulated axis (tune, freqresp).

Each command is a module under :mod:`hil.commands` run by :mod:`virtual_bus.cli`, with the same
failures as ``python -m bridge`` (one line; 2 for bad input, 1 for a failing drive or bus)
plus the simulator's and the tuning's input errors.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from bridge.__main__ import FAILURES as BRIDGE_FAILURES
from plant_sim.errors import PlantSimError
from regulator.errors import RegulatorError
from virtual_bus import cli

from .commands.common import PROG

COMMANDS = ("tune", "freqresp")
DESCRIPTION = (
    "Hardware in the loop without hardware: the bridge's commissioning (beta_T tuning, "
    "frequency response) on the simulated axis, offline."
)
FAILURES = (*BRIDGE_FAILURES, cli.Failure((PlantSimError, RegulatorError)))


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return cli.main(PROG, DESCRIPTION, cli.load_commands("hil", COMMANDS), argv, FAILURES)


if __name__ == "__main__":
    sys.exit(main())

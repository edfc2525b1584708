"""``python -m bridge COMMAND``: run, probe, config, eds, busload, host-latency,
freqresp, tune.

Each command is a module under :mod:`bridge.commands` (``NAME``, ``HELP``,
``add_arguments``, ``run``), run by :mod:`cmdline.cli`. Bad arguments or files end with a
one-line message and exit status 2 (no traceback); a failure while running (drive does not
answer, bus error) with a one-line message and 1.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

import can

from cmdline import cli
from regulator.errors import RegulatorError
from virtual_bus import VirtualBusError
from virtual_bus.errors import BusUnavailableError, RealTimeRefused
from virtual_bus.formats import FormatError

from .commands.common import PROG as PROG  # the parser's name (tests build it)
from .errors import BridgeError, DriveSetupError

COMMANDS = ("run", "probe", "config", "eds", "busload", "host_latency", "freqresp", "tune")
DESCRIPTION = (
    "CANopen bridge running the backlash regulator of Mohammadiasl, 'Vibration Detection and "
    "Backlash Suppression in Machine Tools' (eq. 7, 15) against a CiA 402 drive in cyclic "
    "synchronous velocity mode."
)
#: Checked in this order (subclasses before their roots).
FAILURES = (
    cli.Failure((DriveSetupError,), cli.EXIT_FAILURE, "drive start-up failed"),
    cli.Failure((RealTimeRefused,), cli.EXIT_FAILURE, "refused"),
    cli.Failure((BusUnavailableError,), cli.EXIT_FAILURE),
    cli.Failure((BridgeError, FormatError, VirtualBusError, RegulatorError)),
    cli.Failure((can.CanError,), cli.EXIT_FAILURE, "CAN bus error"),
    cli.FILE_ERRORS,
    cli.Failure((OSError,), cli.EXIT_FAILURE),
)


def quiet_sdo_client_logging() -> None:
    """Warnings as one line each; canopen's SDO client is silenced, because the bridge's
    master reports a failed SDO transfer itself, with object and tries."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("canopen.sdo.client").setLevel(logging.CRITICAL)


def main(argv: Sequence[str] | None = None) -> int:
    quiet_sdo_client_logging()
    return cli.run_package("bridge", DESCRIPTION, COMMANDS, argv, FAILURES)


if __name__ == "__main__":
    sys.exit(main())

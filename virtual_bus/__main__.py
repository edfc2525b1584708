"""Command line: ``python -m virtual_bus setup [NAME]``, ``python -m virtual_bus probe`` and
``python -m virtual_bus guest [--kernel PATH] [--mem MB] -- COMMAND ARGS...``.

Commands are modules under :mod:`virtual_bus.commands`, run by :mod:`cmdline.cli`.
Exit status: 0 ok, 1 environment problem (one-line message), 2 bad arguments.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from cmdline import cli
from virtual_bus.errors import VcanSetupError, VirtualBusError
from virtual_bus.guest.kernel import GuestError
from virtual_bus.vcan import HostProbe, Runner, run_ip

PROG = "python -m virtual_bus"
COMMANDS = ("setup", "probe", "guest")


def main(
    argv: Sequence[str] | None = None,
    runner: Runner = run_ip,
    probe: HostProbe | None = None,
) -> int:
    """Run the CLI; ``runner`` and ``probe`` are injectable for tests."""
    return cli.run_package(
        "virtual_bus",
        "Set up or probe the CAN bus shared by the bridge and the simulated drive.",
        COMMANDS,
        argv,
        failures=(
            cli.Failure((VcanSetupError, GuestError), cli.EXIT_FAILURE),
            cli.Failure((VirtualBusError,)),
        ),
        defaults={"runner": runner, "probe": probe},
    )


if __name__ == "__main__":
    sys.exit(main())

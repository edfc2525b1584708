"""Command line: ``python -m virtual_bus setup [NAME]`` and ``python -m virtual_bus probe``.

Exit status: 0 ok, 1 environment problem (one-line message), 2 bad arguments.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import NoReturn

from virtual_bus.config import BusConfig, Interface
from virtual_bus.errors import BusConfigError, VcanSetupError
from virtual_bus.open import resolve
from virtual_bus.vcan import (
    DEFAULT_VCAN_CHANNEL,
    HostProbe,
    Runner,
    check_ifname,
    run_ip,
    setup_vcan,
)


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error message (no usage dump) and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _ifname(value: str) -> str:
    try:
        return check_ifname(value)
    except BusConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _parser() -> _Parser:
    parser = _Parser(
        prog="python -m virtual_bus",
        description="Set up or probe the CAN bus shared by the bridge and the simulated drive.",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    setup = sub.add_parser(
        "setup",
        help="create a vcan interface and bring it up (needs root and the vcan module)",
        description="Runs `ip link add dev NAME type vcan` and `ip link set up NAME`.",
    )
    setup.add_argument(
        "name",
        nargs="?",
        default=DEFAULT_VCAN_CHANNEL,
        type=_ifname,
        help=f"interface name (default {DEFAULT_VCAN_CHANNEL})",
    )
    probe = sub.add_parser("probe", help="print which bus open_bus would pick here, and why")
    probe.add_argument(
        "--channel",
        type=_ifname,
        default=None,
        help=f"SocketCAN interface to look for (default {DEFAULT_VCAN_CHANNEL})",
    )
    return parser


def main(
    argv: Sequence[str] | None = None,
    runner: Runner = run_ip,
    probe: HostProbe | None = None,
) -> int:
    """Run the CLI; ``runner`` and ``probe`` are injectable for tests."""
    args = _parser().parse_args(argv)
    if args.command == "setup":
        try:
            outcome = setup_vcan(args.name, runner)
        except VcanSetupError as exc:
            print(f"virtual_bus setup: {exc}", file=sys.stderr)
            return 1
        print(f"{args.name}: {outcome.value}")
        return 0
    # AUTO never raises: it falls back to the virtual bus and says why.
    choice = resolve(
        BusConfig(interface=Interface.AUTO, channel=args.channel), probe or HostProbe()
    )
    print(f"mode: {choice.python_can_interface} channel: {choice.channel}")
    print(f"why: {choice.reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

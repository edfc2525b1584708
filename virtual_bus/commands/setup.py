"""``python -m virtual_bus setup [NAME]``: create a vcan interface and bring it up."""

from __future__ import annotations

import argparse

from virtual_bus.errors import BusConfigError
from virtual_bus.vcan import DEFAULT_VCAN_CHANNEL, check_ifname, run_ip, setup_vcan

NAME = "setup"
HELP = "create a vcan interface and bring it up (needs root and the vcan module)"
DESCRIPTION = "Runs `ip link add dev NAME type vcan` and `ip link set up NAME`."


def ifname(value: str) -> str:
    """A Linux network interface name (argument type)."""
    try:
        return check_ifname(value)
    except BusConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "name",
        nargs="?",
        default=DEFAULT_VCAN_CHANNEL,
        type=ifname,
        help=f"interface name (default {DEFAULT_VCAN_CHANNEL})",
    )


def run(args: argparse.Namespace) -> int:
    outcome = setup_vcan(args.name, getattr(args, "runner", None) or run_ip)
    print(f"{args.name}: {outcome.value}")
    return 0

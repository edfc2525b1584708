"""``python -m virtual_bus probe [--channel NAME]``: which bus open_bus would pick, and why."""

from __future__ import annotations

import argparse

from virtual_bus.config import BusConfig, Interface
from virtual_bus.open import resolve
from virtual_bus.vcan import DEFAULT_VCAN_CHANNEL, HostProbe

from .setup import ifname

NAME = "probe"
HELP = "print which bus open_bus would pick here (Interface.AUTO), and why"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--channel",
        type=ifname,
        default=None,
        help=f"SocketCAN interface to look for (default {DEFAULT_VCAN_CHANNEL})",
    )


def run(args: argparse.Namespace) -> int:
    # AUTO never raises: it falls back to the virtual bus and says why.
    config = BusConfig(interface=Interface.AUTO, channel=args.channel)
    choice = resolve(config, getattr(args, "probe", None) or HostProbe())
    if choice.interface is Interface.SOCKETCAN:
        print(f"bus: SocketCAN on {choice.channel}")
    else:
        print(
            f"bus: python-can's in-process virtual bus (SocketCAN {config.socketcan_channel} "
            "not used)"
        )
    print(f"why: {choice.reason}")
    return 0

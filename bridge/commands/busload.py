"""``python -m bridge busload``: bus load of the PDO layout (bridge/busload.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline import cli
from virtual_bus.formats.axis import load_axis
from virtual_bus.shipped import PAPER_AXIS

NAME = "busload"
HELP = "bus load of the PDO layout (SYNC + TPDO1 + TPDO2 + RPDO1 per axis)"
DESCRIPTION = "Worst-case bit stuffing, 11-bit identifiers."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bitrate", type=int, default=1_000_000, help="bit/s (default 1000000)")
    parser.add_argument(
        "--cycle-us", type=cli.positive_float, help="SYNC period in µs (default: axis)"
    )
    parser.add_argument(
        "--axis",
        type=Path,
        default=PAPER_AXIS,
        help="axis file whose position cycle is the default",
    )
    parser.add_argument("--axes", type=cli.count, default=1, help="number of drives (default 1)")


def run(args: argparse.Namespace) -> int:
    from ..busload import report

    cycle_s = args.cycle_us * 1e-6 if args.cycle_us else load_axis(args.axis).control.position_cycle
    print(report(args.axes, cycle_s, args.bitrate))
    return 0

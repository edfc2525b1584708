"""``python -m hil demo --out DIR``: the paper's section X over the bus (hil/demo.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from bridge.commands.common import regulated_axis
from virtual_bus import Interface, cli
from virtual_bus.progress import Progress
from virtual_bus.shipped import PAPER_AXIS

NAME = "demo"
HELP = "the paper's section X over the bus with the simulated drive"
DESCRIPTION = (
    "Runs section X (Fig. 8 and Fig. 9) with the bridge closing the loop over CANopen against "
    "the simulated drive; writes the summary.json and figures of `python -m plant_sim paper`, "
    "the traces and the bus logs."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=cli.output_dir, required=True, help="output directory")
    parser.add_argument(
        "--axis", type=Path, default=PAPER_AXIS, help="axis file (default config/paper_axis.toml)"
    )
    parser.add_argument(
        "--bus",
        choices=["virtual", "socketcan"],
        default="virtual",
        help="virtual (default) or socketcan on vcan0",
    )


def run(args: argparse.Namespace) -> int:
    from ..demo import print_summary, run_demo

    axis = regulated_axis(args.axis)
    interface = Interface.VIRTUAL if args.bus == "virtual" else Interface.SOCKETCAN
    progress = Progress(f"bridge {NAME}", quiet=args.quiet)
    summary = run_demo(args.out, axis, str(args.axis), interface, progress)
    print_summary(summary, args.out)
    return 0

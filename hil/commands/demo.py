"""``python -m hil demo --out DIR [--fmu FMU --fmu-param ...]``: the paper's section X over
the bus (hil/demo.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline import cli
from cmdline.progress import Progress
from plant_sim.fmu.arguments import add_fmu_arguments
from virtual_bus import Interface

from .common import simulated_source

NAME = "demo"
HELP = "the paper's section X over the bus with the simulated drive"
DESCRIPTION = (
    "Runs section X (Fig. 8 and Fig. 9) with the bridge closing the loop over CANopen against "
    "the simulated drive; writes the summary.json and figures of `python -m plant_sim paper`, "
    "the traces and the bus logs, and prints a summary in µm/mm (--json: summary.json's "
    "content). With --fmu the drive's plant is the FMU (its data sheet "
    "configures the bridge unless --axis is given)."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from bridge.scope import add_scope_argument

    add_scope_argument(parser, "the live scope of each bus run while the demo runs")
    cli.add_output_dir(parser)
    parser.add_argument(
        "--axis",
        type=Path,
        help="axis file (default config/paper_axis.toml; with --fmu, the FMU's data sheet)",
    )
    parser.add_argument(
        "--bus",
        choices=["virtual", "socketcan"],
        default="virtual",
        help="virtual (default) or socketcan on vcan0",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print summary.json's content instead of the summary in µm/mm (it is written to "
        "OUT/summary.json either way)",
    )
    add_fmu_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..demo import print_summary, run_demo

    source = simulated_source(args, args.axis)
    interface = Interface.VIRTUAL if args.bus == "virtual" else Interface.SOCKETCAN
    progress = Progress(f"hil {NAME}", quiet=args.quiet)
    scope = None
    if args.scope is not None:
        from bridge.scope import Scope

        scope = Scope(args.scope, command="hil demo")
        scope.start()
    try:
        summary = run_demo(
            args.out,
            source.axis,
            source.name,
            interface,
            progress,
            source,
            watch=None if scope is None else scope.follow,
        )
    finally:
        if scope is not None:
            scope.close()
    print_summary(summary, args.out, as_json=args.json)
    return 0

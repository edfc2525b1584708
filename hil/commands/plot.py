"""``python -m hil plot``: a servo trace as a PNG and a self-contained HTML page.

It lives in ``hil`` (floor 5) because it reads the trace format of floor 1
(virtual_bus.formats.trace) and draws with matplotlib, a simulator-side dependency the
bridge (floor 2) must run without; ``hil`` already carries the simulator's extras.
"""

from __future__ import annotations

import argparse

from cmdline import cli
from virtual_bus.formats.axis import AxisKind, load_axis
from virtual_bus.formats.trace import read_trace

from ..plot import PlotSetup, panels, write

NAME = "plot"
HELP = "plot a trace (PNG and a self-contained HTML page), in mm/µm, eq. 13's band marked"
DESCRIPTION = (
    "Plot a servo trace (docs/trace-file.md) -- from hil demo --out, bridge run --trace, "
    "plant_sim import-emps/import-xl330, an FMU demo, diagnosis/fleet simulate: positions, "
    "following error, the deflection motor_position / k_r - load_position, torque, speed, "
    "beta and lambda, and the following error's spectrum with eq. 13's band k_v/4..k_v "
    "(Hz) shaded. k_r, k_v and the load unit come from --axis; without it the load unit is "
    "m (--load-unit) and the deflection and band are left out."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("trace", type=cli.existing_file, metavar="TRACE.csv")
    parser.add_argument(
        "--axis", type=cli.existing_file, metavar="AXIS.toml", help="the axis file (k_r, k_v)"
    )
    parser.add_argument(
        "--load-unit",
        choices=("m", "rad"),
        help="load unit without --axis: m (linear, shown in mm/µm; default) or rad (rotary)",
    )
    parser.add_argument(
        "--out",
        metavar="PREFIX",
        help="writes PREFIX.png and PREFIX.html (default: next to the trace, its stem)",
    )


def run(args: argparse.Namespace) -> int:
    trace = read_trace(args.trace)  # not a trace: TraceFileError, one line, exit 2
    if args.axis is not None:
        axis = load_axis(args.axis)
        unit = "m" if axis.kind is AxisKind.LINEAR else "rad"
        if args.load_unit is not None and args.load_unit != unit:
            raise cli.UsageError(f"--load-unit {args.load_unit} contradicts {args.axis} ({unit})")
        setup = PlotSetup(unit, axis.transmission_ratio, axis.control.kv)
    else:
        setup = PlotSetup(args.load_unit or "m")
    prefix = args.out if args.out is not None else str(args.trace.with_suffix(""))
    png, page = cli.new_file(prefix + ".png"), cli.new_file(prefix + ".html")
    plots = panels(trace, setup)
    write(plots, f"{args.trace.name}", png, page)
    for p in plots:
        print(f"{p.title.split(':')[0]}: {p.range_text()}")
    print(f"plot: {png}, {page}")
    return 0

"""``python -m diagnosis simulate --axis AXIS.toml --like RECORDING.csv --out SIM.csv``
(or ``--fmu FMU [--fmu-param ...]``).

Simulates the axis file's closed loop (Fig. 1: P position controller, PI/P speed controller,
current loop, dead time, mechanics) driven by the recording's ``position_reference`` (and its
``disturbance`` column when present), on the recording's time base, and writes the simulated
trace with the recording's columns — how a fitted model (``diagnose``'s axis_fitted.toml) is
checked on a second recording. With ``--fmu`` the FMU is the plant and the axis file (default:
its data sheet) the position controller around it. Prints the simulation's fit to the
recording per signal.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline import cli
from plant_sim.commands.common import plain_warnings
from plant_sim.fmu.arguments import add_fmu_arguments, axis_source
from virtual_bus.formats.trace import read_trace

from ..engine import signal_fits
from ..replay import like_recording, prepare_replay, replay

NAME = "simulate"
HELP = (
    "simulate an axis file's (or an FMU's) closed loop like a recording (its "
    "position_reference, disturbance and time base) and write the simulated trace"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--axis",
        type=Path,
        metavar="AXIS.toml",
        help="axis file to simulate (with --fmu: the controller; default its data sheet)",
    )
    parser.add_argument(
        "--like",
        required=True,
        metavar="RECORDING.csv",
        help="servo trace whose position_reference, disturbance and time base drive the run",
    )
    parser.add_argument(
        "--out", type=cli.new_file, required=True, metavar="SIM.csv", help="simulated trace"
    )
    add_fmu_arguments(parser)


def run(args: argparse.Namespace) -> int:
    out = args.out
    source = axis_source(args, args.axis)
    axis = source.axis
    with plain_warnings():
        recording = read_trace(args.like)
        inp = prepare_replay(recording, axis, source=str(args.like))
    plant = source.plant if source.model is not None else None
    simulated = replay(axis, inp, plant=plant)
    like_recording(inp, simulated).to_csv(out)
    fits = signal_fits(inp, simulated)
    summary = ", ".join(f"{s} {f.fit_percent:.1f} %" for s, f in fits.items())
    print(f"wrote {out}: {len(recording)} rows; simulation fit to {args.like}: {summary}")
    return 0

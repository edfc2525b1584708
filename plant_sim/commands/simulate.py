"""``python -m plant_sim simulate --axis AXIS.toml --like RECORDING.csv --out SIM.csv``.

Simulates the axis file's closed loop (Fig. 1: P position controller, PI/P speed controller,
current loop, dead time, mechanics) driven by the recording's ``position_reference`` (and its
``disturbance`` column when present), on the recording's time base, and writes the simulated
trace with the recording's columns — how a fitted model (``diagnose``'s axis_fitted.toml) is
checked on a second recording. Prints the simulation's fit to the recording per signal.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from ..axis import load_axis
from ..diagnose.engine import signal_fits
from ..diagnose.errors import DiagnosisInputError
from ..diagnose.replay import like_recording, prepare_replay, replay
from ..trace import read_trace

NAME = "simulate"
HELP = (
    "simulate an axis file's closed loop like a recording (its position_reference, "
    "disturbance and time base) and write the simulated trace"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--axis", required=True, metavar="AXIS.toml", help="axis file to simulate")
    parser.add_argument(
        "--like",
        required=True,
        metavar="RECORDING.csv",
        help="servo trace whose position_reference, disturbance and time base drive the run",
    )
    parser.add_argument("--out", required=True, metavar="SIM.csv", help="simulated trace to write")


def print_warnings(caught: list[warnings.WarningMessage]) -> None:
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.is_dir():
        raise DiagnosisInputError(f"--out {out}: is a directory, expected a CSV file path")
    if not out.parent.exists():
        raise DiagnosisInputError(f"--out {out}: directory {out.parent} does not exist")
    axis = load_axis(args.axis)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        recording = read_trace(args.like)
        inp = prepare_replay(recording, axis, source=str(args.like))
    print_warnings(caught)
    simulated = replay(axis, inp)
    like_recording(inp, simulated).to_csv(out)
    fits = signal_fits(inp, simulated)
    summary = ", ".join(f"{s} {f.fit_percent:.1f} %" for s, f in fits.items())
    print(f"wrote {out}: {len(recording)} rows; simulation fit to {args.like}: {summary}")
    return 0

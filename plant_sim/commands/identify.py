"""``python -m plant_sim identify RECORDING.csv --axis AXIS.toml``: section IX identification.

Finds the unknown load mass and friction (Coulomb, viscous) of an axis from a servo trace by
Nelder-Mead on the closed-loop simulation error (:mod:`plant_sim.identification`). Prints a JSON
summary; ``--out FILE`` writes the identified axis file, ``--json FILE`` the summary.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cmdline import cli
from cmdline.progress import Progress
from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import dump_axis
from virtual_bus.formats.trace import check_time_base, read_trace

from ..errors import ScenarioError
from ..identification import SECTION_IX_PARAMETERS, IdentifyOptions, identify
from ..physics.model import KernelOptions
from .common import add_axis_argument, add_position_cycle_argument, plain_warnings, read_axis

NAME = "identify"
HELP = "identify load mass and friction from a servo trace (paper section IX, Nelder-Mead)"


def _key_value(text: str) -> tuple[str, float]:
    key, sep, raw = text.partition("=")
    try:
        if not sep or not key:
            raise ValueError
        return key.strip(), float(raw)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected KEY=VALUE, e.g. mechanics.load_mass=5000"
        ) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="servo trace (CSV, trace-file.md)")
    add_axis_argument(parser, default=None)
    parser.add_argument(
        "--param",
        action="append",
        metavar="KEY",
        help="axis key to identify (repeatable); default: " + ", ".join(SECTION_IX_PARAMETERS),
    )
    parser.add_argument(
        "--start",
        action="append",
        type=_key_value,
        default=[],
        metavar="KEY=VALUE",
        help="start value instead of the axis file's (repeatable)",
    )
    parser.add_argument(
        "--drop",
        action="append",
        default=[],
        metavar="KEY",
        help="leave this physics out of the model, e.g. mechanics.backlash (repeatable)",
    )
    add_position_cycle_argument(parser, "must match the trace's sample time")
    parser.add_argument(
        "--substeps",
        type=cli.bounded_int(1, 10_000),
        default=None,
        metavar="N",
        help="mechanics steps per speed cycle (default: fine enough for the speed loop)",
    )
    parser.add_argument("--out", type=cli.new_file, help="write the identified axis file here")
    parser.add_argument("--json", type=cli.new_file, help="write the JSON summary here")
    cli.add_quiet(parser)


def run(args: argparse.Namespace) -> int:
    axis = read_axis(args.axis, args.position_cycle)
    if args.drop:
        axis = axis.with_values(dict.fromkeys(args.drop))
    with plain_warnings():
        trace = read_trace(args.recording)
        check_time_base(trace, axis.control.position_cycle, str(args.recording))
    start = dict(args.start)
    if len(start) != len(args.start):
        raise ScenarioError("--start: a key is given more than once")
    options = IdentifyOptions(
        parameters=tuple(args.param) if args.param else SECTION_IX_PARAMETERS,
        kernel=None if args.substeps is None else KernelOptions(substeps=args.substeps),
    )
    progress = Progress(f"plant_sim {NAME}", quiet=args.quiet)
    with progress.bar(None, "Nelder-Mead on the closed-loop simulation", unit="sim") as bar:
        result = identify(trace, axis, start, options, on_evaluation=bar.update)
    summary = {"recording": str(args.recording), "axis_file": str(args.axis), **result.summary()}
    text = json.dumps(summary, indent=2)
    print(text)
    if args.json:
        write_atomic(args.json, text + "\n")
    if args.out:
        header = (
            f"Identified by `python -m plant_sim identify {args.recording} --axis {args.axis}`\n"
            "(paper section IX: Nelder-Mead on the closed-loop simulation error).\n"
            + "\n".join(
                f"{k}: start {result.start[k]:.6g} -> {v:.6g}" for k, v in result.values.items()
            )
        )
        write_atomic(args.out, dump_axis(result.axis, header))
    return 0

"""``python -m hil tune``: the paper's beta_T procedure on the simulated axis, offline."""

from __future__ import annotations

import argparse
import sys

from bridge.commands.tune import (
    add_tuning_arguments,
    options_from,
    result_line,
    trial_line,
    write_report,
)
from cmdline import cli

from .common import add_axis_and_out, simulated_source

NAME = "tune"
HELP = "find beta_T by the paper's procedure on the simulated axis (offline, fast)"
DESCRIPTION = (
    "The same provoking motions, trials, verdicts and search as `python -m bridge tune`, on "
    "the compiled kernel of the axis file (or an FMU's plant, --fmu) with the bridge's "
    "one-cycle PDO delay and its safety limits (2008h, 2014h, --torque-limit) checked on every "
    "cycle; offline the plant's disturbance input gives the load pulse too. Report: tune.json, "
    "trials.png. Exit 1 with the reason when no beta_T is found."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_axis_and_out(parser)
    parser.add_argument(
        "--following-error-limit",
        type=cli.positive_float,
        help="2008h, load units (default: the bridge's for this axis)",
    )
    parser.add_argument(
        "--travel",
        type=cli.number_list,
        metavar="MIN,MAX",
        help="2014h, load units the axis may reach (default: the bridge's); the axis starts at 0",
    )
    add_tuning_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from bridge.params import BridgeParams
    from regulator.tuning import Outcome, TuningError, TuningInputError

    from ..offline import base_regulator, tune_offline

    source = simulated_source(args, args.axis)
    axis = source.axis
    options = options_from(args, axis)
    travel = None
    if args.travel is not None:
        if len(args.travel) != 2 or not args.travel[0] < 0.0 < args.travel[1]:
            raise cli.UsageError("--travel: MIN,MAX in load units with MIN < 0 < MAX")
        travel = (float(args.travel[0]), float(args.travel[1]))
    bridge_params = BridgeParams.for_axis(axis, base_regulator(axis))
    limit = args.following_error_limit or bridge_params.following_error_limit
    unit = axis.load_unit
    try:
        result = tune_offline(
            source,
            options,
            limit,
            travel,
            on_trial=lambda t: print(trial_line(t, unit), flush=True),
        )
    except TuningInputError as exc:
        raise cli.UsageError(f"{exc}; nothing run, nothing written") from None
    except TuningError as exc:
        print(f"python -m hil tune: {exc}", file=sys.stderr)
        return 1
    write_report(result, axis.control.position_cycle, args.out, {"axis": source.name})
    if result.outcome is not Outcome.FOUND:
        print(f"python -m hil tune: {result.reason}", file=sys.stderr)
        return 1
    print(result_line(result))
    return 0

"""``python -m hil tune``: the paper's beta_T procedure on the simulated axis, offline."""

from __future__ import annotations

import argparse
import sys

from bridge.commands.tune import add_tuning_arguments, options_from, trial_line, write_report
from cmdline import cli

from .common import add_axis_and_out, simulated_source

NAME = "tune"
HELP = "find beta_T by the paper's procedure on the simulated axis (offline, fast)"
DESCRIPTION = (
    "The same test motion, trials, verdicts and search as `python -m bridge tune`, on the "
    "compiled kernel of the axis file (or an FMU's plant, --fmu) with the bridge's one-cycle "
    "PDO delay and its safety limits (2008h, 2014h, --torque-limit) checked on every cycle. "
    "Report: tune.json, trials.png. Exit 1 with the reason when no beta_T is found."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_axis_and_out(parser)
    parser.add_argument(
        "--following-error-limit",
        type=cli.positive_float,
        help="2008h, load units (default: the bridge's for this axis)",
    )
    add_tuning_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from bridge.params import BridgeParams
    from regulator.tuning import Outcome, TuningError, search

    from ..offline import base_regulator, plant_runner, safety_of

    source = simulated_source(args, args.axis)
    axis = source.axis
    options = options_from(args)
    bridge_params = BridgeParams.for_axis(axis, base_regulator(axis))
    limit = args.following_error_limit or bridge_params.following_error_limit
    cycle_s, kv = axis.control.position_cycle, axis.control.kv
    profile = options.motion.profile(cycle_s, kv).repeated(options.repeats)
    safety = safety_of(axis, limit, options.torque_limit)
    runner = plant_runner(source, profile, safety)
    try:
        result = search(
            runner,
            profile,
            options.search,
            cycle_s,
            kv,
            options.standstill_limit,
            velocity_feedforward=axis.control.velocity_feedforward or 0.0,
            on_trial=lambda t: print(trial_line(t), flush=True),
        )
    except TuningError as exc:
        print(f"python -m hil tune: {exc}", file=sys.stderr)
        return 1
    write_report(result, cycle_s, args.out, {"axis": source.name})
    if result.outcome is not Outcome.FOUND:
        print(f"python -m hil tune: {result.reason}", file=sys.stderr)
        return 1
    print(f"beta_T = {result.beta_t_rad_s:.4g} rad/s; {result.reason}")
    return 0

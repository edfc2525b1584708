"""``python -m bridge tune``: the paper's beta_T procedure over the bus (section VIII)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cmdline import cli
from regulator.tuning import (
    Outcome,
    SearchConfig,
    SearchResult,
    TrialResult,
    TuningError,
    TuningInputError,
    Verdict,
)
from regulator.units import length

from ..commission.session import CommissioningStopped

if TYPE_CHECKING:
    from virtual_bus.formats.axis import AxisConfig

    from ..commission.tune import TuneOptions

NAME = "tune"
HELP = "find beta_T (eq. 15) by the paper's procedure over the bus; write and store it"
DESCRIPTION = (
    "Start the drive like `bridge run`; with the regulator off, play test motions of rising "
    "severity (your --motion, a deceleration into the gap, a sharper one sized by the torque "
    "the first one measured, a creep feed, a reversal) until one provokes the limit cycle; "
    "then play it with beta_T from small values upwards until the first sign of vibration; "
    "back off by --margin as far as the axis stays exact at rest, confirm, write 2002h and "
    "store it (1010h). Report: tune.json, trials.png. Any stop reason, --torque-limit, or no "
    "result: the axis stops or is disabled with the reason (exit 1) and nothing is stored."
)

#: The motion options and the TuningMotion fields they set (None: adapted to the axis).
MOTION_OPTIONS = (
    (
        "feed",
        "load units/s at the start of each run (default: 50 mm/s, lower where eq. 1's "
        "following error would pass 40 %% of 2008h)",
    ),
    ("low_feed", "load units/s after the deceleration (default: 40 %% of --feed)"),
    ("accel", "load units/s² of the default motion (default: --feed in 0.5 s)"),
    ("high_s", "s at --feed (default: 10 / k_v, at least 0.5)"),
    ("low_s", "s at --low-feed, the watch window (default: 2 T_v = 40 / k_v)"),
    ("dwell_s", "s at rest, the bound of the wait for the standstill accuracy (default: 3 T_v)"),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .session_args import add_bus_arguments

    add_bus_arguments(parser)
    add_tuning_arguments(parser)


def add_tuning_arguments(parser: argparse.ArgumentParser) -> None:
    """The test motion, the search and the limits (shared with ``python -m hil tune``)."""
    s = SearchConfig()
    pf = cli.positive_float
    parser.add_argument("--torque-limit", type=pf, required=True, help="N m (or per mille)")
    for name, text in MOTION_OPTIONS:
        parser.add_argument("--" + name.replace("_", "-"), type=pf, help=text)
    parser.add_argument(
        "--motion",
        type=cli.existing_file,
        metavar="FILE",
        help="your own test motion, tried first: a trace file (docs/trace-file.md) with time "
        "and position_reference, relative to its start, coming back to it",
    )
    parser.add_argument("--repeats", type=cli.count, default=2, help="runs per trial (2)")
    parser.add_argument(
        "--beta-t-start", type=pf, help="rad/s (default: the limit cycle's beta / 64)"
    )
    parser.add_argument("--factor", type=pf, default=s.factor, help="between trials (2)")
    parser.add_argument(
        "--beta-t-max", type=pf, help="rad/s (default: the limit cycle's beta x 16)"
    )
    parser.add_argument("--margin", type=pf, default=s.margin, help="back-off factor (2)")
    parser.add_argument(
        "--vibration-fraction",
        type=pf,
        default=s.vibration_fraction,
        help="vibration = this share of the regulator-off limit cycle (0.1)",
    )
    parser.add_argument(
        "--standstill-limit",
        type=pf,
        default=1e-6,
        help="load units the result reaches at rest within the dwell (1e-6: 1 µm)",
    )


def trial_line(trial: TrialResult, unit: str = "m") -> str:
    """One line per trial, lengths in µm / mm."""
    m = trial.metrics
    if trial.beta_t_rad_s is None:
        name = f"regulator off, {trial.motion}"
        verdict = "limit cycle" if trial.verdict is Verdict.VIBRATING else trial.verdict.value
        if trial.verdict is Verdict.STABLE:
            verdict = "no limit cycle"
    else:
        name = f"beta_T {trial.beta_t_rad_s:<7.4g} rad/s"
        verdict = trial.verdict.value
    if m is None:
        return f"trial {name}: {verdict} ({trial.reason})"
    numbers = (
        f"oscillation {length(m.vibration, unit)}, standstill {length(m.standstill_error, unit)}"
    )
    if trial.beta_t_rad_s is not None:
        if not math.isnan(m.settle_s):
            numbers += f" after {m.settle_s:.2f} s"
        numbers += (
            f", lambda at rest {m.lambda_at_rest:.2f}, following error "
            f"{length(m.following_deviation, unit)} off eq. 1"
        )
        if trial.verdict is not Verdict.STABLE:
            numbers += f" ({trial.reason})"
    return f"trial {name}: {verdict}, {numbers}"


def options_from(args: argparse.Namespace, axis: AxisConfig) -> TuneOptions:
    """The validated options of ``args`` (UsageError, exit 2, for bad combinations or a bad
    motion file), checked against ``axis`` (k_v, the cycle)."""
    from virtual_bus.formats.trace import read_trace

    from ..commission.tune import MotionSamples, TuneOptions
    from ..params import BridgeParams

    changes = tuple(
        (name, getattr(args, name)) for name, _ in MOTION_OPTIONS if getattr(args, name) is not None
    )
    user = None
    if args.motion is not None:
        trace = read_trace(args.motion, required=("time", "position_reference"))
        user = MotionSamples(trace.time, trace["position_reference"], f"{args.motion.name}")
    try:
        options = TuneOptions(
            motion_changes=changes,
            user_motion=user,
            repeats=args.repeats,
            search=SearchConfig(
                args.beta_t_start,
                args.factor,
                args.beta_t_max,
                args.margin,
                args.vibration_fraction,
            ),
            standstill_limit=args.standstill_limit,
            torque_limit=args.torque_limit,
        )
        kv, cycle_s = axis.control.kv, axis.control.position_cycle
        following = BridgeParams.for_axis(axis).following_error_limit
        base = options.base_motion(kv, following)
        base.profile(cycle_s, kv)
        if user is not None:
            user.profile(cycle_s, kv, base.times(kv)[2])
    except ValueError as exc:
        raise cli.UsageError(str(exc)) from None
    return options


def write_report(result: SearchResult, cycle_s: float, out: Path, extra: dict) -> None:
    """tune.json (the search and ``extra``) and trials.png in ``out``; prints the files
    (shared with ``python -m hil tune``)."""
    from ..commission.figures import available, search_dict, trials_figure, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "tune.json", search_dict(result) | extra)
    if available():
        trials_figure(result, cycle_s, out / "trials.png")
        print(f"wrote {out / 'tune.json'}, {out / 'trials.png'}")
    else:
        print(f"wrote {out / 'tune.json'} (trials.png not drawn: matplotlib is not installed)")


def result_line(result: SearchResult) -> str:
    """The result and what it costs."""
    return f"beta_T = {result.beta_t_rad_s:.4g} rad/s; {result.reason}; {result.cost}"


def run(args: argparse.Namespace) -> int:
    from ..commission.tune import tune
    from .common import regulated_axis
    from .session_args import started_bridge

    axis = regulated_axis(args.axis)
    options = options_from(args, axis)
    unit = axis.load_unit
    with started_bridge(args) as bridge:
        cycle_s = bridge.controller.params.cycle_s
        try:
            report = tune(
                bridge, options, axis, on_trial=lambda t: print(trial_line(t, unit), flush=True)
            )
        except TuningInputError as exc:
            raise cli.UsageError(f"{exc}; nothing moved, nothing stored") from None
        except (TuningError, CommissioningStopped) as exc:
            print(f"python -m bridge tune: {exc}; nothing stored", file=sys.stderr)
            return 1
    result = report.result
    write_report(result, cycle_s, args.out, {"stored": report.stored, "store": report.store_path})
    if result.outcome is not Outcome.FOUND:
        print(f"python -m bridge tune: {result.reason}; nothing stored", file=sys.stderr)
        return 1
    where = f"stored in {report.store_path} (1010h)" if report.stored else "not stored"
    print(f"{result_line(result)}; written to 2002h, {where}")
    return 0

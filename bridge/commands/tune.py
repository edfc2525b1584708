"""``python -m bridge tune``: the paper's beta_T procedure over the bus (section VIII)."""

from __future__ import annotations

import argparse
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
    TuningMotion,
)

from ..commission.session import CommissioningStopped

if TYPE_CHECKING:
    from ..commission.tune import TuneOptions

NAME = "tune"
HELP = "find beta_T (eq. 15) by the paper's procedure over the bus; write and store it"
DESCRIPTION = (
    "Start the drive like `bridge run`, play a test motion (a deceleration that provokes the "
    "limit cycle, in both directions, back to the start) first with the regulator off, then "
    "with beta_T from small values upwards until the first sign of vibration; back off by "
    "--margin, confirm, then write 2002h and store it (1010h). Report: tune.json, trials.png. "
    "Any stop reason, --torque-limit, or no result: the axis stops or is disabled with the "
    "reason (exit 1) and nothing is stored."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .session_args import add_bus_arguments

    add_bus_arguments(parser)
    add_tuning_arguments(parser)


def add_tuning_arguments(parser: argparse.ArgumentParser) -> None:
    """The test motion, the search and the limits (shared with ``python -m hil tune``)."""
    d = TuningMotion()
    s = SearchConfig()
    pf = cli.positive_float
    parser.add_argument("--torque-limit", type=pf, required=True, help="N m (or per mille)")
    parser.add_argument("--feed", type=pf, default=d.feed, help=f"load units/s ({d.feed:g})")
    parser.add_argument("--low-feed", type=pf, default=d.low_feed, help=f"({d.low_feed:g})")
    parser.add_argument("--accel", type=pf, default=d.accel, help=f"load units/s^2 ({d.accel:g})")
    parser.add_argument("--high-s", type=pf, default=d.high_s, help=f"s at feed ({d.high_s:g})")
    parser.add_argument("--low-s", type=pf, default=d.low_s, help=f"s at low feed ({d.low_s:g})")
    parser.add_argument("--dwell-s", type=pf, default=d.dwell_s, help=f"s at rest ({d.dwell_s:g})")
    parser.add_argument("--repeats", type=cli.count, default=2, help="runs per trial (2)")
    parser.add_argument("--beta-t-start", type=pf, default=s.start_rad_s, help="rad/s (0.01)")
    parser.add_argument("--factor", type=pf, default=s.factor, help="between trials (2)")
    parser.add_argument("--beta-t-max", type=pf, default=s.max_rad_s, help="rad/s (100)")
    parser.add_argument("--margin", type=pf, default=s.margin, help="back-off factor (2)")
    parser.add_argument(
        "--vibration-fraction",
        type=pf,
        default=s.vibration_fraction,
        help="vibration = this share of the regulator-off limit cycle (0.1)",
    )
    parser.add_argument(
        "--standstill-limit", type=pf, default=1e-6, help="load units the result holds (1e-6)"
    )


def trial_line(trial: TrialResult) -> str:
    name = "regulator off" if trial.beta_t_rad_s is None else f"beta_T {trial.beta_t_rad_s:<8.4g}"
    m = trial.metrics
    numbers = (
        ""
        if m is None
        else f" oscillation {m.vibration:.3g}, standstill {m.standstill_error:.3g}, "
        f"lambda at rest {m.lambda_at_rest:.3f}"
    )
    return f"trial {name}: {trial.verdict.value}{numbers} ({trial.reason})"


def options_from(args: argparse.Namespace) -> TuneOptions:
    """The validated options of ``args`` (UsageError, exit 2, for bad combinations)."""
    from ..commission.tune import TuneOptions

    try:
        return TuneOptions(
            motion=TuningMotion(
                args.feed, args.low_feed, args.accel, args.high_s, args.low_s, args.dwell_s
            ),
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
    except ValueError as exc:
        raise cli.UsageError(str(exc)) from None


def write_report(result: SearchResult, cycle_s: float, out: Path, extra: dict) -> None:
    """tune.json (the search and ``extra``) and trials.png in ``out``; prints the files
    (shared with ``python -m hil tune``)."""
    from ..commission.figures import available, search_dict, trials_figure, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "tune.json", search_dict(result) | extra)
    if available():
        trials_figure(result, cycle_s, out / "trials.png", 1e6)
        print(f"wrote {out / 'tune.json'}, {out / 'trials.png'}")
    else:
        print(f"wrote {out / 'tune.json'} (trials.png not drawn: matplotlib is not installed)")


def run(args: argparse.Namespace) -> int:
    from ..commission.tune import tune
    from .session_args import started_bridge

    options = options_from(args)
    with started_bridge(args) as bridge:
        cycle_s = bridge.controller.params.cycle_s
        try:
            report = tune(bridge, options, on_trial=lambda t: print(trial_line(t), flush=True))
        except (TuningError, CommissioningStopped) as exc:
            print(f"python -m bridge tune: {exc}; nothing stored", file=sys.stderr)
            return 1
    result = report.result
    write_report(result, cycle_s, args.out, {"stored": report.stored, "store": report.store_path})
    if result.outcome is not Outcome.FOUND:
        print(f"python -m bridge tune: {result.reason}; nothing stored", file=sys.stderr)
        return 1
    where = f"stored in {report.store_path} (1010h)" if report.stored else "not stored"
    print(f"beta_T = {result.beta_t_rad_s:.4g} rad/s written to 2002h, {where}; {result.reason}")
    return 0

"""``python -m diagnosis diagnose RECORDING.csv --axis AXIS.toml --out DIR``.

Says where and when a recording of a real axis and its nominal model differ, which physics
of the axis-file table the model leaves out, adds and fits it, and shows the fit improving on
held-out data. Prints a summary (what is wrong, the evidence, the fit before and after, what
stays unexplained and where, the next experiment) and writes DIR/report.html (the same as a
page, with figures), DIR/report.json, DIR/axis_fitted.toml, DIR/fit_before.csv,
DIR/fit_after.csv and DIR/report.png (see docs/diagnosis.md).
"""

from __future__ import annotations

import argparse
import warnings

from cmdline import cli
from cmdline.progress import Progress
from plant_sim.commands.common import plain_warnings
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.errors import TraceWarning
from virtual_bus.formats.trace import read_trace

from ..effects import Effect
from ..engine import DiagnosisOptions, diagnose, prepare
from ..report import REPORT_FILES, write_report
from ..summary import text_summary

NAME = "diagnose"
HELP = (
    "find which physics an axis file leaves out of a recording, fit it, and report "
    "(report.html, report.json, axis_fitted.toml, fit_before/after.csv, report.png)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="RECORDING.csv", help="servo trace (trace-file.md)")
    parser.add_argument("--axis", required=True, metavar="AXIS.toml", help="nominal axis file")
    parser.add_argument(
        "--out", type=cli.output_dir, required=True, metavar="DIR", help="report directory"
    )
    parser.add_argument(
        "--validate",
        nargs="+",
        metavar="SECOND.csv",
        help="one or more other recordings of the same axis to score the fitted models on "
        "and decide between ambiguous explanations (default: held-out blocks of the first)",
    )
    parser.add_argument(
        "--alpha",
        type=float,
        default=0.01,
        help="false-alarm rate per recording of the evidence stage, divided among the effects "
        "tested (0.01)",
    )
    parser.add_argument(
        "--choice-alpha",
        type=float,
        default=0.05,
        help="level at which the held-out data name an ambiguous alternative over the "
        "evidence's choice (0.05)",
    )
    parser.add_argument(
        "--min-improvement",
        type=float,
        default=0.5,
        help="least held-out cost reduction for a named effect to stay named and for that "
        "choice, per cent (0.5)",
    )
    parser.add_argument(
        "--max-effects", type=int, default=3, help="most effects named (rounds of selection, 3)"
    )
    parser.add_argument(
        "--effects",
        nargs="+",
        metavar="EFFECT",
        choices=[e.value for e in Effect],
        help="only try these effects (default: every effect of the axis-file table)",
    )
    parser.add_argument("--jobs", type=int, default=2, help="simulations in parallel (2)")
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the bootstrap and of the replays' noise"
    )
    cli.add_quiet(parser)
    parser.add_argument("--no-progress", action="store_true", help="the same as --quiet")


def run(args: argparse.Namespace) -> int:
    options = DiagnosisOptions(
        alpha=args.alpha,
        choice_alpha=args.choice_alpha,
        min_improvement=args.min_improvement / 100.0,
        max_effects=args.max_effects,
        jobs=args.jobs,
        seed=args.seed,
        effects=tuple(Effect(e) for e in args.effects) if args.effects else tuple(Effect),
    )
    out = args.out
    axis = load_axis(args.axis)
    with plain_warnings():
        recording = read_trace(args.recording)
        validation = [read_trace(v) for v in args.validate or ()]
        # the one check that axis and recordings fit together, before any long work; the
        # diagnosis goes on from it
        prepared = prepare(
            recording,
            axis,
            validation or None,
            options,
            sources=(str(args.recording), *(str(v) for v in args.validate or ())),
        )
    progress = Progress(f"diagnosis {NAME}", quiet=args.quiet or args.no_progress)
    with progress.bar(None, "diagnose", unit="sim") as bar, warnings.catch_warnings():
        warnings.simplefilter("ignore", TraceWarning)  # already printed above
        warnings.simplefilter("ignore", RuntimeWarning)  # unstable trial parameter sets
        diagnosis = diagnose(recording, axis, validation or None, options, bar, prepared)
    write_report(diagnosis, out, source=str(args.recording), axis_source=str(args.axis))
    written = [name for name in REPORT_FILES if (out / name).exists()]
    files = [f"{out}/: " + ", ".join(written)]
    for line in text_summary(diagnosis, str(args.recording), files):
        print(line)
    return 0

"""``python -m diagnosis matrix [--plant kernel|independent|third] [--seed 2] [--out DIR] ...``.

Runs the diagnosis on the plant's concealed test set
and prints the markdown tables of :mod:`diagnosis.matrix` (confusion matrix,
per-case results, timings). The full set takes several minutes (one diagnosis per case).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from cmdline import cli
from cmdline.progress import Progress
from virtual_bus.atomic import write_atomic
from virtual_bus.formats.records import RecordFile

from ..matrix import (
    PLANTS,
    CaseResult,
    cases_markdown,
    confusion_markdown,
    load_plant,
    run_matrix,
)

NAME = "matrix"
HELP = "confusion matrix of the diagnosis on the concealed test set (several minutes)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--plant",
        choices=sorted(PLANTS),
        default="kernel",
        help="plant that makes the recordings: kernel (this package's, default), independent "
        "or third (the test suite's independently written plants; third has its own test set)",
    )
    parser.add_argument(
        "--out", type=Path, help="also write DIR/matrix_<plant>_seed<S>.md and .jsonl"
    )
    parser.add_argument("--seed", type=int, default=2, help="test-set seed (default 2)")
    parser.add_argument(
        "--duration",
        type=cli.bounded_float(5.0, 600.0),
        default=25.0,
        metavar="S",
        help="seconds per recording, 5..600 (default 25)",
    )
    parser.add_argument(
        "--cases", nargs="+", default=None, metavar="NAME", help="case names (default all)"
    )
    parser.add_argument(
        "--validate",
        type=cli.bounded_int(0, 3),
        default=0,
        metavar="N",
        help="hold out N second recordings of each case's hidden truth, made at another time "
        "(new moves, unrecorded load and noise), as diagnose --validate does; 0..3 (default 0: "
        "interleaved blocks of the one recording)",
    )
    parser.add_argument("--json", type=cli.new_file, help="also write the results (JSON lines)")
    cli.add_quiet(parser)


def run(args: argparse.Namespace) -> int:
    try:
        plant = load_plant(args.plant)
    except ValueError as exc:
        raise cli.UsageError(f"--plant: {exc}") from None
    stem = f"matrix_{args.plant}_seed{args.seed}" + (
        f"_validate{args.validate}" if args.validate else ""
    )
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        if args.json is None:
            args.json = args.out / f"{stem}.jsonl"
    cases = plant.cases(args.seed, args.duration)
    if args.cases:
        known = {c.name for c in cases}
        unknown = [n for n in args.cases if n not in known]
        if unknown:
            raise cli.UsageError(f"--cases: unknown {unknown}; known: {sorted(known)}")
        cases = [c for c in cases if c.name in args.cases]
    progress = Progress(f"diagnosis {NAME}", quiet=args.quiet)
    # a JSON line per case as it completes: a kill leaves whole lines, the last perhaps cut
    # short without its line end (virtual_bus.formats.records)
    sink = RecordFile(args.json, pad=False) if args.json else None

    with progress.bar(len(cases), "diagnoses", unit="case") as bar:

        def on_result(r: CaseResult) -> None:
            bar.update()
            bar.set_description(f"{r.name}: {r.left_out or 'nothing'} ({r.seconds:.0f} s)")
            if sink is not None:
                sink.write_lines([json.dumps(asdict(r)) + "\n"])

        failed: list[str] = []

        def on_error(case: object, exc: Exception) -> None:
            line = f"{case.name}: diagnosis failed ({type(exc).__name__}: {exc})"  # type: ignore[attr-defined]
            progress.stage(line)
            failed.append(line)

        try:
            results = run_matrix(
                cases, on_result=on_result, plant=plant, on_error=on_error, validate=args.validate
            )
        finally:
            if sink is not None:
                sink.close()
    text = (
        f"Plant: {plant.name}, seed {args.seed}, {args.duration:g} s per recording"
        + (
            f", {args.validate} second recording(s) of each held out (--validate).\n\n"
            if args.validate
            else ", interleaved blocks held out.\n\n"
        )
        + confusion_markdown(results)
        + "\n\n"
        + cases_markdown(results)
        + "\n"
        + "".join(f"\nNot counted: {line}" for line in failed)
        + ("\n" if failed else "")
    )
    print(text, end="")
    if args.out is not None:
        write_atomic(args.out / f"{stem}.md", text)
    return 0

"""``python -m hil sweep TASK --fmu FMU --seeds 1000-1299 --out DIR``: one task over many
axes of an FMU family, as Dask tasks, resumable; a Parquet table and its summary
(hil/sweep/runner.py)."""

from __future__ import annotations

import argparse
import json

from cmdline import cli
from cmdline.progress import Progress
from plant_sim.fmu.arguments import add_fmu_arguments, fmu_spec

NAME = "sweep"
HELP = "one task (limit-cycle, ...) over many seeds of an FMU family, on Dask"
DESCRIPTION = (
    "Runs TASK on the axis each seed draws from the FMU (its other parameters as given), as "
    "Dask tasks on local processes (--workers) or a cluster (--scheduler); each finished seed "
    "is a Parquet part in DIR/parts, so a sweep started again with the same --out and options "
    "runs only what is missing. Writes DIR/results.parquet and DIR/summary.json and prints "
    "the summary."
)


def _option(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name or not value:
        raise argparse.ArgumentTypeError(f"{text!r}: write NAME=VALUE")
    return name, value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..sweep.tasks import TASKS

    parser.add_argument("task", choices=sorted(TASKS), help="what runs on each axis")
    parser.add_argument(
        "--seeds", required=True, metavar="N-M,...", help="seeds, e.g. 1000-1299 or 1,5,9"
    )
    cli.add_output_dir(parser, "sweep folder")
    parser.add_argument(
        "--option",
        type=_option,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a task option (repeatable)",
    )
    cli.add_dask(parser)
    add_fmu_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from plant_sim.errors import FmuError

    from ..sweep.runner import Sweep, parse_seeds, run_sweep

    spec = fmu_spec(args)
    if spec is None:
        raise FmuError("give --fmu FMU (the family the seeds draw from)")
    spec.load()  # checked before anything runs
    sweep = Sweep(args.task, spec, parse_seeds(args.seeds), args.out, dict(args.option))
    todo = sweep.prepare()
    progress = Progress(f"hil {NAME}", quiet=args.quiet)
    done_before = len(sweep.seeds) - len(todo)
    progress.stage(
        f"{args.task} on {len(sweep.seeds)} axes of {spec.describe()}"
        + (f" ({done_before} done before, resumed)" if done_before else "")
        + (f" on {args.scheduler}" if args.scheduler else f", {args.workers} workers")
    )
    with progress.bar(len(todo), args.task, "seed") as bar:
        summary = run_sweep(sweep, args.workers, args.scheduler, on_row=lambda _r: bar.update())
    print(json.dumps(summary, indent=2))
    print(f"wrote {args.out}/: results.parquet, summary.json, sweep.json, parts/")
    return 0

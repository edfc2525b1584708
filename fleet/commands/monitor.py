"""``python -m fleet monitor PATH... --out DIR``: condition monitoring of a fleet.

Finds every trace file (``*.csv``) and candump log (``*.log``) under the paths, runs the
paper's vibration detector (Fig. 5) over each, gives each vibration episode its eq. 13 band
verdict, estimates the backlash at reversals where both measuring systems are recorded, and
writes per-recording, per-episode and per-axis tables (CSV and Parquet), the fleet's Fig. 4,
the backlash trends, and ``index.html`` with the ranked list of axes to inspect. Runs on Dask:
local processes (``--workers``) or an existing cluster (``--scheduler``). ``--demo``
simulates a fleet with a known truth first and prints the confusion matrix.

Exit status: 0 when at least one recording was processed (bad files are listed, one line
each), 1 when none could be, 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cmdline import cli
from cmdline.progress import Progress
from plant_sim.errors import SchedulerError
from plant_sim.physics.warm import warm_up
from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import load_axis
from virtual_bus.shipped import PAPER_AXIS

from ..demo_fleet import FleetSpec, generate
from ..errors import FleetError, FleetMapError
from ..job import confusion, confusion_markdown, monitor
from ..ranking import Limits
from ..sources import discover, load_axis_map

NAME = "monitor"
HELP = "condition monitoring of a fleet: vibration episodes, eq. 13 verdicts, backlash trends"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_inputs(
        parser,
        "paths",
        "recordings or folders (MACHINE/AXIS/DATE... layout), recursively",
        metavar="PATH",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--axis", type=Path, help="one axis file for every recording")
    group.add_argument(
        "--axes",
        type=Path,
        metavar="MAP.toml",
        help="axis map: axis file per machine/axis (docs/monitor.md)",
    )
    parser.add_argument(
        "--drive-profile",
        type=Path,
        metavar="P.toml",
        help="decode candump logs with this drive profile's scaling (config/drives/*.toml)",
    )
    cli.add_dask(parser)
    parser.add_argument(
        "--growth-limit",
        type=cli.positive_float,
        default=5.0,
        metavar="UM_PER_MONTH",
        help="warn when backlash grows faster, µm (or µrad) per month (default 5)",
    )
    parser.add_argument(
        "--backlash-limit",
        type=cli.positive_float,
        default=50.0,
        metavar="UM",
        help="flag a backlash above this, µm (or µrad) (default 50)",
    )
    parser.add_argument(
        "--demo",
        action="store_true",
        help="simulate a demo fleet into OUT/demo_fleet first and monitor it",
    )
    parser.add_argument(
        "--demo-size",
        default="4x3x12",
        metavar="MxAxR",
        help="demo fleet: machines x axes x recordings per axis (default 4x3x12)",
    )
    parser.add_argument("--no-figures", action="store_true", help="tables only")


def _demo_size(text: str) -> FleetSpec:
    try:
        m, a, r = (int(x) for x in text.lower().split("x"))
        return FleetSpec(machines=m, axes_per_machine=a, recordings_per_axis=r)
    except ValueError:
        raise FleetError(f"--demo-size {text!r}: expected MxAxR, e.g. 4x3x12") from None


def run(args: argparse.Namespace) -> int:
    progress = Progress("fleet monitor", quiet=args.quiet)
    if args.out.exists() and not args.out.is_dir():
        raise FleetError(f"--out {args.out}: exists and is not a folder")
    paths = list(args.paths)
    truth_file = None
    axis_map = None
    if args.demo:
        spec = _demo_size(args.demo_size)
        if min(spec.machines, spec.axes_per_machine, spec.recordings_per_axis) < 1:
            raise FleetError("--demo-size: every count must be >= 1")
        fleet = args.out / "demo_fleet"
        total = spec.machines * spec.axes_per_machine * spec.recordings_per_axis
        progress.stage(
            "loading the simulator's compiled kernel (numba): a first run compiles it, about a "
            "minute on two busy cores"
        )
        progress.stage(warm_up(load_axis(PAPER_AXIS), bridge=False).sentence())
        with progress.bar(total, f"simulating a demo fleet into {fleet}", "recording") as sim:

            def simulated(done: int, n: int) -> None:
                sim.update()
                if done % spec.recordings_per_axis == 0 and not progress.terminal:
                    sim.set_description(f"simulated {done} of {n} recordings")

            generate(fleet, spec, progress=simulated)
        paths = [fleet]
        truth_file = fleet / "truth.json"
        axis_map = load_axis_map(fleet / "axes.toml")
    elif not paths:
        raise FleetError("no PATH given: name recordings or folders (or use --demo)")
    if args.axes is not None:
        axis_map = load_axis_map(args.axes)
    if args.drive_profile is not None and not args.drive_profile.is_file():
        raise FleetError(f"--drive-profile {args.drive_profile}: no such file")
    found = discover(
        paths, axis_file=args.axis, axis_map=axis_map, drive_profile=args.drive_profile
    )
    for p in found.missing_paths:
        print(f"monitor: {p}: no such file or folder (skipped)", file=sys.stderr)
    if not found.sources:
        print("monitor: no recordings (*.csv, *.log) found", file=sys.stderr)
        return 1
    where = args.scheduler or (
        f"{args.workers} local processes" if args.workers else "this process"
    )
    bar = progress.bar(len(found.sources), f"analysing on {where}", "recording")

    def on_result(result: object) -> None:
        bar.update()

    limits = Limits(growth_per_month=args.growth_limit * 1e-6, backlash=args.backlash_limit * 1e-6)
    try:
        result = monitor(
            found,
            args.out,
            limits,
            workers=args.workers,
            scheduler=args.scheduler,
            figures=not args.no_figures,
            on_result=on_result,
        )
    except SchedulerError as exc:
        print(f"python -m fleet monitor: {exc}", file=sys.stderr)
        return 1
    finally:
        bar.close()
    for r in result.results:
        if r.warning:
            print(f"monitor: warning: {r.warning}", file=sys.stderr)
        if not r.ok:
            print(f"monitor: skipped {r.error}", file=sys.stderr)
    rate = len(result.results) / result.elapsed_s * 60 if result.elapsed_s > 0 else 0.0
    print(
        f"monitor: {result.processed} recordings analysed, {result.failed} skipped, "
        f"{len(result.ranked)} axes, {result.elapsed_s:.1f} s ({rate:.0f} recordings/min)"
    )
    urgent = [t for t in result.ranked if t.reasons][:10]
    for i, t in enumerate(urgent, 1):
        print(f"  {i:2d}. {t.axis_id}: {'; '.join(t.reasons)}")
    if truth_file is not None:
        matrix = confusion(result.ranked, truth_file)
        write_atomic(args.out / "confusion.json", json.dumps(matrix, indent=1))
        print("demo fleet, axes by truth (rows) and monitor verdict (columns):")
        print(confusion_markdown(matrix))
    print("wrote " + ", ".join(str(f) for f in result.files))
    return 0 if result.processed else 1


__all__ = ["HELP", "NAME", "FleetMapError", "add_arguments", "run"]

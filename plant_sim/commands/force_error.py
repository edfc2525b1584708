"""``python -m plant_sim force_error --axis AXIS.toml TRACE.csv ...``: relative force error.

100·||F_meas − F_sim||/||F_meas|| (percent) of an axis file simulated in the loop of each
recording (:mod:`plant_sim.datasets.force_error`, docs/emps.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline.progress import Progress
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import read_trace

from ..datasets.force_error import check_replay_input, relative_force_error
from .common import plain_warnings

NAME = "force_error"
HELP = "relative force error (percent) of an axis file simulated in the loop of recordings"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("traces", nargs="+", type=Path, metavar="TRACE.csv", help="trace files")
    parser.add_argument("--axis", type=Path, required=True, metavar="AXIS.toml", help="axis file")


def run(args: argparse.Namespace) -> int:
    axis = load_axis(args.axis)
    with plain_warnings():
        traces = [(path, read_trace(path)) for path in args.traces]
        for path, trace in traces:
            check_replay_input(axis, trace, str(path))  # every file before the first replay
    progress = Progress(f"plant_sim {NAME}", quiet=args.quiet)
    results = []
    with progress.bar(len(traces), "simulate in the loop of each recording", "trace") as bar:
        for path, trace in traces:
            results.append((path, relative_force_error(axis, trace)))
            bar.update()
    for path, result in results:
        print(
            f"{path}: {result.percent:.3f} % ({result.rows} rows, error {result.error_rms:.4g} "
            f"rms of {result.measured_rms:.4g} rms)"
        )
    return 0

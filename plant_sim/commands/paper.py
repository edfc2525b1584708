"""``python -m plant_sim paper --out DIR``: reproduce section X (Fig. 8 and Fig. 9).

Runs the axis file (default: the paper's axis) with the ordinary control and with the
regulator. With the paper's own friction (viscous 57.3 N·m per m/s) the axis shows no
sustained limit cycle after the disturbance (docs/paper_reproduction.md explains why); the
command then also runs the same axis with the viscous friction lowered to
``plant_sim.paper.outputs.LIMIT_CYCLE_VISCOUS`` — the physical value that makes section X's result
appear — and draws the figures from that variant, saying so in the figures, on the terminal
and in summary.json (which holds both).
"""

from __future__ import annotations

import argparse
import json

from cmdline import cli
from cmdline.progress import Progress
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from ..paper.outputs import (
    files_line,
    limit_cycle_variant,
    summarize,
    write_as_given,
    write_paper_outputs,
)
from ..paper.scenarios import SectionX, run_section_x
from .common import add_axis_argument, add_position_cycle_argument, regulated_axis

NAME = "paper"
HELP = "reproduce the paper's section X (Fig. 8, Fig. 9, summary.json, traces)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_output_dir(parser)
    add_axis_argument(parser)
    add_position_cycle_argument(parser, "e.g. 0.0025")
    cli.add_quiet(parser)


def _runs(axis: AxisConfig, progress: Progress, label: str) -> dict[str, Trace]:
    progress.stage(f"section X, {label}: ordinary control and with the regulator")
    return {
        "ordinary": run_section_x(axis, with_regulator=False),
        "regulated": run_section_x(axis, with_regulator=True),
    }


def run(args: argparse.Namespace) -> int:
    progress = Progress(f"plant_sim {NAME}", quiet=args.quiet)
    axis = regulated_axis(args.axis, args.position_cycle)
    scenario = SectionX()
    runs = _runs(axis, progress, f"axis as given ({args.axis})")
    extra: dict[str, object] = {"axis_file": str(args.axis)}
    published = {name: summarize(tr, axis, scenario) for name, tr in runs.items()}
    decided = limit_cycle_variant(axis, published, str(args.axis), args.out)
    if decided is not None:
        as_given_files, as_given_note = write_as_given(args.out, runs)
        axis, more = decided
        extra.update(more)
        extra["as_given_files"] = as_given_note
        extra["files_written"] = [*more.get("files_written", []), *as_given_files]  # type: ignore[misc]
        print(f"note: {more['finding']}")
        runs = _runs(axis, progress, f"friction.viscous = {axis.friction.viscous:g} N m s/m")
    progress.stage("figures and summary")
    summary = write_paper_outputs(args.out, runs, axis, scenario, extra)
    print(json.dumps({k: summary[k] for k in ("band_hz", "runs", "p2p_reduction")}, indent=2))
    print(files_line(args.out, summary))
    return 0

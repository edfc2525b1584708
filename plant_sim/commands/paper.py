"""``python -m plant_sim paper --out DIR``: reproduce section X (Fig. 8 and Fig. 9).

Runs the axis file (default: the paper's axis) with the ordinary control and with the
regulator. With the paper's own friction (viscous 57.3 N·m per m/s) the axis shows no
sustained limit cycle after the disturbance (docs/paper_reproduction.md explains why); the
command then also runs the same axis with the viscous friction lowered to
``plant_sim.report.LIMIT_CYCLE_VISCOUS`` — the physical value that makes section X's
result appear — and draws
the figures from that variant. summary.json holds both.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..axis import AxisConfig
from ..report import limit_cycle_variant, summarize, write_paper_outputs
from ..scenarios import SectionX, run_section_x
from .common import add_axis_argument, positive_float, read_axis

NAME = "paper"
HELP = "reproduce the paper's section X (Fig. 8, Fig. 9, summary.json, traces)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    add_axis_argument(parser)
    parser.add_argument(
        "--position-cycle",
        type=positive_float,
        default=None,
        metavar="S",
        help="override control.position_cycle (e.g. 0.0025)",
    )


def _runs(axis: AxisConfig) -> dict:
    return {
        "ordinary": run_section_x(axis, with_regulator=False),
        "regulated": run_section_x(axis, with_regulator=True),
    }


def run(args: argparse.Namespace) -> int:
    axis = read_axis(args.axis, args.position_cycle)
    scenario = SectionX()
    runs = _runs(axis)
    extra: dict[str, object] = {"axis_file": str(args.axis)}
    published = {name: summarize(tr, axis, scenario) for name, tr in runs.items()}
    decided = limit_cycle_variant(axis, published, str(args.axis), args.out)
    if decided is not None:
        for name, trace in runs.items():
            trace.to_csv(args.out / f"as_given_{name}.csv")
        axis, more = decided
        extra.update(more)
        runs = _runs(axis)
    summary = write_paper_outputs(args.out, runs, axis, scenario, extra)
    print(json.dumps({k: summary[k] for k in ("band_hz", "runs", "p2p_reduction")}, indent=2))
    print(f"wrote {args.out}/fig8.png, fig9.png, summary.json, ordinary.csv, regulated.csv")
    return 0

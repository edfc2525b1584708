"""``python -m plant_sim xl330 --out DIR [LOG ...]``: BAM XL330 logs -> traces + axis files.

Converts raw BAM XL330 pendulum logs (JSON) to ``DIR/kp<kp>_<trajectory>.csv``
(trace-file.md; columns: docs/xl330.md, :mod:`plant_sim.datasets.xl330`) and writes BAM's published
model and the diagnosis' nominal model per Position P Gain as axis files. Without LOG
arguments every ``*.json`` in the data directory (``$XL330_DATA`` or shared/data/bam_xl330)
is imported, and logs in which the torque is switched off (``lift_and_drop``) are skipped
with a note; named logs are never skipped.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cmdline import cli

from ..datasets.xl330 import (
    DATA_DIR,
    KP_DIVISOR,
    TorqueOffError,
    Xl330FileError,
    control_law_residual,
    import_xl330,
    read_xl330_log,
)

NAME = "xl330"
HELP = "convert BAM XL330 pendulum logs (.json) to trace files and axis files"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_inputs(
        parser, "log", f"raw BAM XL330 logs; default: every *.json in {DATA_DIR} ($XL330_DATA)"
    )
    cli.add_output_dir(parser)


def _default_sources() -> list[Path]:
    if not DATA_DIR.is_dir():
        raise Xl330FileError(
            f"{DATA_DIR}: no such directory; set XL330_DATA or name the logs (docs/xl330.md)"
        )
    sources = []
    for path in sorted(DATA_DIR.glob("*.json")):
        try:
            read_xl330_log(path)
        except TorqueOffError as exc:
            print(f"skipped: {exc}", file=sys.stderr)
            continue
        sources.append(path)
    if not sources:
        raise Xl330FileError(f"{DATA_DIR}: no importable *.json log")
    return sources


def run(args: argparse.Namespace) -> int:
    sources = args.log or _default_sources()
    result = import_xl330(sources, args.out)
    for item in result.traces:
        rec = item.recording
        print(
            f"{item.target}: {item.rows} rows, {rec.time_s[-1] - rec.time_s[0]:.2f} s, "
            f"kp = {rec.kp_register}, mass {rec.mass_kg:g} kg at {rec.length_m:g} m, "
            f"saturated {rec.saturated_share:.1%}, control-law residual "
            f"{control_law_residual(rec):.2%} (kp divisor {KP_DIVISOR})"
        )
    for path in result.axis_files:
        print(path)
    return 0

"""Defaults shared by the ``python -m bridge`` commands."""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline import cli
from regulator import RegulatorConfig
from regulator.errors import RegulatorError
from virtual_bus.formats.axis import AxisConfig, load_axis

from ..timing import TimeMode

PROG = "python -m bridge"


def add_clock_argument(parser: argparse.ArgumentParser) -> None:
    """``--clock``: the loop's time mode (:class:`bridge.timing.TimeMode`)."""
    parser.add_argument(
        "--clock",
        choices=[m.value for m in TimeMode],
        default="realtime",
        help="realtime (default; hardware) or lockstep (simulated drives)",
    )


def regulated_axis(path: Path) -> AxisConfig:
    """The axis file, refused in one line (exit 2) when the regulator cannot run on it
    (e.g. a position cycle above section VII's sampling limit), before anything is written."""
    axis = load_axis(path)
    try:
        RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    except RegulatorError as exc:
        raise cli.UsageError(f"{path}: the regulator cannot run on this axis: {exc}") from None
    return axis


def default_store_path(axis_path: Path) -> Path:
    """The bridge's parameter store beside its axis file: ``AXIS.bridge-store.json``."""
    return axis_path.with_name(f"{axis_path.stem}.bridge-store.json")

"""Argument helpers shared by the ``python -m plant_sim`` commands."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..axis import AxisConfig, load_axis

ROOT = Path(__file__).resolve().parents[2]
PAPER_AXIS = ROOT / "config" / "paper_axis.toml"


def add_axis_argument(parser: argparse.ArgumentParser, default: Path | None = PAPER_AXIS) -> None:
    parser.add_argument(
        "--axis",
        type=Path,
        default=default,
        required=default is None,
        help="axis file (shared/spec/axis-file.md)"
        + (f"; default {default.relative_to(ROOT)}" if default else ""),
    )


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number > 0")
    return value


def read_axis(path: Path, position_cycle_s: float | None = None) -> AxisConfig:
    axis = load_axis(path)
    if position_cycle_s is not None:
        axis = axis.with_values({"control.position_cycle": position_cycle_s})
    return axis

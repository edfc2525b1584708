"""Helpers shared by the ``python -m plant_sim`` commands (argument types: cmdline.cli)."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from cmdline import cli
from regulator import RegulatorConfig
from regulator.errors import RegulatorError
from virtual_bus.formats.axis import AxisConfig, load_axis
from virtual_bus.shipped import CONFIG_DIR, PAPER_AXIS

from ..errors import ScenarioError


def add_axis_argument(parser: argparse.ArgumentParser, default: Path | None = PAPER_AXIS) -> None:
    parser.add_argument(
        "--axis",
        type=Path,
        default=default,
        required=default is None,
        metavar="AXIS.toml",
        help="axis file (docs/axis-file.md)"
        + (f"; default {default.relative_to(CONFIG_DIR.parent)}" if default else ""),
    )


def add_position_cycle_argument(parser: argparse.ArgumentParser, note: str) -> None:
    """``--position-cycle S``: the axis file's control.position_cycle replaced by S
    (:func:`read_axis`); ``note`` says what to give."""
    parser.add_argument(
        "--position-cycle",
        type=cli.positive_float,
        default=None,
        metavar="S",
        help=f"override control.position_cycle ({note})",
    )


def read_axis(path: Path, position_cycle_s: float | None = None) -> AxisConfig:
    axis = load_axis(path)
    if position_cycle_s is not None:
        axis = axis.with_values({"control.position_cycle": position_cycle_s})
    return axis


def regulated_axis(path: Path, position_cycle_s: float | None = None) -> AxisConfig:
    """:func:`read_axis` for the commands that run the regulator (section X): refused in one
    line (exit 2) naming the file when the regulator cannot run on it, e.g. a position cycle
    above section VII's sampling limit."""
    axis = read_axis(path, position_cycle_s)
    try:
        RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    except RegulatorError as exc:
        raise ScenarioError(f"{path}: the regulator cannot run on this axis: {exc}") from None
    return axis


@contextmanager
def plain_warnings() -> Iterator[None]:
    """Warnings raised inside (a trace's implausible unit, ...) are printed as one plain line
    each, ``warning: MESSAGE`` on stderr, instead of Python's file:line form. When the block
    fails, only its error is reported (its one line says what is wrong)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    seen: set[str] = set()
    for w in caught:
        text = str(w.message)
        if text not in seen:
            seen.add(text)
            print(f"warning: {text}", file=sys.stderr)

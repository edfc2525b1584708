"""Defaults shared by the ``python -m hil`` commands."""

from __future__ import annotations

import argparse
from pathlib import Path

from bridge.params import BridgeParams
from cmdline import cli
from plant_sim.fmu.arguments import AxisSource, add_fmu_arguments, axis_source
from plant_sim.physics.model import AxisPlant
from regulator import RegulatorConfig
from regulator.errors import RegulatorError
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.shipped import PAPER_AXIS


def simulated_source(args: argparse.Namespace, axis_path: Path | None) -> AxisSource:
    """The axis of ``--axis`` (default the paper's) or ``--fmu`` for the commands that also
    simulate it, refused in one line (exit 2) before anything runs when the regulator, the
    bridge's scaling or the physics cannot run it (position cycle above section VII's
    sampling limit, substeps)."""
    if axis_path is None and getattr(args, "fmu", None) is None:
        axis_path = PAPER_AXIS
    source = axis_source(args, axis_path)
    axis = source.axis
    try:
        reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    except RegulatorError as exc:
        raise cli.UsageError(
            f"{source.name}: the regulator cannot run on this axis: {exc}"
        ) from None
    BridgeParams.for_axis(axis, reg)
    if source.model is None:
        AxisPlant(axis)
    return source


def simulated_axis_file(path: Path) -> AxisConfig:
    """:func:`simulated_source` of an axis file alone (the kernel as the plant)."""
    return simulated_source(argparse.Namespace(), path).axis


def add_axis_and_out(parser: argparse.ArgumentParser) -> None:
    """The offline commissioning tests' inputs (``hil freqresp``, ``hil tune``)."""
    parser.add_argument(
        "--axis", type=cli.existing_file, help="axis file (with --fmu default: its data sheet)"
    )
    cli.add_output_dir(parser, "report directory")
    add_fmu_arguments(parser)

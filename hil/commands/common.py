"""Defaults shared by the ``python -m hil`` commands."""

from __future__ import annotations

import argparse
from pathlib import Path

from bridge.commands.common import regulated_axis
from bridge.params import BridgeParams
from plant_sim.physics.model import AxisPlant
from regulator import RegulatorConfig
from virtual_bus import cli
from virtual_bus.formats.axis import AxisConfig


def simulated_axis_file(path: Path) -> AxisConfig:
    """:func:`regulated_axis` for the commands that also simulate the axis (demo, bench):
    the bridge's scaling limits and the physics' limits (substeps) are checked too, in one
    line before anything runs."""
    axis = regulated_axis(path)
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    BridgeParams.for_axis(axis, reg)
    AxisPlant(axis)
    return axis


def add_axis_and_out(parser: argparse.ArgumentParser) -> None:
    """The offline commissioning tests' inputs (``hil freqresp``, ``hil tune``)."""
    parser.add_argument("--axis", type=cli.existing_file, required=True, help="axis file")
    parser.add_argument("--out", type=cli.output_dir, required=True, help="report directory")

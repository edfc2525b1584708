"""Defaults shared by the ``python -m bridge`` commands."""

from __future__ import annotations

from pathlib import Path

from plant_sim.axis import AxisConfig, load_axis
from plant_sim.model import AxisPlant
from regulator import RegulatorConfig
from regulator.errors import RegulatorError
from virtual_bus import cli

from ..params import BridgeParams

ROOT = Path(__file__).resolve().parents[2]
PAPER_AXIS = ROOT / "config" / "paper_axis.toml"
PROG = "python -m bridge"


def regulated_axis(path: Path) -> AxisConfig:
    """The axis file, refused in one line (exit 2) when the regulator cannot run on it
    (e.g. a position cycle above section VII's sampling limit), before anything is written."""
    axis = load_axis(path)
    try:
        RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    except RegulatorError as exc:
        raise cli.UsageError(f"{path}: the regulator cannot run on this axis: {exc}") from None
    return axis


def simulated_axis_file(path: Path) -> AxisConfig:
    """:func:`regulated_axis` for the commands that also simulate the axis (demo, bench):
    the bridge's scaling limits and the physics' limits (substeps) are checked too, in one
    line before anything runs."""
    axis = regulated_axis(path)
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    BridgeParams.for_axis(axis, reg)
    AxisPlant(axis)
    return axis


def default_store_path(axis_path: Path) -> Path:
    """The bridge's parameter store beside its axis file: ``AXIS.bridge-store.json``."""
    return axis_path.with_name(f"{axis_path.stem}.bridge-store.json")

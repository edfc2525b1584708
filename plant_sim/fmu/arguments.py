"""The FMU options every command that runs an axis shares, and what they make.

    --fmu FMU [--fmu-param NAME=VALUE,...] [--fmu-map SIGNAL=VARIABLE[UNIT],...]

With ``--fmu`` the FMU is the plant; the axis file (``--axis``) is what the drive and the
bridge are configured from, and without one it is the FMU's data sheet
(:func:`plant_sim.fmu.nominal_axis`). Everything is checked before a bus is touched or a file
written: a bad FMU, parameter or mapping is one line and exit 2.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from cmdline import cli
from virtual_bus.formats.axis import AxisConfig, load_axis

from ..errors import FmuError
from ..plant import Plant
from .model import FmuModel, FmuSpec


def add_fmu_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "FMU axis", "an FMI 2.0 co-simulation FMU as the plant (docs/fmu.md)"
    )
    group.add_argument(
        "--fmu",
        type=cli.existing_file,
        metavar="FMU",
        help="the axis as an FMU (e.g. ../shared/plants/axis_family.fmu)",
    )
    group.add_argument(
        "--fmu-param",
        action="append",
        default=[],
        metavar="NAME=VALUE,...",
        help="FMU parameters by name, e.g. seed=7,family=1 (repeatable)",
    )
    group.add_argument(
        "--fmu-map",
        action="append",
        default=[],
        metavar="SIGNAL=VARIABLE[UNIT],...",
        help="the FMU's variable for a drive signal (speed_setpoint, disturbance, "
        "motor_position, motor_speed, load_position, motor_torque); default: the shared "
        "axis family's names",
    )


def fmu_spec(args: argparse.Namespace) -> FmuSpec | None:
    """The FMU the options name (not loaded yet), or None without ``--fmu``."""
    if getattr(args, "fmu", None) is None:
        if getattr(args, "fmu_param", None) or getattr(args, "fmu_map", None):
            raise FmuError("--fmu-param and --fmu-map need --fmu FMU")
        return None
    return FmuSpec.from_text(args.fmu, ",".join(args.fmu_param), ",".join(args.fmu_map))


@dataclass(frozen=True)
class AxisSource:
    """What a command runs: the axis file the drive/bridge use, and the FMU if one is the
    plant (``model`` loaded and checked)."""

    axis: AxisConfig
    name: str
    fmu: FmuSpec | None = None
    model: FmuModel | None = None

    def plant(self, position: float = 0.0, name: str = "axis") -> Plant:
        """A fresh plant at rest at ``position``: the FMU's, or the kernel's."""
        if self.model is not None:
            from .plant import FmuPlant

            return FmuPlant(self.model, self.axis, position, name)
        from ..physics.model import AxisPlant

        return AxisPlant(self.axis, position=position)


def axis_source(args: argparse.Namespace, axis_path: Path | None) -> AxisSource:
    """The axis of ``--axis`` and/or ``--fmu`` (one of them is needed)."""
    spec = fmu_spec(args)
    if spec is None:
        if axis_path is None:
            raise FmuError("give --axis AXIS.toml or --fmu FMU")
        return AxisSource(load_axis(axis_path), axis_path.name)
    from .nominal import nominal_axis

    model = spec.load()
    if axis_path is None:
        return AxisSource(nominal_axis(model), f"{spec.describe()} data sheet", spec, model)
    axis = load_axis(axis_path)
    from .plant import check_axis

    check_axis(model, axis)
    return AxisSource(axis, axis_path.name, spec, model)

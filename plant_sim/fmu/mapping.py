"""Which FMU variable carries which of the drive's signals, and which parameters say what.

The drive's side of the boundary is fixed (:class:`Signal`: a speed set point and a
disturbance in, four measurements out, in SI units); the FMU's side is configurable by name
with units. The defaults are the names of the shared feed-axis family
(``shared/plants/axis_family.fmu``, its README); another FMU is mapped on the command line:

    --fmu-map speed_setpoint=w_ref,motor_speed=w_m[rpm],disturbance=

``name[unit]`` gives a unit where the FMU declares none (where it declares one, the two must
agree); an empty name leaves an optional signal unmapped (the disturbance: then a disturbance
other than 0 is refused).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum

from ..errors import FmuError
from .units import Quantity


class Signal(Enum):
    """The drive's signals: (name, causality in the FMU, quantities allowed, required)."""

    SPEED_SETPOINT = ("speed_setpoint", "input", (Quantity.ANGULAR_SPEED,), True)
    DISTURBANCE = ("disturbance", "input", (Quantity.FORCE, Quantity.TORQUE), False)
    MOTOR_POSITION = ("motor_position", "output", (Quantity.ANGLE,), True)
    MOTOR_SPEED = ("motor_speed", "output", (Quantity.ANGULAR_SPEED,), True)
    LOAD_POSITION = ("load_position", "output", (Quantity.LENGTH, Quantity.ANGLE), True)
    MOTOR_TORQUE = ("motor_torque", "output", (Quantity.TORQUE,), True)

    def __init__(
        self, key: str, causality: str, quantities: tuple[Quantity, ...], required: bool
    ) -> None:
        self.key = key
        self.causality = causality
        self.quantities = quantities
        self.required = required


#: Measurements in the order of :meth:`plant_sim.plant.Plant.read_measured`.
MEASURED = (Signal.MOTOR_POSITION, Signal.LOAD_POSITION, Signal.MOTOR_SPEED, Signal.MOTOR_TORQUE)


@dataclass(frozen=True)
class Binding:
    """An FMU variable and, where the FMU declares no unit, the unit it is in."""

    variable: str
    unit: str | None = None

    def __str__(self) -> str:
        return self.variable + (f"[{self.unit}]" if self.unit else "")


#: Axis-file keys written from the FMU's data-sheet parameters (the family's names).
NOMINAL_KEYS: dict[str, str] = {
    "axis.transmission_ratio": "nominal_transmission_ratio",
    "mechanics.motor_inertia": "nominal_motor_inertia",
    "mechanics.screw_inertia": "nominal_screw_inertia",
    "mechanics.load_mass": "nominal_mass",
    "mechanics.antiresonance": "nominal_antiresonance",
    "mechanics.damping_ratio": "nominal_damping",
    "friction.coulomb": "nominal_coulomb",
    "friction.viscous": "nominal_viscous",
    "control.kv": "nominal_kv",
    "control.ksp": "nominal_ksp",
    "control.tsi": "nominal_tsi",
    "control.torque_limit": "nominal_torque_limit",
    "control.current_lag": "nominal_current_lag",
    "control.position_cycle": "nominal_position_cycle",
    "control.speed_cycle": "nominal_speed_cycle",
}


@dataclass(frozen=True)
class FmuMapping:
    """The FMU's variables for the drive's signals (module docstring).

    signals: :class:`Signal` key -> :class:`Binding` (None: an optional signal left unmapped);
    initial_position: the parameter that places the load at rest at the start (load units;
    None: the FMU starts where it starts, and a start elsewhere is refused);
    transmission_ratio: the parameter with k_r (rad per load unit), used to turn the
    disturbance torque at the motor into a force when the FMU's input is a force;
    nominal: axis-file key -> the FMU parameter holding its data-sheet value.
    """

    signals: Mapping[str, Binding | None] = field(
        default_factory=lambda: (
            {s.key: Binding(s.key) for s in Signal}
            | {Signal.DISTURBANCE.key: Binding("disturbance_force")}
        )
    )
    initial_position: str | None = "initial_position"
    transmission_ratio: str | None = "nominal_transmission_ratio"
    nominal: Mapping[str, str] = field(default_factory=lambda: dict(NOMINAL_KEYS))

    def __post_init__(self) -> None:
        known = {s.key for s in Signal}
        unknown = set(self.signals) - known
        if unknown:
            raise FmuError(
                f"FMU mapping: unknown signal {sorted(unknown)[0]!r}; allowed: "
                + ", ".join(s.key for s in Signal)
            )
        for signal in Signal:
            if signal.required and self.signals.get(signal.key) is None:
                raise FmuError(f"FMU mapping: {signal.key} must be mapped to a variable")

    def binding(self, signal: Signal) -> Binding | None:
        return self.signals.get(signal.key)

    def with_text(self, text: str) -> FmuMapping:
        """This mapping with ``signal=variable[unit],...`` applied (module docstring)."""
        changed = dict(self.signals)
        for item in _items(text, "--fmu-map"):
            key, _, value = item.partition("=")
            key, value = key.strip(), value.strip()
            if key not in {s.key for s in Signal}:
                raise FmuError(
                    f"--fmu-map {item!r}: unknown signal {key!r}; allowed: "
                    + ", ".join(s.key for s in Signal)
                )
            if not value:
                changed[key] = None
                continue
            match = re.fullmatch(r"([^\[\]]+?)\s*(?:\[([^\[\]]+)\])?", value)
            if match is None:
                raise FmuError(f"--fmu-map {item!r}: write signal=variable or variable[unit]")
            changed[key] = Binding(match.group(1), match.group(2))
        return replace(self, signals=changed)

    def describe(self) -> str:
        return ", ".join(f"{s.key}={self.signals.get(s.key) or '(none)'}" for s in Signal)


def _items(text: str, option: str) -> list[str]:
    items = [part.strip() for part in text.split(",") if part.strip()]
    for item in items:
        if "=" not in item:
            raise FmuError(f"{option} {item!r}: write NAME=VALUE (comma-separated)")
    return items


def parse_parameters(text: str) -> dict[str, str]:
    """``--fmu-param seed=7,family=1`` as name -> text (the FMU's types decide later)."""
    out: dict[str, str] = {}
    for item in _items(text, "--fmu-param"):
        name, _, value = item.partition("=")
        name, value = name.strip(), value.strip()
        if not name or not value:
            raise FmuError(f"--fmu-param {item!r}: write NAME=VALUE")
        out[name] = value
    return out

"""Units of an FMU's variables and their factors to the project's SI units.

An FMU declares a unit per variable (FMI 2.0 ``unit`` / ``declaredType``); the drive's signals
are SI as everywhere in the project (rad, rad/s, m, N·m, N). A unit is accepted when it is in
the table of its quantity; anything else is refused by name, never guessed.
"""

from __future__ import annotations

import math
from enum import Enum

from ..errors import FmuError


class Quantity(Enum):
    """What a mapped signal measures."""

    ANGLE = "angle"
    ANGULAR_SPEED = "angular speed"
    LENGTH = "length"
    TORQUE = "torque"
    FORCE = "force"


#: Spellings of each quantity's units and their factor to the SI unit (the first of each).
FACTORS: dict[Quantity, dict[str, float]] = {
    Quantity.ANGLE: {"rad": 1.0, "deg": math.pi / 180.0, "rev": 2.0 * math.pi},
    Quantity.ANGULAR_SPEED: {
        "rad/s": 1.0,
        "1/s": 1.0,
        "rpm": 2.0 * math.pi / 60.0,
        "1/min": 2.0 * math.pi / 60.0,
        "rev/min": 2.0 * math.pi / 60.0,
        "deg/s": math.pi / 180.0,
        "rev/s": 2.0 * math.pi,
    },
    Quantity.LENGTH: {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6},
    Quantity.TORQUE: {"N.m": 1.0, "N·m": 1.0, "Nm": 1.0, "N*m": 1.0, "mN.m": 1e-3, "kN.m": 1e3},
    Quantity.FORCE: {"N": 1.0, "kN": 1e3},
}


def factor(unit: str, quantities: tuple[Quantity, ...], what: str) -> tuple[Quantity, float]:
    """The quantity ``unit`` belongs to (one of ``quantities``) and its factor to SI; an
    unknown unit raises :class:`FmuError` naming ``what`` and the units allowed."""
    for quantity in quantities:
        if unit in FACTORS[quantity]:
            return quantity, FACTORS[quantity][unit]
    allowed = ", ".join(u for q in quantities for u in FACTORS[q])
    return _refuse(f"{what} has unit {unit!r}; allowed: {allowed}")


def _refuse(message: str) -> tuple[Quantity, float]:
    raise FmuError(message)

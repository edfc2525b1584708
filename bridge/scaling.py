"""Integer scaling of the drive's PDO objects (docs/canopen_layout.md, drive table).

* 6064h position actual value, 606Ch velocity actual value, 60FFh target velocity: motor
  encoder increments (per s), 2^20 increments per motor revolution.
* 60E4h:01 additional position actual value (load scale): nm for a linear axis, µrad for a
  rotary axis.
* 6077h torque actual value: per mille of 6076h motor rated torque (mN·m).

The only difference between the bridge loop over the bus and the offline simulation is this
quantisation (plus the one-cycle PDO delay both have).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant_sim.axis import AxisKind
from virtual_bus.contract import INT32_MAX as INT32_MAX
from virtual_bus.contract import INT32_MIN as INT32_MIN
from virtual_bus.contract import LOAD_INCREMENTS_PER_M, LOAD_INCREMENTS_PER_RAD, PERMILLE
from virtual_bus.contract import MOTOR_INCREMENTS_PER_REV as MOTOR_INCREMENTS_PER_REV

from .errors import BridgeConfigError

#: Motor encoder increments per rad.
MOTOR_INCREMENTS_PER_RAD = MOTOR_INCREMENTS_PER_REV / (2.0 * math.pi)
#: rad per motor encoder increment.
MOTOR_RAD_PER_INCREMENT = 1.0 / MOTOR_INCREMENTS_PER_RAD
#: Load-scale increments (60E4h:01) per load unit: nm per m, µrad per rad.
LOAD_INCREMENTS_PER_UNIT = {
    AxisKind.LINEAR: LOAD_INCREMENTS_PER_M,
    AxisKind.ROTARY: LOAD_INCREMENTS_PER_RAD,
}


@dataclass(frozen=True)
class Scaling:
    """Conversion between the drive's integers and SI values.

    load_increments_per_unit: 60E4h:01 increments per load unit (1e9 nm/m or 1e6 µrad/rad).
    rated_torque_nm: 6076h motor rated torque in N·m (> 0); 6077h is per mille of it.
    """

    load_increments_per_unit: float
    rated_torque_nm: float

    def __post_init__(self) -> None:
        for name in ("load_increments_per_unit", "rated_torque_nm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise BridgeConfigError(f"{name} = {value!r}: must be a finite number > 0")

    @classmethod
    def for_kind(cls, kind: AxisKind, rated_torque_nm: float = 1.0) -> Scaling:
        """Contract scaling of a linear (nm) or rotary (µrad) axis."""
        return cls(LOAD_INCREMENTS_PER_UNIT[kind], rated_torque_nm)

    @property
    def load_unit_per_increment(self) -> float:
        """Load units (m or rad) per 60E4h:01 increment."""
        return 1.0 / self.load_increments_per_unit

    @property
    def torque_nm_per_permille(self) -> float:
        """N·m per 6077h unit (per mille of the rated torque)."""
        return self.rated_torque_nm / PERMILLE


def speed_to_increments(speed_rad_s: float) -> int:
    """Motor speed in rad/s to 60FFh increments/s, rounded and clamped to INTEGER32."""
    inc = round(speed_rad_s * MOTOR_INCREMENTS_PER_RAD)
    return INT32_MAX if inc > INT32_MAX else INT32_MIN if inc < INT32_MIN else inc

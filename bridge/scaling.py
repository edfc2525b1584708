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

from .errors import BridgeConfigError

#: Motor encoder increments per motor revolution (6064h, 606Ch, 60FFh).
MOTOR_INCREMENTS_PER_REV = 1 << 20
#: Motor encoder increments per rad.
MOTOR_INCREMENTS_PER_RAD = MOTOR_INCREMENTS_PER_REV / (2.0 * math.pi)
#: rad per motor encoder increment.
MOTOR_RAD_PER_INCREMENT = 1.0 / MOTOR_INCREMENTS_PER_RAD
#: Load-scale increments (60E4h:01) per load unit: nm per m, µrad per rad.
LOAD_INCREMENTS_PER_UNIT = {AxisKind.LINEAR: 1e9, AxisKind.ROTARY: 1e6}
#: Largest INTEGER32 value.
INT32_MAX = (1 << 31) - 1


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
        return self.rated_torque_nm / 1000.0

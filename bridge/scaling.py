"""Integer scaling of the drive's PDO objects (docs/canopen_layout.md, drive table).

* 6064h position actual value, 606Ch velocity actual value, 60FFh target velocity: motor
  encoder increments (per s), 2^20 increments per motor revolution.
* 60E4h:01 additional position actual value (load scale): nm for a linear axis, µrad for a
  rotary axis.
* 6077h torque actual value: per mille of 6076h motor rated torque (mN·m).

Those are the contract's (the simulated drive's) defaults. A real drive's resolution and
units come from its objects (608Fh, 6091h, 6092h, factor groups) or from its drive profile
(:mod:`virtual_bus.formats.drive_profile`); :class:`Scaling` carries whichever applies.

The only difference between the bridge loop over the bus and the offline simulation is this
quantisation (plus the one-cycle PDO delay both have).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from virtual_bus.contract import INT32_MAX as INT32_MAX
from virtual_bus.contract import INT32_MIN as INT32_MIN
from virtual_bus.contract import LOAD_INCREMENTS_PER_M, LOAD_INCREMENTS_PER_RAD, PERMILLE
from virtual_bus.contract import MOTOR_INCREMENTS_PER_REV as MOTOR_INCREMENTS_PER_REV
from virtual_bus.formats.axis import AxisKind

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

    load_increments_per_unit: load-position increments per load unit (60E4h:01 of the
    contract: 1e9 nm/m or 1e6 µrad/rad; a vendor object or a CiA 406 encoder: its own).
    rated_torque_nm: 6076h motor rated torque in N·m (> 0); 6077h is per mille of it.
    ``None``: 6076h is 0 or absent, the torque is shown in per mille of the rated torque
    (:attr:`torque_unit`).
    position_increments_per_rev: 6064h increments per motor revolution (608Fh / 6091h /
    factor group, or configuration; the contract's 2^20).
    velocity_units_per_rev_s: 606Ch / 60FFh units per motor revolution per second (the
    contract: increments/s, so equal to the position resolution).
    """

    load_increments_per_unit: float
    rated_torque_nm: float | None = 1.0
    position_increments_per_rev: float = MOTOR_INCREMENTS_PER_REV
    velocity_units_per_rev_s: float = MOTOR_INCREMENTS_PER_REV

    def __post_init__(self) -> None:
        names = ["load_increments_per_unit", "position_increments_per_rev"]
        names += ["velocity_units_per_rev_s"]
        if self.rated_torque_nm is not None:
            names.append("rated_torque_nm")
        for name in names:
            value = getattr(self, name)
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and value > 0):
                raise BridgeConfigError(f"{name} = {value!r}: must be a finite number > 0")

    @classmethod
    def for_kind(cls, kind: AxisKind, rated_torque_nm: float | None = 1.0) -> Scaling:
        """Contract scaling of a linear (nm) or rotary (µrad) axis."""
        return cls(LOAD_INCREMENTS_PER_UNIT[kind], rated_torque_nm)

    @property
    def load_unit_per_increment(self) -> float:
        """Load units (m or rad) per load-position increment."""
        return 1.0 / self.load_increments_per_unit

    @property
    def torque_nm_per_permille(self) -> float:
        """N·m per 6077h unit (per mille of the rated torque); 1.0 when the rated torque is
        unknown: the torque is then reported in per mille (:attr:`torque_unit`)."""
        return 1.0 if self.rated_torque_nm is None else self.rated_torque_nm / PERMILLE

    @property
    def torque_unit(self) -> str:
        return "per mille of rated torque" if self.rated_torque_nm is None else "N·m"

    @property
    def motor_rad_per_increment(self) -> float:
        """Motor rad per 6064h increment."""
        return 1.0 / (self.position_increments_per_rev / (2.0 * math.pi))

    @property
    def velocity_units_per_rad_s(self) -> float:
        """606Ch / 60FFh units per motor rad/s."""
        return self.velocity_units_per_rev_s / (2.0 * math.pi)

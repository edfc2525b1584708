"""Configuration of the simulated drive that is not in the axis file."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from virtual_bus.contract import TimeMode

from .errors import DriveConfigError
from .od import DEFAULT_EDS_PATH

__all__ = ["DriveConfig", "TimeMode"]


@dataclass(frozen=True)
class DriveConfig:
    """Settings of the simulated drive that are not in the axis file.

    time_mode: see :class:`TimeMode`.
    rated_torque_nm: motor rated torque 6076h (N·m, held as mN·m); the default 50 N·m makes
        the paper axis' 150 N·m limit 3000 ‰ (a servo motor with 3x peak torque).
    eds_path: the EDS the object dictionary is built from.
    notifier_timeout_s: receive timeout of the notifier thread the drive runs when it is
        given a bus instead of a canopen Network (bounds how long ``stop()`` waits).
    standstill_rad_s: a quick stop / fault reaction is complete once its ramp has reached
        zero and the motor speed is at most this (rad/s at the motor).
    """

    time_mode: TimeMode = TimeMode.LOCKSTEP
    rated_torque_nm: float = 50.0
    eds_path: Path = field(default_factory=lambda: DEFAULT_EDS_PATH)
    notifier_timeout_s: float = 0.05
    standstill_rad_s: float = 0.1

    def __post_init__(self) -> None:
        if not isinstance(self.time_mode, TimeMode):
            raise DriveConfigError(
                f"time_mode = {self.time_mode!r}: must be one of {[m.name for m in TimeMode]}"
            )
        if not (math.isfinite(self.rated_torque_nm) and 0.001 <= self.rated_torque_nm <= 4.29e6):
            raise DriveConfigError(
                f"rated_torque_nm = {self.rated_torque_nm}: allowed [0.001, 4.29e6] N·m "
                "(UNSIGNED32 mN·m)"
            )
        if not (math.isfinite(self.standstill_rad_s) and self.standstill_rad_s > 0.0):
            raise DriveConfigError(
                f"standstill_rad_s = {self.standstill_rad_s}: must be a finite speed > 0 rad/s"
            )
        if not 0.001 <= self.notifier_timeout_s <= 1.0:
            raise DriveConfigError(
                f"notifier_timeout_s = {self.notifier_timeout_s}: allowed [0.001, 1.0] s"
            )

"""What a drive steps: the axis and the drive's inner loops, one position cycle per call.

Two boundaries, from the narrow to the wide:

* :class:`regulator.loop.SteppedAxis` -- what a position loop closes around (the bridge's
  loop without a bus, :mod:`hil.loop`): ``advance(speed_setpoint_rad_s, disturbance_nm)`` and
  the four readings; defined once on the regulator's floor, whose :func:`regulator.loop.play`
  steps it.
* :class:`Plant` -- what the simulated CiA 402 drive (:mod:`plant_sim.drive`) runs behind its
  object dictionary: a stepped axis plus the axis file it is configured from, the power stage
  off (coasting), the torque limit of 6072h and a failure that faults the drive.
  Two implementations fill its hooks: the compiled kernel
  (:class:`plant_sim.physics.model.AxisPlant`) and an FMI 2.0 co-simulation FMU
  (:class:`plant_sim.fmu.FmuPlant`).

Units: motor positions rad, speeds rad/s and torques N·m at the motor; the load position in
load units (m for a linear axis, rad for a rotary one); the disturbance is a load torque
reflected to the motor (N·m, positive pushes towards +x), as in the paper's Fig. 8 B.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable

import numpy as np

from virtual_bus.formats.axis import AxisConfig


class Plant(abc.ABC):
    """Base of the plants a simulated drive runs (module docstring).

    Subclasses fill :meth:`advance`, :meth:`advance_torque`, :meth:`read_measured` and
    :attr:`time_s`; the readings one by one come from :meth:`read_measured` unless a subclass
    has a cheaper way. ``axis`` is the axis file the drive is configured from (cycle, k_r,
    kind, rated and limit torque): the model itself for the kernel, the data sheet's for an
    FMU.

    Capabilities a drive asks before it relies on them:

    * :attr:`coasts` -- :meth:`advance_torque` applies the torque (power stage off: 0 N·m,
      the axis coasts). A plant whose inputs are a speed set point only cannot coast; its
      :meth:`advance_torque` holds a speed set point of zero instead (documented per plant).
    * :attr:`limits_torque` -- :meth:`set_torque_limit_nm` changes the limit the plant's speed
      controller saturates at (6072h); otherwise the plant keeps its own and the call only
      records the value.
    * :attr:`takes_torque_feedforward` -- :meth:`advance`'s ``torque_feedforward_nm`` is
      applied; otherwise it must be 0.
    """

    coasts: bool = True
    limits_torque: bool = True
    takes_torque_feedforward: bool = True

    def __init__(self, axis: AxisConfig) -> None:
        self.axis = axis
        self._readings = np.zeros(4)

    # --- the hooks -----------------------------------------------------------------------------
    @abc.abstractmethod
    def advance(
        self,
        speed_setpoint_rad_s: float,
        disturbance_nm: float = 0.0,
        torque_feedforward_nm: float = 0.0,
    ) -> None:
        """One position cycle at a constant speed set point (rad/s at the motor), external
        disturbance (N·m reflected to the motor) and torque feed-forward (N·m added to the
        speed controller's output, before the limit)."""

    @abc.abstractmethod
    def advance_torque(self, torque_nm: float, disturbance_nm: float = 0.0) -> None:
        """One position cycle with the speed loop bypassed at a fixed torque set point (0 N·m:
        the power stage is off); see :attr:`coasts`."""

    @abc.abstractmethod
    def read_measured(self, out: np.ndarray) -> None:
        """Motor position (rad), load position (load units), motor speed (rad/s), motor torque
        (N·m) into ``out`` (float64, 4 elements): what the drive's measuring systems read now."""

    @property
    @abc.abstractmethod
    def time_s(self) -> float:
        """The plant's own time (s since it was made)."""

    # --- with defaults -------------------------------------------------------------------------
    def stepper(self) -> Callable[[float, float, float], None]:
        """:meth:`advance` for a caller that passes floats every position cycle (a drive)."""
        return self.advance

    def set_torque_limit_nm(self, limit_nm: float) -> None:
        """The torque limit the speed controller saturates at (N·m, ``math.inf`` for none);
        see :attr:`limits_torque`."""
        self._torque_limit_nm = float(limit_nm)

    @property
    def torque_limit_nm(self) -> float:
        return getattr(self, "_torque_limit_nm", math.inf)

    def warm_up(self) -> None:
        """Load (or compile) what the first step would, so that the first SYNC after the
        drive's boot-up is answered at the normal pace. Nothing by default."""
        return None

    def close(self) -> None:
        """Release what the plant holds outside Python (a shared library instance)."""
        return None

    def _reading(self, index: int) -> float:
        self.read_measured(self._readings)
        return float(self._readings[index])

    @property
    def motor_position_rad(self) -> float:
        return self._reading(0)

    @property
    def load_position(self) -> float:
        return self._reading(1)

    @property
    def motor_speed_rad_s(self) -> float:
        return self._reading(2)

    @property
    def motor_torque_nm(self) -> float:
        return self._reading(3)

    @property
    def position_cycle_s(self) -> float:
        return self.axis.control.position_cycle

    def __enter__(self) -> Plant:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

"""An FMU as the plant a drive steps: :class:`FmuPlant`.

One communication step is one position cycle (``axis.control.position_cycle``): the speed set
point and the disturbance are set before ``fmi2DoStep(t_k, T_p)`` and held over the step (a
CiA 402 drive holds 60FFh between SYNCs the same way); the four measurements are read after
each step (FMI 2.0: the outputs at t_k+1). The calls go straight to the FMU's functions with
value-reference and value arrays made once, not through FMPy's per-call conversions: a step
costs about 3 µs where ``setReal``/``doStep``/``getReal`` cost about 5 µs.

What an FMU whose inputs are a speed set point and a force cannot do, and what stands for it
(:class:`plant_sim.plant.Plant`'s capabilities):

* power stage off (``advance_torque``): it cannot coast; it holds a speed set point of zero,
  so its own speed loop brakes the axis to rest and holds it there (the drive's states
  Switch on disabled / Ready to switch on / Switched on stand the axis still instead of
  letting it roll; a drive's holding brake would do the same);
* the torque limit of 6072h: the FMU keeps its own (``nominal_torque_limit`` for the
  family); the drive refuses a 6072h write below it;
* torque feed-forward: none (an axis file with ``control.acceleration_feedforward`` is
  refused for an FMU axis).

A failing FMU call raises :class:`plant_sim.errors.FmuStepError` (with what the FMU logged)
and the plant stops stepping: its readings stay where they were (the drive faults on it).
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from virtual_bus.formats.axis import AxisConfig, AxisKind

from ..errors import FmuError, FmuStepError
from ..plant import Plant
from .model import FmuModel, FmuSpec
from .units import Quantity

_OK_STATUS = 1  # fmi2OK, fmi2Warning: the step was taken


class FmuPlant(Plant):
    """A checked FMU (:class:`FmuModel` or the :class:`FmuSpec` to load) stepped one position
    cycle per :meth:`advance` (module docstring).

    axis: the axis file the drive is configured from (usually the FMU's data-sheet one,
    :func:`plant_sim.fmu.nominal_axis`); position: where the load starts at rest (load units).
    """

    coasts = False
    limits_torque = False
    takes_torque_feedforward = False

    def __init__(
        self,
        fmu: FmuModel | FmuSpec,
        axis: AxisConfig,
        position: float = 0.0,
        name: str = "axis",
    ) -> None:
        super().__init__(axis)
        model = fmu.load() if isinstance(fmu, FmuSpec) else fmu
        self.model = model
        check_axis(model, axis)
        self._h = axis.control.position_cycle
        ratio = model.transmission_ratio() or axis.transmission_ratio
        disturbance = model.disturbance
        # N·m at the motor -> the FMU's unit: a force on the carriage is tau*k_r (linear)
        self._dist_scale = 0.0
        if disturbance is not None:
            per_si = 1.0 / disturbance.factor
            self._dist_scale = per_si * (ratio if disturbance.quantity is Quantity.FORCE else 1.0)
        self._speed_scale = 1.0 / model.set_point.factor
        self._out_scale = np.array([p.factor for p in model.measured])
        self._instance = model.instantiate(name, position)
        inst = self._instance
        self._get = inst.function("fmi2GetReal")
        self._set = inst.function("fmi2SetReal")
        self._do_step = inst.function("fmi2DoStep")
        self._component = inst.component
        n_in = 2 if disturbance is not None else 1
        refs = [model.set_point.reference] + ([disturbance.reference] if disturbance else [])
        self._in_refs = (ctypes.c_uint * n_in)(*refs)
        self._in_values = (ctypes.c_double * n_in)()
        self._n_in = n_in
        self._out_refs = (ctypes.c_uint * 4)(*(p.reference for p in model.measured))
        self._out_values = (ctypes.c_double * 4)()
        self._raw = np.frombuffer(self._out_values, dtype=np.float64)
        self._time_s = 0.0
        self._failed: FmuStepError | None = None
        self._read_outputs()

    # --- stepping ------------------------------------------------------------------------------
    def advance(
        self,
        speed_setpoint_rad_s: float,
        disturbance_nm: float = 0.0,
        torque_feedforward_nm: float = 0.0,
    ) -> None:
        if torque_feedforward_nm != 0.0:
            raise FmuStepError(
                f"FMU {self.model.describe()}: no torque feed-forward input "
                f"({torque_feedforward_nm:g} N·m asked)",
                call="advance",
            )
        if self._failed is not None:
            return
        values = self._in_values
        values[0] = speed_setpoint_rad_s * self._speed_scale
        if self._n_in == 2:
            values[1] = disturbance_nm * self._dist_scale
        elif disturbance_nm != 0.0:
            raise FmuStepError(
                f"FMU {self.model.describe()}: no disturbance input mapped "
                f"({disturbance_nm:g} N·m asked)",
                call="advance",
            )
        self._call("fmi2SetReal", self._set(self._component, self._in_refs, self._n_in, values))
        self._call("fmi2DoStep", self._do_step(self._component, self._time_s, self._h, 1))
        self._time_s += self._h
        self._read_outputs()

    def advance_torque(self, torque_nm: float, disturbance_nm: float = 0.0) -> None:
        """Power stage off: the FMU cannot coast, it holds a speed set point of zero (module
        docstring); a torque other than 0 is refused."""
        if torque_nm != 0.0:
            raise FmuStepError(
                f"FMU {self.model.describe()}: no torque input ({torque_nm:g} N·m asked)",
                call="advance_torque",
            )
        self.advance(0.0, disturbance_nm)

    def _read_outputs(self) -> None:
        if self._failed is None:
            status = self._get(self._component, self._out_refs, 4, self._out_values)
            self._call("fmi2GetReal", status)
        self._measured = self._raw * self._out_scale

    def _call(self, name: str, status: int) -> None:
        if status > _OK_STATUS:
            messages = tuple(self._instance.log)
            said = "; ".join(messages) or f"status {status}"
            self._failed = FmuStepError(
                f"FMU {self.model.describe()}: {name} failed at t = {self._time_s:.6g} s: {said}",
                call=name,
                messages=messages,
            )
            raise self._failed

    # --- readings ------------------------------------------------------------------------------
    def read_measured(self, out: np.ndarray) -> None:
        out[:] = self._measured

    @property
    def motor_position_rad(self) -> float:
        return float(self._measured[0])

    @property
    def load_position(self) -> float:
        return float(self._measured[1])

    @property
    def motor_speed_rad_s(self) -> float:
        return float(self._measured[2])

    @property
    def motor_torque_nm(self) -> float:
        return float(self._measured[3])

    @property
    def time_s(self) -> float:
        return self._time_s

    @property
    def failure(self) -> FmuStepError | None:
        """The failure that stopped the plant, or None while it runs."""
        return self._failed

    @property
    def torque_limit_nm(self) -> float:
        """The FMU's own limit where it states one (data sheet), else the axis file's."""
        name = self.model.spec.mapping.nominal.get("control.torque_limit")
        value = self.model.nominal.get(name) if name else None
        if value is not None and value > 0:
            return value
        limit = self.axis.control.torque_limit
        return math.inf if limit is None else limit

    def close(self) -> None:
        self._instance.free()


def check_axis(model: FmuModel, axis: AxisConfig) -> None:
    """The axis file the drive is configured from must fit the FMU's signals."""
    where = f"FMU {model.describe()}"
    linear = model.measured[1].quantity is Quantity.LENGTH
    if linear != (axis.kind is AxisKind.LINEAR):
        raise FmuError(
            f"{where}: its load position is {'a length' if linear else 'an angle'}, the axis "
            f"file's axis.kind is {axis.kind.value!r}"
        )
    if axis.control.acceleration_feedforward:
        raise FmuError(
            f"{where}: no torque feed-forward input; control.acceleration_feedforward must be "
            "absent or 0 for an FMU axis"
        )

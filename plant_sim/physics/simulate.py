"""Closed-loop simulation (Fig. 1 / Fig. 6) of an axis file, producing a :class:`Trace`.

The position controller, vibration detector and speed regulator run in the compiled kernel
at the position cycle (:func:`simulate`), or in Python around any steppable plant such as an
FMU's (:func:`simulate_plant`); references and disturbances are arrays, one value per
position cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from regulator import RegulatorConfig, cycle
from regulator.core import detector_state_size
from regulator.loop import SteppedAxis, play
from virtual_bus.formats.axis import AxisConfig, PositionFeedback
from virtual_bus.formats.trace import RECORDED_COLUMNS, Trace

from ..errors import ScenarioError
from . import kernel as K
from .model import KernelOptions, build_params, initial_state

#: Columns of a simulated closed-loop trace, in the order of the kernel's ``O_*`` row layout:
#: the trace-file columns, then β, λ, and the detector's inputs ω_s and ω_c (rad/s, motor).
SIM_COLUMNS = (
    *RECORDED_COLUMNS,
    "disturbance",
    "beta",
    "lambda",
    "omega_s",
    "omega_c",
)
assert len(SIM_COLUMNS) == K.N_OUT


@dataclass(frozen=True)
class References:
    """Interpolator output and external disturbance, one value per position cycle.

    position: load units; speed: load units/s (ω_s = k_r·speed); disturbance_nm: N·m reflected
    to the motor, positive pushes the load towards +x.
    """

    position: np.ndarray
    speed: np.ndarray
    disturbance_nm: np.ndarray

    def __post_init__(self) -> None:
        arrays = {
            "position": self.position,
            "speed": self.speed,
            "disturbance_nm": self.disturbance_nm,
        }
        n = len(self.position)
        for name, arr in arrays.items():
            arr = np.ascontiguousarray(arr, dtype=float)
            if arr.ndim != 1 or len(arr) != n:
                raise ScenarioError(f"{name}: shape {arr.shape}, expected ({n},)")
            if not np.all(np.isfinite(arr)):
                raise ScenarioError(f"{name}: contains NaN or inf")
            object.__setattr__(self, name, arr)
        if n < 1:
            raise ScenarioError("references are empty")

    @classmethod
    def from_position(
        cls, position: np.ndarray, cycle_s: float, disturbance_nm: np.ndarray | None = None
    ) -> References:
        """Speed from the position reference by forward difference (the interpolator's speed
        over the coming cycle)."""
        position = np.asarray(position, dtype=float)
        speed = np.empty_like(position)
        speed[:-1] = np.diff(position) / cycle_s
        speed[-1] = speed[-2] if len(position) > 1 else 0.0
        dist = np.zeros_like(position) if disturbance_nm is None else disturbance_nm
        return cls(position, speed, dist)


def simulate(
    axis: AxisConfig,
    refs: References,
    regulator: RegulatorConfig | None = None,
    options: KernelOptions = KernelOptions(),
    start_position: float | None = None,
) -> Trace:
    """Run the closed loop; one trace row per position cycle.

    ``regulator``: None runs the ordinary control of Fig. 1 (the detector still measures β);
    a config with ``enabled=True`` inserts the speed regulator of Fig. 6 / eq. 15.
    Columns: the trace-file columns plus ``beta``, ``lambda``, ``omega_s``, ``omega_c``.

    The axis file's feed-forward works on ``refs.speed``: ω_s·k_vff is added to the speed set
    point (``control.velocity_feedforward``) and J_ff·k_r·Δspeed/T_p to the torque set point
    (``control.acceleration_feedforward``); with ``control.sensor_time_offset`` the recorded
    and fed-back positions are the sensor readings (see :mod:`plant_sim.physics.kernel`).
    """
    p = build_params(axis, regulator, options)
    x0 = float(refs.position[0]) if start_position is None else start_position
    st = initial_state(axis, x0)
    reg_state = np.zeros(detector_state_size(int(p[K.P_REG_N])))
    out = np.empty((len(refs.position), K.N_OUT))
    cyc = K.cycle_block(p)
    K.run_closed_loop(p, st, reg_state, cyc, refs.position, refs.speed, refs.disturbance_nm, out)
    return Trace({name: out[:, i] for i, name in enumerate(SIM_COLUMNS)})


def simulate_plant(
    plant: SteppedAxis,
    axis: AxisConfig,
    refs: References,
    regulator: RegulatorConfig | None = None,
    setpoint_delay_cycles: int = 0,
) -> Trace:
    """The closed loop of :func:`simulate` around any steppable plant (an FMU's, started
    where the caller placed it): the same cycle (:mod:`regulator.cycle`) in Python,
    :func:`regulator.loop.play`; the same columns. ``axis``: the controller (k_r, k_v, the
    cycle, the velocity feed-forward, the position feedback); no limits, as :func:`simulate`.
    """
    c = axis.control
    reg = regulator or RegulatorConfig(kv=c.kv, cycle_s=c.position_cycle, enabled=False)
    block = cycle.block(
        axis.transmission_ratio,
        c.kv,
        c.position_cycle,
        velocity_feedforward=c.velocity_feedforward or 0.0,
        regulator_on=regulator is not None and regulator.enabled,
        n=reg.n,
        tv_s=reg.effective_tv_s,
        tf_s=reg.tf_s,
        beta_t_rad_s=reg.beta_t_rad_s,
    )
    run = play(
        plant,
        refs.position,
        refs.speed,
        block,
        refs.disturbance_nm,
        delay_cycles=setpoint_delay_cycles,
        motor_feedback=c.position_feedback is PositionFeedback.MOTOR,
    )
    time = np.arange(len(refs.position)) * c.position_cycle
    return Trace({"time": time} | {name: run[name] for name in SIM_COLUMNS if name != "time"})

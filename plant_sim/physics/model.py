"""The axis as a steppable plant: kernel parameters from an axis file, and :class:`AxisPlant`.

:class:`AxisPlant` is what a drive runs: the mechanics plus the drive's own loops (PI speed
controller, dead time, current loop). It advances one position cycle per call with a speed set
point, and exposes what a drive measures. The position controller is *not* in here: the
simulator's closed loop (:mod:`plant_sim.physics.simulate`) and the bridge (over the bus) close it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from regulator import (
    DEFAULT_BETA_T_RAD_S,
    DEFAULT_N,
    DEFAULT_TF_S,
    RegulatorConfig,
    default_tv_s,
)
from virtual_bus.formats.axis import AxisConfig, PositionFeedback

from ..errors import ScenarioError
from ..plant import Plant
from . import kernel as K

#: Detector window when only monitoring (no regulator configured): the paper's n.
MONITOR_N = DEFAULT_N

#: Largest ω·dt of a mechanics substep (ω_r for an elastic axis); see kernel docstring.
MAX_OMEGA_DT = 0.1


#: Most mechanics substeps per speed cycle (also the limit of ``KernelOptions.substeps``).
MAX_SUBSTEPS = 10_000


def default_substeps(axis: AxisConfig) -> int:
    """Substeps per speed cycle so that ω_r·dt <= MAX_OMEGA_DT (1 for a rigid axis).
    Raises ScenarioError when that needs more than :data:`MAX_SUBSTEPS` (an axis too stiff
    for its speed cycle to simulate, e.g. an extreme transmission ratio)."""
    wr = axis.resonance
    if wr is None:
        return 1
    need = wr * axis.control.speed_cycle / MAX_OMEGA_DT
    if not need <= MAX_SUBSTEPS:
        raise ScenarioError(
            f"resonance omega_r = {wr:.6g} rad/s (eq. 4) needs {need:.3g} mechanics substeps "
            f"per speed cycle of {axis.control.speed_cycle:g} s (omega_r*dt <= {MAX_OMEGA_DT}); "
            f"at most {MAX_SUBSTEPS} are simulated: check transmission_ratio, masses and "
            "antiresonance of the axis file"
        )
    return max(1, math.ceil(need))


@dataclass(frozen=True)
class KernelOptions:
    """Numerical and loop options that are not physics of the axis.

    substeps: mechanics substeps per speed cycle (None: :func:`default_substeps`).
    setpoint_delay_cycles: 0, or 1 for the one-cycle PDO delay of a CANopen loop (the set point
    computed at SYNC k takes effect at SYNC k+1).
    """

    substeps: int | None = None
    setpoint_delay_cycles: int = 0

    def __post_init__(self) -> None:
        if self.substeps is not None and not 1 <= self.substeps <= MAX_SUBSTEPS:
            raise ScenarioError(f"substeps = {self.substeps}: allowed 1..10000")
        if self.setpoint_delay_cycles not in (0, 1):
            raise ScenarioError(
                f"setpoint_delay_cycles = {self.setpoint_delay_cycles}: allowed 0 or 1"
            )


def build_params(
    axis: AxisConfig,
    regulator: RegulatorConfig | None = None,
    options: KernelOptions = KernelOptions(),
) -> np.ndarray:
    """The kernel's parameter vector (``kernel.P_*``) for an axis, regulator and options."""
    c, m, fr, dist = axis.control, axis.mechanics, axis.friction, axis.disturbance
    kr = axis.transmission_ratio
    p = np.zeros(K.N_PARAMS)
    p[K.P_KR] = kr
    p[K.P_J1] = axis.motor_side_inertia
    if axis.is_rigid:
        p[K.P_RIGID] = 1.0
        p[K.P_M] = m.load_mass + axis.motor_side_inertia * kr**2
    else:
        p[K.P_M] = m.load_mass
        p[K.P_K] = axis.stiffness
        p[K.P_C] = axis.damping_coefficient
        p[K.P_HALF_GAP] = 0.5 * (m.backlash or 0.0)
    coulomb = fr.coulomb or 0.0
    viscous = fr.viscous or 0.0
    p[K.P_FC_POS] = kr * coulomb
    p[K.P_FV_POS] = kr * viscous
    p[K.P_FC_NEG] = kr * (fr.coulomb_negative if fr.coulomb_negative is not None else coulomb)
    p[K.P_FV_NEG] = kr * (fr.viscous_negative if fr.viscous_negative is not None else viscous)
    if fr.stribeck is not None and fr.stribeck_speed is not None:
        p[K.P_FS] = kr * fr.stribeck
        p[K.P_VS] = fr.stribeck_speed
    p[K.P_V_CREEP] = fr.creep_speed or 0.0
    p[K.P_F_CONST] = -kr * (dist.constant_torque or 0.0)
    if dist.periodic_amplitude is not None and dist.periodic_period is not None:
        p[K.P_F_PER] = kr * dist.periodic_amplitude
        p[K.P_PER_PERIOD] = dist.periodic_period
        p[K.P_PER_PHASE] = dist.periodic_phase or 0.0
    p[K.P_KSP] = c.ksp
    p[K.P_KI] = 0.0 if c.tsi is None else c.ksp / c.tsi
    p[K.P_TAU_LIM] = math.inf if c.torque_limit is None else c.torque_limit
    nsub = options.substeps or default_substeps(axis)
    dt_sub = c.speed_cycle / nsub
    p[K.P_LAG_ALPHA] = math.exp(-dt_sub / c.current_lag) if c.current_lag else 0.0
    # exact mean over a substep of the lag's response: start + (cmd - start)·P_LAG_MEAN
    p[K.P_LAG_MEAN] = (
        1.0 - c.current_lag / dt_sub * (1.0 - p[K.P_LAG_ALPHA]) if c.current_lag else 1.0
    )
    p[K.P_SPD_ALPHA] = math.exp(-c.speed_cycle / c.speed_filter) if c.speed_filter else 0.0
    n_delay = round((c.delay or 0.0) / c.speed_cycle)
    if n_delay > K.MAX_DELAY:
        raise ScenarioError(
            f"control.delay = {c.delay} s is {n_delay} speed cycles; at most {K.MAX_DELAY}"
        )
    p[K.P_DELAY_N] = n_delay
    p[K.P_TSC] = c.speed_cycle
    p[K.P_NSC] = c.speed_cycles_per_position_cycle
    p[K.P_NSUB] = nsub
    p[K.P_TP] = c.position_cycle
    p[K.P_KV] = c.kv
    p[K.P_FB_LOAD] = 1.0 if c.position_feedback is PositionFeedback.LOAD else 0.0
    p[K.P_SP_DELAY] = float(options.setpoint_delay_cycles)
    if regulator is None:
        # ordinary control (Fig. 1): no regulator, so none of its rules apply (e.g. the
        # sampling condition at a high k_v); the detector still reports β with the defaults
        p[K.P_REG_ON] = 0.0
        p[K.P_REG_N] = MONITOR_N
        p[K.P_REG_TV] = default_tv_s(c.kv)
        p[K.P_REG_TF] = DEFAULT_TF_S
        p[K.P_REG_BT] = DEFAULT_BETA_T_RAD_S
    else:
        p[K.P_REG_ON] = 1.0 if regulator.enabled else 0.0
        p[K.P_REG_N] = regulator.n
        p[K.P_REG_TV] = regulator.effective_tv_s
        p[K.P_REG_TF] = regulator.tf_s
        p[K.P_REG_BT] = regulator.beta_t_rad_s
    p[K.P_KVFF] = c.velocity_feedforward or 0.0
    p[K.P_JFF] = c.acceleration_feedforward or 0.0
    _reading_delays(axis, p)
    _setpoint_delay(axis, p)
    if c.scale_error_amplitude and c.scale_error_period:
        p[K.P_SCALE_AMP] = c.scale_error_amplitude
        p[K.P_SCALE_PERIOD] = c.scale_error_period
        p[K.P_SCALE_PHASE] = c.scale_error_phase or 0.0
    p[K.P_INV_KR] = 1.0 / p[K.P_KR]
    # a lumped rigid model may have no motor-side inertia (J1 = 0 is then unused)
    p[K.P_INV_J1] = 1.0 / p[K.P_J1] if p[K.P_J1] > 0.0 else 0.0
    p[K.P_INV_M] = 1.0 / p[K.P_M]
    return p


def _reading_delays(axis: AxisConfig, p: np.ndarray) -> None:
    """How late the load and the motor readings are (speed cycles, whole and fraction):
    the load by a positive ``control.sensor_time_offset``, the motor readings by a negative
    one's |offset|, both by ``control.measurement_delay`` on top."""
    c = axis.control
    offset = c.sensor_time_offset or 0.0
    common = c.measurement_delay or 0.0
    load_s = common + max(offset, 0.0)
    motor_s = common + max(-offset, 0.0)
    longest = 0
    for on, whole_i, frac_i, late_s in (
        (K.P_LOAD_DLY_ON, K.P_LOAD_DLY_N, K.P_LOAD_DLY_FRAC, load_s),
        (K.P_MOT_DLY_ON, K.P_MOT_DLY_N, K.P_MOT_DLY_FRAC, motor_s),
    ):
        if late_s == 0.0:
            continue
        cycles = late_s / c.speed_cycle
        whole = math.floor(cycles)
        p[on] = 1.0
        p[whole_i] = whole
        p[frac_i] = cycles - whole
        longest = max(longest, whole)
    if longest + 2 > K.MAX_HIST:
        raise ScenarioError(
            f"control.sensor_time_offset = {offset} s with control.measurement_delay = "
            f"{common} s reads a sensor {longest} speed cycles late; at most {K.MAX_HIST - 2}"
        )
    if p[K.P_LOAD_DLY_ON] or p[K.P_MOT_DLY_ON]:
        p[K.P_HIST_ON] = 1.0
        p[K.P_HIST_LEN] = longest + 2
    else:
        p[K.P_HIST_LEN] = 1.0


def _setpoint_delay(axis: AxisConfig, p: np.ndarray) -> None:
    """The set point applied late: ``control.setpoint_delay`` d0 growing by
    ``control.setpoint_delay_rate`` per second of the run, clipped to
    :data:`kernel.MAX_SETPOINT_DELAY_S`; the history holds the longest delay it can reach."""
    c = axis.control
    d0 = c.setpoint_delay or 0.0
    rate = c.setpoint_delay_rate or 0.0
    if d0 == 0.0 and rate == 0.0:
        return
    longest_s = min(d0, K.MAX_SETPOINT_DELAY_S) if rate == 0.0 else K.MAX_SETPOINT_DELAY_S
    length = math.floor(longest_s / c.speed_cycle + 1e-9) + 2
    if length > K.MAX_SP_HIST:
        raise ScenarioError(
            f"control.setpoint_delay = {d0} s (rate {rate} s/s) may reach {longest_s} s, "
            f"{length - 2} speed cycles of {c.speed_cycle:g} s; at most {K.MAX_SP_HIST - 2}"
        )
    p[K.P_SP_DLY_ON] = 1.0
    p[K.P_SP_DLY0] = d0
    p[K.P_SP_DLY_RATE] = rate
    p[K.P_SPH_LEN] = length


def initial_state(axis: AxisConfig, position: float = 0.0) -> np.ndarray:
    """At rest, load at ``position`` (load units), motor centred in the free play."""
    st = np.zeros(K.N_STATE)
    st[K.S_X] = position
    st[K.S_TH] = axis.transmission_ratio * position
    st[K.S_TH_PREV] = st[K.S_TH]
    # sensor history: at rest since forever
    st[K.S_HX0 : K.S_HX0 + K.MAX_HIST] = st[K.S_X]
    st[K.S_HTH0 : K.S_HTH0 + K.MAX_HIST] = st[K.S_TH]
    return st


class AxisPlant(Plant):
    """Mechanics + the drive's inner loops of one axis, stepped one position cycle at a time,
    in the compiled kernel (a :class:`plant_sim.plant.Plant` with every capability).

    >>> plant = AxisPlant(load_axis("config/paper_axis.toml"))
    >>> plant.advance(speed_setpoint_rad_s=10.0)      # one position cycle (1 ms)
    >>> plant.motor_position_rad, plant.load_position  # what the encoders read
    """

    def __init__(
        self,
        axis: AxisConfig,
        options: KernelOptions = KernelOptions(),
        position: float = 0.0,
    ) -> None:
        super().__init__(axis)
        self._p = build_params(axis, None, options)
        self._st = initial_state(axis, position)

    def advance(
        self,
        speed_setpoint_rad_s: float,
        disturbance_nm: float = 0.0,
        torque_feedforward_nm: float = 0.0,
    ) -> None:
        """Run one position cycle at a constant speed set point (rad/s, motor), external
        disturbance (N·m reflected to the motor, positive pushes towards +x) and torque
        feed-forward (N·m added to the speed controller's output, before the limit)."""
        K.advance(
            self._p,
            self._st,
            float(speed_setpoint_rad_s),
            float(disturbance_nm),
            float(torque_feedforward_nm),
        )

    def stepper(self) -> Callable[[float, float, float], None]:
        """:meth:`advance` for a caller that passes floats every position cycle (a drive):
        the compiled step itself, bound to this plant, without the conversions."""
        return functools.partial(K.advance, self._p, self._st)

    def advance_torque(self, torque_nm: float, disturbance_nm: float = 0.0) -> None:
        """Run one position cycle with the speed loop bypassed at a fixed torque set point
        (0 N·m: power stage off, the axis coasts); clears the speed controller's integral."""
        K.advance_torque(self._p, self._st, float(torque_nm), float(disturbance_nm))

    def set_torque_limit_nm(self, limit_nm: float) -> None:
        """Change the drive's torque limit (the PI output clamp and its anti-windup), N·m;
        ``math.inf`` for none. Raises ScenarioError for a negative or NaN value."""
        if not limit_nm >= 0.0:
            raise ScenarioError(f"torque limit {limit_nm} N·m: must be >= 0 (inf for none)")
        self._p[K.P_TAU_LIM] = float(limit_nm)

    @property
    def torque_limit_nm(self) -> float:
        return float(self._p[K.P_TAU_LIM])

    def warm_up(self) -> None:
        """Load (or compile, on an empty numba cache) every compiled function a drive calls, on
        a throw-away plant of the same axis: ``advance`` (Operation enabled, ramps),
        ``advance_torque`` (every other state), ``read_measured`` (the measuring systems
        after each step) and the three readings one by one (SDO reads of 6064h, 606Ch,
        60E4h): each is a compiled function of its own, compiled at its first call."""
        plant = AxisPlant(self.axis)
        plant.advance(0.0)
        plant.advance_torque(0.0)
        plant.read_measured(np.zeros(4))
        _ = (plant.motor_position_rad, plant.motor_speed_rad_s, plant.load_position)

    @property
    def time_s(self) -> float:
        return float(self._st[K.S_T])

    @property
    def motor_position_rad(self) -> float:
        """Motor encoder reading (older by control.measurement_delay, and by
        |control.sensor_time_offset| when that is negative)."""
        return float(K.motor_measured(self._p, self._st))

    @property
    def motor_speed_rad_s(self) -> float:
        """The drive's speed actual value (encoder difference over the last speed cycle,
        through the ``control.speed_filter`` low-pass when the axis states one), shifted like
        :attr:`motor_position_rad`."""
        return float(K.motor_speed_measured(self._p, self._st))

    @property
    def load_position(self) -> float:
        """Direct measuring system, load units (older by control.measurement_delay, and by
        control.sensor_time_offset when positive: read at t − d, interpolated between speed
        cycles; with the scale's periodic error, control.scale_error_*)."""
        return float(K.load_measured(self._p, self._st))

    @property
    def load_speed(self) -> float:
        return float(self._st[K.S_V])

    @property
    def motor_torque_nm(self) -> float:
        return float(self._st[K.S_TAU])

    def read_measured(self, out: np.ndarray) -> None:
        """:attr:`motor_position_rad`, :attr:`load_position`, :attr:`motor_speed_rad_s` and
        :attr:`motor_torque_nm` into ``out`` (float64, 4 elements) in one compiled call (a
        drive reads them after every step)."""
        K.read_measured(self._p, self._st, out)

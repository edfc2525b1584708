"""The independent test plant as a function: axis file + references -> trace.

Reads the axis file through :mod:`virtual_bus.formats.axis` (the FORMAT is shared) and nothing
else of plant_sim's physics: the equations, the integrator, the friction and contact laws, the
sensors and the controllers are this package's own (see the package docstring).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from virtual_bus.formats.axis import AxisConfig, AxisKind, PositionFeedback
from virtual_bus.formats.trace import RECORDED_COLUMNS, Trace

from . import core as C

#: Columns of :func:`simulate`'s trace (trace-file names).
COLUMNS = (*RECORDED_COLUMNS, "disturbance")


@dataclass(frozen=True)
class PlantOptions:
    """Modelling choices of the independent plant that the axis file does not state.

    friction_smoothing: load units/s, tanh width of Coulomb friction (no stiction logic);
    contact_smoothing_fraction: penetration (as a fraction of the free play) over which the
    contact damping engages; speed_filter_s: first-order filter on the encoder speed (s) for
    an axis file without ``control.speed_filter`` (a file that states it sets it);
    motor_counts_per_rev / load_resolution: sensor quantisation (0: exact);
    current_loop_per_speed_cycle: current-loop samples per speed cycle (PI current loop on an
    R-L winding of electrical time constant ``electrical_time_s``, tuned for the axis file's
    current_lag); max_h_lambda: RK4 step limit, h·(fastest rate) <= this.
    """

    friction_smoothing: float = 2e-5
    contact_smoothing_fraction: float = 0.05
    speed_filter_s: float = 5e-5
    motor_counts_per_rev: int = 2**20
    load_resolution: float = 5e-9
    current_loop_per_speed_cycle: int = 2
    electrical_time_s: float = 0.002
    max_h_lambda: float = 0.4

    def __post_init__(self) -> None:
        if not self.friction_smoothing > 0.0:
            raise ValueError(f"friction_smoothing = {self.friction_smoothing}: must be > 0")
        if not 1 <= self.current_loop_per_speed_cycle <= 16:
            raise ValueError(
                f"current_loop_per_speed_cycle = {self.current_loop_per_speed_cycle}: 1..16"
            )
        if not 0.0 < self.max_h_lambda <= 2.0:
            raise ValueError(f"max_h_lambda = {self.max_h_lambda}: allowed (0, 2]")


def parameters(axis: AxisConfig, options: PlantOptions = PlantOptions()) -> np.ndarray:
    """The core's parameter vector for an axis."""
    m, fr, d, c = axis.mechanics, axis.friction, axis.disturbance, axis.control
    kr = axis.transmission_ratio
    j1 = m.motor_inertia + m.screw_inertia
    q = np.zeros(C.N_Q)
    q[C.Q_KR] = kr
    rigid = m.antiresonance is None
    q[C.Q_RIGID] = 1.0 if rigid else 0.0
    q[C.Q_J1] = j1
    q[C.Q_M] = m.load_mass + (j1 * kr**2 if rigid else 0.0)
    rates = [1.0 / options.electrical_time_s]
    if not rigid:
        k = m.load_mass * m.antiresonance**2
        q[C.Q_K] = k
        q[C.Q_C] = 2.0 * (m.damping_ratio or 0.0) * k / m.antiresonance
        gap = 0.5 * (m.backlash or 0.0)
        q[C.Q_GAP] = gap
        q[C.Q_CONTACT_SMOOTH] = max(options.contact_smoothing_fraction * gap, 1e-12)
        rates.append(math.sqrt(k / m.load_mass + k / (j1 * kr**2)))
    coul = fr.coulomb or 0.0
    visc = fr.viscous or 0.0
    q[C.Q_FC_P] = kr * coul
    q[C.Q_FC_N] = kr * (fr.coulomb_negative if fr.coulomb_negative is not None else coul)
    q[C.Q_FV_P] = kr * visc
    q[C.Q_FV_N] = kr * (fr.viscous_negative if fr.viscous_negative is not None else visc)
    if fr.stribeck is not None and fr.stribeck_speed is not None:
        q[C.Q_FS] = kr * fr.stribeck
        q[C.Q_VS] = fr.stribeck_speed
    q[C.Q_V_SMOOTH] = options.friction_smoothing
    # friction's slope at rest acts like a stiff damper on the lightest mass it moves
    mass_friction = m.load_mass if not rigid else q[C.Q_M]
    slope = (max(q[C.Q_FC_P], q[C.Q_FC_N]) + q[C.Q_FS]) / options.friction_smoothing
    rates.append(slope / mass_friction)
    q[C.Q_F_CONST] = -kr * (d.constant_torque or 0.0)
    if d.periodic_amplitude is not None and d.periodic_period is not None:
        q[C.Q_F_PER] = kr * d.periodic_amplitude
        q[C.Q_PER_LEN] = d.periodic_period
        q[C.Q_PER_PHASE] = d.periodic_phase or 0.0
    q[C.Q_KV] = c.kv
    q[C.Q_KVFF] = c.velocity_feedforward or 0.0
    q[C.Q_JFF] = c.acceleration_feedforward or 0.0
    q[C.Q_KSP] = c.ksp
    q[C.Q_KI] = 0.0 if c.tsi is None else c.ksp / c.tsi
    q[C.Q_TLIM] = math.inf if c.torque_limit is None else c.torque_limit
    q[C.Q_FB_LOAD] = 1.0 if c.position_feedback is PositionFeedback.LOAD else 0.0
    q[C.Q_TP] = c.position_cycle
    q[C.Q_TSC] = c.speed_cycle
    q[C.Q_NSC] = c.speed_cycles_per_position_cycle
    ncc = options.current_loop_per_speed_cycle
    q[C.Q_NCC] = ncc
    tcc = c.speed_cycle / ncc
    if c.current_lag:
        q[C.Q_IDEAL_CURRENT] = 0.0
        q[C.Q_L_E] = options.electrical_time_s
        q[C.Q_CKP] = options.electrical_time_s / c.current_lag
        q[C.Q_CKI] = 1.0 / c.current_lag
        rates.append(1.0 / c.current_lag)
    else:
        q[C.Q_IDEAL_CURRENT] = 1.0
        q[C.Q_L_E] = options.electrical_time_s
    n_delay = round((c.delay or 0.0) / tcc)
    if n_delay >= C.DELAY_RING:
        raise ValueError(f"control.delay = {c.delay} s: at most {C.DELAY_RING - 1} samples")
    q[C.Q_DELAY_N] = n_delay
    # the drive's speed filter: the axis file's setting when it states one, else this plant's
    q[C.Q_SPEED_FILTER] = options.speed_filter_s if c.speed_filter is None else c.speed_filter
    if options.motor_counts_per_rev > 0:
        q[C.Q_MOTOR_QUANTUM] = 2.0 * math.pi / options.motor_counts_per_rev
    if axis.kind is AxisKind.LINEAR:
        q[C.Q_LOAD_QUANTUM] = options.load_resolution
    else:
        q[C.Q_LOAD_QUANTUM] = options.load_resolution * 2.0 * math.pi / 0.01  # same counts
    offset = c.sensor_time_offset or 0.0
    if abs(offset) / tcc >= C.HISTORY - 2:
        raise ValueError(f"control.sensor_time_offset = {offset} s: too long for the history")
    q[C.Q_OFFSET] = offset
    q[C.Q_NRK] = max(1, math.ceil(tcc * max(rates) / options.max_h_lambda))
    return q


def simulate(
    axis: AxisConfig,
    position: np.ndarray,
    speed: np.ndarray,
    disturbance_nm: np.ndarray | None = None,
    options: PlantOptions = PlantOptions(),
) -> Trace:
    """Closed loop on the reference (load units, load units/s, one value per position cycle)
    and an external load torque (N·m at the motor, positive pushes towards +x)."""
    position = np.ascontiguousarray(position, dtype=float)
    speed = np.ascontiguousarray(speed, dtype=float)
    dist = (
        np.zeros_like(position)
        if disturbance_nm is None
        else np.ascontiguousarray(disturbance_nm, dtype=float)
    )
    if not len(position) == len(speed) == len(dist):
        raise ValueError("position, speed and disturbance differ in length")
    q = parameters(axis, options)
    out = np.empty((len(position), len(COLUMNS)))
    C.run(q, float(position[0]), position, speed, dist, out)
    return Trace({name: out[:, i] for i, name in enumerate(COLUMNS)})


class SteppedPlant:
    """This plant as a drive sees it: the speed set point in, one position cycle per call,
    the sensors out (the position loop is the caller's -- the bridge's controller and the
    paper's regulator, or a frequency-response excitation). Same physics and sensors as
    :func:`simulate` (which runs the same :func:`core.advance`)."""

    def __init__(
        self, axis: AxisConfig, options: PlantOptions = PlantOptions(), position: float = 0.0
    ) -> None:
        self.axis = axis
        self._q = parameters(axis, options)
        self._s = np.zeros(C.N_S)
        self._y = np.zeros(5)
        self._hist = (np.zeros(C.HISTORY), np.zeros(C.HISTORY), np.zeros(C.HISTORY))
        self._ring = np.zeros(C.DELAY_RING)
        self._reading = np.zeros(4)
        C.init(self._q, float(position), self._s, self._y, *self._hist, self._ring)
        self._sense()

    def _sense(self) -> None:
        C.sense(self._q, self._s, self._y, *self._hist, self._reading)

    def advance(self, speed_setpoint_rad_s: float, disturbance_nm: float = 0.0) -> None:
        """One position cycle at a constant speed set point (rad/s at the motor) and an
        external load torque (N m at the motor, positive pushes towards +x)."""
        kr = self._q[C.Q_KR]
        C.advance(
            self._q,
            self._s,
            self._y,
            *self._hist,
            self._ring,
            float(speed_setpoint_rad_s),
            0.0,
            kr * float(disturbance_nm),
        )
        self._sense()

    @property
    def motor_position_rad(self) -> float:
        return float(self._reading[0])

    @property
    def motor_speed_rad_s(self) -> float:
        return float(self._reading[1])

    @property
    def load_position(self) -> float:
        return float(self._reading[2])

    @property
    def motor_torque_nm(self) -> float:
        return float(self._reading[3])

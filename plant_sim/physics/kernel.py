"""Fixed-step compiled kernel of the servo axis and its cascade control (numba, nopython).

Physics (paper section III, Fig. 1 and Fig. 3), in load coordinates for the load and motor
coordinates for the motor side:

    J1 * dω_m/dt = τ_m − F_s / k_r                 motor + coupling + screw (J1 = J_m + J_screw)
    M  * dv_l/dt = F_s + F_ext(x_l, t) − F_f(v_l)   carriage (load mass M, or J_l for rotary)
    Δ = θ_m / k_r − x_l                             screw-nut deflection incl. free play
    F_s = dz(Δ)·k + c·dΔ/dt                         dead zone of total width δ (eq. 5's model),
                                                    contact force only pushes (clamped) when δ > 0

with k = M·ω_a² (eq. 2), c = 2·ξ_a·k/ω_a, F_f the friction of the axis file reflected back to
the load (force = k_r·torque), F_ext the load torques of ``[disturbance]`` and the external
disturbance input. A rigid axis (no ω_a) is one mass M + J1·k_r² in load coordinates.

Integration: staggered leapfrog (symplectic Euler with velocities at half steps, one force
evaluation per step) with ``nsub`` fixed substeps per speed cycle.
Friction is a set-valued force: a kick never lets Coulomb friction reverse the load's motion
(the velocity is clamped to zero), and a load at rest stays at rest while the applied force is
within the static level (Karnopp). The dead-zone impacts are resolved by the substep, which is
chosen so that ω_r·dt <= 0.1 (model.MAX_OMEGA_DT); tests/plant_sim/physics/test_convergence.py shows
step-halving convergence.

Control (sampled as in a drive): every speed cycle the motor speed is measured as the backward
difference of the motor encoder and passes the drive's optional first-order speed filter
(``control.speed_filter``, exact at the speed cycle), the PI speed controller (k_sp, T_si,
clamping anti-windup at the torque limit) computes the torque set point, which passes an
optional dead time (whole speed cycles) and the current loop (ideal or first-order lag).
Every position cycle the P position controller (eq. 7) and the paper's vibration detector and
speed regulator (Fig. 5, eq. 15, from :mod:`regulator.core`, compiled here) compute the speed
set point.

Where a machine's signals arrive late (axis file, docs/axis-file.md): the drive may apply the
speed set point (and the torque feed-forward with it) d(t) = clip(d0 + rate·t, 0, 0.1 s) after
it gets it (``control.setpoint_delay``, ``setpoint_delay_rate``: a history of the set point
as it arrives, one sample per speed cycle, read at d with linear interpolation between
samples, so a simulation is continuous in d); the readings the position loop and the
recording get may be late (``control.measurement_delay``, plus ``sensor_time_offset`` for the
one reading it concerns: a history of x, θ and the speed actual value per speed cycle, read
the same way) while the drive's own speed loop reads the encoder at once; the load scale may
read x + A·sin(2πx/P + φ) (``control.scale_error_*``: a measurement error, not a force).

All arrays are float64; the layouts are the ``P_*``, ``S_*`` and ``O_*`` index constants.
"""

from __future__ import annotations

import math
import types

import numba
import numpy as np

from regulator import compiled as _compiled
from regulator import core as _core
from regulator import cycle as _cycle

_njit = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=True)
# Helpers called from the loops are inlined at numba IR level: a plain call passes the arrays
# with reference counting, which cost ~30x the arithmetic of a substep.
_inline = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=True, inline="always")
detector_step = _inline(_core.detector_step)
switching_factor = _inline(_core.switching_factor)
regulated_speed = _inline(_core.regulated_speed)
position_command = _inline(_core.position_command)
_kernel_core = types.ModuleType("regulator.core (the kernel's)")
vars(_kernel_core).update(
    detector_step=detector_step,
    switching_factor=switching_factor,
    regulated_speed=regulated_speed,
    position_command=position_command,
)


#: regulator.cycle's one composition of the position cycle, compiled with the kernel's flags
#: against the inlined core above (regulator.compiled.cycle_copy; its own code names, since the
#: bridge compiles the same source exactly, and numba compiles a callee with its caller's
#: fastmath, so the kernel must not call the bridge's compiled functions). One call per
#: position cycle; measure and apply are inlined into it.
_kernel_cycle = _compiled.cycle_copy(_njit, _inline, _kernel_core, prefix="kernel_")
position_cycle = _kernel_cycle.position_cycle
_CYCLE_OK = _cycle.OK
_Y_OMEGA_S, _Y_OMEGA_C, _Y_OMEGA_R = _cycle.Y_OMEGA_S, _cycle.Y_OMEGA_C, _cycle.Y_OMEGA_R
_Y_BETA, _Y_LAMBDA = _cycle.Y_BETA, _cycle.Y_LAMBDA

# --- parameter vector --------------------------------------------------------------------
(
    P_KR,  # transmission ratio k_r, motor rad per load unit
    P_J1,  # kg m^2, motor side inertia (rigid: unused)
    P_M,  # load mass (rigid: total mass in load coordinates M + J1 k_r^2)
    P_RIGID,  # 1.0: rigid one-mass axis
    P_K,  # N/m, stiffness of the screw-nut element (load coordinates)
    P_C,  # N s/m, its damping
    P_HALF_GAP,  # half the total free play, load units
    P_FC_POS,  # N, Coulomb friction force at the load for v > 0
    P_FV_POS,  # N per load unit/s, viscous, v > 0
    P_FC_NEG,  # N, Coulomb, v < 0
    P_FV_NEG,  # N per load unit/s, viscous, v < 0
    P_FS,  # N, Stribeck excess static friction
    P_VS,  # load units/s, Stribeck speed (0: none)
    P_F_CONST,  # N, constant load force (= -k_r * constant_torque)
    P_F_PER,  # N, amplitude of the position-periodic force (= k_r * periodic_amplitude)
    P_PER_PERIOD,  # load units
    P_PER_PHASE,  # rad
    P_KSP,  # N m s/rad
    P_KI,  # N m/rad (= ksp / tsi; 0: P-only)
    P_TAU_LIM,  # N m (inf: none)
    P_LAG_ALPHA,  # exp(-dt_sub / current_lag) (0: ideal current loop)
    P_DELAY_N,  # dead time in whole speed cycles
    P_TSC,  # s, speed cycle
    P_NSC,  # speed cycles per position cycle
    P_NSUB,  # mechanics substeps per speed cycle
    P_TP,  # s, position cycle
    P_KV,  # 1/s, position gain
    P_FB_LOAD,  # 1.0: position loop on the load scale, 0.0: on the motor encoder
    P_SP_DELAY,  # 1.0: the speed set point takes effect one position cycle later (PDO delay)
    P_REG_ON,  # 1.0: eq. 15 regulator in the loop (the detector always measures beta)
    P_REG_N,  # detector window n (n + 1 samples)
    P_REG_TV,  # s, T_v
    P_REG_TF,  # s, T_f
    P_REG_BT,  # rad/s, beta_T
    P_INV_KR,  # 1 / k_r  (reciprocals: divisions would dominate the substep's critical path)
    P_INV_J1,  # 1 / J1
    P_INV_M,  # 1 / P_M
    P_LAG_MEAN,  # mean of the lag's step response over a substep: T/dt·(1 − alpha) (1: ideal)
    P_KVFF,  # velocity feed-forward gain on ω_s (0: none)
    P_JFF,  # kg m^2, acceleration feed-forward inertia (0: none)
    P_HIST_ON,  # 1.0: a reading is taken from the sensor history (a reading delay > 0)
    P_LOAD_DLY_N,  # whole speed cycles the load reading is late (sensor offset + delay)
    P_LOAD_DLY_FRAC,  # fraction of a speed cycle on top of P_LOAD_DLY_N
    P_HIST_LEN,  # ring-buffer length in use (>= the larger reading delay in cycles + 2)
    P_V_CREEP,  # load units/s, creep speed of a regularised friction law (0: set-valued)
    P_SPD_ALPHA,  # exp(-T_sc / speed_filter): speed-measurement filter pole (0: no filter)
    P_LOAD_DLY_ON,  # 1.0: the load reading is late (P_LOAD_DLY_N, P_LOAD_DLY_FRAC)
    P_MOT_DLY_ON,  # 1.0: the motor readings (encoder, speed actual value) are late
    P_MOT_DLY_N,  # whole speed cycles the motor readings are late
    P_MOT_DLY_FRAC,  # fraction of a speed cycle on top of P_MOT_DLY_N
    P_SP_DLY_ON,  # 1.0: the drive applies the speed set point late (control.setpoint_delay)
    P_SP_DLY0,  # s, set-point dead time at t = 0
    P_SP_DLY_RATE,  # s/s, its growth per second of the run (control.setpoint_delay_rate)
    P_SPH_LEN,  # set-point history ring length in use (>= largest delay in cycles + 2)
    P_SCALE_AMP,  # load units, periodic error of the load scale (0: none)
    P_SCALE_PERIOD,  # load units
    P_SCALE_PHASE,  # rad
    N_PARAMS,
) = range(58)

#: Largest set-point dead time, s (control.setpoint_delay and its growth are clipped to it).
MAX_SETPOINT_DELAY_S = 0.1

# --- state vector --------------------------------------------------------------------------
MAX_DELAY = 2048  # speed cycles of dead time the ring buffer holds
MAX_HIST = 2048  # speed-cycle samples of sensor history (sensor_time_offset, measurement_delay)
MAX_SP_HIST = 2048  # speed-cycle samples of set-point history (setpoint_delay)
(
    S_TH,  # rad, motor angle
    S_OM,  # rad/s, motor speed
    S_X,  # load units, load position
    S_V,  # load units/s, load speed
    S_INT,  # N m, integral part of the PI speed controller
    S_TAU,  # N m, motor torque (current loop output)
    S_TAU_CMD,  # N m, torque set point after the dead time
    S_TH_PREV,  # rad, motor encoder at the previous speed sample
    S_OM_MEAS,  # rad/s, measured motor speed (drive's actual value, after its filter)
    S_T,  # s, simulated time
    S_SP_PENDING,  # rad/s, set point waiting for the next position cycle
    S_DLY_IDX,  # index into the dead-time ring buffer
    S_TAU_PREV,  # N m, torque applied over the previous substep (kick averaging)
    S_FD_PREV,  # N, external load force over the previous substep
    S_TAU_FF,  # N m, torque feed-forward held over the position cycle
    S_HIST_IDX,  # next slot of the sensor history ring buffers
    S_FF_PENDING,  # N m, torque feed-forward waiting for the next position cycle
    S_SPH_IDX,  # next slot of the set-point history ring buffers
    S_DLY0,  # first slot of the dead-time ring buffer
) = range(19)
S_HX0 = S_DLY0 + MAX_DELAY  # load position history, one sample per speed cycle
S_HTH0 = S_HX0 + MAX_HIST  # motor angle history
S_HOM0 = S_HTH0 + MAX_HIST  # measured motor speed history
S_SPH0 = S_HOM0 + MAX_HIST  # speed set point as it arrives at the drive, per speed cycle
S_FFH0 = S_SPH0 + MAX_SP_HIST  # torque feed-forward as it arrives, per speed cycle
N_STATE = S_FFH0 + MAX_SP_HIST

# --- trace rows of the closed loop (one per position cycle) ------------------------------------
(
    O_T,
    O_XREF,
    O_WSET,
    O_TH,
    O_WM,
    O_X,
    O_TAU,
    O_DIST,
    O_BETA,
    O_LAM,
    O_WS,
    O_WC,
    N_OUT,
) = range(13)


@_inline
def spring_force(p: np.ndarray, th: float, om: float, x: float, v: float) -> float:
    """Force of the screw-nut element on the load (N), positive towards +x."""
    d = th * p[P_INV_KR] - x
    ddot = om * p[P_INV_KR] - v
    half = p[P_HALF_GAP]
    if half <= 0.0:
        return p[P_K] * d + p[P_C] * ddot
    if d > half:
        f = p[P_K] * (d - half) + p[P_C] * ddot
        return f if f > 0.0 else 0.0
    if d < -half:
        f = p[P_K] * (d + half) + p[P_C] * ddot
        return f if f < 0.0 else 0.0
    return 0.0


@_inline
def load_force(p: np.ndarray, x: float) -> float:
    """Position-dependent load force of ``[disturbance]`` (N), positive towards +x."""
    f = p[P_F_CONST]
    if p[P_F_PER] != 0.0:
        f -= p[P_F_PER] * math.sin(2.0 * math.pi * x / p[P_PER_PERIOD] + p[P_PER_PHASE])
    return f


@_inline
def kick_load_creep(p: np.ndarray, v: float, f_applied: float, h: float) -> float:
    """New load speed under the regularised friction law (``P_V_CREEP`` > 0): below the creep
    speed v_c the Coulomb/Stribeck level S grows linearly with speed, S·v/v_c (a linear zone,
    Karnopp's regularisation without stiction: a load under a force below the break-away
    level creeps at F/S·v_c instead of sticking, as a ball screw's pre-sliding does); above
    it S·sign(v). Viscous friction b·v on top. The friction is taken implicitly (backward
    Euler, stable for any zone slope S/v_c): v' + h/M·f(v') = v + h/M·F, solved exactly on
    the law's linear pieces (the Stribeck excess is evaluated at the old speed)."""
    h_m = h * p[P_INV_M]
    vc = p[P_V_CREEP]
    excess = 0.0
    if p[P_FS] != 0.0:
        r = v / p[P_VS]
        excess = p[P_FS] * math.exp(-r * r)
    s_pos = p[P_FC_POS] + excess
    s_neg = p[P_FC_NEG] + excess
    b_pos = p[P_FV_POS]
    b_neg = p[P_FV_NEG]
    a = v + f_applied * h_m
    if a >= vc * (1.0 + h_m * b_pos) + h_m * s_pos:
        return (a - h_m * s_pos) / (1.0 + h_m * b_pos)
    if a <= -vc * (1.0 + h_m * b_neg) - h_m * s_neg:
        return (a + h_m * s_neg) / (1.0 + h_m * b_neg)
    if a >= 0.0:
        return a / (1.0 + h_m * (s_pos / vc + b_pos))
    return a / (1.0 + h_m * (s_neg / vc + b_neg))


@_inline
def kick_load(p: np.ndarray, v: float, f_applied: float, h: float) -> float:
    """New load speed after impulse ``f_applied*h`` plus friction (set-valued at v = 0, or
    the regularised law of :func:`kick_load_creep`)."""
    if p[P_V_CREEP] > 0.0:
        return kick_load_creep(p, v, f_applied, h)
    h_m = h * p[P_INV_M]
    fs = p[P_FS]
    if v == 0.0:
        if f_applied > 0.0:
            level = p[P_FC_POS] + fs
            return 0.0 if f_applied <= level else (f_applied - level) * h_m
        if f_applied < 0.0:
            level = p[P_FC_NEG] + fs
            return 0.0 if -f_applied <= level else (f_applied + level) * h_m
        return 0.0
    if v > 0.0:
        fc = p[P_FC_POS]
        fv = p[P_FV_POS]
        sgn = 1.0
    else:
        fc = p[P_FC_NEG]
        fv = p[P_FV_NEG]
        sgn = -1.0
    if fs != 0.0:
        r = v / p[P_VS]
        fc += fs * math.exp(-r * r)
    vn = v + (f_applied - sgn * fc - fv * v) * h_m
    if fc > 0.0 and vn * sgn < 0.0:
        return 0.0  # Coulomb friction stops the load; it cannot reverse it
    return vn


@_inline
def step_state(
    p: np.ndarray, th: float, om: float, x: float, v: float, tau: float, f_dist: float, dt: float
) -> tuple[float, float, float, float]:
    """One staggered leapfrog step of the mechanics under constant motor torque and load force:
    velocities live at half steps (v_{n+1/2} = v_{n-1/2} + a(x_n, v_{n-1/2})·dt, then
    x_{n+1} = x_n + v_{n+1/2}·dt). One force evaluation per step, symplectic and second order
    for the conservative forces, first order in the small velocity-dependent ones.

    On scalars, returning the new (θ, ω, x, v): the callers keep the state in locals over a
    speed cycle, so the compiler need not reload parameters after every store to the state
    array (it cannot know that the two arrays do not overlap)."""
    if p[P_RIGID] != 0.0:
        kr = p[P_KR]
        v = kick_load(p, v, kr * tau + f_dist + load_force(p, x), dt)
        x += v * dt
        return kr * x, kr * v, x, v
    fs = spring_force(p, th, om, x, v)
    om += (tau - fs * p[P_INV_KR]) * dt * p[P_INV_J1]
    v = kick_load(p, v, fs + f_dist + load_force(p, x), dt)
    x += v * dt
    th += om * dt
    return th, om, x, v


@_inline
def substep(p: np.ndarray, st: np.ndarray, tau: float, f_dist: float, dt: float) -> None:
    """:func:`step_state` on the state vector."""
    st[S_TH], st[S_OM], st[S_X], st[S_V] = step_state(
        p, st[S_TH], st[S_OM], st[S_X], st[S_V], tau, f_dist, dt
    )


@_inline
def _measure_speed(p: np.ndarray, st: np.ndarray) -> None:
    """The drive's speed actual value: backward difference of the motor encoder over the
    speed cycle, then the optional first-order low-pass (``control.speed_filter`` = T_f).
    The filter is discretised exactly for its input held over the cycle (the difference is
    the cycle's mean speed): y_k = u_k + a·(y_{k−1} − u_k), a = exp(−T_sc/T_f), which is the
    continuous filter's response sampled at the cycle instants; its state is ``S_OM_MEAS``."""
    raw = (st[S_TH] - st[S_TH_PREV]) / p[P_TSC]
    a = p[P_SPD_ALPHA]
    if a != 0.0:
        raw += a * (st[S_OM_MEAS] - raw)
    st[S_OM_MEAS] = raw
    st[S_TH_PREV] = st[S_TH]


@_inline
def _torque_phase(p: np.ndarray, st: np.ndarray, cmd: float, f_dist: float) -> None:
    """Current loop and mechanics over one speed cycle for a torque set point ``cmd``.

    The first-order current loop is solved exactly: the torque applied over a substep is its
    exact mean, and ``S_TAU`` holds the sampled value at the substep's end. A leapfrog kick at
    t_n spans [t_n − dt/2, t_n + dt/2], so it applies the mean of the previous and the coming
    substep's torque and load force: without that, every torque change (each speed cycle)
    would cost a first-order error."""
    st[S_TAU_CMD] = cmd
    nsub = int(p[P_NSUB])
    dt = p[P_TSC] / nsub
    alpha = p[P_LAG_ALPHA]
    mean = p[P_LAG_MEAN]
    th, om, x, v = st[S_TH], st[S_OM], st[S_X], st[S_V]
    tau, tau_prev, fd_prev = st[S_TAU], st[S_TAU_PREV], st[S_FD_PREV]
    for _ in range(nsub):
        applied = cmd + (tau - cmd) * (1.0 - mean)
        tau = cmd + (tau - cmd) * alpha
        tau_kick = 0.5 * (tau_prev + applied)
        f_kick = 0.5 * (fd_prev + f_dist)
        tau_prev = applied
        fd_prev = f_dist
        th, om, x, v = step_state(p, th, om, x, v, tau_kick, f_kick, dt)
    st[S_TH], st[S_OM], st[S_X], st[S_V] = th, om, x, v
    st[S_TAU], st[S_TAU_PREV], st[S_FD_PREV] = tau, tau_prev, fd_prev
    st[S_T] += p[P_TSC]


@_inline
def _push_history(p: np.ndarray, st: np.ndarray) -> None:
    """Store this speed cycle's sensor values for a late reading (no-op without one)."""
    if p[P_HIST_ON] == 0.0:
        return
    i = int(st[S_HIST_IDX])
    st[S_HX0 + i] = st[S_X]
    st[S_HTH0 + i] = st[S_TH]
    st[S_HOM0 + i] = st[S_OM_MEAS]
    st[S_HIST_IDX] = (i + 1) % int(p[P_HIST_LEN])


@_inline
def _history(p: np.ndarray, st: np.ndarray, base: int, whole: float, frac: float) -> float:
    """Linear interpolation of a history buffer at (whole + frac) speed cycles before the
    latest sample."""
    n = int(p[P_HIST_LEN])
    latest = int(st[S_HIST_IDX]) - 1
    m = int(whole)
    a = st[base + (latest - m) % n]
    b = st[base + (latest - m - 1) % n]
    return a + (b - a) * frac


@_inline
def load_measured(p: np.ndarray, st: np.ndarray) -> float:
    """Load measuring system's reading now: x(t − d) when it is read late by d (a positive
    sensor time offset plus the measurement delay; linear interpolation between speed-cycle
    samples), else x(t); plus the scale's periodic error A·sin(2πx/P + φ) at the position
    read (control.scale_error_*)."""
    if p[P_LOAD_DLY_ON] != 0.0:
        x = _history(p, st, S_HX0, p[P_LOAD_DLY_N], p[P_LOAD_DLY_FRAC])
    else:
        x = st[S_X]
    if p[P_SCALE_AMP] != 0.0:
        x += p[P_SCALE_AMP] * math.sin(2.0 * math.pi * x / p[P_SCALE_PERIOD] + p[P_SCALE_PHASE])
    return x


@_inline
def motor_measured(p: np.ndarray, st: np.ndarray) -> float:
    """Motor encoder reading for the position loop and the recording: θ(t − d) when it is
    read late by d (a negative sensor time offset's |offset| plus the measurement delay),
    else θ(t)."""
    if p[P_MOT_DLY_ON] != 0.0:
        return _history(p, st, S_HTH0, p[P_MOT_DLY_N], p[P_MOT_DLY_FRAC])
    return st[S_TH]


@_inline
def motor_speed_measured(p: np.ndarray, st: np.ndarray) -> float:
    """The drive's speed actual value as recorded, shifted like :func:`motor_measured`."""
    if p[P_MOT_DLY_ON] != 0.0:
        return _history(p, st, S_HOM0, p[P_MOT_DLY_N], p[P_MOT_DLY_FRAC])
    return st[S_OM_MEAS]


@_inline
def _delayed_setpoint(
    p: np.ndarray, st: np.ndarray, omega_set: float, tau_ff: float
) -> tuple[float, float]:
    """The set point (and torque feed-forward) the drive applies in this speed cycle when
    it applies them late (``control.setpoint_delay``): the values as they arrive are stored
    once per speed cycle; the drive uses the value of time t − d(t), d(t) = clip(d0 +
    rate·t, 0, MAX_SETPOINT_DELAY_S), t this speed cycle's start in the run (``S_T``),
    linearly interpolated between the two neighbouring speed-cycle samples (continuous in
    d). Before the run the set point was 0 (at rest)."""
    n = int(p[P_SPH_LEN])
    i = int(st[S_SPH_IDX])
    st[S_SPH0 + i] = omega_set
    st[S_FFH0 + i] = tau_ff
    st[S_SPH_IDX] = (i + 1) % n
    d = p[P_SP_DLY0] + p[P_SP_DLY_RATE] * st[S_T]
    d = min(MAX_SETPOINT_DELAY_S, max(0.0, d))
    cycles = d / p[P_TSC]
    m = math.floor(cycles + 1e-9)
    if m > n - 2:
        m = n - 2
    f = cycles - m
    # a delay of whole cycles within rounding (0.5 ms / 125 µs) reads the sample itself
    f = 0.0 if f < 1e-9 else min(1.0, f)
    a = st[S_SPH0 + (i - m) % n]
    b = st[S_SPH0 + (i - m - 1) % n]
    fa = st[S_FFH0 + (i - m) % n]
    fb = st[S_FFH0 + (i - m - 1) % n]
    return a + (b - a) * f, fa + (fb - fa) * f


@_inline
def _speed_cycle(
    p: np.ndarray, st: np.ndarray, omega_set: float, f_dist: float, tau_ff: float
) -> None:
    tsc = p[P_TSC]
    if p[P_SP_DLY_ON] != 0.0:
        omega_set, tau_ff = _delayed_setpoint(p, st, omega_set, tau_ff)
    _measure_speed(p, st)
    err = omega_set - st[S_OM_MEAS]
    kp_part = p[P_KSP] * err + tau_ff
    lim = p[P_TAU_LIM]
    if p[P_KI] != 0.0:
        integ = st[S_INT] + p[P_KI] * err * tsc
        # clamping anti-windup: the integral never pushes the sum beyond the torque limit
        if integ > lim - kp_part:
            integ = max(lim - kp_part, min(st[S_INT], integ))
        elif integ < -lim - kp_part:
            integ = min(-lim - kp_part, max(st[S_INT], integ))
        st[S_INT] = integ
    u = kp_part + st[S_INT]
    u = min(lim, max(-lim, u))
    n_delay = int(p[P_DELAY_N])
    if n_delay > 0:
        i = int(st[S_DLY_IDX])
        cmd = st[S_DLY0 + i]
        st[S_DLY0 + i] = u
        st[S_DLY_IDX] = (i + 1) % n_delay
    else:
        cmd = u
    _torque_phase(p, st, cmd, f_dist)


@_inline
def speed_cycle(p: np.ndarray, st: np.ndarray, omega_set: float, f_dist: float) -> None:
    """One speed-controller cycle: measure, PI with anti-windup, dead time, current loop,
    mechanics for one speed cycle. The torque feed-forward ``S_TAU_FF`` adds to the
    proportional part (so the anti-windup clamp accounts for it)."""
    _speed_cycle(p, st, omega_set, f_dist, st[S_TAU_FF])
    _push_history(p, st)


@_inline
def _advance(
    p: np.ndarray, st: np.ndarray, omega_set: float, disturbance_nm: float, torque_ff_nm: float
) -> None:
    st[S_TAU_FF] = torque_ff_nm
    f_dist = p[P_KR] * disturbance_nm
    # loop invariants in locals: p and st may alias for the compiler, so a p[...] in the loop
    # would be reloaded after every store to st
    history = p[P_HIST_ON] != 0.0
    for _ in range(int(p[P_NSC])):
        _speed_cycle(p, st, omega_set, f_dist, torque_ff_nm)
        if history:
            _push_history(p, st)


@_njit
def advance(
    p: np.ndarray,
    st: np.ndarray,
    omega_set: float,
    disturbance_nm: float,
    torque_ff_nm: float = 0.0,
) -> None:
    """One position cycle of the drive: ``nsc`` speed cycles at a constant speed set point
    (rad/s at the motor), a constant external disturbance (N·m reflected to the motor,
    positive pushes towards +x) and a constant torque feed-forward (N·m, added to the
    speed controller's output before the torque limit)."""
    _advance(p, st, omega_set, disturbance_nm, torque_ff_nm)


@_njit
def read_measured(p: np.ndarray, st: np.ndarray, out: np.ndarray) -> None:
    """What the drive's measuring systems read now, in one call: ``out`` = motor encoder
    (:func:`motor_measured`), load measuring system (:func:`load_measured`), speed actual
    value (:func:`motor_speed_measured`), motor torque (rad, load units, rad/s, N·m)."""
    out[0] = motor_measured(p, st)
    out[1] = load_measured(p, st)
    out[2] = motor_speed_measured(p, st)
    out[3] = st[S_TAU]


@_njit
def advance_torque(p: np.ndarray, st: np.ndarray, torque_nm: float, disturbance_nm: float) -> None:
    """One position cycle with the speed controller bypassed: a fixed torque set point (N·m)
    through the current loop (0 for a disabled drive: the axis coasts). The speed is still
    measured and the PI integral is cleared, as a drive does when its power stage is off."""
    f_dist = p[P_KR] * disturbance_nm
    st[S_INT] = 0.0
    st[S_TAU_FF] = 0.0
    for _ in range(int(p[P_NSC])):
        if p[P_SP_DLY_ON] != 0.0:
            _delayed_setpoint(p, st, 0.0, 0.0)  # a disabled drive's set point is 0
        _measure_speed(p, st)
        _torque_phase(p, st, torque_nm, f_dist)
        _push_history(p, st)


@_njit
def run_closed_loop(
    p: np.ndarray,
    st: np.ndarray,
    reg: np.ndarray,
    cyc: np.ndarray,
    x_ref: np.ndarray,
    v_ref: np.ndarray,
    dist_nm: np.ndarray,
    out: np.ndarray,
) -> None:
    """Fig. 1 (regulator off) or Fig. 6 (on): one row of ``out`` per position cycle.

    x_ref: load units, interpolator position; v_ref: load units/s, interpolator speed
    (ω_s = k_r·v_ref); dist_nm: N·m at the motor, held over each position cycle.
    Row k holds the values sampled at the start of cycle k and the set point computed there.

    Feed-forward (axis file ``control.velocity_feedforward`` / ``acceleration_feedforward``):
    ω_c = eq. 7 + k_vff·ω_s, so the detector's input ω_s − ω_c keeps its meaning (≈ 0 on a
    well-followed path); τ_ff = J_ff·k_r·(v_ref[k] − v_ref[k−1])/T_p over cycle k (v_ref[k]
    is the speed over cycle k, so that is the step the reference makes at its start).
    The position feedback and the recorded positions are the sensor readings
    (:func:`load_measured`, :func:`motor_measured`: sensor time offset). ``cyc``: the
    cycle block of :mod:`regulator.cycle` (:func:`cycle_block`); ``reg``: the detector state.
    """
    kr = p[P_KR]
    inv_tp = 1.0 / p[P_TP]
    v_prev = v_ref[0]
    for k in range(x_ref.shape[0]):
        x_load = load_measured(p, st)
        th_motor = motor_measured(p, st)
        x_fb = x_load if p[P_FB_LOAD] != 0.0 else th_motor / kr
        # regulator.cycle: eq. 7 + k_vff, the detector, eq. 15 (no limits in cyc: inf)
        if position_cycle(cyc, reg, x_ref[k], v_ref[k], x_fb, 0.0, False) == _CYCLE_OK:
            w_s, w_c = cyc[_Y_OMEGA_S], cyc[_Y_OMEGA_C]
            w_r, beta, lam = cyc[_Y_OMEGA_R], cyc[_Y_BETA], cyc[_Y_LAMBDA]
        else:  # a non-finite feedback (an unstable parameter set): it stays non-finite
            w_s = kr * v_ref[k]
            w_c = w_r = beta = lam = math.nan
        tau_ff = p[P_JFF] * kr * (v_ref[k] - v_prev) * inv_tp
        v_prev = v_ref[k]
        if p[P_SP_DELAY] != 0.0:
            w_apply = st[S_SP_PENDING]
            st[S_SP_PENDING] = w_r
            ff_apply = st[S_FF_PENDING]
            st[S_FF_PENDING] = tau_ff
        else:
            w_apply = w_r
            ff_apply = tau_ff
        out[k, O_T] = st[S_T]
        out[k, O_XREF] = x_ref[k]
        out[k, O_WSET] = w_r
        out[k, O_TH] = th_motor
        out[k, O_WM] = motor_speed_measured(p, st)
        out[k, O_X] = x_load
        out[k, O_TAU] = st[S_TAU]
        out[k, O_DIST] = dist_nm[k]
        out[k, O_BETA] = beta
        out[k, O_LAM] = lam
        out[k, O_WS] = w_s
        out[k, O_WC] = w_c
        _advance(p, st, w_apply, dist_nm[k], ff_apply)  # inlined: no call per cycle


def cycle_block(p: np.ndarray) -> np.ndarray:
    """The cycle block of :mod:`regulator.cycle` for :func:`run_closed_loop`: the law of the
    parameter vector ``p`` (k_r, k_v, k_vff, the regulator), no limits (the simulated
    machine has no bridge supervising it)."""
    return np.array(
        _cycle.block(
            p[P_KR],
            p[P_KV],
            p[P_TP],
            velocity_feedforward=p[P_KVFF],
            regulator_on=p[P_REG_ON] != 0.0,
            n=int(p[P_REG_N]),
            tv_s=p[P_REG_TV],
            tf_s=p[P_REG_TF],
            beta_t_rad_s=p[P_REG_BT],
        )
    )


@_njit
def run_mechanics(
    p: np.ndarray, st: np.ndarray, tau: float, f_dist: float, dt: float, out: np.ndarray
) -> None:
    """Open-loop mechanics under a constant motor torque: row i = (θ, ω, x, v) after step i.

    For physics tests (free oscillation, energy) without the controllers."""
    for i in range(out.shape[0]):
        substep(p, st, tau, f_dist, dt)
        out[i, 0] = st[S_TH]
        out[i, 1] = st[S_OM]
        out[i, 2] = st[S_X]
        out[i, 3] = st[S_V]

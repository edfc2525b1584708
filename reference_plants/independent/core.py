"""Compiled core of the independent test plant: RK4 on smooth physics, sampled controllers.

Written apart from ``plant_sim/physics/kernel.py`` with other modelling choices where reality
allows one (see the package docstring). Everything is in load coordinates for the load and
motor coordinates for the motor; forces on the load in N (N·m for a rotary axis).

State of the mechanics (continuous, integrated by classic RK4 with a fixed step):
``th`` motor angle, ``om`` motor speed, ``x`` load position, ``v`` load speed, ``cur`` motor
current expressed as torque (N·m, torque constant 1). A rigid axis keeps ``th = k_r·x``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

# --- parameter layout (own names; not the kernel's) ------------------------------------------
(
    Q_KR,
    Q_RIGID,
    Q_J1,  # kg m^2 motor side
    Q_M,  # load mass (rigid: total mass in load coordinates)
    Q_K,  # N/m
    Q_C,  # N s/m
    Q_GAP,  # half free play, load units (0: none)
    Q_CONTACT_SMOOTH,  # load units: penetration over which the contact damping engages
    Q_FC_P,  # N, Coulomb for v > 0
    Q_FC_N,  # N, Coulomb for v < 0
    Q_FV_P,  # N/(unit/s)
    Q_FV_N,
    Q_FS,  # N, Stribeck excess
    Q_VS,  # unit/s (0: none)
    Q_V_SMOOTH,  # unit/s, tanh smoothing speed of Coulomb friction
    Q_F_CONST,  # N on the load, positive towards +x
    Q_F_PER,  # N amplitude of the position-periodic force
    Q_PER_LEN,  # load units
    Q_PER_PHASE,  # rad
    Q_KV,
    Q_KVFF,
    Q_JFF,
    Q_KSP,
    Q_KI,
    Q_TLIM,  # N m (inf: none)
    Q_FB_LOAD,
    Q_TP,
    Q_TSC,
    Q_NSC,  # speed cycles per position cycle
    Q_NCC,  # current-loop cycles per speed cycle
    Q_NRK,  # RK4 steps per current-loop cycle
    Q_IDEAL_CURRENT,  # 1: torque follows its set point at once
    Q_L_E,  # H-equivalent: electrical time constant * R (R = 1)
    Q_CKP,  # current controller gain (= L / T_cl)
    Q_CKI,  # current controller integral gain (= R / T_cl)
    Q_DELAY_N,  # dead time in current-loop cycles
    Q_SPEED_FILTER,  # s, first-order filter on the encoder speed (0: none)
    Q_MOTOR_QUANTUM,  # rad per encoder count (0: exact)
    Q_LOAD_QUANTUM,  # load units per scale count (0: exact)
    Q_OFFSET,  # s, sensor time offset (load sample time minus motor's)
    N_Q,
) = range(41)

HISTORY = 4096  # current-loop samples of sensor history
DELAY_RING = 4096  # current-loop samples of dead time


@_jit
def _friction(q: np.ndarray, v: float) -> float:
    """Friction force on the load (N), opposing v: tanh-smoothed Coulomb + Stribeck + viscous."""
    s = math.tanh(v / q[Q_V_SMOOTH])
    f = q[Q_FC_P] * s + q[Q_FV_P] * v if v >= 0.0 else q[Q_FC_N] * s + q[Q_FV_N] * v
    if q[Q_VS] > 0.0:
        r = v / q[Q_VS]
        f += q[Q_FS] * math.exp(-r * r) * s
    return f


@_jit
def _load_force(q: np.ndarray, x: float) -> float:
    f = q[Q_F_CONST]
    if q[Q_F_PER] != 0.0:
        f -= q[Q_F_PER] * math.sin(2.0 * math.pi * x / q[Q_PER_LEN] + q[Q_PER_PHASE])
    return f


@_jit
def _coupling(q: np.ndarray, th: float, om: float, x: float, v: float) -> float:
    """Force of the screw-nut on the load. Without free play: linear spring-damper. With free
    play: a dead zone; beyond it a spring plus a damper that engages smoothly with the
    penetration (Hunt–Crossley-like, tanh of penetration), never pulling."""
    kr = q[Q_KR]
    d = th / kr - x
    dd = om / kr - v
    gap = q[Q_GAP]
    if gap <= 0.0:
        return q[Q_K] * d + q[Q_C] * dd
    if d > gap:
        p = d - gap
        f = q[Q_K] * p + q[Q_C] * math.tanh(p / q[Q_CONTACT_SMOOTH]) * dd
        return max(f, 0.0)
    if d < -gap:
        p = d + gap
        f = q[Q_K] * p + q[Q_C] * math.tanh(-p / q[Q_CONTACT_SMOOTH]) * dd
        return min(f, 0.0)
    return 0.0


@_jit
def _deriv(
    q: np.ndarray, y: np.ndarray, volt: float, tau_ideal: float, f_ext: float, dy: np.ndarray
) -> None:
    th, om, x, v, cur = y[0], y[1], y[2], y[3], y[4]
    if q[Q_IDEAL_CURRENT] != 0.0:
        tau = tau_ideal
        dy[4] = 0.0
    else:
        tau = cur
        dy[4] = (volt - cur) / q[Q_L_E]  # R = 1
    kr = q[Q_KR]
    if q[Q_RIGID] != 0.0:
        a = (kr * tau + f_ext + _load_force(q, x) - _friction(q, v)) / q[Q_M]
        dy[0] = kr * v
        dy[1] = kr * a
        dy[2] = v
        dy[3] = a
        return
    fs = _coupling(q, th, om, x, v)
    dy[0] = om
    dy[1] = (tau - fs / kr) / q[Q_J1]
    dy[2] = v
    dy[3] = (fs + f_ext + _load_force(q, x) - _friction(q, v)) / q[Q_M]


@_jit
def _rk4(
    q: np.ndarray,
    y: np.ndarray,
    h: float,
    volt: float,
    tau_ideal: float,
    f_ext: float,
    k1: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    k4: np.ndarray,
    tmp: np.ndarray,
) -> None:
    _deriv(q, y, volt, tau_ideal, f_ext, k1)
    for j in range(5):
        tmp[j] = y[j] + 0.5 * h * k1[j]
    _deriv(q, tmp, volt, tau_ideal, f_ext, k2)
    for j in range(5):
        tmp[j] = y[j] + 0.5 * h * k2[j]
    _deriv(q, tmp, volt, tau_ideal, f_ext, k3)
    for j in range(5):
        tmp[j] = y[j] + h * k3[j]
    _deriv(q, tmp, volt, tau_ideal, f_ext, k4)
    for j in range(5):
        y[j] += h * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]) / 6.0


@_jit
def _quantise(value: float, quantum: float) -> float:
    if quantum <= 0.0:
        return value
    return math.floor(value / quantum + 0.5) * quantum


@_jit
def _past(buf: np.ndarray, newest: int, filled: int, back: float) -> float:
    """Value ``back`` current-loop samples before the newest (linear interpolation)."""
    n = buf.shape[0]
    if back > filled - 1:
        back = filled - 1
    i = int(back)  # back >= 0
    frac = back - i
    a = buf[(newest - i) % n]
    b = buf[(newest - i - 1) % n] if frac > 0.0 else a
    return a + (b - a) * frac


#: scalar state of :func:`run`'s loop, kept between calls of :func:`advance`
(
    S_NEWEST,
    S_FILLED,
    S_RING_I,
    S_TH_PREV,
    S_W_MEAS,
    S_INTEG,
    S_C_INT,
    S_I_REF,
    S_T,
    N_S,
) = range(10)


@_jit
def init(
    q: np.ndarray,
    x0: float,
    s: np.ndarray,
    y: np.ndarray,
    hist_x: np.ndarray,
    hist_th: np.ndarray,
    hist_w: np.ndarray,
    ring: np.ndarray,
) -> None:
    """At rest at load position ``x0``: the state of :func:`run` before its first cycle."""
    kr = q[Q_KR]
    y[:] = 0.0
    y[0] = kr * x0
    y[2] = x0
    hist_x[:] = x0
    hist_th[:] = kr * x0
    hist_w[:] = 0.0
    ring[:] = 0.0
    s[:] = 0.0
    s[S_FILLED] = 1.0
    s[S_TH_PREV] = _quantise(y[0], q[Q_MOTOR_QUANTUM])


@_jit
def sense(
    q: np.ndarray,
    s: np.ndarray,
    y: np.ndarray,
    hist_x: np.ndarray,
    hist_th: np.ndarray,
    hist_w: np.ndarray,
    reading: np.ndarray,
) -> None:
    """The sensors at the position-cycle instant: reading = (theta, omega, x, torque)."""
    tcc = q[Q_TSC] / int(q[Q_NCC])
    back = abs(q[Q_OFFSET]) / tcc
    newest = int(s[S_NEWEST])
    filled = int(s[S_FILLED])
    x_true = y[2]
    th_true = y[0]
    w_read = s[S_W_MEAS]
    if q[Q_OFFSET] > 0.0:
        x_true = _past(hist_x, newest, filled, back)
    elif q[Q_OFFSET] < 0.0:
        th_true = _past(hist_th, newest, filled, back)
        w_read = _past(hist_w, newest, filled, back)
    reading[0] = _quantise(th_true, q[Q_MOTOR_QUANTUM])
    reading[1] = w_read
    reading[2] = _quantise(x_true, q[Q_LOAD_QUANTUM])
    reading[3] = y[4] if q[Q_IDEAL_CURRENT] == 0.0 else s[S_I_REF]


@_jit
def advance(
    q: np.ndarray,
    s: np.ndarray,
    y: np.ndarray,
    hist_x: np.ndarray,
    hist_th: np.ndarray,
    hist_w: np.ndarray,
    ring: np.ndarray,
    w_set: float,
    tau_ff: float,
    f_ext: float,
) -> None:
    """One position cycle at the speed set point ``w_set`` (rad/s), torque feed-forward
    ``tau_ff`` (N m) and external load force ``f_ext`` (N)."""
    kr = q[Q_KR]
    k1 = np.zeros(5)
    k2 = np.zeros(5)
    k3 = np.zeros(5)
    k4 = np.zeros(5)
    tmp = np.zeros(5)
    nsc = int(q[Q_NSC])
    ncc = int(q[Q_NCC])
    nrk = int(q[Q_NRK])
    tsc = q[Q_TSC]
    tcc = tsc / ncc
    h = tcc / nrk
    n_delay = int(q[Q_DELAY_N])
    filt = 1.0 - math.exp(-tsc / q[Q_SPEED_FILTER]) if q[Q_SPEED_FILTER] > 0.0 else 1.0
    lim = q[Q_TLIM]
    th_prev = s[S_TH_PREV]
    w_meas = s[S_W_MEAS]
    integ = s[S_INTEG]
    c_int = s[S_C_INT]
    i_ref = s[S_I_REF]
    t = s[S_T]
    newest = int(s[S_NEWEST])
    filled = int(s[S_FILLED])
    ring_i = int(s[S_RING_I])
    for _ in range(nsc):
        # --- speed controller: quantised encoder, backward difference, filter ---------
        th_q = _quantise(y[0], q[Q_MOTOR_QUANTUM])
        w_raw = (th_q - th_prev) / tsc
        th_prev = th_q
        w_meas += filt * (w_raw - w_meas)
        err = w_set - w_meas
        prop = q[Q_KSP] * err + tau_ff
        u = prop + integ
        # conditional integration: freeze the integral while it would deepen saturation
        if q[Q_KI] != 0.0:
            if not ((u >= lim and err > 0.0) or (u <= -lim and err < 0.0)):
                integ += q[Q_KI] * err * tsc
            u = prop + integ
        u = min(lim, max(-lim, u))
        for _c in range(ncc):
            # --- dead time on the torque set point, then the PI current loop -----------
            ring[ring_i] = u
            i_ref = ring[(ring_i - n_delay) % DELAY_RING] if n_delay > 0 else u
            ring_i = (ring_i + 1) % DELAY_RING
            volt = 0.0
            if q[Q_IDEAL_CURRENT] == 0.0:
                e_c = i_ref - y[4]
                c_int += q[Q_CKI] * e_c * tcc
                volt = q[Q_CKP] * e_c + c_int
            for _r in range(nrk):
                _rk4(q, y, h, volt, i_ref, f_ext, k1, k2, k3, k4, tmp)
                if q[Q_RIGID] != 0.0:
                    y[0] = kr * y[2]
                    y[1] = kr * y[3]
            t += tcc
            newest = (newest + 1) % HISTORY
            filled = min(filled + 1, HISTORY)
            hist_x[newest] = y[2]
            hist_th[newest] = y[0]
            hist_w[newest] = w_meas
    s[S_TH_PREV] = th_prev
    s[S_W_MEAS] = w_meas
    s[S_INTEG] = integ
    s[S_C_INT] = c_int
    s[S_I_REF] = i_ref
    s[S_T] = t
    s[S_NEWEST] = newest
    s[S_FILLED] = filled
    s[S_RING_I] = ring_i


@_jit
def run(
    q: np.ndarray,
    x0: float,
    x_ref: np.ndarray,
    v_ref: np.ndarray,
    dist_nm: np.ndarray,
    out: np.ndarray,
) -> None:
    """Closed loop, one output row per position cycle sampled at its start:
    (t, x_ref, ω_set, θ reading, ω reading, x reading, torque, disturbance)."""
    kr = q[Q_KR]
    s = np.zeros(N_S)
    y = np.zeros(5)
    hist_x = np.zeros(HISTORY)
    hist_th = np.zeros(HISTORY)
    hist_w = np.zeros(HISTORY)
    ring = np.zeros(DELAY_RING)
    reading = np.zeros(4)
    init(q, x0, s, y, hist_x, hist_th, hist_w, ring)
    v_prev = v_ref[0]
    for k in range(x_ref.shape[0]):
        sense(q, s, y, hist_x, hist_th, hist_w, reading)
        th_read = reading[0]
        x_read = reading[2]
        # --- position controller with feed-forward --------------------------------------
        fb = x_read if q[Q_FB_LOAD] != 0.0 else th_read / kr
        w_set = kr * (q[Q_KV] * (x_ref[k] - fb) + q[Q_KVFF] * v_ref[k])
        tau_ff = q[Q_JFF] * kr * (v_ref[k] - v_prev) / q[Q_TP]
        v_prev = v_ref[k]
        f_ext = kr * dist_nm[k]
        out[k, 0] = k * q[Q_TP]
        out[k, 1] = x_ref[k]
        out[k, 2] = w_set
        out[k, 3] = th_read
        out[k, 4] = reading[1]
        out[k, 5] = x_read
        out[k, 6] = reading[3]
        out[k, 7] = dist_nm[k]
        advance(q, s, y, hist_x, hist_th, hist_w, ring, w_set, tau_ff, f_ext)

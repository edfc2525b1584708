"""Compiled core of the third test plant: a torsional three-mass drive train with LuGre
friction, a PI current loop on an R-L winding with back-EMF and a voltage limit, a sin/cos
encoder with interpolation error, and a trace recorder with its own anti-alias filter.

Written from the physics for this package, neither importing nor copying
``plant_sim/physics/kernel.py`` or ``reference_plants/independent`` (see the package docstring
for the modelling choices that differ). Angles of the motor side in rad, the load in load units
(m or rad), forces on the load in N (N·m for a rotary axis).

Equations (one step h):

    motor      J_m·ω̇_m = K_t·i − T_c,           T_c = k_c·(θ_m − θ_s) + c_c·(ω_m − ω_s)
    screw      J_s·ω̇_s = T_c − F_n/k_r
    nut        F_n = k_n·dz(θ_s/k_r − x) + c_n·(ω_s/k_r − v)   in contact (dead zone of the
               free play, never pulling)
    load       M·v̇ = F_n − F_f − F_l(x) + F_ext
    LuGre      ż = v − σ0·|v|·z/g(v),  g(v) = F_c + (F_s − F_c)·exp(−(v/v_s)²)   (per direction)
               F_f = σ0·z + σ1·ż + σ2·v
    winding    L·di/dt = u − R·i − K_e·ω_m

Integration: symplectic (semi-implicit) Euler for the mechanics with a fixed step from the
stiffest mode (h·ω ≤ 0.05), the winding implicitly (backward Euler), the bristle state z by
the exact solution of its linear equation over the step with v held (an exponential
integrator: σ0 may be stiff).
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

(
    KR,
    JM,
    JS,
    KC,
    CC,
    M,
    KN,
    CN,
    HALF_GAP,
    FC_P,
    FC_N,
    FS_P,
    FS_N,
    VS,
    SIG0,
    SIG1,
    SIG2_P,
    SIG2_N,
    F_CONST,
    F_PER,
    PER_LEN,
    PER_PHASE,
    KV,
    KVFF,
    KSP,
    KI,
    I_LIM,
    TP,
    TSC,
    NSC,
    NCC,
    NH,
    FB_LOAD,
    SPD_FILT,
    SP_DELAY_N,
    OFFSET,
    R_W,
    L_W,
    KT,
    KE,
    U_MAX,
    CKP,
    CKI,
    ENC_LINES,
    ENC_ERR,
    ENC_QUANT,
    SCALE_QUANT,
    AA_TAU,
    N_PAR,
) = range(49)

HISTORY = 8192  # samples (current periods) of the load scale's history
SP_RING = 64  # position cycles of speed set-point delay


@_jit
def _g(p: np.ndarray, v: float) -> float:
    if v >= 0.0:
        fc, fs = p[FC_P], p[FS_P]
    else:
        fc, fs = p[FC_N], p[FS_N]
    if p[VS] > 0.0:
        r = v / p[VS]
        return fc + (fs - fc) * math.exp(-r * r)
    return fc


@_jit
def _encoder(p: np.ndarray, theta: float) -> float:
    """sin/cos encoder: interpolation error once per line, then the interpolator's quantum."""
    lines = p[ENC_LINES]
    read = theta
    if lines > 0.0 and p[ENC_ERR] != 0.0:
        read += p[ENC_ERR] * math.sin(lines * theta)
    q = p[ENC_QUANT]
    if q > 0.0:
        read = math.floor(read / q + 0.5) * q
    return read


@_jit
def _quant(value: float, q: float) -> float:
    if q <= 0.0:
        return value
    return math.floor(value / q + 0.5) * q


@_jit
def run(
    p: np.ndarray,
    x0: float,
    x_ref: np.ndarray,
    v_ref: np.ndarray,
    f_ext_nm: np.ndarray,
    out: np.ndarray,
) -> None:
    """Closed loop, one row per position cycle sampled at its start:
    (t, x_ref, speed set point, motor reading, speed actual value, load reading, logged
    torque, external torque)."""
    kr = p[KR]
    # mechanical state
    th_m = kr * x0
    w_m = 0.0
    th_s = kr * x0
    w_s = 0.0
    x = x0
    v = 0.0
    z = 0.0
    cur = 0.0  # winding current (A)
    # drive state
    nsc = int(p[NSC])
    ncc = int(p[NCC])
    nh = int(p[NH])
    tsc = p[TSC]
    tcc = tsc / ncc
    h = tcc / nh
    a_filt = math.exp(-tsc / p[SPD_FILT]) if p[SPD_FILT] > 0.0 else 0.0
    a_aa = math.exp(-tcc / p[AA_TAU]) if p[AA_TAU] > 0.0 else 0.0
    th_prev = _encoder(p, th_m)
    w_meas = 0.0
    integ = 0.0
    c_int = 0.0
    u_pending = 0.0
    logged = 0.0
    sp_ring = np.zeros(SP_RING)
    sp_i = 0
    n_sp = int(p[SP_DELAY_N])
    hist = np.full(HISTORY, x0)
    newest = 0
    filled = 1
    back = p[OFFSET] / tcc
    t = 0.0
    tsi_back = p[KSP] / p[KI] if p[KI] > 0.0 else 1.0  # back-calculation time constant
    for k in range(x_ref.shape[0]):
        # --- sensors at the position-cycle instant -----------------------------------------
        if back > 0.0:
            b = min(back, filled - 1.0)
            i0 = int(b)
            frac = b - i0
            a0 = hist[(newest - i0) % HISTORY]
            a1 = hist[(newest - i0 - 1) % HISTORY] if frac > 0.0 else a0
            x_true = a0 + (a1 - a0) * frac
        else:
            x_true = x
        x_read = _quant(x_true, p[SCALE_QUANT])
        th_read = _encoder(p, th_m)
        fb = x_read if p[FB_LOAD] != 0.0 else th_read / kr
        w_set_now = kr * (p[KV] * (x_ref[k] - fb) + p[KVFF] * v_ref[k])
        # a dead time in the speed set-point path (a field-bus stage), whole position cycles
        sp_ring[sp_i] = w_set_now
        w_set = sp_ring[(sp_i - n_sp) % SP_RING] if n_sp > 0 else w_set_now
        sp_i = (sp_i + 1) % SP_RING
        out[k, 0] = t
        out[k, 1] = x_ref[k]
        out[k, 2] = w_set
        out[k, 3] = th_read
        out[k, 4] = w_meas
        out[k, 5] = x_read
        out[k, 6] = logged
        out[k, 7] = f_ext_nm[k]
        f_ext = kr * f_ext_nm[k]
        for _s in range(nsc):
            # --- speed controller: encoder difference, first-order filter, PI -------------
            th_q = _encoder(p, th_m)
            w_raw = (th_q - th_prev) / tsc
            th_prev = th_q
            w_meas = w_raw + a_filt * (w_meas - w_raw)
            err = w_set - w_meas
            u_sc = p[KSP] * err + integ
            tau_ref = min(p[I_LIM], max(-p[I_LIM], u_sc))
            # back-calculation anti-windup: the integral is pulled back by the clipped part
            integ += p[KI] * err * tsc + (tau_ref - u_sc) * tsc / tsi_back
            i_ref = tau_ref / p[KT]
            for _c in range(ncc):
                # --- PI current loop; its voltage acts one current period later (PWM) -----
                e_c = i_ref - cur
                c_int += p[CKI] * e_c * tcc
                u_cmd = p[CKP] * e_c + c_int
                u_cmd = min(p[U_MAX], max(-p[U_MAX], u_cmd))
                u_apply = u_pending
                u_pending = u_cmd
                for _h in range(nh):
                    # winding, backward Euler in the current
                    cur = (cur + h / p[L_W] * (u_apply - p[KE] * w_m)) / (1.0 + h * p[R_W] / p[L_W])
                    tau_e = p[KT] * cur
                    # coupling and nut forces at the step's start
                    t_c = p[KC] * (th_m - th_s) + p[CC] * (w_m - w_s)
                    d = th_s / kr - x
                    dd = w_s / kr - v
                    half = p[HALF_GAP]
                    if half <= 0.0:
                        f_n = p[KN] * d + p[CN] * dd
                    elif d > half:
                        f_n = max(p[KN] * (d - half) + p[CN] * dd, 0.0)
                    elif d < -half:
                        f_n = min(p[KN] * (d + half) + p[CN] * dd, 0.0)
                    else:
                        f_n = 0.0
                    # LuGre friction with the bristle state at the step's start
                    gv = _g(p, v)
                    zdot = v - p[SIG0] * abs(v) * z / gv if gv > 0.0 else v
                    sig2 = p[SIG2_P] if v >= 0.0 else p[SIG2_N]
                    f_f = p[SIG0] * z + p[SIG1] * zdot + sig2 * v
                    f_l = p[F_CONST]
                    if p[F_PER] != 0.0:
                        f_l += p[F_PER] * math.sin(2.0 * math.pi * x / p[PER_LEN] + p[PER_PHASE])
                    # symplectic Euler: speeds first, positions with the new speeds
                    w_m += h * (tau_e - t_c) / p[JM]
                    w_s += h * (t_c - f_n / kr) / p[JS]
                    v += h * (f_n - f_f - f_l + f_ext) / p[M]
                    th_m += h * w_m
                    th_s += h * w_s
                    x += h * v
                    # bristles: exact for ż = v − a·z with v held over the step
                    a = p[SIG0] * abs(v) / gv if gv > 0.0 else 0.0
                    if a * h > 1e-12:
                        z_ss = v / a
                        z = z_ss + (z - z_ss) * math.exp(-a * h)
                    else:
                        z += h * v
                # the trace's torque: the current through its anti-alias filter
                logged = p[KT] * cur + a_aa * (logged - p[KT] * cur)
                t += tcc
                newest = (newest + 1) % HISTORY
                filled = min(filled + 1, HISTORY)
                hist[newest] = x
    return

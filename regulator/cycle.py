"""One position cycle of the control law, composed once (paper Fig. 1 and Fig. 6).

:func:`position_cycle` is the whole decision of one position-control cycle:

1. eq. 7 on the position feedback plus the velocity feed-forward of the axis file,
   ``omega_c = k_r k_v (x_ref - x_fb) + k_vff omega_s`` with ``omega_s = k_r v_ref``;
2. the supervision a bridge owes a real axis, on measured cycles: the following error
   (2008h), the discrepancy of the two measuring systems (2009h, paper section II.B) and the
   software travel limits (2014h; leaving them is allowed only heading back);
3. the vibration detector (Fig. 5) on ``omega_s - omega_c`` and eq. 15,
   ``lambda = exp(-beta / beta_T)``, ``omega_r = omega_s - lambda (omega_s - omega_c)``
   (``omega_r = omega_c`` with the regulator off, while beta is still measured);
4. the speed clamp (2007h).

It is what the bridge's compiled core (:mod:`bridge.cyclecore`), the simulator's kernel
(:mod:`plant_sim.physics.kernel`) and the bridge's loop without a bus (:mod:`hil.loop`) all
call: a change of the cycle is made here, once. Like :mod:`regulator.core` it takes only
floats, ints and float vectors and uses only :mod:`math`, so numba compiles it (nopython) and
Python runs the same code.

The cycle block. Parameters and results live at the start of the caller's float vector (a
list or a float64 array), so the bridge keeps them inside its own cycle vector without a
copy: ``C_*`` the parameters (a limit of ``inf`` checks nothing), ``Y_*`` the results of the
last call. :func:`block` makes one.

Codes: :data:`OK` (the results hold the set point), or why the cycle stopped before the
detector: :data:`FOLLOWING_ERROR`, :data:`DISCREPANCY`, :data:`POSITION_LIMIT` (the stored
results hold omega_s, omega_c and the error of this cycle; detector and lambda untouched),
:data:`NOT_FINITE` (an input of eq. 7 or eq. 15 is not finite: nothing but what was computed
before it is stored). Units: load units (m or rad), rad/s at the motor, s.
"""

from __future__ import annotations

import math
from typing import Any

from . import core

# --- the cycle block ----------------------------------------------------------------------------
(
    C_KR,  # k_r, motor rad per load unit
    C_KV,  # k_v, 1/s
    C_VFF,  # k_vff, velocity feed-forward gain (200Bh; 0 in the paper)
    C_REG_ON,  # 1.0: eq. 15 in the loop (2001h)
    C_REG_N,  # detector window n (n + 1 samples)
    C_CYCLE,  # s, the position cycle
    C_REG_TV,  # s, T_v (eq. 14)
    C_REG_TF,  # s, T_f
    C_REG_BT,  # rad/s, beta_T (eq. 15)
    C_SPEED_LIMIT,  # rad/s, |omega_r| clamp (2007h)
    C_FE_LIMIT,  # load units, |x_ref - x_fb| (2008h)
    C_DISC_LIMIT,  # load units, |motor / k_r - load| since enable (2009h)
    C_POS_MIN,  # load units (2014h:01)
    C_POS_MAX,  # load units (2014h:02)
    Y_OMEGA_S,  # rad/s, k_r v_ref
    Y_OMEGA_C,  # rad/s, eq. 7 + feed-forward
    Y_OMEGA_R,  # rad/s, the set point
    Y_BETA,  # rad/s, vibration level
    Y_LAMBDA,  # eq. 15's switching factor
    Y_ERROR,  # load units, x_ref - x_fb
    BLOCK_SIZE,
) = range(21)

# --- codes (the bridge's core uses the values between them for its own: 1 and 6) ------------------
OK = 0
FOLLOWING_ERROR = 2
DISCREPANCY = 3
POSITION_LIMIT = 4
NOT_FINITE = 5


def position_cycle(
    c: Any,
    det: Any,
    x_ref: float,
    speed: float,
    x_fb: float,
    difference: float,
    check_limits: bool,
) -> int:
    """One cycle (module docstring) with the interpolator's ``x_ref`` (load units) and
    ``speed`` (load units/s), the feedback ``x_fb`` (load units) and the measuring systems'
    ``difference`` (load units, motor / k_r - load since enable); ``check_limits``: this
    cycle's values are measured (not extrapolated over a lost frame), so the limits apply.
    ``c``: the cycle block; ``det``: the detector state of :mod:`regulator.core`. Returns a
    code; the set point is ``c[Y_OMEGA_R]``. It is :func:`measure` then :func:`apply` with
    this axis's own lambda (eq. 15 with the regulator off: lambda 1, and
    :func:`regulator.core.regulated_speed` returns omega_c exactly)."""
    code = measure(c, det, x_ref, speed, x_fb, difference, check_limits)
    if code == OK:
        apply(c, c[Y_LAMBDA])
    return code


def measure(
    c: Any,
    det: Any,
    x_ref: float,
    speed: float,
    x_fb: float,
    difference: float,
    check_limits: bool,
) -> int:
    """The first half of :func:`position_cycle` for axes whose eq. 15 shares one lambda (the
    contour axes of section II.A, which must keep identical dynamics, eq. 1): steps 1-3 up to
    this axis's own ``lambda = exp(-beta / beta_T)`` (1 with the regulator off), stored in
    ``c[Y_LAMBDA]`` with beta; the set point is left to :func:`apply`. :func:`position_cycle`
    is ``measure`` then ``apply(c, c[Y_LAMBDA])``, so the law is written once."""
    if not (math.isfinite(x_ref) and math.isfinite(x_fb)):
        return NOT_FINITE
    kr = c[C_KR]
    omega_s = kr * speed
    omega_c = core.position_command(x_ref, x_fb, c[C_KV], kr) + c[C_VFF] * omega_s
    error = x_ref - x_fb
    c[Y_OMEGA_S] = omega_s
    c[Y_OMEGA_C] = omega_c
    c[Y_ERROR] = error
    if check_limits:
        if abs(error) > c[C_FE_LIMIT]:
            return FOLLOWING_ERROR
        if abs(difference) > c[C_DISC_LIMIT]:
            return DISCREPANCY
        if (x_fb < c[C_POS_MIN] and speed <= 0.0) or (x_fb > c[C_POS_MAX] and speed >= 0.0):
            return POSITION_LIMIT
    u = omega_s - omega_c
    if not (math.isfinite(omega_s) and math.isfinite(omega_c) and math.isfinite(u)):
        return NOT_FINITE
    beta = core.detector_step(det, int(c[C_REG_N]), c[C_CYCLE], c[C_REG_TV], c[C_REG_TF], u)
    lam = core.switching_factor(beta, c[C_REG_BT]) if c[C_REG_ON] != 0.0 else 1.0
    c[Y_BETA] = beta
    c[Y_LAMBDA] = lam
    return OK


def apply(c: Any, lam: float) -> None:
    """The second half of :func:`position_cycle` after :func:`measure`: eq. 15 with ``lam``
    (this axis's own, or the one the contour axes share, :func:`shared_lambda`) and the speed
    clamp (2007h); ``c[Y_LAMBDA]`` becomes ``lam``."""
    omega_r = core.regulated_speed(c[Y_OMEGA_S], c[Y_OMEGA_C], lam)
    limit = c[C_SPEED_LIMIT]
    if omega_r > limit:
        omega_r = limit
    elif omega_r < -limit:
        omega_r = -limit
    c[Y_LAMBDA] = lam
    c[Y_OMEGA_R] = omega_r


def shared_lambda(blocks: Any) -> float:
    """The lambda interpolating axes share: the smallest of their own (after
    :func:`measure`), so that the axis that shakes most fades the load scale out of every
    contour axis's loop alike and their following errors stay equal (eq. 1)."""
    lam = 1.0
    for c in blocks:
        if c[Y_LAMBDA] < lam:
            lam = c[Y_LAMBDA]
    return lam


def block(
    kr: float,
    kv: float,
    cycle_s: float,
    *,
    velocity_feedforward: float = 0.0,
    regulator_on: bool = False,
    n: int = core.DEFAULT_N,
    tv_s: float = 1.0,
    tf_s: float = core.DEFAULT_TF_S,
    beta_t_rad_s: float = core.DEFAULT_BETA_T_RAD_S,
    speed_limit_rad_s: float = math.inf,
    following_error_limit: float = math.inf,
    discrepancy_limit: float = math.inf,
    position_min: float = -math.inf,
    position_max: float = math.inf,
) -> list[float]:
    """A cycle block (a list of :data:`BLOCK_SIZE` floats, results 0); the limits default to
    none (``inf``), as the simulator's kernel runs the law."""
    c = [0.0] * BLOCK_SIZE
    c[C_KR], c[C_KV], c[C_VFF] = kr, kv, velocity_feedforward
    c[C_REG_ON], c[C_REG_N], c[C_CYCLE] = (1.0 if regulator_on else 0.0), float(n), cycle_s
    c[C_REG_TV], c[C_REG_TF], c[C_REG_BT] = tv_s, tf_s, beta_t_rad_s
    c[C_SPEED_LIMIT], c[C_FE_LIMIT] = speed_limit_rad_s, following_error_limit
    c[C_DISC_LIMIT], c[C_POS_MIN], c[C_POS_MAX] = discrepancy_limit, position_min, position_max
    c[Y_LAMBDA] = 1.0
    return c

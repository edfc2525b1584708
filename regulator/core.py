"""The regulator's algorithm as plain, numba-compilable functions (paper sections VII, VIII).

Everything here takes only floats, ints and float64 numpy state arrays (the Python classes
keep the detector state in a list of floats, faster element by element) and uses only
:mod:`math`, so that the simulator can compile it with ``numba.njit`` (nopython mode) and call
it from its compiled kernel, while the Python classes (:mod:`regulator.detector`,
:mod:`regulator.speed_regulator`) call the very same functions uncompiled. No exceptions, no
Python objects, no keyword-only arguments; preconditions are checked by the callers.

Units: speeds in rad/s at the motor shaft, times in s, the position gain ``kv`` in 1/s.

Vibration detector (Fig. 5, section VII), once per position-control cycle, input
``u = omega_s - omega_c``:

1. Window of the last ``n + 1`` inputs. A crossing of ``omega_c`` with ``omega_s`` (a sign
   change of ``u``) lies in the window iff ``mean(|w|) > |mean(w)|``, compared with a relative
   tolerance (:data:`CROSSING_RTOL`): ``sum|w| - |sum w| > CROSSING_RTOL * sum|w|``. No
   detection before the window is full.
2. A crossing *event* is the rising edge of "crossing in window" (one event per crossing; a
   crossing stays in the window for ``n + 1`` cycles). The sampling condition of section VII
   (cycle < period / (2(n+1))) is exactly what makes every half-wave at least ``n + 1``
   samples long, so that the window is crossing-free once between two crossings.
3. Holder: ``peak`` is the largest ``|u|`` of the half-wave that is running (since the last
   event). At an event the half-wave just finished has height ``peak``; the holder takes
   ``h = min(peak, previous half-wave's peak)`` -- a vibration is an alternation, so a
   half-wave only counts as high as its neighbour. This rejects the one long monotone
   half-wave of a speed step or a ramp (``u`` decays from the step height to the noise level
   without a crossing) that would otherwise be held as a huge "vibration" at the first noise
   crossing (see docs/regulator.md). ``t_p`` := now.
4. Holder output ``y = h * exp(-(t - t_p) / T_v)`` (the exponential decay of section VII whose
   time constant eq. 14 bounds).
5. ``beta`` is ``y`` through a first-order low pass with time constant ``T_f``, discretised
   exactly for a piecewise-constant input: ``beta += (y - beta) * (1 - exp(-cycle / T_f))``.

Speed regulator (eq. 15): ``lambda = exp(-beta / beta_T)``,
``omega_r = omega_s - lambda * (omega_s - omega_c)``.
"""

from __future__ import annotations

import math

import numpy as np

# --- Defaults (module-level so the simulator and the Python classes share them) -------------

#: Window length is ``n + 1``; the paper uses n = 4 (section VII).
DEFAULT_N: int = 4
#: Vibration threshold beta_T of eq. 15, rad/s at the motor. Not given by the paper ("defined
#: experimentally by starting from small values"); this project's starting value.
DEFAULT_BETA_T_RAD_S: float = 0.2
#: Time constant T_f of the smoothing low pass (section VII), s. Not given by the paper.
DEFAULT_TF_S: float = 0.05
#: Default holder decay time T_v = DEFAULT_TV_TIMES_KV / kv: eq. 14, T_v = 5 / f at the lower
#: band end f = kv / 4 of eq. 13, i.e. five of the longest expected vibration periods.
DEFAULT_TV_TIMES_KV: float = 20.0
#: Relative tolerance of the crossing test ``sum|w| - |sum w| > CROSSING_RTOL * sum|w|``.
CROSSING_RTOL: float = 1e-12

# --- Detector state layout (float64 array) ---------------------------------------------------

_I_COUNT = 0  # number of inputs seen, saturating at n + 1
_I_POS = 1  # ring index where the next input is written
_I_PREV_CROSSING = 2  # 1.0 if the previous window contained a crossing
_I_PEAK = 3  # largest |u| of the running half-wave, rad/s
_I_PREV_PEAK = 4  # peak of the half-wave finished at the last event, rad/s
_I_HELD = 5  # held peak h, rad/s
_I_CYCLES_SINCE_EVENT = 6  # (t - t_p) / cycle
_I_HOLDER_OUT = 7  # y after the last step, rad/s
_I_BETA = 8  # vibration level beta after the last step, rad/s
_HEADER = 9  # the ring of n + 1 inputs follows


def detector_state_size(n: int) -> int:
    """Length of the float64 state array of a detector with window ``n + 1`` (``n >= 1``)."""
    return _HEADER + n + 1


def detector_reset(state: np.ndarray | list[float]) -> None:
    """Zero the whole detector state (no inputs seen, no held peak, beta = 0)."""
    for i in range(len(state)):
        state[i] = 0.0


def detector_step(
    state: np.ndarray | list[float],
    n: int,
    cycle_s: float,
    tv_s: float,
    tf_s: float,
    u_rad_s: float,
) -> float:
    """Feed one input ``u = omega_s - omega_c`` (rad/s) and return beta (rad/s) after it.

    Fig. 5 / section VII, see the module docstring for the exact rules. ``state`` must have
    ``detector_state_size(n)`` elements (zeroed by :func:`detector_reset` before the first
    call); ``n >= 1``; ``cycle_s`` (the position-control cycle), ``tv_s`` (holder decay time,
    eq. 14) and ``tf_s`` (low-pass time constant) are > 0 s; ``u_rad_s`` is finite.
    The callers check these preconditions; this function raises nothing.
    """
    m = n + 1
    # 1. ring window of the last n + 1 inputs
    pos = int(state[_I_POS])
    state[_HEADER + pos] = u_rad_s
    pos += 1
    if pos >= m:
        pos = 0
    state[_I_POS] = float(pos)
    count = state[_I_COUNT] + 1.0
    if count > m:
        count = float(m)
    state[_I_COUNT] = count

    crossing = False
    if count >= m:
        sum_abs = 0.0
        total = 0.0
        for i in range(m):
            w = state[_HEADER + i]
            sum_abs += abs(w)
            total += w
        # mean(|w|) > |mean(w)|  <=>  some w of opposite signs (a crossing) in the window
        crossing = sum_abs - abs(total) > CROSSING_RTOL * sum_abs

    # 2. + 3. rising edge of "crossing in window" -> hold the finished half-wave's height
    abs_u = abs(u_rad_s)
    if crossing and state[_I_PREV_CROSSING] < 0.5:
        finished = state[_I_PEAK]
        before = state[_I_PREV_PEAK]
        state[_I_HELD] = finished if finished < before else before
        state[_I_PREV_PEAK] = finished
        state[_I_PEAK] = abs_u  # u is the first sample of the new half-wave
        state[_I_CYCLES_SINCE_EVENT] = 0.0
    else:
        if abs_u > state[_I_PEAK]:
            state[_I_PEAK] = abs_u
        state[_I_CYCLES_SINCE_EVENT] += 1.0
    state[_I_PREV_CROSSING] = 1.0 if crossing else 0.0

    # 4. exponentially decaying holder output, y = h exp(-(t - t_p) / T_v)
    y = state[_I_HELD] * math.exp(-state[_I_CYCLES_SINCE_EVENT] * cycle_s / tv_s)
    state[_I_HOLDER_OUT] = y

    # 5. first-order low pass (T_f), exact for an input held over one cycle
    beta = state[_I_BETA]
    beta += (y - beta) * (1.0 - math.exp(-cycle_s / tf_s))
    state[_I_BETA] = beta
    return beta


def detector_beta(state: np.ndarray | list[float]) -> float:
    """Vibration level beta (rad/s) stored in a detector state."""
    return state[_I_BETA]


def detector_holder_output(state: np.ndarray | list[float]) -> float:
    """Holder output y (rad/s) after the last step (before the low pass)."""
    return state[_I_HOLDER_OUT]


def switching_factor(beta_rad_s: float, beta_t_rad_s: float) -> float:
    """Eq. 15: regulating-switching factor ``lambda = exp(-beta / beta_T)`` in (0, 1].

    ``beta_rad_s`` >= 0 is the vibration level, ``beta_t_rad_s`` > 0 the vibration threshold,
    both rad/s at the motor.
    """
    return math.exp(-beta_rad_s / beta_t_rad_s)


def regulated_speed(omega_s: float, omega_c: float, lam: float) -> float:
    """Eq. 15: regulated speed set point ``omega_r = omega_s - lambda (omega_s - omega_c)``.

    ``omega_s`` is the interpolator's speed, ``omega_c`` the position controller's output,
    both rad/s at the motor; ``lam`` in [0, 1]. Evaluated as the algebraically identical
    ``lam * omega_c + (1 - lam) * omega_s`` so that lambda = 1 returns exactly ``omega_c`` and
    lambda = 0 exactly ``omega_s``.
    """
    return lam * omega_c + (1.0 - lam) * omega_s


def position_command(
    x_ref: float, x_fb: float, kv_per_s: float, transmission_ratio: float
) -> float:
    """Eq. 7: speed set point ``omega_c = k_r * k_v * (x_ref - x_fb)`` in rad/s at the motor.

    ``x_ref`` (interpolator) and ``x_fb`` (position feedback) are in load units (m or rad),
    ``kv_per_s`` is the position gain in 1/s, ``transmission_ratio`` k_r is motor rad per load
    unit. ``x_ref - x_fb`` is the following error e_l of eq. 1.
    """
    return transmission_ratio * kv_per_s * (x_ref - x_fb)

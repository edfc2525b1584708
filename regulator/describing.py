"""Describing function of the dead zone (paper section IV, eq. 5) and limit-cycle prediction.

The paper models backlash as a dead zone (free play with elastic contact): the transmitted
torque is ``k_s * dz(x)`` with ``dz(x) = 0`` for ``|x| <= d`` and ``x - d sign(x)`` beyond.
Its sinusoidal-input describing function (normalised gain, unit slope) is

    N(A) = 0                                                       A <= d
    N(A) = 1 - (2/pi) [asin(d/A) + (d/A) sqrt(1 - (d/A)^2)]         A >  d        (eq. 5)

where ``d`` is the dead zone's HALF-width. The paper prints the two conditions the wrong way
round (``delta >= A`` for the formula); for ``A < d`` the formula is not even real.

Units: the paper's delta is the backlash reflected to the load side. The axis file's
``mechanics.backlash`` is the TOTAL free play between motor side and load, so the dead zone
seen by the relative displacement has half-width ``backlash / 2``: call
``deadzone_df(amplitude, backlash / 2)`` with the amplitude in the same load units.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from .errors import AnalysisError, is_real


def _check_delta(delta: float) -> float:
    if not (is_real(delta) and math.isfinite(delta) and delta > 0):
        raise AnalysisError(f"delta = {delta!r}: must be a finite dead-zone half-width > 0")
    return float(delta)


def _check_amplitudes(amplitude: float | np.ndarray) -> np.ndarray:
    a = np.asarray(amplitude, dtype=np.float64)
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise AnalysisError("amplitude: must be finite and >= 0 (same units as delta)")
    return a


def deadzone_df(amplitude: float | np.ndarray, delta: float) -> float | np.ndarray:
    """Eq. 5 (with the corrected condition): dead-zone describing function N(A) in [0, 1).

    ``amplitude`` A >= 0 of the input sinusoid (scalar or array, vectorised) and ``delta``
    the dead zone's half-width > 0, both in the same units (for an axis file: amplitude in
    load units and ``delta = backlash / 2``). Returns a float for a scalar input, else an
    array of the input's shape.
    """
    d = _check_delta(delta)
    a = _check_amplitudes(amplitude)
    ratio = np.divide(d, a, out=np.full(a.shape, np.inf), where=a > 0)
    outside = ratio < 1.0
    r = np.where(outside, ratio, 1.0)
    n = np.where(outside, 1.0 - (2.0 / math.pi) * (np.arcsin(r) + r * np.sqrt(1.0 - r * r)), 0.0)
    return float(n) if n.ndim == 0 else n


def deadzone_first_harmonic(
    amplitude: float | np.ndarray, delta: float, samples: int = 65536
) -> float | np.ndarray:
    """N(A) computed numerically: b1 / A of the dead-zone output for the input A sin(theta).

    ``b1 = (1/pi) * integral_0^{2 pi} dz(A sin theta) sin theta dtheta`` by the midpoint rule
    with ``samples`` points (error O(samples^-2) from the kinks at |A sin theta| = delta).
    An independent check of :func:`deadzone_df`; same arguments and return shapes.
    """
    d = _check_delta(delta)
    a = _check_amplitudes(amplitude)
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 16:
        raise AnalysisError(f"samples = {samples!r}: must be an integer >= 16")
    theta = (np.arange(samples) + 0.5) * (2.0 * math.pi / samples)
    sin_t = np.sin(theta)
    flat = a.reshape(-1)
    out = np.zeros(flat.shape)
    for i, amp in enumerate(flat):
        if amp == 0.0:
            continue
        x = amp * sin_t
        y = np.where(np.abs(x) > d, x - d * np.sign(x), 0.0)
        b1 = np.mean(y * sin_t) * 2.0  # (1/pi) * sum * (2 pi / samples)
        out[i] = b1 / amp
    result = out.reshape(a.shape)
    return float(result) if result.ndim == 0 else result


def deadzone_amplitude_for_gain(gain: float, delta: float) -> float:
    """Inverse of eq. 5: the amplitude A with N(A) = ``gain`` (0 < gain < 1), units of delta."""
    d = _check_delta(delta)
    if not (is_real(gain) and 0.0 < gain < 1.0):
        raise AnalysisError(f"gain = {gain!r}: must be in (0, 1), the range of N(A) for A > delta")
    # N(A) rises monotonically from 0 at A = d towards 1; 1 - N ~ 4 d / (pi A) for large A.
    upper = d * max(2.0, 8.0 / (math.pi * (1.0 - gain)))
    return float(brentq(lambda amp: deadzone_df(amp, d) - gain, d, upper, xtol=1e-14 * d))


@dataclass(frozen=True)
class LimitCycle:
    """A describing-function limit-cycle prediction.

    frequency_rad_s:  omega_pc, where arg L(j omega) = -180 degrees.
    frequency_hz:     the same in Hz.
    loop_gain:        |L(j omega_pc)| (> 1).
    amplitude:        A with N(A) = 1 / |L(j omega_pc)|, amplitude of the dead zone's input,
                      in the units of ``delta``.
    """

    frequency_rad_s: float
    frequency_hz: float
    loop_gain: float
    amplitude: float


def predict_limit_cycle(
    loop_frequency_response: Callable[[np.ndarray], np.ndarray],
    delta: float,
    omega_min_rad_s: float = 1e-3,
    omega_max_rad_s: float = 1e4,
    points: int = 20000,
) -> LimitCycle | None:
    """Harmonic balance ``N(A) L(j omega) = -1`` for a dead zone in a loop with linear part L.

    ``loop_frequency_response(omega)`` returns the complex L(j omega) of the linear part for an
    array of angular frequencies omega (rad/s); the dead zone (half-width ``delta``) is in
    series with it. Since N is real in [0, 1), -1/N(A) runs along the negative real axis from
    -inf to -1, so a solution needs a phase crossover omega_pc (L real and negative) with
    |L(j omega_pc)| > 1; then A follows from N(A) = 1 / |L|. The crossovers are searched on a
    log grid of ``points`` frequencies in [omega_min_rad_s, omega_max_rad_s] and refined by
    root finding on Im L. If there are several, the one with the largest |L| (smallest
    amplitude, met first by a growing disturbance) is returned; ``None`` if there is none.

    For a pure dead zone N rises with A, so by the usual (Loeb) argument the predicted cycle
    of a loop that is unstable at N = 1 is an unstable one: smaller oscillations decay, larger
    ones grow (until another nonlinearity, e.g. torque saturation, bounds them).
    """
    d = _check_delta(delta)
    if not (0 < omega_min_rad_s < omega_max_rad_s and math.isfinite(omega_max_rad_s)):
        raise AnalysisError(
            f"omega range [{omega_min_rad_s!r}, {omega_max_rad_s!r}] rad/s: need "
            "0 < omega_min_rad_s < omega_max_rad_s < inf"
        )
    if isinstance(points, bool) or not isinstance(points, int) or points < 10:
        raise AnalysisError(f"points = {points!r}: must be an integer >= 10")

    def response(omega: np.ndarray) -> np.ndarray:
        return np.asarray(loop_frequency_response(omega), dtype=np.complex128)

    omega = np.geomspace(omega_min_rad_s, omega_max_rad_s, points)
    values = response(omega)
    if values.shape != omega.shape:
        raise AnalysisError(
            f"loop_frequency_response returned shape {values.shape}, expected {omega.shape}"
        )
    imag = values.imag
    best: tuple[float, float] | None = None
    for i in np.nonzero(np.signbit(imag[:-1]) != np.signbit(imag[1:]))[0]:
        if values.real[i] >= 0 and values.real[i + 1] >= 0:
            continue  # crossing of the positive real axis
        lo, hi = float(omega[i]), float(omega[i + 1])
        if imag[i] == 0.0:
            w_pc = lo
        else:
            w_pc = float(
                brentq(lambda w: float(response(np.array([w]))[0].imag), lo, hi, xtol=1e-13 * lo)
            )
        l_pc = complex(response(np.array([w_pc]))[0])
        if l_pc.real >= 0:
            continue
        gain = abs(l_pc)
        if gain > 1.0 and (best is None or gain > best[1]):
            best = (w_pc, gain)
    if best is None:
        return None
    w_pc, gain = best
    return LimitCycle(
        frequency_rad_s=w_pc,
        frequency_hz=w_pc / (2.0 * math.pi),
        loop_gain=gain,
        amplitude=deadzone_amplitude_for_gain(1.0 / gain, d),
    )

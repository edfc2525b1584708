"""What the measured signals of one trace say about the motion, on a uniform time grid: the
evidence stage's input (:mod:`.idim`, :mod:`.loop_tests`).

The same function reads a recording and a closed-loop replay of a model (:mod:`.replay`):
every estimator of the evidence stage is applied to both, so that what the estimator itself
does (the smoothing of a derivative, the torque sampled once per position cycle while the
speed loop moves it within the cycle — on the test set's slide the sampled torque carries
12 % less inertial torque than the cycle's mean) is the same on both sides and cancels when
the two are compared (docs/diagnosis.md, "Evidence").

Derivatives are Savitzky–Golay (cubic, a window of about :data:`WINDOW_S`, at least
:data:`MIN_WINDOW` samples): centred, so positions, speeds, accelerations and the sampled
torque keep their common time base. A recording with a non-uniform sample time (a bus
recorder, the XL330's ~5.3 ms reads) is put on a uniform grid at its median sample time
first (positions by a cubic spline, the other columns linearly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal as sps
from scipy.interpolate import CubicSpline

from virtual_bus.formats.axis import AxisConfig, PositionFeedback
from virtual_bus.formats.trace import Trace

from .errors import DiagnosisInputError

#: Length of the derivative window, s.
WINDOW_S = 0.02
#: Fewest samples in a derivative window (odd).
MIN_WINDOW = 5
#: Fewest samples the evidence stage works on.
MIN_SAMPLES = 50
#: Relative spread of sample times beyond which a trace is resampled onto a uniform grid.
UNIFORM_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Measured:
    """Kinematics and torque of one trace on a uniform grid (load units, N·m at the motor).

    ``motor_position`` rad at the motor; ``load_position`` the load measuring system's reading
    when recorded, else the motor's divided by k_r (``two_systems`` False); ``speed``,
    ``accel`` of the load side (from the load reading when recorded); ``motor_accel``
    rad/s² from the motor reading; ``deflection`` θ/k_r − x (load units, None with one
    measuring system); ``reference`` the position reference on the grid; ``feedback`` the
    position the loop closes on."""

    time_s: np.ndarray
    dt: float
    transmission_ratio: float
    motor_position: np.ndarray
    load_position: np.ndarray
    two_systems: bool
    speed: np.ndarray
    accel: np.ndarray
    motor_accel: np.ndarray
    motor_speed: np.ndarray
    torque: np.ndarray
    reference: np.ndarray
    feedback: np.ndarray
    deflection: np.ndarray | None
    deflection_rate: np.ndarray | None
    jerk2: np.ndarray  # fourth derivative of the motor-side load position (compliance test)

    @property
    def n(self) -> int:
        return len(self.time_s)


def window_samples(dt: float, n: int) -> int:
    """Odd Savitzky–Golay window for sample time ``dt`` (≈ WINDOW_S, at least MIN_WINDOW)."""
    win = max(MIN_WINDOW, 2 * round(WINDOW_S / dt / 2.0) + 1)
    if win > n:
        win = n if n % 2 else n - 1
    return win


def _grid(trace: Trace) -> tuple[np.ndarray, float, bool]:
    t = trace.time
    steps = np.diff(t)
    dt = float(np.median(steps))
    uniform = bool(np.max(np.abs(steps - dt)) <= UNIFORM_TOLERANCE * dt)
    if uniform:
        return t.copy(), dt, True
    n = int(np.floor((t[-1] - t[0]) / dt)) + 1
    return t[0] + np.arange(n) * dt, dt, False


def _derivatives(x: np.ndarray, dt: float, orders: tuple[int, ...]) -> list[np.ndarray]:
    win = window_samples(dt, len(x))
    poly = min(3, win - 2)
    out = []
    for d in orders:
        if d == 4:
            # the fourth derivative needs a quartic fit; a wider window keeps its noise down
            w4 = min(2 * win + 1 if (2 * win + 1) <= len(x) else win, len(x) - (1 - len(x) % 2))
            out.append(sps.savgol_filter(x, w4, min(5, w4 - 1), deriv=4, delta=dt))
        else:
            out.append(sps.savgol_filter(x, win, max(poly, d), deriv=d, delta=dt))
    return out


def measured(trace: Trace, axis: AxisConfig) -> Measured:
    """The kinematics of ``trace`` (a recording or a replay with the same columns)."""
    if len(trace) < MIN_SAMPLES:
        raise DiagnosisInputError(
            f"the recording has {len(trace)} samples; the evidence stage needs at least "
            f"{MIN_SAMPLES}"
        )
    kr = axis.transmission_ratio
    t, dt, uniform = _grid(trace)

    def col(name: str, smooth: bool = False) -> np.ndarray:
        values = trace[name]
        if uniform:
            return values.astype(float, copy=True)
        if smooth:
            return CubicSpline(trace.time, values)(t)
        return np.interp(t, trace.time, values)

    theta = col("motor_position", smooth=True)
    two = "load_position" in trace
    x = col("load_position", smooth=True) if two else theta / kr
    torque = col("motor_torque")
    ref = col("position_reference", smooth=True) if "position_reference" in trace else x
    wm, am = _derivatives(theta, dt, (1, 2))
    (j4,) = _derivatives(theta / kr, dt, (4,))
    if two:
        v, a = _derivatives(x, dt, (1, 2))
        defl = theta / kr - x
        (ddefl,) = _derivatives(defl, dt, (1,))
    else:
        v, a = wm / kr, am / kr
        defl = ddefl = None
    fb = x if axis.control.position_feedback is PositionFeedback.LOAD and two else theta / kr
    return Measured(
        time_s=t,
        dt=dt,
        transmission_ratio=kr,
        motor_position=theta,
        load_position=x,
        two_systems=two,
        speed=v,
        accel=a,
        motor_accel=am,
        motor_speed=wm,
        torque=torque,
        reference=ref,
        feedback=fb,
        deflection=defl,
        deflection_rate=ddefl,
        jerk2=j4,
    )


#: Columns whose measurement noise a calibration replay is given (regressors are built from
#: them: errors in variables bias a least-squares fit, on the recording and the replay alike
#: only if both carry the noise).
NOISY_COLUMNS = ("motor_position", "load_position", "motor_torque")


def high_frequency_sigma(x: np.ndarray) -> float:
    """Robust σ of the white part of ``x``: MAD of its third difference / √20 (a smooth signal
    has a third difference far below the noise's, white noise of σ one of σ·√20)."""
    if len(x) < 8:
        return 0.0
    d3 = np.diff(x, 3)
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(20.0))


def measurement_noise(recording: Trace, simulated: Trace) -> dict[str, float]:
    """White measurement noise per column of :data:`NOISY_COLUMNS`: the recording's
    high-frequency σ less what the noise-free replay of the model has there (the speed loop's
    ripple within a position cycle, which both show), in quadrature."""
    out = {}
    for name in NOISY_COLUMNS:
        if name in recording and name in simulated:
            rec = high_frequency_sigma(recording[name])
            sim = high_frequency_sigma(simulated[name])
            out[name] = math.sqrt(max(rec**2 - sim**2, 0.0))
    return out


def with_noise(trace: Trace, sigma: dict[str, float], rng: np.random.Generator) -> Trace:
    """``trace`` with white noise of ``sigma`` added per column."""
    cols = dict(trace.columns)
    for name, s in sigma.items():
        if name in cols and s > 0.0:
            cols[name] = cols[name] + s * rng.standard_normal(len(cols[name]))
    return Trace(cols)

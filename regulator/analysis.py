"""Analysis formulas of the paper and its spectral condition monitoring (sections II, VI, VII).

Plain functions, no state:

- :func:`following_error` -- eq. 1.
- :func:`restitution_frequency_hz` -- eq. 12, vibration frequency from the coefficient of
  restitution; :func:`vibration_band_hz` -- eq. 13; :func:`min_decay_time_s` -- eq. 14.
- :func:`dominant_frequency_hz`, :func:`condition_monitoring` -- the FFT-based detection of
  section VI ("detection of estimated dominant frequency bandwidth from the current or speed
  signal spectrum").
- Re-exported from :mod:`regulator.describing`: the dead-zone describing function (eq. 5),
  its numerical check and a limit-cycle prediction.

Units: kv in 1/s. Eq. 12 derives f = 1/T from the period T in s, so f is in Hz (cycles per
second) when kv is in 1/s -- the way the paper's Fig. 4 compares it with measured vibrations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .describing import (
    LimitCycle,
    deadzone_amplitude_for_gain,
    deadzone_df,
    deadzone_first_harmonic,
    predict_limit_cycle,
)
from .errors import AnalysisError, is_real

__all__ = [
    "BandVerdict",
    "LimitCycle",
    "condition_monitoring",
    "deadzone_amplitude_for_gain",
    "deadzone_df",
    "deadzone_first_harmonic",
    "dominant_frequency_hz",
    "following_error",
    "min_decay_time_s",
    "predict_limit_cycle",
    "restitution_frequency_hz",
    "vibration_band_hz",
]

#: Coefficients of restitution spanning the band of eq. 13 (section VI): a fully plastic
#: impact (e = 0) and two steel balls (e ~ 0.6).
RESTITUTION_RANGE: tuple[float, float] = (0.0, 0.6)


def _check_kv(kv_per_s: float) -> float:
    if not (is_real(kv_per_s) and math.isfinite(kv_per_s) and kv_per_s > 0):
        raise AnalysisError(f"kv_per_s = {kv_per_s!r}: must be a finite position gain > 0 1/s")
    return float(kv_per_s)


def following_error(speed: float | np.ndarray, kv_per_s: float) -> float | np.ndarray:
    """Eq. 1: steady following error = speed / k_v (vectorised over ``speed``).

    ``speed`` in load units/s (m/s or rad/s at the load) gives the error in load units; any
    consistent unit works (motor rad/s gives motor rad).
    """
    kv = _check_kv(kv_per_s)
    result = np.asarray(speed, dtype=np.float64) / kv
    return float(result) if result.ndim == 0 else result


def restitution_frequency_hz(kv_per_s: float, e: float) -> float:
    """Eq. 12: vibration frequency f = (1/4) (1 + e) / (1 - e) k_v, Hz for k_v in 1/s.

    ``e`` is the coefficient of restitution of the backlash impact, 0 <= e < 1.
    """
    kv = _check_kv(kv_per_s)
    if not (is_real(e) and 0.0 <= e < 1.0):
        raise AnalysisError(f"e = {e!r}: coefficient of restitution must be in [0, 1)")
    return 0.25 * (1.0 + e) / (1.0 - e) * kv


def vibration_band_hz(kv_per_s: float) -> tuple[float, float]:
    """Eq. 13: expected vibration band (kv/4, kv) in Hz for kv in 1/s.

    Exactly eq. 12 evaluated at e = 0 (kv/4) and e = 0.6 ((1.6/0.4)/4 kv = kv).
    """
    kv = _check_kv(kv_per_s)
    return (kv / 4.0, kv)


def min_decay_time_s(kv_per_s: float) -> float:
    """Eq. 14: smallest holder decay time T_v = 5 / f with f = kv / 4 (eq. 13), i.e. 20 / kv s.

    Five periods of the slowest vibration in the band.
    """
    kv = _check_kv(kv_per_s)
    return 5.0 / (kv / 4.0)


@dataclass(frozen=True)
class BandVerdict:
    """Result of :func:`condition_monitoring`.

    frequency_hz:  dominant frequency of the signal, Hz (nan if the signal is constant).
    band_hz:       expected vibration band of eq. 13, (kv/4, kv) Hz.
    in_band:       True if frequency_hz lies in band_hz (edges included).
    amplitude:     peak amplitude of the dominant sinusoidal component, signal units.
    """

    frequency_hz: float
    band_hz: tuple[float, float]
    in_band: bool
    amplitude: float


def _spectral_peak(
    signal: np.ndarray, dt_s: float, f_min_hz: float, f_max_hz: float | None
) -> tuple[float, float]:
    """(frequency Hz, amplitude) of the largest spectral peak in [f_min_hz, f_max_hz].

    Linear trend removed, Hann window, zero-padded to >= 4x the length, parabolic
    interpolation of the log magnitude around the peak bin. (nan, 0.0) for a signal that is
    a straight line.
    """
    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1 or x.size < 16:
        raise AnalysisError(f"signal: need a 1-D array of at least 16 samples, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise AnalysisError("signal: contains NaN or inf")
    if not (is_real(dt_s) and math.isfinite(dt_s) and dt_s > 0):
        raise AnalysisError(f"dt_s = {dt_s!r}: must be a finite sampling time > 0 s")
    nyquist = 0.5 / dt_s
    f_hi = nyquist if f_max_hz is None else float(f_max_hz)
    if not (0.0 <= f_min_hz < f_hi <= nyquist):
        raise AnalysisError(
            f"frequency range [{f_min_hz!r}, {f_max_hz!r}] Hz: need 0 <= f_min_hz < f_max_hz "
            f"<= Nyquist = {nyquist:g} Hz"
        )
    size_of_signal = float(np.max(np.abs(x)))
    t = np.arange(x.size, dtype=np.float64)
    slope, intercept = np.polyfit(t, x, 1)
    x = x - (slope * t + intercept)
    window = np.hanning(x.size)
    nfft = 1 << max((4 * x.size - 1).bit_length(), 4)
    magnitude = np.abs(np.fft.rfft(x * window, nfft))
    freqs = np.fft.rfftfreq(nfft, dt_s)
    candidates = np.nonzero((freqs >= f_min_hz) & (freqs <= f_hi) & (freqs > 0))[0]
    if candidates.size == 0:
        raise AnalysisError(f"frequency range [{f_min_hz!r}, {f_hi!r}] Hz holds no FFT bin")
    k = int(candidates[np.argmax(magnitude[candidates])])
    peak = magnitude[k]
    scale = 2.0 / window.sum()
    if not peak * scale > 1e-12 * size_of_signal:
        return (math.nan, 0.0)  # rounding noise of a straight line (or all zeros)
    if 0 < k < magnitude.size - 1:
        floor = peak * 1e-300
        alpha, beta, gamma = (math.log(max(float(m), floor)) for m in magnitude[k - 1 : k + 2])
        denominator = alpha - 2.0 * beta + gamma
        p = 0.5 * (alpha - gamma) / denominator if denominator < 0 else 0.0
        p = min(max(p, -0.5), 0.5)
        log_peak = beta - 0.25 * (alpha - gamma) * p
    else:
        p = 0.0
        log_peak = math.log(float(peak))
    frequency = (k + p) * (freqs[1] - freqs[0])
    return (float(frequency), float(math.exp(log_peak) * scale))


def dominant_frequency_hz(
    signal: np.ndarray,
    dt_s: float,
    f_min_hz: float = 0.0,
    f_max_hz: float | None = None,
) -> float:
    """Dominant frequency (Hz) of a uniformly sampled signal (section VI, FFT).

    ``signal`` (any unit) sampled every ``dt_s`` s; the peak is searched in
    [``f_min_hz``, ``f_max_hz``] (default: above DC up to Nyquist). Mean and linear trend are
    removed, a Hann window applied, and the peak bin refined by parabolic interpolation of
    the log magnitude (zero-padded FFT), so the error is a small fraction of a bin (1 / (N dt)).
    Raises :class:`~regulator.errors.AnalysisError` for bad arguments or a signal without
    any oscillation.
    """
    frequency, _ = _spectral_peak(signal, dt_s, float(f_min_hz), f_max_hz)
    if math.isnan(frequency):
        raise AnalysisError("signal: no oscillating component (a straight line after detrending)")
    return frequency


def condition_monitoring(
    signal: np.ndarray,
    dt_s: float,
    kv_per_s: float,
    f_min_hz: float = 0.0,
    f_max_hz: float | None = None,
) -> BandVerdict:
    """Section VI: is the dominant frequency of a speed or current signal in eq. 13's band?

    ``signal`` e.g. motor speed (rad/s) or torque (N m) sampled every ``dt_s`` s, ``kv_per_s``
    the axis' position gain (1/s). The optional range limits where the dominant peak is
    searched (Hz). A signal without any oscillation gives frequency nan, amplitude 0 and
    ``in_band`` False.
    """
    band = vibration_band_hz(kv_per_s)
    frequency, amplitude = _spectral_peak(signal, dt_s, float(f_min_hz), f_max_hz)
    in_band = (not math.isnan(frequency)) and band[0] <= frequency <= band[1]
    return BandVerdict(
        frequency_hz=frequency, band_hz=band, in_band=bool(in_band), amplitude=amplitude
    )

"""Frequency response of a speed loop over the bus, as in the paper's Fig. 2 (section V).

The paper takes the antiresonance omega_a "through the experimental frequency response like
Fig. 2" (section IX). This module is the measurement's arithmetic, pure numpy/scipy:

* :class:`Multisine` -- one period of a periodic excitation of the speed set point: every DFT
  line from ``f_min_hz`` to ``f_max_hz`` with Schroeder phases (low crest factor); above
  ``corner_hz`` the line amplitudes fall as 1/f, so each line needs about the same torque
  (the torque limit bounds a flat speed spectrum at high frequencies, not a 1/f one);
* :func:`estimate` -- the frequency response at the excited lines from whole periods of an
  input and an output sampled every cycle (the SYNC rate): the DFT of each period, averaged over
  the periods, their ratio; the standard deviation of that ratio from the spread of the periods
  (the "robust" method of Pintelon & Schoukens, *System Identification*, ch. 2 and 7, with
  the covariance of input and output, so that the set point may be inside a closed loop);
* :func:`antiresonance` -- omega_a where the torque is measured as the two-mass model of eq. 2
  fitted to the motor admittance (:mod:`regulator.admittance_fit`: its verdict from an F test
  against the rigid body and the realizations' spread); without torque, as the notch of the
  speed loop ``omega_m / omega_r``: the
  zeros P of eq. 2 are zeros of eq. 6a, so the loop's magnitude dips at omega_a (Fig. 2). The
  notch is the deepest local minimum relative to the median of its neighbourhood, located
  between lines by a parabola through log-magnitudes; its uncertainty (about 95 %) combines
  the jackknife over the periods or realizations (noise; Student's t for their number), half a
  line of resolution and half the distance to
  the notch of the motor admittance ``|omega_m / tau_m * j omega|`` (eq. 2) where the torque
  is measured -- the two sampled-data estimates of one zero differ by what sampling the drive's
  torque at the SYNC instant moves it. Lines in the noise (relative deviation above
  :data:`MAX_NOTCH_REL_STD`) are no candidates. A notch shallower than :data:`MIN_NOTCH_DB`,
  or less certain than :data:`MAX_NOTCH_REL_UNCERTAINTY` of its frequency, is "not resolved"
  (a backlash gap open at standstill decouples the load: no notch);
* :func:`bandwidth` -- the -3 dB frequency of ``omega_m / omega_r`` with the band of
  frequencies where the estimate +- its deviation crosses -3 dB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import t as student_t

from .admittance_fit import TwoMassFit, fit_two_mass
from .errors import AnalysisError, require_positive

#: Coverage factor of the stated uncertainty (about 95 % for a normal estimate).
COVERAGE = 2.0


@dataclass(frozen=True)
class Multisine:
    """A periodic multisine of ``period_samples`` samples every ``cycle_s``.

    amplitude: peak of the period (set-point units, e.g. rad/s at the motor); the lines from
    f_min_hz to f_max_hz (inclusive, on the DFT grid 1 / (period_samples * cycle_s)); above
    corner_hz each line's amplitude is scaled by corner_hz / f.
    """

    cycle_s: float
    period_samples: int
    f_min_hz: float
    f_max_hz: float
    amplitude: float
    corner_hz: float | None = None
    #: None: Schroeder phases; an integer: uniformly random phases from this seed (one
    #: realization of a random-phase multisine, :meth:`realization`)
    seed: int | None = None

    def __post_init__(self) -> None:
        require_positive("cycle_s", self.cycle_s, "s")
        require_positive("amplitude", self.amplitude, "")
        n = self.period_samples
        if isinstance(n, bool) or not isinstance(n, int) or n < 16:
            raise AnalysisError(f"period_samples = {n!r}: an integer >= 16")
        nyquist = 0.5 / self.cycle_s
        df = self.resolution_hz
        require_positive("f_min_hz", self.f_min_hz, "Hz")
        if not self.f_min_hz >= df * (1 - 1e-9):
            raise AnalysisError(
                f"f_min_hz = {self.f_min_hz:g}: at least the resolution {df:.6g} Hz of a "
                f"period of {n} samples of {self.cycle_s:g} s"
            )
        if not self.f_min_hz < self.f_max_hz < nyquist:
            raise AnalysisError(
                f"f_max_hz = {self.f_max_hz!r}: must lie between f_min_hz = {self.f_min_hz:g} "
                f"and the Nyquist frequency {nyquist:g} Hz of the cycle"
            )
        if self.corner_hz is not None:
            require_positive("corner_hz", self.corner_hz, "Hz")
        if self.lines.size < 2:
            raise AnalysisError("the band holds fewer than 2 lines: widen it, lengthen the period")

    @property
    def resolution_hz(self) -> float:
        return 1.0 / (self.period_samples * self.cycle_s)

    @property
    def period_s(self) -> float:
        return self.period_samples * self.cycle_s

    @property
    def lines(self) -> np.ndarray:
        """DFT bin indices that are excited."""
        df = self.resolution_hz
        first = math.ceil(self.f_min_hz / df - 1e-9)
        last = math.floor(self.f_max_hz / df + 1e-9)
        return np.arange(max(first, 1), last + 1)

    @property
    def frequencies_hz(self) -> np.ndarray:
        return self.lines * self.resolution_hz

    def period(self) -> np.ndarray:
        """One period, zero mean, peak |value| = amplitude."""
        lines = self.lines
        k = np.arange(self.period_samples)
        count = lines.size
        if self.seed is None:
            phases = -np.pi * np.arange(count) * (np.arange(count) + 1) / count  # Schroeder
        else:
            phases = np.random.default_rng(self.seed).uniform(-np.pi, np.pi, count)
        gains = np.ones(count)
        if self.corner_hz is not None:
            gains = np.minimum(1.0, self.corner_hz / self.frequencies_hz)
        angle = 2.0 * np.pi * np.outer(lines, k) / self.period_samples + phases[:, None]
        signal = (gains[:, None] * np.cos(angle)).sum(axis=0)
        return signal * (self.amplitude / np.max(np.abs(signal)))

    def realization(self, index: int) -> Multisine:
        """The same lines and amplitudes with random phases (seed ``index``): averaging
        realizations turns what a periodic excitation makes periodic -- quantisation,
        friction, the backlash -- into a spread the uncertainty shows (the best linear
        approximation of Pintelon & Schoukens, ch. 3)."""
        return replace(self, seed=int(index))

    def signal(self, periods: int) -> np.ndarray:
        """``periods`` periods back to back."""
        if isinstance(periods, bool) or not isinstance(periods, int) or periods < 1:
            raise AnalysisError(f"periods = {periods!r}: an integer >= 1")
        return np.tile(self.period(), periods)


@dataclass(frozen=True)
class Frf:
    """A measured frequency response: complex ``response`` at ``frequency_hz`` with the
    standard deviation ``std`` of each value, from ``periods`` periods."""

    frequency_hz: np.ndarray
    response: np.ndarray
    std: np.ndarray
    periods: int
    #: the estimate with each period left out in turn (periods x lines): the jackknife
    leave_one_out: np.ndarray

    def magnitude_db(self) -> np.ndarray:
        return 20.0 * np.log10(np.abs(self.response))

    def phase_deg(self) -> np.ndarray:
        return np.degrees(np.unwrap(np.angle(self.response)))

    def band(self, low_hz: float, high_hz: float) -> Frf:
        keep = (self.frequency_hz >= low_hz) & (self.frequency_hz <= high_hz)
        return Frf(
            self.frequency_hz[keep],
            self.response[keep],
            self.std[keep],
            self.periods,
            self.leave_one_out[:, keep],
        )


def _spectra(
    excitation: Multisine, u: np.ndarray, y: np.ndarray, skip_periods: int
) -> tuple[np.ndarray, np.ndarray]:
    n = excitation.period_samples
    periods = u.size // n - skip_periods
    if periods < 1:
        raise AnalysisError(f"{u.size} samples hold no period of {n} after {skip_periods} skipped")
    start = skip_periods * n
    stop = start + periods * n
    lines = excitation.lines
    uk = np.fft.rfft(u[start:stop].reshape(periods, n), axis=1)[:, lines]
    yk = np.fft.rfft(y[start:stop].reshape(periods, n), axis=1)[:, lines]
    if np.any(np.abs(uk.mean(axis=0)) == 0.0):
        raise AnalysisError("the input has no power at some excited line")
    return uk, yk


def estimate(
    excitation: Multisine,
    u: np.ndarray,
    y: np.ndarray,
    skip_periods: int = 1,
    realizations: int = 1,
) -> Frf:
    """Y/U at the excited lines. ``u``, ``y``: ``realizations`` equal blocks (realization m
    of the excitation each, :meth:`Multisine.realization`), each ``skip_periods`` transient
    periods and then whole periods. One realization: the spectra averaged over its periods,
    the deviation and the jackknife from the periods' spread (noise only). Several: the
    estimate of each realization averaged, the deviation and the jackknife from the
    realizations' spread (noise and what the excitation's periodicity made periodic)."""
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.shape != y.shape or u.ndim != 1:
        raise AnalysisError(f"u {u.shape} and y {y.shape}: equal 1-d arrays")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise AnalysisError("u and y must be finite")
    if isinstance(realizations, bool) or not isinstance(realizations, int) or realizations < 1:
        raise AnalysisError(f"realizations = {realizations!r}: an integer >= 1")
    if realizations == 1:
        uk, yk = _spectra(excitation, u, y, skip_periods)
        periods = uk.shape[0]
        if periods < 2:
            raise AnalysisError(
                f"{u.size} samples hold {u.size // excitation.period_samples} periods; need "
                f"{skip_periods} to skip and at least 2 to average"
            )
        um, ym = uk.mean(axis=0), yk.mean(axis=0)
        g = ym / um
        var_u = uk.var(axis=0, ddof=1) / periods
        var_y = yk.var(axis=0, ddof=1) / periods
        cov = np.sum((yk - ym) * np.conj(uk - um), axis=0) / (periods - 1) / periods
        cross = np.real(cov / (ym * np.conj(um)))
        rel = var_y / np.abs(ym) ** 2 + var_u / np.abs(um) ** 2 - 2.0 * cross
        std = np.abs(g) * np.sqrt(np.maximum(rel, 0.0))
        u_sum, y_sum = uk.sum(axis=0), yk.sum(axis=0)
        leave_one_out = (y_sum - yk) / (u_sum - uk)
        return Frf(excitation.frequencies_hz, g, std, periods, leave_one_out)
    if u.size % realizations:
        raise AnalysisError(f"{u.size} samples are not {realizations} equal blocks")
    block = u.size // realizations
    each = []
    periods = 0
    for m in range(realizations):
        part = slice(m * block, (m + 1) * block)
        uk, yk = _spectra(excitation.realization(m), u[part], y[part], skip_periods)
        each.append(yk.mean(axis=0) / uk.mean(axis=0))
        periods += uk.shape[0]
    g_m = np.array(each)
    g = g_m.mean(axis=0)
    std = np.sqrt((g_m.real.var(axis=0, ddof=1) + g_m.imag.var(axis=0, ddof=1)) / realizations)
    leave_one_out = (g_m.sum(axis=0) - g_m) / (realizations - 1)
    return Frf(excitation.frequencies_hz, g, std, periods, leave_one_out)


#: A notch shallower than this (dB below the median of its neighbourhood) is not resolved.
MIN_NOTCH_DB = 6.0
#: Lines whose relative standard deviation exceeds this are no notch candidates: a line in
#: the noise (a quantised encoder at a frequency the loop hardly passes) can dip anywhere.
MAX_NOTCH_REL_STD = 0.3
#: A notch whose uncertainty exceeds this share of its frequency is not resolved.
MAX_NOTCH_REL_UNCERTAINTY = 0.1


@dataclass(frozen=True)
class Antiresonance:
    """omega_a of a measured speed loop, rad/s, with its uncertainty.

    estimate_rad_s: the estimate -- the two-mass fit of the motor admittance where the torque
    was measured (``fit``, :mod:`regulator.admittance_fit`), else the notch of the loop;
    loop_notch_rad_s: the notch of omega_m / omega_r; admittance_notch_rad_s: that of the
    motor admittance (nan without torque); uncertainty_rad_s: half-width of the estimate's
    interval (about 95 %); depth_db: how far the notch lies below its neighbourhood (the
    fit's: below the rigid body's level); resolved and, where not, ``reason``.
    """

    estimate_rad_s: float
    loop_notch_rad_s: float
    admittance_notch_rad_s: float
    uncertainty_rad_s: float
    jackknife_std_rad_s: float
    depth_db: float
    resolved: bool
    reason: str = ""
    fit: TwoMassFit | None = None

    @property
    def rad_s(self) -> float:
        return self.estimate_rad_s

    @property
    def hz(self) -> float:
        return self.estimate_rad_s / (2.0 * math.pi)

    @property
    def method(self) -> str:
        return "two-mass fit of the motor admittance" if self.fit is not None else "loop notch"

    def contains(self, truth_rad_s: float) -> bool:
        return abs(truth_rad_s - self.estimate_rad_s) <= self.uncertainty_rad_s


def _notch(
    f: np.ndarray, response: np.ndarray, std: np.ndarray | None = None, window: float = 1.25
) -> tuple[float, float, bool]:
    """(frequency Hz, depth dB, inside) of the deepest notch of |response| relative to the
    median log-magnitude within a factor ``window`` of each line, among the lines whose
    relative deviation is at most MAX_NOTCH_REL_STD (all lines without ``std``)."""
    log_mag = np.log(np.abs(response))
    trend = np.array([np.median(log_mag[(f > x / window) & (f < x * window)]) for x in f])
    depth = log_mag - trend
    if std is not None:
        depth = np.where(std <= MAX_NOTCH_REL_STD * np.abs(response), depth, np.inf)
        if not np.any(np.isfinite(depth)):
            return float(f[0]), 0.0, False
    i = int(np.argmin(depth))
    inside = 0 < i < f.size - 1
    if not inside:
        return float(f[i]), float(depth[i] * 20.0 / math.log(10.0)), False
    y0, y1, y2 = log_mag[i - 1], log_mag[i], log_mag[i + 1]
    curvature = y0 - 2.0 * y1 + y2
    shift = 0.5 * (y0 - y2) / curvature if curvature > 0.0 else 0.0
    return (
        float(f[i] + shift * (f[i + 1] - f[i])),
        float(depth[i] * 20.0 / math.log(10.0)),
        True,
    )


def antiresonance(
    loop: Frf,
    low_hz: float,
    high_hz: float,
    admittance: Frf | None = None,
    sheet_damping: float | None = None,
) -> Antiresonance:
    """omega_a in [low_hz, high_hz]: the two-mass fit of ``admittance`` (omega_m / tau_m)
    where given (``sheet_damping``: the axis file's damping ratio, which bounds the fit's,
    :func:`regulator.admittance_fit.fit_two_mass`), else the notch of ``loop``
    (omega_m / omega_r)."""
    band = loop.band(low_hz, high_hz)
    if band.frequency_hz.size < 8:
        raise AnalysisError(
            f"band {low_hz:g}..{high_hz:g} Hz holds {band.frequency_hz.size} lines; need 8"
        )
    f = band.frequency_hz
    notch_hz, depth_db, inside = _notch(f, band.response, band.std)
    two_pi = 2.0 * math.pi
    adm_hz = math.nan
    if admittance is not None:
        ab = admittance.band(low_hz, high_hz)
        scale = 2j * np.pi * ab.frequency_hz
        adm_hz = _notch(ab.frequency_hz, ab.response * scale, ab.std * np.abs(scale))[0]
        fit = fit_two_mass(
            ab.frequency_hz,
            ab.response,
            ab.std,
            ab.leave_one_out,
            MAX_NOTCH_REL_STD,
            MAX_NOTCH_REL_UNCERTAINTY,
            sheet_damping,
        )
        if fit is not None:
            return Antiresonance(
                estimate_rad_s=fit.antiresonance_rad_s,
                loop_notch_rad_s=two_pi * notch_hz,
                admittance_notch_rad_s=two_pi * adm_hz,
                uncertainty_rad_s=fit.uncertainty_rad_s,
                jackknife_std_rad_s=fit.jackknife_std_rad_s,
                depth_db=fit.depth_db,
                resolved=fit.resolved,
                reason=fit.reason,
                fit=fit,
            )
    # the loop's notch is the estimate: its jackknife over the realizations
    keep = (loop.frequency_hz >= low_hz) & (loop.frequency_hz <= high_hz)
    others = [_notch(f, row[keep], band.std)[0] for row in loop.leave_one_out]
    n = len(others)
    jack = math.sqrt((n - 1) / n * float(np.sum((np.array(others) - np.mean(others)) ** 2)))
    resolution_hz = float(f[1] - f[0])
    systematic_hz = 0.0 if math.isnan(adm_hz) else 0.5 * abs(adm_hz - notch_hz)
    coverage = float(student_t.ppf(0.975, n - 1))  # about 95 % for n - 1 degrees of freedom
    half_width_hz = math.hypot(coverage * jack, 0.5 * resolution_hz) + systematic_hz
    resolved = bool(
        inside and depth_db < -MIN_NOTCH_DB and half_width_hz < MAX_NOTCH_REL_UNCERTAINTY * notch_hz
    )
    return Antiresonance(
        estimate_rad_s=two_pi * notch_hz,
        loop_notch_rad_s=two_pi * notch_hz,
        admittance_notch_rad_s=two_pi * adm_hz,
        uncertainty_rad_s=two_pi * half_width_hz,
        jackknife_std_rad_s=two_pi * jack,
        depth_db=depth_db,
        resolved=resolved,
        reason=""
        if resolved
        else f"the deepest notch of the loop, {depth_db:.1f} dB at {two_pi * notch_hz:.1f} "
        "rad/s, is too shallow or uncertain ("
        + (
            "no torque measured for the admittance's fit)"
            if admittance is None
            else "the admittance's lines are in the noise: no two-mass fit)"
        ),
    )


@dataclass(frozen=True)
class Bandwidth:
    """-3 dB frequency of a speed loop and the range where estimate +- std crosses it (Hz);
    nan when the magnitude never falls below -3 dB in the measured band."""

    frequency_hz: float
    low_hz: float
    high_hz: float


def _crossing(f: np.ndarray, mag: np.ndarray, level: float) -> float:
    below = np.nonzero(mag < level)[0]
    if below.size == 0:
        return math.nan
    i = int(below[0])
    if i == 0:
        return float(f[0])
    # interpolate on log frequency between the last line above and the first below
    x0, x1 = math.log(f[i - 1]), math.log(f[i])
    y0, y1 = mag[i - 1], mag[i]
    t = (y0 - level) / (y0 - y1) if y0 != y1 else 0.0
    return math.exp(x0 + t * (x1 - x0))


def bandwidth(loop: Frf) -> Bandwidth:
    """The first frequency where |omega_m / omega_r| falls below 1/sqrt(2)."""
    level = 1.0 / math.sqrt(2.0)
    mag = np.abs(loop.response)
    f = loop.frequency_hz
    return Bandwidth(
        _crossing(f, mag, level),
        _crossing(f, mag - loop.std, level),
        _crossing(f, mag + loop.std, level),
    )

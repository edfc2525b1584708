"""Where and when a simulation departs from a recording, and what the residual correlates with.

Operating conditions are classified per recording sample from the *reference* (what the
machine was asked to do, independent of any model): ``reversal`` (from the end of a motion,
dwell included, until the next motion in the opposite direction ends its acceleration — at
most 0.5 s, at least 2/k_v, in which the position loop settles), ``standstill``,
``acceleration`` and ``deceleration`` (|a| above 5 % of the peak), ``constant speed``.

Mismatch windows: per signal the residual r (recorded − simulated, in the signal's unit;
following error for positions) is averaged over a sliding window of w samples (50 ms). White
measurement noise of std σ (estimated from first differences of r, which remove anything slow)
leaves that average within ±σ/√w. A stretch is flagged where the average leaves ±4σ/√w and
either is an outlier of the average's own robust spread s (beyond ±3·s around zero, s = MAD
around the median — so a slowly wandering residual, an unrecorded disturbance, is not flagged
everywhere) or the model with the named effects removes more than 4σ/√w of it there
(``explained``). Flags closer than a window merge, a merged run is split where the operating
condition changes (one condition per window), runs shorter than a window are dropped, and the
strongest windows (peak over threshold times duration) are kept.

Tests on the residual: Ljung-Box whiteness; cross-correlation (lags ±0.2 s) with the set point,
its speed, speed sign and acceleration, and the measured position, judged against the bound
3/√n_eff with Bartlett's n_eff for two autocorrelated series.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from itertools import pairwise

import numpy as np

from .metrics import autocorrelation, autocorrelation_time, effective_samples, ljung_box

WINDOW_S = 0.05
NOISE_SIGMAS = 4.0
SPREAD_SIGMAS = 3.0
MAX_WINDOWS = 30
CCF_LAG_S = 0.2
CCF_BOUND = 3.0


class Condition(Enum):
    REVERSAL = "reversal"
    STANDSTILL = "standstill"
    ACCELERATION = "acceleration"
    DECELERATION = "deceleration"
    CONSTANT_SPEED = "constant speed"


@dataclass(frozen=True)
class Kinematics:
    """Reference speed/acceleration and measured position at the recording samples."""

    time_s: np.ndarray
    speed: np.ndarray  # load units/s
    accel: np.ndarray  # load units/s^2
    position: np.ndarray  # load units (feedback)
    set_point: np.ndarray  # position_reference


def reference_kinematics(
    time_s: np.ndarray, reference: np.ndarray, position: np.ndarray
) -> Kinematics:
    v = np.gradient(reference, time_s)
    a = np.gradient(v, time_s)
    return Kinematics(time_s, v, a, position, reference)


def classify(kin: Kinematics, kv: float) -> np.ndarray:
    """Condition per sample (array of :class:`Condition`)."""
    v, a, t = kin.speed, kin.accel, kin.time_s
    vmax = max(float(np.max(np.abs(v))), 1e-300)
    amax = max(float(np.max(np.abs(a))), 1e-300)
    moving = np.abs(v) > 0.01 * vmax
    labels = np.full(len(v), Condition.CONSTANT_SPEED, dtype=object)
    labels[~moving] = Condition.STANDSTILL
    acc = moving & (np.abs(a) > 0.05 * amax)
    labels[acc & (v * a > 0)] = Condition.ACCELERATION
    labels[acc & (v * a < 0)] = Condition.DECELERATION
    sign = np.sign(v) * moving
    idx = np.nonzero(sign)[0]
    if len(idx) > 1:
        changes = idx[1:][sign[idx[1:]] != sign[idx[:-1]]]
        settle = 2.0 / kv
        accelerating = np.abs(a) > 0.05 * amax
        for i in changes:
            t0 = t[i]
            # from the end of the previous motion (dwell included) to the end of the new
            # motion's acceleration, at least 2/kv after it starts (the loop settles)
            prev = idx[idx < i]
            start = t[prev[-1]] if len(prev) else t0
            after = np.nonzero(~accelerating[i:])[0]
            end_acc = t[i + int(after[0])] if len(after) else t[-1]
            end = max(t0 + settle, min(end_acc, t0 + 0.5))
            in_window = (t >= min(start, t0 - 0.05)) & (t <= end)
            labels[in_window] = Condition.REVERSAL
    return labels


@dataclass(frozen=True)
class MismatchWindow:
    """A stretch where the simulation departs from the recording beyond noise."""

    t_start: float
    t_end: float
    signal: str
    condition: str  # dominant operating condition
    conditions: dict[str, float]  # share of each condition in the window
    position_min: float
    position_max: float
    speed_sign: int  # +1, -1, 0 (mixed or standstill)
    peak_residual: float  # signal units (following error for positions)
    peak_over_threshold: float  # peak of the averaged residual / noise threshold 4σ/√w
    explained: bool  # the model with the named effects removes this departure


def _moving_average(x: np.ndarray, w: int) -> np.ndarray:
    if w <= 1:
        return x.copy()
    kernel = np.ones(w) / w
    return np.convolve(x, kernel, mode="same")


def white_noise_sigma(r: np.ndarray) -> float:
    """σ of the white part of r: 1.4826·MAD(Δr)/√2."""
    d = np.diff(r)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def find_windows(
    residuals: Mapping[str, np.ndarray],
    kin: Kinematics,
    labels: np.ndarray,
    final: Mapping[str, np.ndarray] | None = None,
) -> list[MismatchWindow]:
    """Mismatch windows of ``residuals`` (the re-fitted nominal model's, per signal).

    With ``final`` (the residuals of the model with the named effects) a stretch is also
    flagged where the final model removes more than the noise threshold of the departure,
    even if the departure is not an outlier of the residual's own spread: that locates
    a pervasive effect (a load torque acting whenever the axis moves)."""
    t = kin.time_s
    dt = float(np.median(np.diff(t)))
    w = max(3, round(WINDOW_S / dt))
    out: list[MismatchWindow] = []
    for signal, r in residuals.items():
        r = np.where(np.isfinite(r), r, 0.0)
        sigma = white_noise_sigma(r)
        avg = _moving_average(r, w)
        spread = 1.4826 * float(np.median(np.abs(avg - np.median(avg))))
        thr_noise = max(NOISE_SIGMAS * sigma / np.sqrt(w), 1e-300)
        thr = max(thr_noise, SPREAD_SIGMAS * spread)
        flag = np.abs(avg) > thr
        explained = np.zeros(len(r), dtype=bool)
        if final is not None and signal in final:
            avg1 = _moving_average(np.where(np.isfinite(final[signal]), final[signal], 0.0), w)
            explained = (np.abs(avg) > thr_noise) & (np.abs(avg) - np.abs(avg1) > thr_noise)
            flag |= explained
        if not flag.any():
            continue
        # merge flags closer than one window; drop runs shorter than one window
        edges = np.diff(np.concatenate([[0], flag.astype(int), [0]]))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        runs: list[list[int]] = []
        for s, e in zip(starts, ends, strict=True):
            if runs and s - runs[-1][1] <= w:
                runs[-1][1] = e
            else:
                runs.append([s, e])
        pieces: list[tuple[int, int]] = []
        for s, e in runs:
            # one window per operating condition: split a run where the condition changes
            cuts = [s, *(s + 1 + np.nonzero(labels[s + 1 : e] != labels[s : e - 1])[0]), e]
            pieces += [(a, b) for a, b in pairwise(cuts) if b - a >= w]
        for s, e in pieces:
            seg = slice(s, e)
            lab = labels[seg]
            shares = {c.value: float(np.mean(lab == c)) for c in Condition}
            shares = {k: round(v, 3) for k, v in shares.items() if v > 0}
            dominant = max(shares, key=lambda k: shares[k])
            vs = np.sign(kin.speed[seg])
            sign = int(vs[0]) if np.all(vs == vs[0]) else 0
            k = s + int(np.argmax(np.abs(avg[seg])))
            out.append(
                MismatchWindow(
                    t_start=float(t[s]),
                    t_end=float(t[e - 1]),
                    signal=signal,
                    condition=dominant,
                    conditions=shares,
                    position_min=float(np.min(kin.position[seg])),
                    position_max=float(np.max(kin.position[seg])),
                    speed_sign=sign,
                    peak_residual=float(avg[k]),
                    peak_over_threshold=float(abs(avg[k]) / thr_noise),
                    explained=bool(np.mean(explained[seg]) > 0.5),
                )
            )
    out.sort(key=lambda m: -m.peak_over_threshold * (m.t_end - m.t_start + dt))
    kept = out[:MAX_WINDOWS]
    kept.sort(key=lambda m: (m.t_start, m.signal))
    return kept


def condition_summary(windows: list[MismatchWindow]) -> dict[str, float]:
    """Seconds of mismatch per condition (all signals), largest first."""
    acc: dict[str, float] = {}
    for m in windows:
        span = m.t_end - m.t_start
        for cond, share in m.conditions.items():
            acc[cond] = acc.get(cond, 0.0) + share * span
    return dict(sorted(acc.items(), key=lambda kv: -kv[1]))


# ----------------------------------------------------------------------------------------
# tests
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CrossCorrelation:
    r: float  # largest |normalised cross-correlation| over the lags (signed)
    lag_s: float  # lag of that peak (residual lags the regressor when > 0)
    bound: float  # significance bound 3/sqrt(n_eff)
    significant: bool


@dataclass(frozen=True)
class ResidualTests:
    signal: str
    ljung_box_p: float
    white: bool
    autocorrelation_time: float
    rms: float
    mean: float
    cross_correlation: dict[str, CrossCorrelation]


def _bartlett_neff(r: np.ndarray, z: np.ndarray, max_lag: int) -> float:
    """n_eff of a cross-correlation of r and z (Bartlett: n / Σ_k ρ_r(k)·ρ_z(k)), with ρ_r
    of r after removing its part proportional to z (under the null r does not contain z)."""
    r = r - r.mean()
    zc = z - z.mean()
    denom = float(zc @ zc)
    if denom > 0.0:
        r = r - float(r @ zc) / denom * zc
    rr = autocorrelation(r, max_lag)
    rz = autocorrelation(z, max_lag)
    s = 1.0 + 2.0 * float(np.sum(rr[1:] * rz[1:]))
    return effective_samples(len(r), max(s, 1.0))


def _ccf(r: np.ndarray, z: np.ndarray, max_lag: int) -> tuple[float, int]:
    r = r - r.mean()
    z = z - z.mean()
    denom = float(np.sqrt((r @ r) * (z @ z)))
    if denom <= 0.0:
        return 0.0, 0
    n = len(r)
    size = 1 << (2 * n - 1).bit_length()
    c = np.fft.irfft(np.fft.rfft(r, size) * np.conj(np.fft.rfft(z, size)), size)
    lags = np.concatenate([np.arange(0, max_lag + 1), np.arange(-max_lag, 0)])
    vals = np.concatenate([c[: max_lag + 1], c[size - max_lag :]]) / denom
    k = int(np.argmax(np.abs(vals)))
    return float(vals[k]), int(lags[k])


def residual_tests(
    residuals: Mapping[str, np.ndarray], kin: Kinematics, alpha: float = 0.01
) -> list[ResidualTests]:
    dt = float(np.median(np.diff(kin.time_s)))
    max_lag = max(1, round(CCF_LAG_S / dt))
    regressors = {
        "set_point": kin.set_point,
        "speed": kin.speed,
        "speed_sign": np.sign(kin.speed) * (np.abs(kin.speed) > 0.01 * np.max(np.abs(kin.speed))),
        "acceleration": kin.accel,
        "position": kin.position,
    }
    out = []
    for signal, r in residuals.items():
        r = np.where(np.isfinite(r), r, 0.0)
        _, p = ljung_box(r, 20)
        cc: dict[str, CrossCorrelation] = {}
        for name, z in regressors.items():
            if np.ptp(z) <= 0.0:
                continue
            value, lag = _ccf(r, z, max_lag)
            n_eff = _bartlett_neff(r, z, 4 * max_lag)
            bound = CCF_BOUND / np.sqrt(n_eff)
            cc[name] = CrossCorrelation(value, lag * dt, float(bound), abs(value) > bound)
        out.append(
            ResidualTests(
                signal=signal,
                ljung_box_p=p,
                white=p >= alpha,
                autocorrelation_time=autocorrelation_time(r),
                rms=float(np.sqrt(np.mean(r**2))),
                mean=float(np.mean(r)),
                cross_correlation=cc,
            )
        )
    return out

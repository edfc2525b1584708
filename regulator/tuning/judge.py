"""What a trial of the beta_T procedure measured and its verdict, from what the bridge itself
measures (reference and load position, the detector's beta and lambda, the torque): judged by
what the axis does -- no vibration in eq. 13's band, the standstill accuracy reached by the end
of the dwell -- never by an internal state (lambda's recovery is reported, not judged)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from scipy.signal import butter, sosfiltfilt

from ..errors import TuningError, require_positive
from ..units import length
from .motion import STANDSTILL_AVERAGE_S, MotionProfile


class Verdict(Enum):
    STABLE = "stable"
    INEXACT = "inexact"
    VIBRATING = "vibrating"
    STOPPED = "stopped"


@dataclass(frozen=True)
class Record:
    """What a runner recorded of one trial, one value per cycle: reference and load position
    (load units), the detector's beta (rad/s) and lambda; ``stopped``: the stop reason's
    message if the axis stopped (the arrays then end there); the motor torque where measured."""

    position_reference: np.ndarray
    load_position: np.ndarray
    beta: np.ndarray
    switching_factor: np.ndarray
    stopped: str | None = None
    torque: np.ndarray | None = None


@dataclass(frozen=True)
class SafetyLimits:
    """The limits every runner applies (the bridge's 2008h, 2014h, and a torque limit)."""

    following_error: float
    position_min: float
    position_max: float
    torque_nm: float = math.inf


def safety_stop(record: Record, limits: SafetyLimits) -> str | None:
    """The first limit ``record`` breaks (the message the bridge would stop with), or None.
    For runners without a supervisor of their own (the offline simulation)."""
    e = record.position_reference - record.load_position
    checks = [
        (np.abs(e) > limits.following_error, "following error", e, limits.following_error),
        (
            (record.load_position < limits.position_min)
            | (record.load_position > limits.position_max),
            "load position outside 2014h",
            record.load_position,
            (limits.position_min, limits.position_max),
        ),
    ]
    if record.torque is not None:
        checks.append(
            (np.abs(record.torque) > limits.torque_nm, "torque", record.torque, limits.torque_nm)
        )
    first: tuple[int, str] | None = None
    for broken, what, values, limit in checks:
        idx = np.nonzero(broken)[0]
        if idx.size and (first is None or idx[0] < first[0]):
            first = (int(idx[0]), f"{what} {values[idx[0]]:.6g} beyond the limit {limit}")
    return None if first is None else f"cycle {first[0]}: {first[1]}"


def band_amplitude(signal: np.ndarray, cycle_s: float, kv: float) -> float:
    """The oscillation of ``signal`` in eq. 13's band k_v/4..k_v Hz widened by half an
    octave each side: the median height of its half-waves (between zero crossings of the
    band-passed signal, 8th-order Butterworth, zero phase, after a cubic trend is removed), the
    window's first and last tenth left out (the filter's edges).

    The median of half-waves, like the paper's detector taking the smaller of two half-waves
    (Fig. 5, docs/regulator.md D5), counts what alternates for most of the window: a limit
    cycle, not the one or two half-waves a monotone transient (a faded-out load scale coming
    back) leaves in the band."""
    nyquist = 0.5 / cycle_s
    widen = math.sqrt(2.0)
    high = min(kv * widen, 0.9 * nyquist)
    sos = butter(4, [kv / 4.0 / widen, high], btype="band", fs=1.0 / cycle_s, output="sos")
    if signal.size < 60:
        raise TuningError(f"watch window of {signal.size} cycles is too short to judge")
    t = np.linspace(-1.0, 1.0, signal.size)
    x = signal - np.polyval(np.polyfit(t, signal, 3), t)
    edge = x.size // 10
    y = sosfiltfilt(sos, x, padlen=x.size - 1)[edge : x.size - edge]
    crossings = np.nonzero(np.signbit(y[1:]) != np.signbit(y[:-1]))[0] + 1
    if crossings.size < 2:
        return 0.0
    peaks = [float(np.max(np.abs(seg))) for seg in np.split(y, crossings)[1:-1]]
    return float(np.median(peaks)) if peaks else 0.0


@dataclass(frozen=True)
class Metrics:
    """What :func:`measure` found in one trial (load units, s, rad/s, 1)."""

    vibration: float  # worst band amplitude of the following error in a watch or rest window
    following_deviation: float  # worst |mean following error - eq. 1| in a watch window
    standstill_error: float  # worst |mean following error| at the end of a dwell
    settle_s: float  # longest wait in a dwell for the standstill accuracy (nan: not reached)
    lambda_at_rest: float  # smallest lambda at the end of a dwell (reported, not judged)
    beta_max: float  # largest beta of the trial (detector)


@dataclass(frozen=True)
class Limits:
    """Verdict limits, load units. vibration: the band amplitude that counts as vibration."""

    vibration: float
    standstill_error: float

    def __post_init__(self) -> None:
        for name in ("vibration", "standstill_error"):
            require_positive(name, getattr(self, name), "load units")


@dataclass(frozen=True)
class TrialResult:
    beta_t_rad_s: float | None  # None: a reference trial (regulator off)
    verdict: Verdict
    metrics: Metrics | None
    reason: str
    record: Record = field(repr=False)
    motion: str = ""  # the name of the motion played


def _settle_s(e: np.ndarray, a: int, b: int, cycle_s: float, limit: float) -> float:
    """Seconds from a dwell's start ``a`` until the mean |e| over 0.1 s stays within
    ``limit`` to the dwell's end ``b`` (nan: not within the dwell)."""
    w = max(1, round(STANDSTILL_AVERAGE_S / cycle_s))
    seg = np.abs(e[a:b])
    if seg.size < w:
        return math.nan
    mean = np.convolve(seg, np.ones(w) / w, mode="valid")  # mean[i] over seg[i : i + w]
    bad = np.nonzero(mean > limit)[0]
    if bad.size == 0:
        return w * cycle_s
    if bad[-1] == mean.size - 1:
        return math.nan
    return (int(bad[-1]) + 1 + w) * cycle_s


def dwell_ranges(profile: MotionProfile) -> list[tuple[int, int]]:
    """Each dwell (from the end of its ramp to standstill) as (start, end) cycle indices."""
    out = []
    for _, b in profile.standstill:
        a = b - 1
        while (
            a > 0
            and profile.speed[a - 1] == 0.0
            and profile.position[a - 1] == profile.position[b - 1]
        ):
            a -= 1
        out.append((a, b))
    return out


def measure(
    record: Record,
    profile: MotionProfile,
    cycle_s: float,
    kv: float,
    velocity_feedforward: float,
    standstill_limit: float | None = None,
) -> Metrics:
    """The metrics of a complete record of ``profile`` (module docstring); ``settle_s``
    needs ``standstill_limit``."""
    e = record.position_reference - record.load_position
    vibration = deviation = 0.0
    for a, b in profile.rest:
        vibration = max(vibration, band_amplitude(e[a:b], cycle_s, kv))
    for a, b in profile.watch:
        vibration = max(vibration, band_amplitude(e[a:b], cycle_s, kv))
        v = float(np.mean(profile.speed[a:b]))
        expected = (1.0 - velocity_feedforward) * v / kv  # eq. 1
        deviation = max(deviation, abs(float(np.mean(e[a:b])) - expected))
    standstill = max(abs(float(np.mean(e[a:b]))) for a, b in profile.standstill)
    settle = math.nan
    if standstill_limit is not None:
        waits = [_settle_s(e, a, b, cycle_s, standstill_limit) for a, b in dwell_ranges(profile)]
        settle = math.nan if any(math.isnan(w) for w in waits) else max(waits)
    lam = min(float(record.switching_factor[b - 1]) for _, b in profile.standstill)
    return Metrics(vibration, deviation, standstill, settle, lam, float(np.max(record.beta)))


def judge(
    record: Record,
    profile: MotionProfile,
    limits: Limits,
    cycle_s: float,
    kv: float,
    beta_t_rad_s: float | None,
    velocity_feedforward: float = 0.0,
    unit: str = "m",
) -> TrialResult:
    """The verdict of one trial: STOPPED (the axis stopped), VIBRATING (the following error
    oscillates in eq. 13's band above ``limits.vibration``), INEXACT (quiet, but the
    standstill error is above ``limits.standstill_error`` at the end of a dwell: the
    standstill accuracy was not reached within the wait) or STABLE."""
    if record.stopped is not None:
        return TrialResult(
            beta_t_rad_s, Verdict.STOPPED, None, record.stopped, record, profile.name
        )
    if record.load_position.size < profile.position.size:
        raise TuningError(
            f"record of {record.load_position.size} cycles for a motion of "
            f"{profile.position.size}: incomplete without a stop reason"
        )
    m = measure(record, profile, cycle_s, kv, velocity_feedforward, limits.standstill_error)
    if m.vibration > limits.vibration:
        verdict, reason = (
            Verdict.VIBRATING,
            f"the following error oscillates by {length(m.vibration, unit)} in eq. 13's band, "
            f"above {length(limits.vibration, unit)}",
        )
    elif m.standstill_error > limits.standstill_error:
        verdict, reason = (
            Verdict.INEXACT,
            f"standstill error {length(m.standstill_error, unit)} at the end of the dwell, above "
            f"{length(limits.standstill_error, unit)} (lambda {m.lambda_at_rest:.2f})",
        )
    else:
        verdict, reason = Verdict.STABLE, "quiet and exact at rest"
    return TrialResult(beta_t_rad_s, verdict, m, reason, record, profile.name)

"""Where the best model still misses: "unexplained, here" as a verdict (docs/diagnosis.md).

When the residual of the fitted model stays far above the noise (:mod:`.adequacy`), the
report says where it is, in terms an engineer can act on:

* **time windows** — the mismatch windows of the final residual (:mod:`.mismatch`);
* **speed ranges and position ranges** — the residual's RMS per bin of the load's speed
  (signed: the direction matters) and of its position, over the white noise: bins above
  :data:`RANGE_RATIO` times the noise are listed;
* **a frequency band** — the band where the residual's spectrum (Welch) lies above
  :data:`BAND_RATIO` times the white-noise floor (σ² of the residual's white part, spread over
  the band up to the Nyquist frequency).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

from .mismatch import MismatchWindow, white_noise_sigma

#: Speed and position bins.
BINS = 12
#: A bin is listed when its RMS residual exceeds this many white-noise σ.
RANGE_RATIO = 3.0
#: "Far above the noise" in part of the recording: a speed or position range holding at least
#: LOCAL_SHARE of the samples whose RMS residual exceeds LOCAL_RATIO times the white noise and
#: stands out from
#: the model's own residual elsewhere: at least LOCAL_CONTRAST times the RMS of the residual
#: outside the range (so that an effect spread over two or three bins still stands out).
#: Measured on clean axes of the FMU family (development seeds 0-44, 10 s and 25 s): the
#: first-difference noise misses the slow part of any model's residual; their worst bins were
#: 6-12.4 x the noise (near standstill: every model's friction law differs there; at 5 x the
#: noise alone, 2 of 4 clean recordings were "unexplained").
LOCAL_RATIO = 15.0
LOCAL_SHARE = 0.05
LOCAL_CONTRAST = 3.0
#: Signals judged that way (a following error integrates every slow disturbance).
LOCAL_SIGNALS = ("motor_speed", "motor_torque")
#: A frequency is in the band when the residual's spectral density exceeds this many times
#: the white-noise floor.
BAND_RATIO = 10.0


@dataclass(frozen=True)
class Range:
    low: float
    high: float
    rms_over_noise: float
    share: float  # of the residual's mean square
    samples: float  # share of the samples in the range


@dataclass(frozen=True)
class Where:
    """Where one signal's residual stays above the noise."""

    signal: str
    noise_ratio: float
    windows: list[tuple[float, float]]
    speed_ranges: list[Range]
    position_ranges: list[Range]
    band_hz: tuple[float, float] | None


def _ranges(x: np.ndarray, r: np.ndarray, sigma: float) -> list[Range]:
    ok = np.isfinite(x) & np.isfinite(r)
    x, r = x[ok], r[ok]
    if len(x) < 4 * BINS or np.ptp(x) <= 0.0 or sigma <= 0.0:
        return []
    edges = np.quantile(x, np.linspace(0.0, 1.0, BINS + 1))
    edges = np.unique(edges)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    total = float(np.sum(r**2)) or 1.0
    out = []
    for b in range(len(edges) - 1):
        m = idx == b
        if m.sum() < 4:
            continue
        rms = float(np.sqrt(np.mean(r[m] ** 2)))
        if rms > RANGE_RATIO * sigma:
            out.append(
                Range(
                    float(edges[b]),
                    float(edges[b + 1]),
                    rms / sigma,
                    float(np.sum(r[m] ** 2)) / total,
                    float(m.mean()),
                )
            )
    return out


def _band(r: np.ndarray, dt: float, sigma: float) -> tuple[float, float] | None:
    r = np.where(np.isfinite(r), r, 0.0)
    if len(r) < 64 or sigma <= 0.0:
        return None
    f, p = sps.welch(r - r.mean(), fs=1.0 / dt, nperseg=min(len(r), 1024))
    floor = 2.0 * sigma**2 * dt  # one-sided density of white noise of σ
    above = np.nonzero(p[1:] > BAND_RATIO * floor)[0] + 1
    if not len(above):
        return None
    return float(f[above[0]]), float(f[above[-1]])


def where(
    residuals: Mapping[str, np.ndarray],
    time_s: np.ndarray,
    speed: np.ndarray,
    position: np.ndarray,
    windows: list[MismatchWindow],
    signals: tuple[str, ...],
) -> list[Where]:
    """:class:`Where` for each of ``signals`` whose residual is above the noise."""
    dt = float(np.median(np.diff(time_s)))
    out = []
    for s in signals:
        if s not in residuals:
            continue
        r = np.where(np.isfinite(residuals[s]), residuals[s], 0.0)
        sigma = white_noise_sigma(r)
        rms = float(np.sqrt(np.mean(r**2)))
        ratio = rms / sigma if sigma > 0.0 else (np.inf if rms > 0.0 else 1.0)
        out.append(
            Where(
                signal=s,
                noise_ratio=float(ratio),
                windows=[(w.t_start, w.t_end) for w in windows if w.signal == s][:8],
                speed_ranges=_ranges(speed, r, sigma),
                position_ranges=_ranges(position, r, sigma),
                band_hz=_band(r, dt, sigma),
            )
        )
    return out


def _rest(overall: float, r: Range) -> float:
    """RMS (in noise σ) of the residual outside range ``r``, from the whole one's."""
    if r.samples >= 1.0:
        return 0.0
    rest = (overall**2 - r.rms_over_noise**2 * r.samples) / (1.0 - r.samples)
    return float(np.sqrt(max(rest, 0.0)))


def local_misfit(items: list[Where]) -> list[str]:
    """Hints for each speed or torque residual that is far above the noise in part of the
    recording (LOCAL_RATIO in a range of at least LOCAL_SHARE of the samples) and there far
    above its own level elsewhere (LOCAL_CONTRAST)."""
    out = []
    for w in items:
        if w.signal not in LOCAL_SIGNALS:
            continue
        for kind, ranges in (("speed", w.speed_ranges), ("position", w.position_ranges)):
            bad = [
                r
                for r in ranges
                if r.rms_over_noise >= LOCAL_RATIO
                and r.samples >= LOCAL_SHARE
                and r.rms_over_noise >= LOCAL_CONTRAST * _rest(w.noise_ratio, r)
            ]
            if bad:
                worst = max(bad, key=lambda r: r.rms_over_noise)
                out.append(
                    f"{w.signal} residual {worst.rms_over_noise:.3g} x the noise at {kind} "
                    f"{worst.low:.4g}..{worst.high:.4g}: a {kind}-dependent effect the table "
                    "lacks there"
                )
    return out

"""Torque clipping found in the recorded torque itself (issue 30, item 2): a drive whose torque
limit is lower than its data sheet states clips the torque at that limit on both signs, so
the recorded torque sits **on a plateau at one level, +L and −L**, for tens of milliseconds at
every fast acceleration, while an axis that is not limited reaches its largest torque at the
top of a peak and leaves it again (a few samples within the noise of its extreme).

The test (:func:`clipping_test`) counts, on each sign, the samples within :data:`BAND_SIGMAS`
noise σ of the recorded extreme and the longest run of consecutive ones. Clipping: on both
signs at least :data:`MIN_SHARE` of the samples and a run of :data:`MIN_RUN_S`, at levels that
agree within :data:`LEVEL_TOLERANCE` (a drive's limit is symmetric). The limit it estimates is
the median of the plateau samples (the extreme itself is the noise's maximum above it).

Its false-alarm rate is measured, not derived: on the clean axes of the FMU family's
development seeds (0–44, every family but the clipped one, 33 recordings of 25 s) the largest
share of samples within 4 σ of an extreme was 0.11 % (the longest run 11 ms), against 0.56–12 %
(runs of 10 ms to 1.1 s) on the 45 axes 0–44 with family 10's lower limit (docs/diagnosis.md,
"Clipping"). It is a threshold test, not a bootstrap: its p is reported as 0 or 1. The torque
balance is not used: the recorded torque is the one that acted, the balance holds with or
without a limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .effects import Effect
from .randomization import ScanResult
from .regression import EffectTest

#: Width of the band below each extreme, in the torque's noise σ (third differences).
BAND_SIGMAS = 4.0
#: Least share of the samples in each band.
MIN_SHARE = 0.003
#: Least duration of one run in each band (s).
MIN_RUN_S = 0.01
#: Largest relative difference of the two plateau levels.
LEVEL_TOLERANCE = 0.05


@dataclass(frozen=True)
class Clipping:
    """What :func:`clipping_test` found on each sign of the recorded torque."""

    clipped: bool
    level: float  # the limit estimate (median |τ| of both plateaus), N·m
    level_positive: float
    level_negative: float
    share_positive: float  # share of the samples in the band below +max
    share_negative: float
    run_positive_s: float  # longest run in the band
    run_negative_s: float
    noise: float  # σ of the torque's noise

    def describe(self) -> str:
        return (
            f"recorded torque on plateaus at +{self.level_positive:.4g} and "
            f"−{self.level_negative:.4g} N·m ({100 * self.share_positive:.2g} % and "
            f"{100 * self.share_negative:.2g} % of the samples within {BAND_SIGMAS:g} σ = "
            f"{BAND_SIGMAS * self.noise:.3g} N·m, longest runs {1e3 * self.run_positive_s:.0f} "
            f"and {1e3 * self.run_negative_s:.0f} ms)"
        )


def torque_noise(torque: np.ndarray) -> float:
    """σ of white noise on ``torque`` from its third differences (var = 20 σ²)."""
    d3 = np.diff(np.asarray(torque, dtype=float), 3)
    return float(np.std(d3) / math.sqrt(20.0)) if len(d3) > 1 else 0.0


def _longest_run(mask: np.ndarray) -> int:
    if not mask.any():
        return 0
    padded = np.concatenate([[0], mask.astype(np.int8), [0]])
    edges = np.flatnonzero(np.diff(padded))
    return int(np.max(edges[1::2] - edges[0::2]))


def clipping_test(torque: np.ndarray, sample_time_s: float) -> Clipping:
    """Plateaus of ``torque`` (recorded, one sample every ``sample_time_s``) at its extremes
    (module docstring)."""
    tau = np.asarray(torque, dtype=float)
    tau = tau[np.isfinite(tau)]
    noise = torque_noise(tau)
    if len(tau) < 10 or not noise > 0.0 or not sample_time_s > 0.0:
        return Clipping(False, math.nan, math.nan, math.nan, 0.0, 0.0, 0.0, 0.0, noise)
    band = BAND_SIGMAS * noise
    hi, lo = float(tau.max()), float(-tau.min())
    top, bottom = tau >= hi - band, -tau >= lo - band
    lp = float(np.median(tau[top])) if hi > band else math.nan
    ln = float(np.median(-tau[bottom])) if lo > band else math.nan
    sp, sn = float(top.mean()), float(bottom.mean())
    rp, rn = _longest_run(top) * sample_time_s, _longest_run(bottom) * sample_time_s
    level = float(np.median(np.abs(tau[top | bottom])))
    agree = (
        math.isfinite(lp) and math.isfinite(ln) and abs(lp - ln) <= LEVEL_TOLERANCE * max(lp, ln)
    )
    clipped = bool(
        agree and min(sp, sn) >= MIN_SHARE and min(rp, rn) >= MIN_RUN_S - 0.5 * sample_time_s
    )
    return Clipping(clipped, level, lp, ln, sp, sn, rp, rn, noise)


#: z reported for a plateau found (a threshold test: the ranking among significant effects).
CLIPPED_Z = 8.0


def effect_test(clip: Clipping, relation: str) -> EffectTest:
    """The evidence for ``torque_saturation`` from :func:`clipping_test`, in the form of the
    other tests (p 0 when the torque is clipped, else 1; the limit at the plateau level)."""
    p, z = (0.0, CLIPPED_Z) if clip.clipped else (1.0, 0.0)
    share = min(clip.share_positive, clip.share_negative)
    test = ScanResult(
        statistic=share / MIN_SHARE,
        best=0,
        p=p,
        p_bootstrap=p,
        p_tail=p,
        z=z,
        n_blocks=0,
        replicates=0,
        coefficients=np.array([1.0]),
        residual=np.zeros(0),
    )
    estimate = {"control.torque_limit": clip.level, "gain": 1.0}
    return EffectTest(Effect.TORQUE_SATURATION, relation, test, estimate, dict(estimate))

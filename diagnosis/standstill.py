"""The torque at standstill before the axis first moves: evidence that tells apart two effects
that are one torque law while the axis moves (issue 30; docs/diagnosis.md, "Standstill").

A constant load torque τ_L on Coulomb friction c and direction-dependent Coulomb friction
c + τ_L / c − τ_L give the same torque at every speed ≠ 0 (the torque balance cannot separate
them), and at a rest after a move too: the axis stops with what its friction held in the
direction it came from, τ_L ± c or ±(c ± τ_L) alike. They differ before the first move: a
load acts on an axis that has not moved yet and the position loop holds it (the torque at
rest is τ_L), friction does not act without motion (the torque at rest is 0). Each effect
says what it makes there (:meth:`.effects.EffectModel.at_rest`); the recording's mean torque
over the second half of its first rest (the loop has settled) decides when it matches one
prediction within the uncertainty and not the other, or, matching neither, lies on a non-zero
prediction's side (:func:`decide`).

The uncertainty of that mean is not the white noise's alone: a torque the model does not
explain and that wanders slowly (an unrecorded process load) moves a short mean as much. So
its scale is the standard deviation of the means of the torque balance's own residual (the
model with the effect, on the moving rows) over windows of the same number of samples.

Limits: a load smaller than the static friction on an axis whose friction sticks without
pre-sliding (set-valued Coulomb friction) is held by the friction at the start, at zero
torque; the evidence then takes it for friction. A ball screw's pre-sliding lets the loop
take the load over (the FMU family, the third plant's LuGre friction); the kernel's own
set-valued law does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

#: Least samples in the window (the second half of the first rest).
MIN_ROWS = 20
#: Least windows of the residual to take the spread of their means from.
MIN_WINDOWS = 8


@dataclass(frozen=True)
class RestTorque:
    """The recorded torque over the settled part of the first rest, and its uncertainty."""

    mean: float  # N·m
    scale: float  # spread of same-length means of the torque balance residual, N·m
    start_s: float
    end_s: float
    rows: int


def first_rest(reference: np.ndarray) -> slice | None:
    """The second half of the samples before the reference first moves (None: fewer than
    :data:`MIN_ROWS` there)."""
    ref = np.asarray(reference, dtype=float)
    moves = np.flatnonzero(np.diff(ref) != 0.0)
    n0 = int(moves[0]) + 1 if len(moves) else len(ref)
    start = n0 // 2
    return slice(start, n0) if n0 - start >= MIN_ROWS else None


def window_spread(residual: np.ndarray, rows: int) -> float:
    """Standard deviation of the means of consecutive windows of ``rows`` samples of
    ``residual`` (NaN with fewer than :data:`MIN_WINDOWS` windows). Not a robust spread: a
    load that steps and stays moves a few windows' means far, and must widen it (the third
    plant's clean recording of seed 12, ``tests/diagnosis/test_second_recording.py``)."""
    r = np.asarray(residual, dtype=float)
    r = r[np.isfinite(r)]
    k = len(r) // rows
    if k < MIN_WINDOWS:
        return math.nan
    means = r[: k * rows].reshape(k, rows).mean(axis=1)
    return float(np.std(means))


def rest_torque(
    time_s: np.ndarray, reference: np.ndarray, torque: np.ndarray, residual: np.ndarray
) -> RestTorque | None:
    """The recorded ``torque`` over :func:`first_rest`, its scale from ``residual`` (the
    torque balance's, moving rows in time order); None without a first rest or a scale."""
    rest = first_rest(reference)
    if rest is None:
        return None
    rows = rest.stop - rest.start
    scale = window_spread(residual, rows)
    if not math.isfinite(scale) or not scale > 0.0:
        return None
    mean = float(np.mean(np.asarray(torque, dtype=float)[rest]))
    return RestTorque(mean, scale, float(time_s[rest.start]), float(time_s[rest.stop - 1]), rows)


@dataclass(frozen=True)
class RestDecision:
    """Which of two predictions of the torque at rest the recording matches."""

    winner: int | None  # index into the predictions, None: undecided
    predictions: tuple[float, float]
    rest: RestTorque
    k: float  # the match's half-width in scales

    def describe(self, names: tuple[str, str]) -> str:
        r = self.rest
        said = ", ".join(f"{n} {p:.3g}" for n, p in zip(names, self.predictions, strict=True))
        if self.winner is None:
            verdict = "both or neither match it: undecided"
        elif abs(r.mean - self.predictions[self.winner]) <= self.k * r.scale:
            verdict = f"{names[self.winner]} matches it, the other does not"
        else:
            verdict = (
                f"{names[self.winner]}: a held torque of its sign, nearer its estimate; the "
                "other's is refuted"
            )
        return (
            f"torque at rest before the first move ({r.start_s:.2f}–{r.end_s:.2f} s): "
            f"{r.mean:.3g} ± {self.k:.2g} × {r.scale:.2g} N·m; predicted: {said}; {verdict}"
        )


def decide(predictions: tuple[float, float], rest: RestTorque, alpha: float) -> RestDecision:
    """The prediction the rest torque matches within k scales (k = Φ⁻¹(1 − α/2)) while the
    other lies beyond them. Where neither matches, a rest torque of a prediction's sign and
    nearer to it than to the other's decides for it when it is not zero: friction before the
    first move can take part of a load over (static friction), so a held torque may fall short
    of the load's estimate, but it never makes one; a prediction of zero must match. Otherwise
    undecided."""
    k = float(stats.norm.isf(0.5 * alpha))
    m = rest.mean
    match = [abs(m - p) <= k * rest.scale for p in predictions]
    winner = match.index(True) if sum(match) == 1 else None
    if not any(match):
        near = 0 if abs(m - predictions[0]) < abs(m - predictions[1]) else 1
        p = predictions[near]
        if p != 0.0 and math.copysign(1.0, p) == math.copysign(1.0, m):
            winner = near
    return RestDecision(winner, predictions, rest, k)

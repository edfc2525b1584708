"""Backlash compensation as a CNC does it: at each reversal of an axis's commanded direction
the set point gets an offset of the backlash, spread over a few cycles.

A CNC whose position loop closes on the motor encoder adds the backlash to the position set
point when the axis reverses (Sinumerik: MD32450 ``BACKLASH``), so the motor crosses the gap
and the load follows its command at once; a loop closed on the load scale (paper Fig. 1)
needs no position offset -- its feedback sees the load -- but the motor still has to cross the
gap before the load moves, which is the reversal spike of the circular test (docs/contour.md).
The offset is therefore given here as what the bridge actually sends, a speed set point:
``n`` cycles of ``sign · k_r · b / (n T)`` rad/s at the motor after the commanded direction
changes sign, whose integral is the gap ``b`` at the motor (``k_r b`` rad). Added to the
position loop's output, it is the set-point offset of a motor-encoder loop, differentiated --
and in the load-scale loop it is the feed-forward of the motor's travel through the gap (what
a CNC's quadrant-error compensation injects at the same moment). The backlash ``b`` is a
machine datum: the circular test's lost motion measures it (:mod:`.ballbar`).

The reversals are found on the reference alone (the interpolator's commanded speed, as a
CNC triggers its compensation), never on measurements: an axis's first move from rest is not
a reversal (where in the gap it stands is unknown). A loop without full velocity feed-forward
reverses the axis later than its reference, by its lag ``(1 - k_ff) / k_v``: the reference
given here is then the one delayed by that lag (:mod:`hil.contour` does so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ContourError


@dataclass(frozen=True)
class ReversalCompensation:
    """``backlash`` (load units, >= 0) crossed in ``cycles`` position cycles (>= 1)."""

    backlash: float
    cycles: int = 5

    def __post_init__(self) -> None:
        b = self.backlash
        if isinstance(b, bool) or not isinstance(b, int | float) or not math.isfinite(b) or b < 0:
            raise ContourError(f"compensation backlash = {b!r}: must be a finite number >= 0")
        if isinstance(self.cycles, bool) or not isinstance(self.cycles, int) or self.cycles < 1:
            raise ContourError(f"compensation cycles = {self.cycles!r}: must be an integer >= 1")

    def reversals(self, speed: np.ndarray, threshold: float = 0.0) -> list[tuple[int, int]]:
        """(sample, new direction) of every reversal of the commanded direction in ``speed``
        (load units/s per cycle): a sign change across any run of standstill."""
        out = []
        last = 0
        for k in np.flatnonzero(np.abs(speed) > threshold):
            sign = 1 if speed[k] > 0 else -1
            if last and sign != last:
                out.append((int(k), sign))
            last = sign
        return out

    def speed_offset(self, speed: np.ndarray, kr: float, cycle_s: float) -> np.ndarray:
        """The motor speed (rad/s) to add to the set point, per cycle of the reference whose
        speeds are ``speed`` (load units/s), for an axis of transmission ratio ``kr``."""
        out = np.zeros(len(speed))
        if self.backlash == 0.0:
            return out
        pulse = kr * self.backlash / (self.cycles * cycle_s)
        for k, sign in self.reversals(np.asarray(speed, dtype=float)):
            out[k : k + self.cycles] += sign * pulse
        return out

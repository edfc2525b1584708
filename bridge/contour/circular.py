"""The circular test of ISO 230-4 (a CNC's circularity test, a telescoping ballbar's run): the
contour axes interpolate a circle at a programmed feed in both directions, and the radial
deviation of the path the axes took is judged (:mod:`.ballbar`).

Each direction is one arc on the circle: a lead-in of ``overrun_deg`` (the axes accelerate
to the feed and their following error settles), the data arc of 360° from ``start_deg``, and
a lead-out of ``overrun_deg`` in which they decelerate. ISO 230-4 evaluates the data arc only,
so every quadrant transition (the axis reversals at 0°, 90°, 180°, 270°) is passed at the
feed. Counter-clockwise is G03, clockwise G02.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ..errors import ContourError
from .path import Arc, Point
from .planner import Block, ContourReference


class Direction(enum.Enum):
    """The direction of travel on the circle: counter-clockwise (G03) or clockwise (G02)."""

    CCW = 1
    CW = -1

    @property
    def sign(self) -> int:
        return self.value

    @property
    def label(self) -> str:
        return "counter-clockwise (G03)" if self is Direction.CCW else "clockwise (G02)"


@dataclass(frozen=True)
class CircularTest:
    """A circle of ``radius`` about ``centre`` (load units) at ``feed`` (load units/s)."""

    radius: float
    feed: float
    centre: Point = (0.0, 0.0)
    overrun_deg: float = 90.0
    start_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("radius", "feed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not (v > 0):
                raise ContourError(f"circular test {name} = {v!r}: must be a number > 0")
            if not math.isfinite(v):
                raise ContourError(f"circular test {name} = {v!r}: must be finite")
        if not 0.0 <= self.overrun_deg <= 360.0:
            raise ContourError(
                f"circular test overrun_deg = {self.overrun_deg!r}: allowed 0..360 degrees"
            )
        if not math.isfinite(self.start_deg):
            raise ContourError(f"circular test start_deg = {self.start_deg!r}: must be finite")

    def arc(self, direction: Direction) -> Arc:
        """Lead-in, data arc and lead-out as one arc."""
        d = direction.sign
        start = math.radians(self.start_deg - d * self.overrun_deg)
        sweep = d * math.radians(360.0 + 2 * self.overrun_deg)
        return Arc(self.centre, self.radius, start, sweep)

    def blocks(self, direction: Direction) -> tuple[Block, ...]:
        return (Block(self.arc(direction), self.feed),)

    def start_point(self, direction: Direction) -> Point:
        """Where the axes stand before the run (the lead-in's start)."""
        return self.arc(direction).start

    def data_mask(self, reference: ContourReference) -> np.ndarray:
        """The samples on the data arc (360° from ``start_deg``, after the lead-in)."""
        lead = math.radians(self.overrun_deg) * self.radius
        return (reference.path >= lead) & (reference.path <= lead + 2 * math.pi * self.radius)

    @property
    def period_s(self) -> float:
        """The time of one full circle at the feed."""
        return 2 * math.pi * self.radius / self.feed

"""The geometry of a contour in the plane of two interpolated axes: lines and circular arcs.

A CNC's interpolator moves its contour axes along programmed segments so that all of them
start and stop together (paper section II.A): straight lines (G01) and circular arcs, clockwise
(G02) or counter-clockwise (G03), each at a programmed feed (the path speed). The segments here
are pure geometry in load units (m for the linear axes of a machine tool); :mod:`.planner`
puts time on them, :mod:`.program` reads them from G-code-like text.

Every segment is parametrised by its arc length ``s`` in [0, length]: :meth:`point` is the
position, :meth:`tangent` the unit direction of motion there. An :class:`Arc` is given by its
centre, radius, start angle and *signed* sweep (positive counter-clockwise, as G03; any
magnitude, so a circular test's lead-in, full circle and lead-out are one arc).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ContourError

Point = tuple[float, float]

#: Two points closer than this are the same point (load units: 1 nm).
POINT_TOLERANCE = 1e-9


def _finite_point(name: str, p: object) -> Point:
    if (
        not isinstance(p, tuple | list)
        or len(p) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in p)
        or not all(math.isfinite(v) for v in p)
    ):
        raise ContourError(f"{name} = {p!r}: must be two finite numbers (x, y) in load units")
    return (float(p[0]), float(p[1]))


@dataclass(frozen=True)
class Line:
    """G01: a straight line from ``start`` to ``end`` (load units), of non-zero length."""

    start: Point
    end: Point

    def __post_init__(self) -> None:
        a = _finite_point("line start", self.start)
        b = _finite_point("line end", self.end)
        object.__setattr__(self, "start", a)
        object.__setattr__(self, "end", b)
        if math.dist(a, b) <= POINT_TOLERANCE:
            raise ContourError(f"line from {a} to {b}: start and end are the same point")

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    def direction(self) -> Point:
        length = self.length
        return ((self.end[0] - self.start[0]) / length, (self.end[1] - self.start[1]) / length)

    def point(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self.direction()
        return self.start[0] + cx * s, self.start[1] + cy * s

    def tangent(self, s: float) -> Point:
        return self.direction()

    def bounds(self) -> tuple[Point, Point]:
        """Lowest and highest (x, y) the segment reaches."""
        (x0, y0), (x1, y1) = self.start, self.end
        return (min(x0, x1), min(y0, y1)), (max(x0, x1), max(y0, y1))

    def largest_direction_cosines(self) -> Point:
        """Largest |dx/ds|, |dy/ds| along the segment (the share of the feed each axis runs)."""
        cx, cy = self.direction()
        return abs(cx), abs(cy)

    @property
    def radius(self) -> float:
        return math.inf


@dataclass(frozen=True)
class Arc:
    """G02/G03: a circular arc about ``centre`` of ``radius`` from ``start_angle`` (rad, from
    +x towards +y) through ``sweep`` (rad, signed: > 0 counter-clockwise = G03, < 0 clockwise
    = G02; |sweep| may exceed 2π)."""

    centre: Point
    radius: float
    start_angle: float
    sweep: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", _finite_point("arc centre", self.centre))
        for name in ("radius", "start_angle", "sweep"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ContourError(f"arc {name} = {v!r}: must be a finite number")
            object.__setattr__(self, name, float(v))
        if self.radius <= POINT_TOLERANCE:
            raise ContourError(f"arc radius = {self.radius!r}: must be > {POINT_TOLERANCE:g}")
        if abs(self.sweep) * self.radius <= POINT_TOLERANCE:
            raise ContourError(f"arc sweep = {self.sweep!r} rad: the arc has no length")

    @classmethod
    def through(cls, start: Point, end: Point, centre: Point, *, ccw: bool) -> Arc:
        """The arc from ``start`` to ``end`` about ``centre`` (G02: ``ccw=False``, G03: True);
        ``start == end`` is a full circle. Start and end must be at the same distance from the
        centre (within 1 µm or 1e-6 of the radius, as a CNC checks its programmed circles)."""
        start = _finite_point("arc start", start)
        end = _finite_point("arc end", end)
        centre = _finite_point("arc centre", centre)
        r0, r1 = math.dist(start, centre), math.dist(end, centre)
        if abs(r0 - r1) > max(1e-6, 1e-6 * r0):
            raise ContourError(
                f"arc from {start} to {end} about {centre}: the end is {r1:.9g} from the centre, "
                f"the start {r0:.9g}; they must be equal (a circle)"
            )
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
        sweep = (a1 - a0) % (2 * math.pi) if ccw else -((a0 - a1) % (2 * math.pi))
        if abs(sweep) * r0 <= POINT_TOLERANCE:
            sweep = 2 * math.pi if ccw else -2 * math.pi
        return cls(centre, r0, a0, sweep)

    @property
    def ccw(self) -> bool:
        return self.sweep > 0

    @property
    def length(self) -> float:
        return abs(self.sweep) * self.radius

    def angle(self, s: np.ndarray | float) -> np.ndarray | float:
        return self.start_angle + math.copysign(1.0, self.sweep) * s / self.radius

    def point(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = self.angle(s)
        return self.centre[0] + self.radius * np.cos(a), self.centre[1] + self.radius * np.sin(a)

    @property
    def start(self) -> Point:
        x, y = self.point(np.array([0.0]))
        return (float(x[0]), float(y[0]))

    @property
    def end(self) -> Point:
        x, y = self.point(np.array([self.length]))
        return (float(x[0]), float(y[0]))

    def tangent(self, s: float) -> Point:
        a = float(self.angle(s))
        d = math.copysign(1.0, self.sweep)
        return (-d * math.sin(a), d * math.cos(a))

    def _reaches(self, angle: float) -> bool:
        """The arc passes through the direction ``angle`` (rad) from its centre."""
        if abs(self.sweep) >= 2 * math.pi:
            return True
        lo = self.start_angle if self.sweep > 0 else self.start_angle + self.sweep
        return (angle - lo) % (2 * math.pi) <= abs(self.sweep) + 1e-12

    def bounds(self) -> tuple[Point, Point]:
        (x0, y0), (x1, y1) = self.start, self.end
        xs, ys = [x0, x1], [y0, y1]
        cx, cy, r = self.centre[0], self.centre[1], self.radius
        for k, (dx, dy) in enumerate(((r, 0.0), (0.0, r), (-r, 0.0), (0.0, -r))):
            if self._reaches(k * math.pi / 2):
                xs.append(cx + dx)
                ys.append(cy + dy)
        return (min(xs), min(ys)), (max(xs), max(ys))

    def largest_direction_cosines(self) -> Point:
        # |dx/ds| = |sin a| is 1 where the arc passes a = ±90°, |dy/ds| = |cos a| at 0°, 180°
        def peak(trig, angles: tuple[float, ...]) -> float:
            if any(self._reaches(a) for a in angles):
                return 1.0
            a0 = self.start_angle
            return max(abs(trig(a0)), abs(trig(a0 + self.sweep)))

        return (
            peak(math.sin, (math.pi / 2, 3 * math.pi / 2)),
            peak(math.cos, (0.0, math.pi)),
        )


Segment = Line | Arc


def check_continuous(segments: tuple[Segment, ...]) -> None:
    """Each segment starts where the one before it ends (within 1 µm)."""
    if not segments:
        raise ContourError("a contour needs at least one segment")
    for i in range(1, len(segments)):
        a, b = segments[i - 1].end, segments[i].start
        if math.dist(a, b) > 1e-6:
            raise ContourError(
                f"segment {i + 1} starts at {b}, but segment {i} ends at {a}: a contour is "
                "continuous"
            )


def tangent_continuous(a: Segment, b: Segment, tolerance_rad: float = 1e-6) -> bool:
    """``b`` leaves in the direction ``a`` arrives (no corner between them)."""
    ta, tb = a.tangent(a.length), b.tangent(0.0)
    cross = ta[0] * tb[1] - ta[1] * tb[0]
    dot = ta[0] * tb[0] + ta[1] * tb[1]
    return dot > 0 and abs(math.atan2(cross, dot)) <= tolerance_rad

"""Time on a contour: the feed profile shared by the interpolated axes, one sample per cycle.

The interpolator of a CNC moves all contour axes by one path parameter ``s`` (the length
travelled along the contour), so that they start and stop together and stay on the contour
whatever the speed (paper section II.A). :func:`plan` gives ``s`` a time law and samples it
once per position cycle:

* each block runs at its programmed feed (the path speed); the path accelerates and
  decelerates at a constant tangential acceleration (a trapezoidal speed profile), lower on
  an arc by the centripetal acceleration ``v²/R`` it already spends, so that the vector
  acceleration never exceeds the shared limit nor any axis's own;
* blocks that join without a corner (tangent-continuous) are passed at the lower of their
  feeds; at a corner the path stops (exact stop), since no axis can change its speed in no
  time;
* with a jerk limit the path position is filtered by a moving average of ``a / (j T)``
  cycles (the FIR jerk limiter of CNC interpolators), per stretch between stops: a
  trapezoidal acceleration, on the contour exactly, since the filter acts on ``s``, not on
  the axes;
* everything the axes cannot do is refused before a sample is made (:class:`ContourError`,
  one line): a point outside an axis's travel limits, a feed that would run an axis above its
  speed limit, an arc whose centripetal acceleration alone exceeds the acceleration limits.

Sample ``k`` holds the positions at ``t_k = k T`` and the speeds over the coming cycle
(forward differences, ``(x[k+1] - x[k]) / T``), the convention of the single-axis
:class:`bridge.interpolator.Table` and the simulator's references, so one axis's column is a
reference any position loop of the project plays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import ContourError
from .path import Arc, Line, Segment, check_continuous, tangent_continuous


def _positive(name: str, value: object, *, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise ContourError(f"{name} = {value!r}: must be a number > 0")
    if value <= 0 or (math.isinf(value) and not allow_inf):
        raise ContourError(f"{name} = {value!r}: must be a finite number > 0")
    return float(value)


@dataclass(frozen=True)
class AxisLimits:
    """What one interpolated axis allows: its travel (the bridge's software position limits,
    2014h), its speed (load units/s: the speed clamp 2007h over k_r) and its acceleration
    (load units/s²)."""

    name: str
    position_min: float
    position_max: float
    speed_max: float
    accel_max: float

    def __post_init__(self) -> None:
        for key in ("position_min", "position_max"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ContourError(f"axis {self.name}: {key} = {v!r}: must be a finite number")
        if not self.position_min < self.position_max:
            raise ContourError(
                f"axis {self.name}: position_min = {self.position_min!r} must be below "
                f"position_max = {self.position_max!r}"
            )
        _positive(f"axis {self.name}: speed_max", self.speed_max)
        _positive(f"axis {self.name}: accel_max", self.accel_max)


@dataclass(frozen=True)
class Block:
    """One programmed segment at its feed (the path speed, load units/s)."""

    segment: Segment
    feed: float

    def __post_init__(self) -> None:
        if not isinstance(self.segment, Line | Arc):
            raise ContourError(f"a block's segment is a Line or an Arc, not {self.segment!r}")
        _positive("feed", self.feed)


@dataclass(frozen=True)
class PathLimits:
    """The limits the axes share along the path: acceleration (load units/s²) and, if given,
    jerk (load units/s³)."""

    accel: float
    jerk: float | None = None

    def __post_init__(self) -> None:
        _positive("path acceleration", self.accel)
        if self.jerk is not None:
            _positive("path jerk", self.jerk)


@dataclass(frozen=True)
class ContourReference:
    """The interpolator's output, one row per cycle: ``position`` and ``speed`` (n × axes, load
    units and load units/s over the coming cycle), ``path`` (s, load units along the contour)
    and ``block`` (the index of the block the sample is on)."""

    cycle_s: float
    position: np.ndarray
    speed: np.ndarray
    path: np.ndarray
    block: np.ndarray
    feeds: tuple[float, ...] = field(default=())

    def __len__(self) -> int:
        return int(self.path.size)

    def axis(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Axis ``i``'s position and speed references (contiguous float arrays)."""
        return (
            np.ascontiguousarray(self.position[:, i]),
            np.ascontiguousarray(self.speed[:, i]),
        )

    @property
    def duration_s(self) -> float:
        return (len(self) - 1) * self.cycle_s


# --- checks ---------------------------------------------------------------------------------
def _check_travel(blocks: Sequence[Block], axes: Sequence[AxisLimits]) -> None:
    for i, b in enumerate(blocks, start=1):
        lo, hi = b.segment.bounds()
        for k, ax in enumerate(axes):
            if lo[k] < ax.position_min or hi[k] > ax.position_max:
                raise ContourError(
                    f"block {i} reaches {ax.name} = {lo[k]:.6g}..{hi[k]:.6g} load units, outside "
                    f"the travel limits of axis {ax.name} [{ax.position_min:g}, "
                    f"{ax.position_max:g}] load units"
                )


def _tangential_accel(b: Block, axes: Sequence[AxisLimits], limits: PathLimits, i: int) -> float:
    """The tangential acceleration a block may use (module docstring)."""
    seg = b.segment
    cos = seg.largest_direction_cosines()
    for k, ax in enumerate(axes):
        if b.feed * cos[k] > ax.speed_max * (1 + 1e-12):
            allowed = ax.speed_max / cos[k]
            raise ContourError(
                f"block {i}: feed {b.feed:.6g} load units/s runs axis {ax.name} at up to "
                f"{b.feed * cos[k]:.6g}, above its speed limit {ax.speed_max:.6g}; allowed "
                f"feed <= {allowed:.6g} load units/s"
            )
    if isinstance(seg, Line):
        a = limits.accel
        for k, ax in enumerate(axes):
            if cos[k] > 0:
                a = min(a, ax.accel_max / cos[k])
        return a
    a_max = min(limits.accel, *(ax.accel_max for ax in axes))
    normal = b.feed**2 / seg.radius
    if normal >= a_max:
        allowed = math.sqrt(a_max * seg.radius)
        raise ContourError(
            f"block {i}: feed {b.feed:.6g} load units/s on a radius of {seg.radius:.6g} needs a "
            f"centripetal acceleration of {normal:.6g} load units/s², not below the limit "
            f"{a_max:.6g}; allowed feed < {allowed:.6g} load units/s"
        )
    return math.sqrt(a_max**2 - normal**2)


# --- the time law -----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Phase:
    s0: float
    v0: float
    a: float
    t0: float
    duration: float


def _trapezoid(s0: float, t0: float, length: float, v0: float, v1: float, feed: float, a: float):
    """Phases from ``v0`` to ``v1`` over ``length`` with cruise ``<= feed`` and accel ``a``."""
    peak = min(feed, math.sqrt(max((2 * a * length + v0 * v0 + v1 * v1) / 2, 0.0)))
    peak = max(peak, v0, v1)
    d1 = (peak * peak - v0 * v0) / (2 * a)
    d3 = (peak * peak - v1 * v1) / (2 * a)
    d2 = max(length - d1 - d3, 0.0)
    out = []
    t, s = t0, s0
    for acc, dur, v_start, dist in (
        (a, (peak - v0) / a, v0, d1),
        (0.0, d2 / peak if peak > 0 else 0.0, peak, d2),
        (-a, (peak - v1) / a, peak, d3),
    ):
        if dur > 0:
            out.append(_Phase(s, v_start, acc, t, dur))
            t += dur
            s += dist
    return out, t


def _stretch_profile(
    blocks: Sequence[Block], accels: Sequence[float], cycle_s: float
) -> np.ndarray:
    """``s`` (from 0) per cycle over tangent-continuous blocks, at rest at both ends."""
    n = len(blocks)
    lengths = [b.segment.length for b in blocks]
    v = [0.0] * (n + 1)
    for i in range(1, n):
        v[i] = min(blocks[i - 1].feed, blocks[i].feed)
    for i in range(n):  # forward: what can be reached
        v[i + 1] = min(v[i + 1], math.sqrt(v[i] ** 2 + 2 * accels[i] * lengths[i]))
    for i in range(n - 1, -1, -1):  # backward: what can still stop
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * accels[i] * lengths[i]))
    phases: list[_Phase] = []
    t, s = 0.0, 0.0
    for i, b in enumerate(blocks):
        ph, t = _trapezoid(s, t, lengths[i], v[i], v[i + 1], b.feed, accels[i])
        phases.extend(ph)
        s += lengths[i]
    total = s
    k = np.arange(math.ceil(t / cycle_s - 1e-9) + 1)
    tk = k * cycle_s
    out = np.full(tk.size, total)
    starts = np.array([p.t0 for p in phases])
    idx = np.searchsorted(starts, tk, side="right") - 1
    for j, p in enumerate(phases):
        sel = (idx == j) & (tk < p.t0 + p.duration)
        dt = tk[sel] - p.t0
        out[sel] = p.s0 + p.v0 * dt + 0.5 * p.a * dt * dt
    np.minimum(out, total, out=out)
    out[0] = 0.0
    out[-1] = total
    return out


def _jerk_filter(s: np.ndarray, taps: int) -> np.ndarray:
    """Moving average of ``taps`` samples, starting and ending at rest."""
    if taps <= 1:
        return s
    padded = np.concatenate((np.zeros(taps - 1), s, np.full(taps - 1, s[-1])))
    c = np.cumsum(np.concatenate(([0.0], padded)))
    out = (c[taps:] - c[:-taps]) / taps
    out[-1] = s[-1]
    return out


def plan(
    blocks: Sequence[Block],
    axes: Sequence[AxisLimits],
    limits: PathLimits,
    cycle_s: float,
) -> ContourReference:
    """The reference of ``blocks`` for two axes ``axes`` (x, y) at ``cycle_s`` (module
    docstring); :class:`ContourError` for anything the axes cannot do."""
    cycle_s = _positive("cycle_s", cycle_s)
    if len(axes) != 2:
        raise ContourError(f"a planar contour has two axes, not {len(axes)}")
    if axes[0].name == axes[1].name:
        raise ContourError(f"the two axes need different names, not {axes[0].name!r} twice")
    blocks = tuple(blocks)
    check_continuous(tuple(b.segment for b in blocks))
    _check_travel(blocks, axes)
    accels = [_tangential_accel(b, axes, limits, i) for i, b in enumerate(blocks, start=1)]
    # stretches between exact stops
    stretches: list[list[int]] = [[0]]
    for i in range(1, len(blocks)):
        if tangent_continuous(blocks[i - 1].segment, blocks[i].segment):
            stretches[-1].append(i)
        else:
            stretches.append([i])
    lengths = np.array([b.segment.length for b in blocks])
    starts = np.concatenate(([0.0], np.cumsum(lengths)))
    pieces = []
    for stretch in stretches:
        s = _stretch_profile([blocks[i] for i in stretch], [accels[i] for i in stretch], cycle_s)
        if limits.jerk is not None:
            a_used = max(accels[i] for i in stretch)
            s = _jerk_filter(s, math.ceil(a_used / (limits.jerk * cycle_s)))
        pieces.append(starts[stretch[0]] + s if not pieces else starts[stretch[0]] + s[1:])
    path = np.concatenate(pieces)
    block = np.clip(np.searchsorted(starts, path, side="right") - 1, 0, len(blocks) - 1)
    pos = np.empty((path.size, 2))
    for i, b in enumerate(blocks):
        sel = block == i
        if np.any(sel):
            local = np.clip(path[sel] - starts[i], 0.0, lengths[i])
            pos[sel, 0], pos[sel, 1] = b.segment.point(local)
    speed = np.zeros_like(pos)
    speed[:-1] = np.diff(pos, axis=0) / cycle_s
    return ContourReference(cycle_s, pos, speed, path, block, tuple(b.feed for b in blocks))

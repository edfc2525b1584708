"""The test motions of the beta_T procedure: the built-in one, adapted to the axis, its
variants that provoke harder (:mod:`.ladder`), and the user's own motion.

A motion is played as a table of reference positions and speeds, one per position cycle,
from wherever the axis stands and back to it. What the verdicts look at is marked in it
(:class:`MotionProfile`): *watch* windows (moving at a constant speed after the position
loop's transient: where the limit cycle of eq. 12-13 lives), *rest* windows (at standstill
after the transient: a limit cycle at rest) and *standstill* windows (a dwell's last 0.1 s:
the standstill accuracy). Everything is in load units (m or rad) and seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import RegulatorConfigError, TuningError, TuningInputError, require_positive
from ..units import acceleration, speed

#: A window's first ``SETTLE_TIMES_KV / kv`` seconds are the position loop's transient
#: (e^-10 of a speed step's following error).
SETTLE_TIMES_KV = 10.0
#: Standstill error is averaged over a dwell's last this many seconds.
STANDSTILL_AVERAGE_S = 0.1
#: A window judged for oscillation lasts at least this many periods of eq. 13's lowest
#: frequency k_v / 4, so the band-pass has settled in it.
MIN_WINDOW_PERIODS = 5.0
#: eq. 14's T_v = 20 / k_v (the detector's default decay, :data:`regulator.DEFAULT_TV_TIMES_KV`).
TV_TIMES_KV = 20.0
#: The default watch window: 2 T_v = the transient (0.5 T_v) and 7.5 periods of k_v / 4.
WATCH_TIMES_TV = 2.0
#: The default dwell at rest, the bound of the wait for the standstill accuracy: 3 T_v, the
#: time the detector's holder needs to forget a limit cycle (beta falls by e^-3) and the position
#: loop to pull the load in.
DWELL_TIMES_TV = 3.0
#: The default feed, load units/s (3 m/min, section X's).
DEFAULT_FEED = 0.05
#: The default feed keeps eq. 1's following error v / k_v at this share of 2008h.
FEED_SHARE_OF_FOLLOWING_LIMIT = 0.4
#: The default slow feed (where the limit cycle is watched) as a share of the feed.
LOW_FEED_SHARE = 0.4
#: The default acceleration: the feed reached in this many seconds (0.05 m/s: 0.1 m/s²).
RAMP_S = 0.5


def settle_cycles(kv: float, cycle_s: float) -> int:
    return round(SETTLE_TIMES_KV / kv / cycle_s)


def shortest_window_cycles(kv: float, cycle_s: float) -> int:
    return math.ceil(MIN_WINDOW_PERIODS * 4.0 / kv / cycle_s)


def tv_s(kv: float) -> float:
    return TV_TIMES_KV / kv


@dataclass(frozen=True)
class MotionProfile:
    """One trial's motion from 0 (the runner adds where the axis stands): reference position
    and speed per cycle, the watch, standstill and rest windows (index ranges), the torque
    pulse (N m at the motor as a load disturbance, per cycle; None: none) and its name."""

    position: np.ndarray
    speed: np.ndarray
    watch: tuple[tuple[int, int], ...]
    standstill: tuple[tuple[int, int], ...]
    rest: tuple[tuple[int, int], ...]
    disturbance_nm: np.ndarray | None = None
    name: str = "test motion"

    def repeated(self, times: int) -> MotionProfile:
        """The motion ``times`` times back to back (it ends where it started)."""
        if isinstance(times, bool) or not isinstance(times, int) or times < 1:
            raise TuningError(f"repeats = {times!r}: at least 1")
        n = self.position.size

        def shift(ranges: tuple[tuple[int, int], ...]) -> tuple[tuple[int, int], ...]:
            return tuple((a + k * n, b + k * n) for k in range(times) for a, b in ranges)

        return MotionProfile(
            np.tile(self.position, times),
            np.tile(self.speed, times),
            shift(self.watch),
            shift(self.standstill),
            shift(self.rest),
            None if self.disturbance_nm is None else np.tile(self.disturbance_nm, times),
            self.name,
        )

    @property
    def cycles(self) -> int:
        return int(self.position.size)

    def excursion(self) -> tuple[float, float]:
        """(lowest, highest) position relative to the start, load units."""
        return float(np.min(self.position)), float(np.max(self.position))


@dataclass(frozen=True)
class TuningMotion:
    """The built-in test motion (load units, s): in each direction a ramp to ``feed``, held
    ``high_s``; a deceleration at ``accel`` to ``low_feed`` (to ``-low_feed`` with
    ``reverse``: across the gap) that throws the load into the backlash gap, after which the
    position loop on the load scale sustains the limit cycle; held ``low_s`` (the watch),
    with ``pulse_nm`` first (a load torque at the motor in the direction of motion for
    ``pulse_s``, released: section X's disturbance); a ramp to standstill and a dwell of
    ``dwell_s`` (the bound of the wait for the standstill accuracy). None: adapted to k_v
    (``high_s``: the transient, at least 0.5 s; ``low_s``: :data:`WATCH_TIMES_TV` T_v;
    ``dwell_s``: :data:`DWELL_TIMES_TV` T_v; ``pulse_s``: T_v)."""

    feed: float = 0.05
    low_feed: float = 0.02
    accel: float = 0.1
    high_s: float | None = None
    low_s: float | None = None
    dwell_s: float | None = None
    reverse: bool = False
    pulse_nm: float = 0.0
    pulse_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("feed", "low_feed", "accel"):
            require_positive(name, getattr(self, name), "")
        for name in ("high_s", "low_s", "dwell_s", "pulse_s"):
            if getattr(self, name) is not None:
                require_positive(name, getattr(self, name), "s")
        if not self.low_feed < self.feed:
            raise RegulatorConfigError(
                f"low_feed = {self.low_feed!r}: must be below feed = {self.feed!r} (the "
                "deceleration between them provokes the limit cycle)",
                field="low_feed",
                value=self.low_feed,
            )
        if self.dwell_s is not None and not self.dwell_s > STANDSTILL_AVERAGE_S:
            raise RegulatorConfigError(
                f"dwell_s = {self.dwell_s!r}: must exceed {STANDSTILL_AVERAGE_S} s",
                field="dwell_s",
                value=self.dwell_s,
            )
        if not (math.isfinite(self.pulse_nm) and self.pulse_nm >= 0.0):
            raise RegulatorConfigError(
                f"pulse_nm = {self.pulse_nm!r}: a torque >= 0", field="pulse_nm", value=self
            )

    @classmethod
    def for_axis(
        cls,
        kv: float,
        following_error_limit: float,
        feed: float | None = None,
        low_feed: float | None = None,
        accel: float | None = None,
        **times: float | None,
    ) -> TuningMotion:
        """The default motion of an axis, with what the user set (not None) kept: the feed
        :data:`DEFAULT_FEED`, lowered until eq. 1's following error v / k_v stays within
        :data:`FEED_SHARE_OF_FOLLOWING_LIMIT` of 2008h; the slow feed :data:`LOW_FEED_SHARE`
        of the feed; the acceleration reaching the feed in :data:`RAMP_S`; the times adapted
        to k_v (None)."""
        require_positive("kv", kv, "1/s")
        require_positive("following_error_limit", following_error_limit, "load units")
        v = (
            feed
            if feed is not None
            else min(DEFAULT_FEED, FEED_SHARE_OF_FOLLOWING_LIMIT * following_error_limit * kv)
        )
        return cls(
            feed=v,
            low_feed=low_feed if low_feed is not None else LOW_FEED_SHARE * v,
            accel=accel if accel is not None else v / RAMP_S,
            **times,  # type: ignore[arg-type]
        )

    def times(self, kv: float) -> tuple[float, float, float, float]:
        """(high_s, low_s, dwell_s, pulse_s) with the defaults for ``kv`` filled in."""
        t_v = tv_s(kv)
        return (
            self.high_s if self.high_s is not None else max(0.5, SETTLE_TIMES_KV / kv),
            self.low_s if self.low_s is not None else WATCH_TIMES_TV * t_v,
            self.dwell_s if self.dwell_s is not None else DWELL_TIMES_TV * t_v,
            self.pulse_s if self.pulse_s is not None else t_v,
        )

    def profile(self, cycle_s: float, kv: float, name: str = "test motion") -> MotionProfile:
        """Samples of one run (positive direction, then back), one per cycle, from 0."""
        require_positive("cycle_s", cycle_s, "s")
        require_positive("kv", kv, "1/s")
        high_s, low_s, dwell_s, pulse_s = self.times(kv)
        settle = settle_cycles(kv, cycle_s)
        shortest = shortest_window_cycles(kv, cycle_s)
        speeds: list[np.ndarray] = []
        pushes: list[np.ndarray] = []
        watch: list[tuple[int, int]] = []
        standstill: list[tuple[int, int]] = []
        rest: list[tuple[int, int]] = []
        n = 0
        low = -self.low_feed if self.reverse else self.low_feed
        pulse_n = round(pulse_s / cycle_s) if self.pulse_nm > 0.0 else 0
        for sign in (1.0, -1.0):
            level = 0.0
            for target, hold_s, kind in (
                (self.feed, high_s, ""),
                (low, low_s, "watch"),
                (0.0, dwell_s, "dwell"),
            ):
                steps = max(1, math.ceil(abs(target - level) / self.accel / cycle_s))
                ramp = level + (target - level) * np.arange(1, steps + 1) / steps
                hold = round(hold_s / cycle_s)
                push = pulse_n if kind == "watch" else 0
                speeds += [sign * ramp, np.full(push + hold, sign * target)]
                pushes += [np.zeros(steps), np.full(push, sign * np.sign(target) * self.pulse_nm)]
                pushes.append(np.zeros(hold))
                n += steps + push
                if kind == "watch":
                    if hold < settle + shortest:
                        raise TuningError(
                            f"low_s = {low_s:g} s: the watch window must outlast the transient "
                            f"of {settle * cycle_s:g} s (10 / k_v) by {shortest * cycle_s:g} s "
                            "(5 periods of k_v / 4); leave low_s out to have it fit k_v"
                        )
                    watch.append((n + settle, n + hold))
                elif kind == "dwell":
                    last = round(STANDSTILL_AVERAGE_S / cycle_s)
                    standstill.append((n + hold - last, n + hold))
                    if hold >= settle + shortest:  # else too short to judge oscillation
                        rest.append((n + settle, n + hold))
                n += hold
                level = target
        v = np.concatenate(speeds)
        # forward difference convention of the interpolator: x[k+1] = x[k] + v[k] cycle
        position = np.concatenate([[0.0], np.cumsum(v[:-1]) * cycle_s])
        disturbance = np.concatenate(pushes) if pulse_n else None
        return MotionProfile(
            position, v, tuple(watch), tuple(standstill), tuple(rest), disturbance, name
        )

    def describe(self, unit: str = "m") -> str:
        low = f"-{speed(self.low_feed, unit)}" if self.reverse else speed(self.low_feed, unit)
        text = f"{speed(self.feed, unit)} -> {low} at {acceleration(self.accel, unit)}"
        if self.pulse_nm > 0.0:
            text += f", a {self.pulse_nm:.3g} N·m load pulse"
        return text

    def travel(self, cycle_s: float, kv: float) -> float:
        """Largest excursion from the start, load units."""
        lo, hi = self.profile(cycle_s, kv).excursion()
        return max(-lo, hi)

    def with_changes(self, **changes: object) -> TuningMotion:
        return replace(self, **changes)  # type: ignore[arg-type]


def motion_from_samples(
    time_s: np.ndarray,
    position: np.ndarray,
    cycle_s: float,
    kv: float,
    dwell_s: float | None = None,
    name: str = "your motion",
) -> MotionProfile:
    """The user's own motion (``time_s`` strictly increasing, ``position`` load units, e.g.
    a trace file's ``position_reference``): resampled to the cycle from its first sample,
    relative to its start, a dwell of ``dwell_s`` (default :data:`DWELL_TIMES_TV` T_v) added
    at its end. It must come back to its start at rest (each trial starts where the last
    ended); its watch windows are where it moves at a constant speed for at least the
    transient and 5 periods of k_v / 4, its rest windows where it stands as long."""
    require_positive("cycle_s", cycle_s, "s")
    require_positive("kv", kv, "1/s")
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(position, dtype=float)
    if t.ndim != 1 or t.shape != x.shape or t.size < 2 or np.any(np.diff(t) <= 0.0):
        raise TuningInputError("a motion needs >= 2 samples of strictly increasing time")
    grid = np.arange(0.0, t[-1] - t[0] + 0.5 * cycle_s, cycle_s)
    x = np.interp(grid + t[0], t, x) - x[0]
    span = float(np.ptp(x))
    if span == 0.0:
        raise TuningInputError(f"{name} does not move")
    if abs(x[-1]) > 1e-6 * max(1.0, span) + 1e-9:
        raise TuningInputError(
            f"{name} ends {abs(x[-1]) * 1e3:.4g} mm from where it starts: a tuning motion "
            "comes back to its start (each trial starts where the last one ended)"
        )
    dwell = dwell_s if dwell_s is not None else DWELL_TIMES_TV * tv_s(kv)
    hold = round(dwell / cycle_s)
    x = np.concatenate([x[:-1], np.zeros(hold + 1)])
    v = np.append(np.diff(x) / cycle_s, 0.0)
    settle = settle_cycles(kv, cycle_s)
    shortest = shortest_window_cycles(kv, cycle_s)
    tolerance = 1e-3 * float(np.max(np.abs(v)))
    edges = np.nonzero(np.abs(np.diff(v)) > tolerance)[0] + 1
    watch, rest = [], []
    for a, b in zip(np.r_[0, edges], np.r_[edges, v.size], strict=True):
        if b - a < settle + shortest:
            continue
        (rest if abs(v[a]) <= tolerance else watch).append((int(a) + settle, int(b)))
    if not watch:
        raise TuningInputError(
            f"{name} never moves at a constant speed for {(settle + shortest) * cycle_s:.3g} s "
            "(the transient 10 / k_v and 5 periods of k_v / 4): nothing where the limit cycle "
            "could be watched"
        )
    last = round(STANDSTILL_AVERAGE_S / cycle_s)
    return MotionProfile(x, v, tuple(watch), ((x.size - last, x.size),), tuple(rest), None, name)

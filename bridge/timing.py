"""Time modes of the loop: lockstep (simulated time) and real time (wall clock), injected.

A :class:`Pacer` tells the loop when to send SYNC k (a wall-clock instant, or "now") and
until when to wait for the drive's TPDOs of that SYNC, and provides the control time the
controller and the heartbeat supervision see (:meth:`Pacer.now`).

* :class:`LockstepPacer`: control time is exactly ``k * cycle_s`` at SYNC k; SYNC k+1 is sent
  as soon as the exchange of cycle k is done (TPDOs in or ``wait_s`` of wall time without
  them, set point sent). Deterministic for a drive that answers within ``wait_s``; for tests,
  demos and benchmarks with the simulated drive.
* :class:`RealTimePacer`: SYNC k at ``t0 + k * cycle_s`` of the wall clock (the last
  ``spin_s`` before it polled, not slept); TPDOs accepted until ``deadline_fraction`` of the
  cycle after the SYNC. For hardware.

A SYNC is never sent in a burst to catch up: :meth:`Pacer.slot` gives the loop the first slot
on the schedule it can still meet. A slot is met when its SYNC leaves no later than
``late_fraction`` of a cycle after its instant; a slot the loop cannot meet is skipped (the
loop counts it) and its SYNC is never sent, so the drive sees SYNCs on the schedule's grid
only, with gaps instead of bunches.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Protocol

from virtual_bus.contract import TimeMode as TimeMode

from .errors import BridgeConfigError

WallClock = Callable[[], float]

#: Lockstep: wall time to wait for a TPDO before declaring it missing, s.
DEFAULT_LOCKSTEP_WAIT_S = 0.25
#: Real time: share of the cycle after SYNC during which TPDOs count for that cycle.
DEFAULT_DEADLINE_FRACTION = 0.5
#: Real time: share of the cycle a SYNC may leave after its instant; later, its slot is
#: skipped (a late SYNC would shorten the interval to the next one: a bunch).
DEFAULT_LATE_FRACTION = 0.2
#: Real time: the last part of the wait for a SYNC instant is spent polling the clock instead
#: of sleeping (a blocking wait wakes 50-100 µs late on Linux), s; at most 20 % of the cycle.
DEFAULT_SPIN_S = 0.0002


def _positive(name: str, value: float, high: float = math.inf) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and 0.0 < value <= high)
    ):
        raise BridgeConfigError(f"{name} = {value!r}: must be a finite number in (0, {high:g}]")
    return float(value)


class Pacer(Protocol):
    """What the loop needs from a time mode."""

    mode: TimeMode
    cycle_s: float
    spin_s: float  # poll (do not block) this long before a wall-clock instant
    late_s: float  # a SYNC may leave this long after its instant (later: the slot is skipped)

    def now(self) -> float:
        """Control time, s (simulated in lockstep, wall-clock since start in real time)."""
        ...

    def begin_cycle(self, k: int) -> float | None:
        """Start cycle ``k``: the wall instant SYNC k is due (``None``: send it now)."""
        ...

    def slot(self, k: int) -> tuple[int, float | None]:
        """The first slot ``>= k`` whose SYNC can still go out on time, and its due instant
        (``None``: now); starts that cycle like :meth:`begin_cycle`."""
        ...

    def on_time(self, due: float, sent_s: float) -> bool:
        """Whether a SYNC leaving at ``sent_s`` still meets its slot ``due``."""
        ...

    def window_end(self, sync_wall_s: float) -> float:
        """Wall instant until which TPDOs of the SYNC sent at ``sync_wall_s`` are awaited."""
        ...


class LockstepPacer:
    """Simulated time advancing exactly one cycle per SYNC (see the module docstring).

    ``wall`` is only used to bound the wait for a missing TPDO (``wait_s``)."""

    mode = TimeMode.LOCKSTEP
    spin_s = 0.0
    late_s = 0.0  # never late: SYNC k+1 goes out when the exchange of cycle k is done

    def __init__(
        self,
        cycle_s: float,
        wait_s: float = DEFAULT_LOCKSTEP_WAIT_S,
        wall: WallClock = time.monotonic,
    ) -> None:
        self.cycle_s = _positive("cycle_s", cycle_s, 1.0)
        self.wait_s = _positive("wait_s", wait_s, 60.0)
        self.wall = wall
        self._k = 0

    def now(self) -> float:
        return self._k * self.cycle_s

    def begin_cycle(self, k: int) -> float | None:
        self._k = k
        return None

    def slot(self, k: int) -> tuple[int, float | None]:
        self._k = k
        return k, None

    def on_time(self, due: float, sent_s: float) -> bool:
        return True

    def window_end(self, sync_wall_s: float) -> float:
        return sync_wall_s + self.wait_s


class RealTimePacer:
    """SYNC from the wall clock: SYNC k at ``t0 + k * cycle_s`` (t0 = first call of
    :meth:`begin_cycle`); TPDOs count until ``deadline_fraction * cycle_s`` after the SYNC."""

    mode = TimeMode.REAL_TIME

    def __init__(
        self,
        cycle_s: float,
        deadline_fraction: float = DEFAULT_DEADLINE_FRACTION,
        wall: WallClock = time.monotonic,
        spin_s: float | None = None,
        late_fraction: float = DEFAULT_LATE_FRACTION,
    ) -> None:
        self.cycle_s = _positive("cycle_s", cycle_s, 1.0)
        self.deadline_fraction = _positive("deadline_fraction", deadline_fraction, 0.95)
        self.late_fraction = _positive("late_fraction", late_fraction, 0.5)
        self.late_s = self.late_fraction * self.cycle_s
        if spin_s is None:
            spin_s = min(DEFAULT_SPIN_S, 0.2 * self.cycle_s)
        if not (isinstance(spin_s, int | float) and 0.0 <= spin_s <= self.cycle_s):
            raise BridgeConfigError(f"spin_s = {spin_s!r}: must be in [0, cycle_s] s")
        self.spin_s = float(spin_s)
        self.wall = wall
        self._t0: float | None = None

    def now(self) -> float:
        return 0.0 if self._t0 is None else self.wall() - self._t0

    def begin_cycle(self, k: int) -> float | None:
        if self._t0 is None:
            self._t0 = self.wall() - k * self.cycle_s
        return self._t0 + k * self.cycle_s

    def slot(self, k: int) -> tuple[int, float | None]:
        now = self.wall()
        if self._t0 is None:
            self._t0 = now - k * self.cycle_s
        due = self._t0 + k * self.cycle_s
        if now - due > self.late_s:  # missed: the next slot still ahead of the clock
            k = max(k + 1, math.ceil((now - self._t0) / self.cycle_s))
            due = self._t0 + k * self.cycle_s
        return k, due

    def on_time(self, due: float, sent_s: float) -> bool:
        """Whether a SYNC sent at ``sent_s`` met its slot ``due``."""
        return sent_s - due <= self.late_s

    def window_end(self, sync_wall_s: float) -> float:
        return sync_wall_s + self.deadline_fraction * self.cycle_s

    def cycles_behind(self, k: int) -> int:
        """How many whole cycles the wall clock is past SYNC k's due time (0: on time)."""
        if self._t0 is None:
            return 0
        late_s = self.wall() - (self._t0 + k * self.cycle_s)
        return max(0, int(late_s // self.cycle_s))

"""The simulated drive as a process of its own: serve one bus until told to stop.

:func:`serve` is the whole life of a standalone drive (``python -m plant_sim drive``, or a
harness that runs the drive in a subprocess or thread of its own):

1. build the :class:`SimulatedDrive` of the axis on the given bus (the EDS is checked);
2. ``start()``: the physics kernels are loaded / compiled first, *then* the boot-up message
   goes out and the drive is Pre-operational with its heartbeat running - so from the
   boot-up on, every SDO request and SYNC is answered at the normal pace (a master's 0.3 s
   SDO timeout never meets a compiling drive);
3. the real-time options (:class:`~virtual_bus.realtime.RealTimeOptions`, the same as the
   bridge's) are applied to the calling thread, which from now on is the one thread that
   receives: it serves NMT, SDO, SYNC and RPDOs (the physics steps on each SYNC, after the
   TPDOs of that SYNC have gone out) and checks every ``check_interval_s`` that no bus
   callback failed and whether ``stop`` is set. With ``busy_poll`` it polls the bus instead
   of blocking in a window of ``sync_poll_lead_s`` either side of the instant the next SYNC
   is due, and after the SYNC until the master's set point is in (:class:`SyncWatch`): a
   blocked thread wakes 50-60 µs after its frame arrived on a small VM, a polling one at
   once. With ``freeze_gc`` the collector runs only right after a SYNC has been answered;
4. with the real-time clock (``TimeMode.REAL_TIME``) the drive keeps its own clock, as a
   real drive's control loop runs on its own oscillator (:class:`OwnClock`): from the first
   SYNC on, a position cycle whose SYNC has not come half a cycle after it was due is run by
   the drive itself on the last set point (:meth:`SimulatedDrive.free_cycle`), and so is
   every cycle after it until SYNC comes back -- a master that dies leaves a motor that goes
   on, as a real one does, until a supervision stops it: the heartbeat consumer (1016h,
   checked on the wall clock here, :meth:`SimulatedDrive.watch_master`) acts through 6007h.
   At rest with the power stage off nothing changes (no measuring system moved in the last
   cycle), so no cycles run then;
5. on ``stop`` (SIGINT/SIGTERM in the command) the drive leaves the bus (heartbeat stopped);
   the bus stays the caller's to shut down.

>>> stop = threading.Event()
>>> result = serve(DriveProcessConfig(axis), bus, stop, ready=lambda drive: ...)
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.frame_guard import FrameFault
from virtual_bus.framing import NOTHING
from virtual_bus.realtime import GcBetweenCycles, RealTimeOptions, apply_realtime

from ..fmu.model import FmuSpec
from ..plant import Plant
from .cia402 import State402
from .config import DriveConfig, TimeMode
from .drive import SimulatedDrive
from .errors import DriveConfigError
from .node import NmtState

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DriveProcessConfig:
    """What a standalone drive serves.

    axis: the axis the plant simulates; node_id: 1..127 (the contract's default 2);
    drive: drive settings (default: heartbeat on the wall clock, ``TimeMode.REAL_TIME``,
    since a drive on its own has no other clock before the first SYNC);
    check_interval_s: how often :func:`serve` looks for a failed bus callback and ``stop`` (s);
    realtime: the process's real-time options (applied by :func:`serve`; all off by default);
    sync_poll_lead_s: with ``realtime.busy_poll``, the bus is polled from this long before
    the next SYNC is due until this long after (None: :func:`default_sync_poll_lead_s`);
    fmu: an FMU as the plant (None: the compiled kernel of ``axis``), made when the drive
    is built.
    """

    axis: AxisConfig
    node_id: int = 2
    drive: DriveConfig = field(default_factory=lambda: DriveConfig(time_mode=TimeMode.REAL_TIME))
    check_interval_s: float = 0.2
    realtime: RealTimeOptions = field(default_factory=RealTimeOptions)
    sync_poll_lead_s: float | None = None
    fmu: FmuSpec | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.node_id, int) or not 1 <= self.node_id <= 127:
            raise DriveConfigError(f"node_id = {self.node_id!r}: allowed 1..127")
        if not 0.001 <= self.check_interval_s <= 10.0:
            raise DriveConfigError(
                f"check_interval_s = {self.check_interval_s}: allowed [0.001, 10] s"
            )
        lead = self.sync_poll_lead_s
        half = self.axis.control.position_cycle / 2
        if lead is not None and not (math.isfinite(lead) and 0.0 < lead <= half):
            raise DriveConfigError(
                f"sync_poll_lead_s = {lead}: allowed (0, {half:g}] s (half the position cycle)"
            )

    def make_plant(self) -> Plant | None:
        """The FMU's plant at rest at 0, or None for the kernel's (the drive makes it)."""
        if self.fmu is None:
            return None
        from ..fmu import FmuPlant

        return FmuPlant(self.fmu, self.axis, 0.0, f"drive{self.node_id}")

    @property
    def poll_lead_s(self) -> float:
        """The SYNC poll window's lead in force (s)."""
        if self.sync_poll_lead_s is not None:
            return self.sync_poll_lead_s
        return default_sync_poll_lead_s(self.axis.control.position_cycle)


#: Default lead of the SYNC poll window: this share of the position cycle, at most
#: :data:`MAX_SYNC_POLL_LEAD_S` (it covers the SYNC's own jitter and the wake-up delay of a
#: SYNC that came while the loop was blocked).
SYNC_POLL_LEAD_FRACTION = 0.2
MAX_SYNC_POLL_LEAD_S = 150e-6
#: After a SYNC the loop polls until the next frame (the set point) is in, at most this
#: share of the position cycle after the SYNC. With the lead window either side of the due
#: SYNC, the loop polls at most 0.25 + 2 * 0.2 = 65 % of the time (a master that sends SYNC
#: and no set point); below the kernel's real-time throttling (95 %), and other tasks on
#: that CPU keep a third of it.
SYNC_HOLD_FRACTION = 0.25


def default_sync_poll_lead_s(cycle_s: float) -> float:
    """:data:`SYNC_POLL_LEAD_FRACTION` of ``cycle_s``, at most :data:`MAX_SYNC_POLL_LEAD_S`."""
    return min(SYNC_POLL_LEAD_FRACTION * cycle_s, MAX_SYNC_POLL_LEAD_S)


class SyncWatch:
    """When the drive's loop polls the bus for its next SYNC and when it may block.

    A SYNC producer sends on a fixed period (the position cycle, ``cycle_s``); a SYNC slot it
    skips comes one period later. After a SYNC received at ``t`` (:meth:`synced`), the next
    is due at ``t + cycle_s``: from ``lead_s`` before until ``lead_s`` after that instant
    :meth:`wait_s` says 0 (poll); outside it, how long the loop may block. A SYNC that does
    not come moves the window one period on, once; after a second miss the loop blocks until
    a SYNC comes (a producer that stopped costs no CPU).

    After the SYNC the loop also polls until the next frame is in (:meth:`received`: the
    master's set point, sent in answer to the TPDOs), at most ``hold_s`` after the SYNC: a
    frame sent to a polling receiver leaves the sender's ``sendto`` without waking a thread
    on another CPU (some 10 µs less in the master's set-point path on a small VM). The clock
    is the caller's (s).
    """

    #: Windows in a row without their SYNC before the watch gives up until the next SYNC.
    MISSES = 2

    def __init__(self, cycle_s: float, lead_s: float, hold_s: float = 0.0) -> None:
        self.cycle_s = cycle_s
        self.lead_s = lead_s
        self.hold_s = hold_s
        self.due_s: float | None = None
        self.hold_until_s: float | None = None
        self._misses = 0

    def synced(self, t: float) -> None:
        """A SYNC was received at ``t``."""
        self.due_s = t + self.cycle_s
        self.hold_until_s = t + self.hold_s
        self._misses = 0

    def received(self) -> None:
        """A frame other than the SYNC was received (ends the hold after a SYNC)."""
        self.hold_until_s = None

    def wait_s(self, now: float, longest_s: float) -> float:
        """0.0: poll now; else block at most this long (never more than ``longest_s``)."""
        hold = self.hold_until_s
        if hold is not None:
            if now < hold:
                return 0.0
            self.hold_until_s = None
        due = self.due_s
        while due is not None:
            if now < due - self.lead_s:
                return min(longest_s, due - self.lead_s - now)
            if now <= due + self.lead_s:
                return 0.0
            self._misses += 1
            due = None if self._misses >= self.MISSES else due + self.cycle_s
            self.due_s = due
        return longest_s


#: A SYNC that has not come this share of a cycle after it was due is replaced by a cycle
#: of the drive's own clock (a SYNC slot the master skips, one it sends late, a dead master).
OWN_CLOCK_GRACE_FRACTION = 0.5
#: Own cycles that are due wait until the socket is empty, at most for this many frames (a
#: flood that never lets it empty must not stop the drive's clock).
OWN_CLOCK_DRAIN_FRAMES = 256
#: At most this many own cycles are run at once to catch up with the wall clock (a drive
#: process held off its CPU for longer loses the rest: its physics falls behind, never
#: runs in a burst longer than a second of cycles).
OWN_CLOCK_CATCH_UP_S = 1.0


class OwnClock:
    """The drive's own clock in real time (module docstring, point 4): the instant of the
    next position cycle it runs itself unless a SYNC comes first. Armed by the first SYNC
    (:meth:`synced`); :meth:`due` says how many cycles are due at ``now`` and moves on. The
    clock is the caller's (s)."""

    def __init__(self, cycle_s: float, grace_s: float) -> None:
        self.cycle_s = cycle_s
        self.grace_s = grace_s
        self.due_s: float | None = None
        #: the axis moved in the last cycle (the own clock runs while it does, or while the
        #: power stage holds it)
        self.moving = True
        #: cycles of its own are running (no SYNC came for more than a cycle and a half, and
        #: the axis moves or the power stage holds it)
        self.running = False
        self._most = max(1, round(OWN_CLOCK_CATCH_UP_S / cycle_s))

    def synced(self, t: float) -> None:
        """A SYNC ran a cycle at ``t``: the next one is its successor's, due a cycle on."""
        self.due_s = t + self.cycle_s + self.grace_s
        self.moving = True
        self.running = False

    def wait_s(self, now: float, longest_s: float) -> float:
        """How long the loop may block before a cycle is due (at most ``longest_s``)."""
        due = self.due_s
        return longest_s if due is None else max(0.0, min(longest_s, due - now))

    def due(self, now: float) -> tuple[float, int]:
        """The instant of the first cycle due at ``now`` and how many are due (0 before the
        first SYNC); the next is a cycle after the last of them."""
        due = self.due_s
        if due is None or now < due:
            return now, 0
        n = int((now - due) // self.cycle_s) + 1
        self.due_s = due + n * self.cycle_s
        if n > self._most:  # held off its CPU for long: the oldest cycles are lost
            due += (n - self._most) * self.cycle_s
            n = self._most
        return due, n

    def idle(self, now: float, look_again_s: float) -> None:
        """Nothing to run now (at rest, power stage off): look again in ``look_again_s``."""
        if self.due_s is not None:
            self.due_s = now + look_again_s
        self.running = False


@dataclass
class LoopCounts:
    """What the serving loop counted: frames it could not receive (no CAN frame)."""

    receive_errors: int = 0


@dataclass(frozen=True)
class ServeResult:
    """How the drive ended: SYNCs run, CiA 402 state, NMT state, active error codes,
    datagrams the loop could not receive as a CAN frame (ignored), cycles of its own clock
    (real time, while no SYNC came), frames its frame guard refused by kind (2105h)."""

    sync_count: int
    state: State402
    nmt_state: NmtState
    active_errors: tuple[int, ...]
    receive_errors: int = 0
    free_cycles: int = 0
    refused: tuple[tuple[FrameFault, int], ...] = ()

    def summary(self) -> str:
        errors = ", ".join(f"0x{code:04X}" for code in self.active_errors) or "none"
        refused = ", ".join(f"{f.name.lower()} {n}" for f, n in self.refused if n) or "none"
        return (
            f"{self.sync_count} SYNCs served; CiA 402 {self.state.value}, NMT "
            f"{self.nmt_state.name.lower().replace('_', '-')}, active errors {errors}"
            + (f"; {self.receive_errors} datagrams ignored" if self.receive_errors else "")
            + (f"; {self.free_cycles} cycles on its own clock" if self.free_cycles else "")
            + f"; refused frames (2105h) {refused}"
        )


def serve(
    config: DriveProcessConfig,
    bus: can.BusABC,
    stop: threading.Event,
    *,
    ready: Callable[[SimulatedDrive], None] | None = None,
    wall: Callable[[], float] = time.monotonic,
    epoch: Callable[[], float] = time.time,
) -> ServeResult:
    """Serve the drive on ``bus`` until ``stop`` is set (see the module docstring), from the
    calling thread; ``wall``: the loop's clock (s); ``epoch``: the clock of the frames'
    timestamps (s since the epoch; python-can's convention).

    ready(drive): called once the boot-up message is out and the real-time options are
    applied. A bus callback that raised is raised here (after the drive has left the bus);
    a real-time option the OS refuses raises :class:`~virtual_bus.errors.RealTimeRefused`.
    The bus is not shut down.
    """
    plant = config.make_plant()
    try:
        return _serve(
            config,
            bus,
            stop,
            SimulatedDrive(bus, config.node_id, config.axis, config.drive, plant),
            ready,
            wall,
            epoch,
        )
    finally:
        if plant is not None:
            plant.close()


def _serve(
    config: DriveProcessConfig,
    bus: can.BusABC,
    stop: threading.Event,
    drive: SimulatedDrive,
    ready: Callable[[SimulatedDrive], None] | None,
    wall: Callable[[], float],
    epoch: Callable[[], float],
) -> ServeResult:
    drive.start()
    gc_control = GcBetweenCycles() if config.realtime.freeze_gc else None
    counts = LoopCounts()
    try:
        with drive.receiving_here() as handle:
            apply_realtime(config.realtime)
            if ready is not None:
                ready(drive)
            if gc_control is not None:
                gc_control.start()
            try:
                _loop(drive, handle, stop, config, gc_control, wall, epoch, counts)
            finally:
                if gc_control is not None:
                    gc_control.stop()
    finally:
        drive.stop()
    drive.check()
    return ServeResult(
        drive.sync_count,
        drive.state,
        drive.nmt_state,
        drive.active_errors,
        counts.receive_errors,
        drive.free_cycles,
        tuple((fault, drive.guard.count(fault)) for fault in FrameFault),
    )


def _loop(
    drive: SimulatedDrive,
    handle: Callable[[can.Message], None],
    stop: threading.Event,
    config: DriveProcessConfig,
    gc_control: GcBetweenCycles | None,
    wall: Callable[[], float],
    epoch: Callable[[], float],
    counts: LoopCounts,
) -> None:
    """Receive and handle frames until ``stop``; see :func:`serve`. A receive error (a
    datagram that is no CAN frame) is logged, counted in ``counts`` and skipped. Frames come
    through the drive's port (:meth:`SimulatedDrive.receiving_here`: the bus's raw socket
    where it has one), a SYNC or an RPDO is handed over without a message
    (:meth:`SimulatedDrive.take`)."""
    port = drive.port
    assert port is not None, "the loop runs inside drive.receiving_here()"
    take = drive.take
    interval = config.check_interval_s
    cycle_s = config.axis.control.position_cycle
    watch = SyncWatch(cycle_s, config.poll_lead_s, SYNC_HOLD_FRACTION * cycle_s)
    busy_poll = config.realtime.busy_poll
    next_check = wall() + interval
    # real time: the drive's own clock and its watch of the master (module docstring)
    real_time = config.drive.time_mode is TimeMode.REAL_TIME
    own = OwnClock(cycle_s, OWN_CLOCK_GRACE_FRACTION * cycle_s) if real_time else None
    drive.wall = wall
    master_at = 0.0  # when to look at the master's heartbeat next
    overdue_frames = 0  # frames read while own cycles were overdue
    while not stop.is_set():
        now = wall()
        if now >= next_check:
            drive.check()
            next_check = now + interval
        if own is not None:
            longest = watch.wait_s(now, interval) if busy_poll else interval
            if not own.running:  # (while it runs, each own cycle checks the master)
                if now >= master_at:
                    deadline = drive.watch_master(now)
                    master_at = now + interval
                    if deadline is not None:
                        master_at = min(deadline, master_at)
                if master_at < now + longest:
                    longest = max(0.0, master_at - now)
            timeout = own.wait_s(now, longest)
        else:
            timeout = watch.wait_s(now, interval) if busy_poll else interval
        try:
            cob_id = port.receive(timeout)
            if cob_id == NOTHING:
                if own is not None:
                    _own_cycles(drive, own, wall())
                    overdue_frames = 0
                continue
            received, received_epoch = wall(), epoch()
            synced = take(cob_id, port, handle)
        except (can.CanError, OSError) as exc:  # e.g. a datagram that is no CAN frame
            counts.receive_errors += 1
            logger.warning("drive %d: receive failed, frame ignored: %s", drive.node_id, exc)
            continue
        due = None if own is None or synced else own.due_s
        if due is not None and received - due >= cycle_s:
            # own cycles overdue: they run once the socket is empty (every frame that came
            # before their instants read: the master's heartbeat among them); a flood that
            # never lets it empty must not hold the clock: after so many frames they run
            overdue_frames += 1
            if overdue_frames >= OWN_CLOCK_DRAIN_FRAMES:
                _own_cycles(drive, own, received)  # type: ignore[arg-type]
                overdue_frames = 0
        else:
            overdue_frames = 0
        if synced:  # a SYNC: answered, the physics stepped
            # the frame's own timestamp (epoch s: the kernel's receive time where the port
            # has it, python-can's messages) says how long it waited for this thread; a
            # plausible age dates the SYNC back to its arrival, so a late wake-up does not
            # shift the next window (a raw socket's port: the time it was read, age <= 0)
            age = received_epoch - port.timestamp
            watch.synced(received - age if 0.0 <= age < cycle_s else received)
            if own is not None:
                own.synced(received)
            if gc_control is not None and gc_control.due():
                gc_control.collect()
        else:
            watch.received()


#: At rest with the power stage off the own clock looks this often whether it has to run.
OWN_CLOCK_IDLE_S = 0.05


def _own_cycles(drive: SimulatedDrive, own: OwnClock, now: float) -> None:
    """Run the cycles of the drive's own clock due at ``now`` (none at rest, power off)."""
    first, n = own.due(now)
    if not n:
        return
    if not (own.moving or drive.holding):
        own.idle(now, OWN_CLOCK_IDLE_S)
        return
    own.running = True
    cycle_s = own.cycle_s
    for i in range(n):
        # the master's heartbeat checked at the cycle's own instant: a drive held off its
        # CPU reacts in the cycle its clock says, not when it gets the CPU back
        drive.watch_master(first + i * cycle_s)
        own.moving = drive.free_cycle()

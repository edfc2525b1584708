"""The real-time loop against a scripted drive on an injected clock (no sleeps, no threads).

The fake bus answers each SYNC at once with the two TPDOs of a drive in Operation Enabled and
moves a fake wall clock: a receive that times out advances it by the timeout, a stall
scripted for a cycle parks the "process" for that long after its RPDO (or while it waits for
the next slot). Checked against the schedule itself (SYNC instants on the grid t0 + k*cycle),
not against the loop's own bookkeeping only.
"""

from __future__ import annotations

import gc
import itertools
import math

import can
import pytest

from bridge.cycle import BridgeState, StopReason
from bridge.cyclecore import Functions
from bridge.layout import RPDO1_STRUCT, SYNC_COB_ID, TPDO1_STRUCT, TPDO2_STRUCT
from bridge.node import Bridge, BridgeConfig
from bridge.params import BridgeParams
from bridge.timing import RealTimePacer
from virtual_bus.errors import RealTimeRefused
from virtual_bus.formats.axis import load_axis
from virtual_bus.realtime import GcBetweenCycles, RealTimeOptions, apply_realtime

AXIS = load_axis("config/paper_axis.toml")
CYCLE_S = AXIS.control.position_cycle
DRIVE_ID = 2
OPERATION_ENABLED = 0x0027


class Clock:
    """Fake wall clock; each reading takes 1 µs (so a loop polling it moves on)."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        self.t += 1e-6
        return self.t


class ScriptedBus:
    """Duck-typed python-can bus on a fake clock (see the module docstring)."""

    channel_info = "scripted"

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.queue: list[can.Message] = []
        self.sync_times: list[float] = []
        self.rpdos: list[tuple[int, int]] = []
        self.stall_after_rpdo: dict[int, float] = {}  # cycle (RPDO count) -> stall, s
        self.stall_in_wait: dict[int, float] = {}  # SYNCs sent -> stall in the next idle wait
        self.fail_send: set[int] = set()  # RPDO numbers whose send raises
        self.answer_s = 50e-6  # the drive's answer after SYNC
        self.flood = 0  # a tool floods the bus: this many frames, one always waiting
        self.work_after_rpdo: dict[int, float] = {}  # cycle -> the loop computes this long, s
        self.off_cpu = 0.0  # time the loop's thread did not run: stalls and sleeps, s

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == SYNC_COB_ID:
            self.sync_times.append(self.clock.t)
            self.clock.t += self.answer_s
            self.queue.append(self._frame(0x180 + DRIVE_ID, TPDO1_STRUCT.pack(0, 0)))
            self.queue.append(
                self._frame(0x280 + DRIVE_ID, TPDO2_STRUCT.pack(OPERATION_ENABLED, 0, 0))
            )
        elif msg.arbitration_id == 0x200 + DRIVE_ID:
            n = len(self.rpdos)
            if n in self.fail_send:
                self.fail_send.discard(n)
                self.rpdos.append((-1, -1))
                raise can.CanOperationError("transmit buffer full")
            self.rpdos.append(RPDO1_STRUCT.unpack(msg.data))
            stall = self.stall_after_rpdo.get(n, 0.0)
            self.clock.t += 20e-6 + stall + self.work_after_rpdo.get(n, 0.0)
            self.off_cpu += stall

    @staticmethod
    def _frame(can_id: int, data: bytes) -> can.Message:
        return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)

    def recv(self, timeout: float | None) -> can.Message | None:
        if self.queue:
            return self.queue.pop(0)
        if self.flood:
            self.flood -= 1
            self.clock.t += 2e-6
            return self._frame(0x601, bytes(8))
        stall = self.stall_in_wait.pop(len(self.sync_times), 0.0) + max(timeout or 0.0, 1e-6)
        self.clock.t += stall
        self.off_cpu += stall
        return None

    def cpu(self) -> float:
        """The loop thread's CPU clock: the wall clock less the time it did not run."""
        return self.clock.t - self.off_cpu


def make_bridge(
    clock: Clock, bus: ScriptedBus, overrun_limit: int | None = 3, **pacer: float
) -> Bridge:
    bridge = Bridge(
        bus,  # type: ignore[arg-type]
        BridgeParams.for_axis(AXIS),
        AXIS.kind,
        RealTimePacer(CYCLE_S, wall=clock, **pacer),
        config=BridgeConfig(drive_id=DRIVE_ID),
        keep_timing=True,
        wall=clock,
        overrun_limit=overrun_limit,
        cpu=bus.cpu,
    )
    bridge.start(configure_drive=False)
    return bridge


def slots_of(bus: ScriptedBus, pacer: RealTimePacer) -> list[int]:
    """Slot number of every SYNC sent; each must leave within ``late_s`` after its slot
    instant t0 + k * cycle of the schedule."""
    t0 = pacer.begin_cycle(0)  # the schedule's origin
    assert t0 is not None
    slots = []
    for t in bus.sync_times:
        k = math.floor((t - t0) / CYCLE_S + 1e-9)
        assert 0.0 <= t - (t0 + k * CYCLE_S) <= pacer.late_s + 1e-12, (t, k)
        slots.append(k)
    return slots


def test_a_late_loop_skips_slots_and_never_bunches_syncs() -> None:
    clock = Clock()
    bus = ScriptedBus(clock)
    bus.stall_after_rpdo[5] = 2.5 * CYCLE_S  # parked 2.5 cycles after cycle 5
    bridge = make_bridge(clock, bus)
    bridge.run(cycles=20)
    slots = slots_of(bus, bridge.pacer)  # type: ignore[arg-type]
    assert slots[:6] == [0, 1, 2, 3, 4, 5]
    assert slots[6] == 8  # slots 6 and 7 skipped, 8 on time: no catch-up burst
    assert all(b - a >= 1 for a, b in itertools.pairwise(slots))
    assert all(
        b - a >= CYCLE_S * (1 - 0.2)
        for a, b in zip(bus.sync_times, bus.sync_times[1:], strict=False)
    )
    timing = bridge.timing
    assert timing.skipped_syncs == 2 and timing.overruns == 1
    assert bridge.controller.state is BridgeState.RUNNING  # one overrun: counted only


@pytest.mark.parametrize("host", [True, False], ids=["host-stall", "own-work"])
def test_a_skipped_slot_is_the_hosts_or_the_loops_own(host: bool) -> None:
    """The same 2.5 cycles after cycle 5: the loop parked (off the CPU: the host's) or
    computing (its own work, on the CPU); and a late wake-up while waiting is the host's."""
    clock = Clock()
    bus = ScriptedBus(clock)
    (bus.stall_after_rpdo if host else bus.work_after_rpdo)[5] = 2.5 * CYCLE_S
    bus.stall_in_wait[12] = 0.5 * CYCLE_S  # woken half a cycle late before SYNC 12
    bridge = make_bridge(clock, bus, overrun_limit=None)
    bridge.run(cycles=20)
    timing = bridge.timing
    assert timing.skipped_syncs == 3 and timing.overruns == 2
    assert (timing.own_skipped, timing.host_skipped) == ((0, 3) if host else (2, 1))
    assert (timing.own_overruns, timing.host_overruns) == ((0, 2) if host else (1, 1))
    own = timing.work_cpu_s[:5]
    assert 0.0 < own.max() < 0.1 * CYCLE_S  # the loop's own work is short on this bus


def test_preempted_while_waiting_the_slot_is_skipped_not_sent_late() -> None:
    clock = Clock()
    bus = ScriptedBus(clock)
    bus.stall_in_wait[4] = 0.9 * CYCLE_S  # after SYNC 3, parked during the wait for slot 4
    bridge = make_bridge(clock, bus)
    bridge.run(cycles=10)
    slots = slots_of(bus, bridge.pacer)  # type: ignore[arg-type]
    assert 4 not in slots and slots[4] == 5
    assert bridge.timing.skipped_syncs == 1
    assert max(bridge.timing.sync_late_s) <= bridge.pacer.late_s  # type: ignore[attr-defined]


@pytest.mark.parametrize(("pattern", "stops"), [("every", True), ("every_other", False)])
def test_overruns_in_a_row_stop_the_axis(pattern: str, stops: bool) -> None:
    clock = Clock()
    bus = ScriptedBus(clock)
    step = 1 if pattern == "every" else 2
    for n in range(10, 40, step):
        bus.stall_after_rpdo[n] = 1.5 * CYCLE_S
    bridge = make_bridge(clock, bus, overrun_limit=3)
    bridge.run(cycles=30)
    c = bridge.controller
    if stops:
        assert c.state is BridgeState.STOPPED and c.stop_reason is StopReason.CYCLE_OVERRUN
        assert "3 cycles in a row" in c.stop_message
        assert bus.rpdos[-1] == (0x0002, 0)  # quick stop, no set point
        assert bridge.timing.max_consecutive_overruns >= 3
    else:
        assert c.state is BridgeState.RUNNING
        assert bridge.timing.overruns > 5 and bridge.timing.max_consecutive_overruns == 1


def test_counting_only_never_stops() -> None:
    clock = Clock()
    bus = ScriptedBus(clock)
    for n in range(5, 30):
        bus.stall_after_rpdo[n] = 1.5 * CYCLE_S
    bridge = make_bridge(clock, bus, overrun_limit=None)
    bridge.run(cycles=25)
    assert bridge.controller.state is BridgeState.RUNNING
    assert bridge.timing.max_consecutive_overruns >= 19


def test_errors_on_the_cycle_path_are_counted_not_raised(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    bus = ScriptedBus(clock)
    bus.fail_send.add(3)
    bridge = make_bridge(clock, bus)

    def broken_notify(can_id: int, data: bytearray, timestamp: float) -> None:
        raise ValueError("malformed request")

    bridge.network.notify = broken_notify  # type: ignore[method-assign]
    bus.queue.append(can.Message(arbitration_id=0x601, data=bytes(8), is_extended_id=False))
    bridge.run(cycles=10)
    assert bridge.timing.errors == 2  # the failed RPDO send and the failed frame
    assert bridge.controller.state is BridgeState.RUNNING
    assert len(bus.sync_times) == 10
    assert "transmit buffer full" in caplog.text and "malformed request" in caplog.text


def test_a_failing_controller_step_stops_the_axis() -> None:
    clock = Clock()
    bus = ScriptedBus(clock)
    bridge = make_bridge(clock, bus)
    bridge.run(cycles=3)
    c = bridge.controller

    def failing(*args: object) -> tuple[int, int]:
        raise ZeroDivisionError("bug")

    c.core = Functions(c.core.measure, failing, failing, compiled=False)
    bridge.run(cycles=2)
    assert c.stop_reason is StopReason.INTERNAL_ERROR and "bug" in c.stop_message
    assert bus.rpdos[-1] == (0x0002, 0)


def test_service_frames_wait_for_time_between_cycles() -> None:
    """300 SDO requests at once, each taking 0.3 ms to handle: every SYNC stays on its slot,
    the requests are handled over the following cycles, and those the ring cannot hold are
    counted as dropped."""
    clock = Clock()
    bus = ScriptedBus(clock)
    bridge = make_bridge(clock, bus)
    handled: list[float] = []

    def slow_notify(can_id: int, data: bytearray, timestamp: float) -> None:
        clock.t += 0.3 * CYCLE_S
        handled.append(clock.t)

    bridge.network.notify = slow_notify  # type: ignore[method-assign]
    bridge.run(cycles=2)
    for _ in range(300):
        bus.queue.append(can.Message(arbitration_id=0x601, data=bytes(8), is_extended_id=False))
    bridge.run(cycles=200)
    slots = slots_of(bus, bridge.pacer)  # type: ignore[arg-type]
    assert slots == list(range(202))
    assert bridge.timing.skipped_syncs == 0
    dropped = bridge.timing.service_dropped
    assert dropped > 0 and dropped + len(handled) == 300
    assert handled[-1] - handled[0] > 50 * CYCLE_S  # spread over many cycles


def test_a_flood_of_frames_moves_no_sync() -> None:
    """A tool floods the bus with SDO requests (a frame always waiting): every SYNC still
    leaves on its slot and the TPDOs are still used; the requests are served in between."""
    clock = Clock()
    bus = ScriptedBus(clock)
    bridge = make_bridge(clock, bus)
    handled: list[int] = []
    notify = lambda can_id, data, ts: handled.append(can_id)  # noqa: E731
    bridge.network.notify = notify  # type: ignore[method-assign]
    bridge.run(cycles=2)
    # ~10 000 frames fit in 50 cycles; a loop reading until the bus is quiet would hold its
    # SYNC until the flood ends
    bus.flood = 100_000
    bridge.run(cycles=50)
    assert slots_of(bus, bridge.pacer) == list(range(52))  # type: ignore[arg-type]
    assert bridge.counters.missed_cycles == 0
    assert len(handled) > 50 * 10  # the flood was served between cycles meanwhile


def test_the_loop_collects_garbage_only_between_cycles() -> None:
    """With the collector frozen, the loop collects only while the next SYNC is more than the
    service guard away, and collections happen (the allocations of the cycles add up)."""
    clock = Clock()
    bus = ScriptedBus(clock)
    control = GcBetweenCycles(threshold=50)
    bridge = Bridge(
        bus,  # type: ignore[arg-type]
        BridgeParams.for_axis(AXIS),
        AXIS.kind,
        RealTimePacer(CYCLE_S, wall=clock),
        config=BridgeConfig(drive_id=DRIVE_ID),
        wall=clock,
        gc_control=control,
    )
    bridge.start(configure_drive=False)
    pacer = bridge.pacer
    assert isinstance(pacer, RealTimePacer)
    margins: list[float] = []
    collect = control.collect

    def recorded() -> None:
        t0 = pacer.begin_cycle(0)
        assert t0 is not None
        next_slot = t0 + math.ceil((clock.t - t0) / CYCLE_S) * CYCLE_S
        margins.append(next_slot - clock.t)
        assert not gc.isenabled()
        collect()

    control.collect = recorded  # type: ignore[method-assign]
    bridge.run(cycles=200)
    assert gc.isenabled()  # given back after the run
    assert len(margins) >= 2
    assert min(margins) > bridge.service_guard_s
    assert bridge.timing.skipped_syncs == 0


def test_real_time_options_are_checked_and_off_by_default() -> None:
    assert not RealTimeOptions().any
    with pytest.raises(ValueError, match=r"1\.\.99"):
        RealTimeOptions(rt_priority=0)
    with pytest.raises(ValueError, match="CPU number"):
        RealTimeOptions(cpu=-1)
    assert apply_realtime(RealTimeOptions()) == []


def test_a_cpu_the_process_may_not_use_is_refused_in_one_line() -> None:
    import os

    cpu = max(os.sched_getaffinity(0)) + 64
    with pytest.raises(RealTimeRefused) as info:
        apply_realtime(RealTimeOptions(cpu=cpu))
    assert info.value.setting == "cpu" and "\n" not in str(info.value)
    assert str(cpu) in str(info.value)


def test_gc_runs_only_when_the_loop_calls_it() -> None:
    was = gc.isenabled()
    control = GcBetweenCycles(threshold=10)
    control.start()
    try:
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        junk = [[i] for i in range(50)]  # allocations the collector would otherwise act on
        assert control.due()
        control.collect()
        assert gc.get_count()[0] < 10 and junk
    finally:
        control.stop()
    assert gc.isenabled() == was and gc.get_freeze_count() == 0


@pytest.mark.parametrize("lost_first", [1, 3])
def test_a_late_first_answer_does_not_knock_the_drive_out_of_operation_enabled(
    lost_first: int,
) -> None:
    """After the start-up the drive is in Operation Enabled. If the first SYNCs bring no
    statusword (answered after the window), the controller repeats 000Fh instead of
    commanding a transition from a state it never read; checked against the simulated
    drive's own CiA 402 state machine (plant_sim.drive.cia402)."""
    from bridge.cycle import CW_RUNNING
    from plant_sim.drive import cia402
    from tests.bridge_helpers import PayloadDrive, controller  # tests/ helper module

    c = controller()  # ENABLING, as after Bridge.start()
    c.controlword = CW_RUNNING  # what Bridge.start() leaves after the SDO start-up
    fsm = cia402.StateMachine()
    fsm.state = cia402.State402.OPERATION_ENABLED
    drive = PayloadDrive(AXIS)
    for k in range(lost_first + 5):
        tpdo1, _ = drive.tpdos()
        sw = cia402.status_bits(fsm.state)
        tpdo2 = None if k < lost_first else TPDO2_STRUCT.pack(sw, 0, 0)
        rpdo = c.step(k * CYCLE_S, tpdo1, tpdo2)
        cw, _ = RPDO1_STRUCT.unpack(rpdo)
        fsm.controlword_written(cw, quick_stop_stays=False, fault_cleared=lambda: True)
        assert fsm.state is cia402.State402.OPERATION_ENABLED, (k, hex(cw))
    assert c.state is BridgeState.RUNNING

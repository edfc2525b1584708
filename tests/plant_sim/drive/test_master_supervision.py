"""The drive supervises its master as CiA 301 and CiA 402 say: a heartbeat consumer (1016h)
watching the master's heartbeat, and a lost heartbeat, the master's boot-up, or an NMT
command that takes the enabled drive out of Operational acting through 6007h -- with an EMCY
that names the cause and, for a quick stop, the motor ramped to standstill.

The master is this test: frames on a python-can end of the bus (SYNC, RPDO1, its heartbeat),
where it also reads the drive's EMCYs in the bus's order (CiA 301: code, 1001h, 5 bytes);
python canopen's own RemoteNode configures the drive over SDO and sends NMT. States are
decoded from the TPDO2 statusword with ``canopen.profiles.p402`` (``bridge.cycle.
drive_state``), not with the drive's own state machine. Lockstep: the drive's clock is the
SYNC count, so every instant below is exact. Real time: the drive's own clock
(``plant_sim.drive.process``) is driven with an injected time, as the serving loop drives
it.
"""

from __future__ import annotations

import math
import struct

import pytest

from bridge.cycle import Drive402State, drive_state
from plant_sim.drive import DriveConfig, TimeMode
from plant_sim.drive.process import OWN_CLOCK_GRACE_FRACTION, OwnClock, _own_cycles
from plant_sim.drive.rig import Rig, virtual_rig
from virtual_bus.formats.axis import AxisConfig, load_axis

AXIS_FILE = "config/paper_axis.toml"
INC_PER_RAD = 2**20 / (2 * math.pi)
MASTER = 1
HEARTBEAT_MS = 100
CONSUMER_MS = 250
SPEED_RAD_S = 15.0
#: Backstop of each wait for the drive's answer (a stuck thread, never reached when all is
#: well; the drive answers in its notifier thread).
BOUND_S = 60.0

S = Drive402State


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(AXIS_FILE)


class Master:
    """The test as the drive's master: SYNC + RPDO1 each cycle, its heartbeat on demand."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.probe = rig.probe
        self.probe.timeout_s = BOUND_S
        self.node = rig.sdo
        self.node.sdo.RESPONSE_TIMEOUT = BOUND_S
        self.syncs = 0
        #: the drive's EMCYs so far: (code, error register, manufacturer bytes)
        self.emcy: list[tuple[int, int, bytes]] = []

    def _take_emcys(self) -> None:
        seen = self.probe.seen
        for msg in [m for m in seen if m.arbitration_id == 0x082]:
            seen.remove(msg)
            code, register = struct.unpack_from("<HB", msg.data)
            self.emcy.append((code, register, bytes(msg.data[3:])))

    def heartbeat(self, state: int = 0x05) -> None:
        self.probe.send(0x700 + MASTER, bytes([state]))

    def cycle(self, controlword: int = 0x0F, speed_rad_s: float = SPEED_RAD_S) -> tuple[S, float]:
        """RPDO1, then SYNC; the drive's state and motor speed (rad/s) from its TPDO2."""
        self.probe.setpoint(controlword, round(speed_rad_s * INC_PER_RAD))
        return self.sync()

    def sync(self) -> tuple[S, float]:
        got = self.probe.sync_and_collect([0x182, 0x282])
        self._take_emcys()
        self.syncs += 1
        statusword, _torque, velocity = struct.unpack("<HhI", got[0x282])
        velocity = struct.unpack("<i", struct.pack("<I", velocity))[0]
        return drive_state(statusword), velocity / INC_PER_RAD

    def enable(self, watch: bool = True) -> None:
        if watch:
            self.node.sdo[0x1016][1].raw = (MASTER << 16) | CONSUMER_MS
        self.node.nmt.state = "OPERATIONAL"
        for controlword in (0x06, 0x07, 0x0F):
            self.cycle(controlword, 0.0)
        assert self.cycle()[0] is S.OPERATION_ENABLED

    def drain(self) -> None:
        """Take what waits on the test's end of the bus (EMCYs kept)."""
        self.probe.seen = self.probe.drain()  # the frames already seen and those waiting
        self._take_emcys()
        self.probe.seen.clear()

    def emcys(self, code: int) -> list[bytes]:
        return [data for c, _, data in self.emcy if c == code]


def _ramp_cycles(master: Master, speed_rad_s: float, cycle_s: float) -> int:
    """Cycles of the quick stop ramp from ``speed_rad_s`` at 6085h (CiA 402: the drive's
    quick stop deceleration, read over SDO): speed / deceleration, in whole cycles."""
    decel_rad_s2 = master.node.sdo[0x6085].raw / INC_PER_RAD
    return math.ceil(abs(speed_rad_s) / (decel_rad_s2 * cycle_s))


def test_a_lost_heartbeat_stops_the_motor_at_consumer_time_with_an_emcy(
    axis: AxisConfig,
) -> None:
    """CiA 301: the watch starts with the first heartbeat; none for 250 ms of the drive's
    clock (250 SYNCs of 1 ms in lockstep) and the drive reacts at the first SYNC after that,
    per 6007h (3: quick stop): EMCY 8130h (1016h, node 1, option 3), the ramp of 6085h, then
    Switch On Disabled at standstill (605Ah = 2)."""
    cycle_s = axis.control.position_cycle
    with virtual_rig(axis) as rig:
        master = Master(rig)
        master.enable()
        assert master.node.sdo[0x6007].raw == 3  # quick stop, the drive's default
        last = 0
        for k in range(3 * HEARTBEAT_MS):  # moving at 15 rad/s, the heartbeat every 100 ms
            if k % HEARTBEAT_MS == 0:
                master.heartbeat()
                last = master.syncs  # received before this SYNC: at the drive's time `last`
            state, speed = master.cycle()
            assert state is S.OPERATION_ENABLED
        assert speed == pytest.approx(SPEED_RAD_S, rel=0.01)
        # the master's heartbeat stops (its set points go on: a thread of it died)
        states = []
        while True:
            states.append(master.cycle()[0])
            if states[-1] is not S.OPERATION_ENABLED:
                break
        # reacted at the end of the first SYNC cycle whose time is more than 250 ms after the
        # heartbeat; the next SYNC's TPDO shows it: consumer time + 2 cycles
        assert master.syncs - last == round(CONSUMER_MS * 1e-3 / cycle_s) + 2
        assert states[-1] is S.QUICK_STOP_ACTIVE
        assert master.emcys(0x8130) == [bytes([0x16, 0x10, MASTER, 3, 0])]
        assert [r for c, r, _ in master.emcy if c == 0x8130] == [0x11]  # generic + comm.
        ramp = 0
        while (got := master.cycle())[0] is S.QUICK_STOP_ACTIVE:
            ramp += 1
        expected = _ramp_cycles(master, SPEED_RAD_S, cycle_s)
        # no faster than 6085h allows; the speed loop settles behind the ramp, well within
        # its length again (a coasting motor, power off, takes ~1.4 s from 15 rad/s)
        assert expected <= ramp <= 2 * expected, (ramp, expected)
        assert got[0] is S.SWITCH_ON_DISABLED and abs(got[1]) <= 0.1
        assert master.node.sdo[0x603F].raw == 0x8130  # the cause stays readable


def test_the_masters_boot_up_is_a_lost_connection(axis: AxisConfig) -> None:
    """A boot-up (00h) of the watched master while it was watched: it restarted, its session
    with the drive is gone -- the same reaction at once, the EMCY's last byte 1."""
    with virtual_rig(axis) as rig:
        master = Master(rig)
        master.enable()
        master.heartbeat()
        assert master.cycle()[0] is S.OPERATION_ENABLED
        master.heartbeat(0x00)
        assert master.cycle()[0] is S.QUICK_STOP_ACTIVE
        assert master.emcys(0x8130) == [bytes([0x16, 0x10, MASTER, 3, 1])]


def test_no_reaction_before_the_first_heartbeat_nor_while_it_comes(axis: AxisConfig) -> None:
    """CiA 301: the watch starts with the first heartbeat after 1016h is written; a master
    whose heartbeat keeps coming is never taken for lost."""
    with virtual_rig(axis) as rig:
        master = Master(rig)
        master.enable()
        for _ in range(2 * CONSUMER_MS):  # no heartbeat yet: not watched
            assert master.cycle()[0] is S.OPERATION_ENABLED
        for k in range(5 * CONSUMER_MS):
            if k % HEARTBEAT_MS == 0:
                master.heartbeat()
            assert master.cycle()[0] is S.OPERATION_ENABLED
        assert not master.node.emcy.log


def test_fault_reaction_and_fault_reset_only_once_the_heartbeat_is_back(
    axis: AxisConfig,
) -> None:
    """6007h = 1: Fault; a fault reset is refused while the master's heartbeat is missing;
    its heartbeat back clears the error (EMCY 0000h) and the reset is granted."""
    with virtual_rig(axis) as rig:
        master = Master(rig)
        master.node.sdo[0x6007].raw = 1
        master.enable()
        master.heartbeat()
        while (state := master.cycle()[0]) is S.OPERATION_ENABLED:
            pass
        while state is not S.FAULT:  # the fault reaction ramp, then Fault
            state = master.cycle(0x0F)[0]
        assert master.emcys(0x8130) == [bytes([0x16, 0x10, MASTER, 1, 0])]
        master.cycle(0x00, 0.0)
        assert master.cycle(0x80, 0.0)[0] is S.FAULT  # the cause is still there
        master.heartbeat()
        master.cycle(0x00, 0.0)
        assert master.cycle(0x80, 0.0)[0] is S.SWITCH_ON_DISABLED
        assert master.emcys(0x0000)  # error reset
        assert master.node.sdo[0x1001].raw == 0


@pytest.mark.parametrize("command", ["PRE-OPERATIONAL", "STOPPED"])
@pytest.mark.parametrize(
    ("option", "reaction"),
    [
        (0, [S.OPERATION_ENABLED]),
        (1, [S.FAULT_REACTION_ACTIVE, S.FAULT]),
        (2, [S.SWITCH_ON_DISABLED]),
        (3, [S.QUICK_STOP_ACTIVE, S.SWITCH_ON_DISABLED]),
    ],
)
def test_nmt_out_of_operational_while_enabled_acts_per_6007h(
    axis: AxisConfig, command: str, option: int, reaction: list[S]
) -> None:
    """CiA 402 6007h (NMT Stopped entered; and Pre-operational, where no set point comes any
    more): the reaction of ``option``; SYNCs go on running the physics (the machine's time),
    so a quick stop reaches standstill. The drive's state is read from its statusword over
    SDO (Pre-operational) or, in Stopped (no SDO, no PDO, CiA 301 table 46), after the NMT
    start that follows; in Pre-operational its EMCY 8100h names the NMT command."""
    cycle_s = axis.control.position_cycle
    with virtual_rig(axis) as rig:
        master = Master(rig)
        master.node.sdo[0x6007].raw = option
        master.enable(watch=False)
        for _ in range(200):
            master.cycle()
        ramp = _ramp_cycles(master, SPEED_RAD_S, cycle_s)  # read while SDO is answered
        master.node.nmt.state = command
        for _ in range(2 * ramp):
            master.probe.sync()  # no TPDOs outside Operational: SYNC alone
        if command == "STOPPED":
            master.node.nmt.state = "OPERATIONAL"
        assert master.node.sdo[0x1000].raw  # answered: every frame before it was handled
        master.drain()
        state = drive_state(master.node.sdo[0x6041].raw)
        assert state is reaction[-1]
        speed = master.node.sdo[0x606C].raw / INC_PER_RAD
        if option in (1, 3):  # a ramp: at standstill now
            assert abs(speed) <= 0.1
        specifier = {"PRE-OPERATIONAL": 0x80, "STOPPED": 0x02}[command]
        got = master.emcys(0x8100)
        if command == "PRE-OPERATIONAL":
            assert got == [bytes([0, 0, specifier, option, 0])]
        else:
            assert got == []  # CiA 301: no EMCY in Stopped


# --- real time: the drive's own clock -------------------------------------------------------
class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_without_sync_the_motor_goes_on_then_the_consumer_stops_it(axis: AxisConfig) -> None:
    """Real time: after the last SYNC the drive runs cycles of its own on the last set point
    (the load moves on at the commanded speed: x = x0 + omega / k_r * t), until its
    heartbeat consumer finds the master lost -- in the own cycle whose instant is first more
    than 250 ms after the last heartbeat -- and the quick stop brings the motor to rest; at
    rest with the power stage off its clock runs no more cycles."""
    cycle_s = axis.control.position_cycle
    clock = Clock()
    with virtual_rig(axis, config=DriveConfig(time_mode=TimeMode.REAL_TIME)) as rig:
        drive = rig.drive
        drive.wall = clock
        master = Master(rig)
        master.enable()
        master.heartbeat()
        last_heartbeat = clock.t  # its time on the drive's clock:
        assert master.node.sdo[0x1000].raw  # handled before the clock moves on
        for _ in range(100):
            clock.t += cycle_s
            master.cycle()
        own = OwnClock(cycle_s, OWN_CLOCK_GRACE_FRACTION * cycle_s)
        own.synced(clock.t)  # the last SYNC; then none
        x0 = drive.plant.load_position
        t0 = clock.t
        instants = []  # the own cycles' instants on the drive's clock
        while drive.state.name == "OPERATION_ENABLED":
            clock.t += cycle_s
            due, before = own.due_s, drive.free_cycles
            _own_cycles(drive, own, clock.t)
            assert drive.free_cycles - before in (0, 1)
            if drive.free_cycles > before:
                instants.append(due)
        # the load went on at the commanded speed meanwhile (the speed loop holds it)
        travelled = drive.plant.load_position - x0
        expected = SPEED_RAD_S / axis.transmission_ratio * (clock.t - t0)
        assert travelled == pytest.approx(expected, rel=0.02)
        # the reaction: in the first own cycle more than 250 ms after the last heartbeat
        late = [t - last_heartbeat - CONSUMER_MS * 1e-3 for t in instants]
        assert late[-1] > 0 and all(x <= 1e-9 for x in late[:-1])
        assert late[-1] <= cycle_s + 1e-9  # within the consumer time and a cycle
        master.drain()
        assert master.emcys(0x8130) == [bytes([0x16, 0x10, MASTER, 3, 0])]
        # the quick stop ramp on the drive's own clock, to standstill, then no cycles
        for _ in range(_ramp_cycles(master, SPEED_RAD_S, cycle_s) + 200):
            clock.t += cycle_s
            _own_cycles(drive, own, clock.t)
        assert drive.state.name == "SWITCH_ON_DISABLED"
        assert abs(drive.plant.motor_speed_rad_s) <= 0.1
        # power off: the motor coasts out (in the backlash, its friction on the load side)
        # until no measuring system moves any more; then the clock runs no more cycles
        for _ in range(round(10.0 / cycle_s)):
            if not own.moving:
                break
            clock.t += cycle_s
            _own_cycles(drive, own, clock.t)
        assert not own.moving
        resting, position = drive.free_cycles, drive.plant.motor_position_rad
        for _ in range(100):
            clock.t += cycle_s
            _own_cycles(drive, own, clock.t)
        assert drive.free_cycles == resting
        assert drive.plant.motor_position_rad == position


def test_the_own_clock_fills_a_missed_sync_once_and_catches_up_a_second_at_most() -> None:
    cycle = 0.001
    own = OwnClock(cycle, OWN_CLOCK_GRACE_FRACTION * cycle)
    assert own.due(5.0) == (5.0, 0)  # before the first SYNC: nothing
    own.synced(10.0)
    assert own.due(10.0 + cycle)[1] == 0  # the next SYNC is due now: wait for it
    first, n = own.due(10.0 + 1.6 * cycle)  # it did not come half a cycle after
    assert (first, n) == (pytest.approx(10.0 + 1.5 * cycle), 1)
    own.synced(10.0 + 2.0 * cycle)  # it came a cycle late: no second own cycle for it
    assert own.due(10.0 + 3.2 * cycle)[1] == 0
    first, n = own.due(20.0)  # held off the CPU for ten seconds: one second of cycles
    assert n == round(1.0 / cycle) and first == pytest.approx(19.0 + 0.5 * cycle, abs=cycle)

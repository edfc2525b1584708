"""CiA 402 state machine of the simulated drive, NMT, boot-up and heartbeat.

The expected transitions, controlwords and statusword patterns are written out here as the
standard prints them (CiA 402 / IEC 61800-7-201), independently of the tables in
``plant_sim.drive.cia402``.
"""

from __future__ import annotations

import math
import struct
import uuid

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from plant_sim.drive import (
    DriveConfig,
    Event,
    NmtCommand,
    NmtState,
    SimulatedDrive,
    State402,
    StateMachine,
    TimeMode,
)
from plant_sim.drive.rig import BusProbe, Rig, virtual_rig
from tests.paths import ROOT
from virtual_bus.formats.axis import AxisConfig, load_axis

REPO = ROOT
S = State402

# controlwords of the device control commands (bits 7, 3..0)
SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP, FAULT_RESET = (
    0x06,
    0x07,
    0x0F,
    0x00,
    0x02,
    0x80,
)
COMMANDS = (SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP, FAULT_RESET)

# statusword patterns, bits 7..0 as printed in the standard ("x" = any)
PATTERNS = {
    S.NOT_READY_TO_SWITCH_ON: "x0xx0000",
    S.SWITCH_ON_DISABLED: "x1xx0000",
    S.READY_TO_SWITCH_ON: "x01x0001",
    S.SWITCHED_ON: "x01x0011",
    S.OPERATION_ENABLED: "x01x0111",
    S.QUICK_STOP_ACTIVE: "x00x0111",
    S.FAULT_REACTION_ACTIVE: "x0xx1111",
    S.FAULT: "x0xx1000",
}


def matching_states(statusword: int) -> list[State402]:
    """States whose printed pattern the low byte of ``statusword`` matches."""
    out = []
    for state, pattern in PATTERNS.items():
        bits = [(statusword >> (7 - i)) & 1 for i in range(8)]
        if all(p == "x" or int(p) == b for p, b in zip(pattern, bits, strict=True)):
            out.append(state)
    return out


def reach(sm: StateMachine, state: State402) -> None:
    """Drive a fresh state machine (Switch on disabled) to ``state``."""
    cleared = {"quick_stop_stays": False, "fault_cleared": lambda: True}
    path = {
        S.SWITCH_ON_DISABLED: [],
        S.READY_TO_SWITCH_ON: [SHUTDOWN],
        S.SWITCHED_ON: [SHUTDOWN, SWITCH_ON],
        S.OPERATION_ENABLED: [SHUTDOWN, SWITCH_ON, ENABLE],
        S.QUICK_STOP_ACTIVE: [SHUTDOWN, SWITCH_ON, ENABLE, QUICK_STOP],
    }
    if state is S.NOT_READY_TO_SWITCH_ON:
        return
    sm.event(Event.INITIALISED)
    if state in (S.FAULT_REACTION_ACTIVE, S.FAULT):
        sm.event(Event.FAULT)
        if state is S.FAULT:
            sm.event(Event.FAULT_REACTION_COMPLETED)
    else:
        for cw in path[state]:
            sm.controlword_written(cw, **cleared)
    assert sm.state is state


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(REPO / "config" / "paper_axis.toml")


# ------------------------------------------------------------------------------------------
# the pure state machine
# ------------------------------------------------------------------------------------------
def test_power_on_is_transition_0_then_1() -> None:
    sm = StateMachine()
    assert sm.state is S.NOT_READY_TO_SWITCH_ON
    assert (
        sm.controlword_written(SHUTDOWN, quick_stop_stays=False, fault_cleared=lambda: True) == ()
    )
    transition = sm.event(Event.INITIALISED)
    assert transition is not None and transition.number == 1
    assert sm.state is S.SWITCH_ON_DISABLED


# (from, controlword, 605Ah stays in QSA, transitions, to)
COMMAND_TRANSITIONS = [
    (S.SWITCH_ON_DISABLED, SHUTDOWN, False, [2], S.READY_TO_SWITCH_ON),
    (S.READY_TO_SWITCH_ON, SWITCH_ON, False, [3], S.SWITCHED_ON),
    (S.READY_TO_SWITCH_ON, ENABLE, False, [3, 4], S.OPERATION_ENABLED),
    (S.SWITCHED_ON, ENABLE, False, [4], S.OPERATION_ENABLED),
    (S.OPERATION_ENABLED, SWITCH_ON, False, [5], S.SWITCHED_ON),
    (S.SWITCHED_ON, SHUTDOWN, False, [6], S.READY_TO_SWITCH_ON),
    (S.READY_TO_SWITCH_ON, QUICK_STOP, False, [7], S.SWITCH_ON_DISABLED),
    (S.READY_TO_SWITCH_ON, DISABLE_VOLTAGE, False, [7], S.SWITCH_ON_DISABLED),
    (S.OPERATION_ENABLED, SHUTDOWN, False, [8], S.READY_TO_SWITCH_ON),
    (S.OPERATION_ENABLED, DISABLE_VOLTAGE, False, [9], S.SWITCH_ON_DISABLED),
    (S.SWITCHED_ON, DISABLE_VOLTAGE, False, [10], S.SWITCH_ON_DISABLED),
    (S.SWITCHED_ON, QUICK_STOP, False, [10], S.SWITCH_ON_DISABLED),
    (S.OPERATION_ENABLED, QUICK_STOP, False, [11], S.QUICK_STOP_ACTIVE),
    (S.QUICK_STOP_ACTIVE, DISABLE_VOLTAGE, False, [12], S.SWITCH_ON_DISABLED),
    (S.FAULT, FAULT_RESET, False, [15], S.SWITCH_ON_DISABLED),
    (S.QUICK_STOP_ACTIVE, ENABLE, True, [16], S.OPERATION_ENABLED),
]


@pytest.mark.parametrize(
    ("source", "controlword", "stays", "numbers", "target"),
    COMMAND_TRANSITIONS,
    ids=[f"T{row[3]}-{row[0].name}-0x{row[1]:02X}" for row in COMMAND_TRANSITIONS],
)
def test_command_transitions(
    source: State402, controlword: int, stays: bool, numbers: list[int], target: State402
) -> None:
    sm = StateMachine()
    reach(sm, source)
    taken = sm.controlword_written(controlword, quick_stop_stays=stays, fault_cleared=lambda: True)
    assert [t.number for t in taken] == numbers
    assert sm.state is target


@pytest.mark.parametrize(
    ("source", "event", "number", "target"),
    [
        (S.QUICK_STOP_ACTIVE, Event.QUICK_STOP_COMPLETED, 12, S.SWITCH_ON_DISABLED),
        *[
            (src, Event.FAULT, 13, S.FAULT_REACTION_ACTIVE)
            for src in (
                S.NOT_READY_TO_SWITCH_ON,
                S.SWITCH_ON_DISABLED,
                S.READY_TO_SWITCH_ON,
                S.SWITCHED_ON,
                S.OPERATION_ENABLED,
                S.QUICK_STOP_ACTIVE,
            )
        ],
        (S.FAULT_REACTION_ACTIVE, Event.FAULT_REACTION_COMPLETED, 14, S.FAULT),
    ],
)
def test_event_transitions(source: State402, event: Event, number: int, target: State402) -> None:
    sm = StateMachine()
    reach(sm, source)
    taken = sm.event(event)
    assert taken is not None and taken.number == number
    assert sm.state is target


# controlwords that do something in a state (605Ah 2, fault cause gone); all others must not
ALLOWED = {
    S.NOT_READY_TO_SWITCH_ON: set(),
    S.SWITCH_ON_DISABLED: {SHUTDOWN},
    S.READY_TO_SWITCH_ON: {SWITCH_ON, ENABLE, QUICK_STOP, DISABLE_VOLTAGE},
    S.SWITCHED_ON: {ENABLE, SHUTDOWN, DISABLE_VOLTAGE, QUICK_STOP},
    S.OPERATION_ENABLED: {SWITCH_ON, SHUTDOWN, DISABLE_VOLTAGE, QUICK_STOP},
    S.QUICK_STOP_ACTIVE: {DISABLE_VOLTAGE},
    S.FAULT_REACTION_ACTIVE: set(),
    S.FAULT: {FAULT_RESET},
}
WRONG = [(state, cw) for state, ok in ALLOWED.items() for cw in COMMANDS if cw not in ok]


@pytest.mark.parametrize(
    ("state", "controlword"), WRONG, ids=[f"{s.name}-0x{cw:02X}" for s, cw in WRONG]
)
def test_wrong_controlword_changes_nothing(state: State402, controlword: int) -> None:
    sm = StateMachine()
    reach(sm, state)
    sm.controlword = 0  # a fault reset needs a 0 -> 1 edge; give it one
    assert (
        sm.controlword_written(controlword, quick_stop_stays=False, fault_cleared=lambda: True)
        == ()
    )
    assert sm.state is state


def test_fault_reset_needs_an_edge_and_a_cleared_cause() -> None:
    sm = StateMachine()
    reach(sm, S.FAULT)
    cause_gone = False

    def cleared() -> bool:
        return cause_gone

    def write(cw: int) -> list[int]:
        return [
            t.number
            for t in sm.controlword_written(cw, quick_stop_stays=False, fault_cleared=cleared)
        ]

    assert write(FAULT_RESET) == []  # cause still there
    cause_gone = True
    assert write(FAULT_RESET) == []  # bit 7 held: no new edge
    assert write(FAULT_RESET | ENABLE) == []
    assert write(DISABLE_VOLTAGE) == []
    assert sm.state is S.FAULT
    assert write(FAULT_RESET) == [15]
    assert sm.state is S.SWITCH_ON_DISABLED


def test_manufacturer_and_halt_bits_do_not_change_the_command() -> None:
    sm = StateMachine()
    reach(sm, S.SWITCH_ON_DISABLED)
    taken = sm.controlword_written(
        SHUTDOWN | 0x0100 | 0x7800, quick_stop_stays=False, fault_cleared=lambda: True
    )
    assert [t.number for t in taken] == [2]


# ------------------------------------------------------------------------------------------
# the running drive: controlword and statusword over SDO
# ------------------------------------------------------------------------------------------
def sdo_state(rig: Rig) -> State402:
    word = rig.sdo.sdo[0x6041].raw
    states = matching_states(word)
    assert len(states) == 1, f"statusword 0x{word:04X} matches {states}"
    return states[0]


def write_cw(rig: Rig, controlword: int) -> None:
    rig.sdo.sdo[0x6040].raw = controlword


def test_sdo_walk_through_the_states(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        assert sdo_state(rig) is S.SWITCH_ON_DISABLED
        walk = [
            (SWITCH_ON, S.SWITCH_ON_DISABLED),  # wrong command: nothing happens
            (SHUTDOWN, S.READY_TO_SWITCH_ON),
            (SWITCH_ON, S.SWITCHED_ON),
            (ENABLE, S.OPERATION_ENABLED),
            (SWITCH_ON, S.SWITCHED_ON),
            (SHUTDOWN, S.READY_TO_SWITCH_ON),
            (DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
        ]
        for cw, expected in walk:
            write_cw(rig, cw)
            assert sdo_state(rig) is expected
            assert rig.drive.state is expected
        assert rig.sdo.sdo[0x6061].raw == 9
        assert rig.sdo.sdo[0x6041].raw & (1 << 9)  # remote


def test_modes_of_operation_only_csv(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        with pytest.raises(SdoAbortedError) as info:
            rig.sdo.sdo[0x6060].raw = 3
        assert info.value.code == 0x06090030
        rig.sdo.sdo[0x6060].raw = 9
        assert rig.sdo.sdo[0x6061].raw == 9


def speed_increments(rad_s: float) -> int:
    return round(rad_s * 2**20 / (2 * math.pi))


def run_to_speed(rig: Rig, rad_s: float, cycles: int) -> None:
    for cw in (SHUTDOWN, ENABLE):
        write_cw(rig, cw)
    rig.sdo.sdo[0x60FF].raw = speed_increments(rad_s)
    rig.sdo.sdo[0x2102].raw = 0  # set point watchdog off: set points come by SDO here
    for _ in range(cycles):
        rig.drive.on_sync()
    assert rig.drive.plant.motor_speed_rad_s == pytest.approx(rad_s, rel=0.02)


def test_quick_stop_ramps_down_then_switch_on_disabled(axis: AxisConfig) -> None:
    """605Ah = 2: quick stop ramp (6085h) to zero, then transition 12 by itself once the
    motor is at standstill (DriveConfig.standstill_rad_s = 0.1 rad/s)."""
    with virtual_rig(axis) as rig:
        speed = 15.0
        run_to_speed(rig, speed, 300)
        decel = 2e7  # increments/s^2
        rig.sdo.sdo[0x6085].raw = int(decel)
        write_cw(rig, QUICK_STOP)
        assert sdo_state(rig) is S.QUICK_STOP_ACTIVE
        step = decel * 2 * math.pi / 2**20 * axis.control.position_cycle
        start = rig.drive.plant.motor_speed_rad_s
        ramp_cycles = math.ceil(start / step)  # the set point reaches 0 in this cycle
        speeds = []
        while rig.drive.state is S.QUICK_STOP_ACTIVE and len(speeds) < 10 * ramp_cycles:
            speeds.append(rig.drive.plant.motor_speed_rad_s)
            rig.drive.on_sync()
        assert rig.drive.state is S.SWITCH_ON_DISABLED
        assert sdo_state(rig) is S.SWITCH_ON_DISABLED
        assert len(speeds) > ramp_cycles
        assert abs(speeds[-1]) <= 0.1
        halfway = ramp_cycles // 2
        assert speeds[halfway] == pytest.approx(start - step * halfway, abs=0.1 * speed)


def test_quick_stop_option_6_stays_and_transition_16(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.sdo.sdo[0x605A].raw = 6
        run_to_speed(rig, 5.0, 200)
        write_cw(rig, QUICK_STOP)
        for _ in range(200):
            rig.drive.on_sync()
        assert sdo_state(rig) is S.QUICK_STOP_ACTIVE
        assert abs(rig.drive.plant.motor_speed_rad_s) < 0.05
        write_cw(rig, ENABLE)
        assert sdo_state(rig) is S.OPERATION_ENABLED


def test_quick_stop_option_0_disables_at_once(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.sdo.sdo[0x605A].raw = 0
        run_to_speed(rig, 5.0, 200)
        write_cw(rig, QUICK_STOP)
        assert sdo_state(rig) is S.SWITCH_ON_DISABLED
        rig.drive.on_sync()
        # coasting: no torque but the current loop's decay (0.3 ms lag over 1 ms)
        assert abs(rig.drive.plant.motor_torque_nm) < 0.1


def test_quick_stop_option_codes_3_and_4_refused(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        for code in (3, 4):
            with pytest.raises(SdoAbortedError) as info:
                rig.sdo.sdo[0x605A].raw = code
            assert info.value.code == 0x06090030
        assert rig.sdo.sdo[0x605A].raw == 2


# ------------------------------------------------------------------------------------------
# NMT, boot-up, heartbeat
# ------------------------------------------------------------------------------------------
def test_boot_up_message(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        msg = rig.probe.expect(0x702)
        assert bytes(msg.data) == b"\x00"
        assert rig.drive.nmt_state is NmtState.PRE_OPERATIONAL


def test_heartbeat_follows_simulated_time_in_lockstep(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.probe.expect(0x702)  # boot-up
        rig.sdo.sdo[0x1017].raw = 5  # ms = 5 position cycles of 1 ms
        for _ in range(22):
            rig.probe.sync()
        assert rig.sdo.sdo[0x2103].raw == 22  # SDO answered after the 22 SYNCs
        beats = [m for m in rig.probe.drain() if m.arbitration_id == 0x702]
        assert [bytes(m.data) for m in beats] == [b"\x7f"] * 4  # after SYNC 5, 10, 15, 20
        rig.probe.nmt(NmtCommand.START)
        for _ in range(5):
            rig.probe.sync()
        assert bytes(rig.probe.expect(0x702).data) == b"\x05"


def test_heartbeat_on_wall_clock_in_real_time_mode(axis: AxisConfig) -> None:
    with virtual_rig(axis, config=DriveConfig(time_mode=TimeMode.REAL_TIME)) as rig:
        rig.probe.expect(0x702)  # boot-up
        rig.sdo.sdo[0x1017].raw = 10
        beats = [rig.probe.expect(0x702, timeout_s=2.0) for _ in range(3)]
        assert all(bytes(m.data) == b"\x7f" for m in beats)
        assert rig.drive.sync_count == 0  # no SYNC: the wall clock drove them


def test_nmt_gates_pdos_and_sdo(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        probe = rig.probe
        probe.sync()
        assert rig.sdo.sdo[0x2103].raw == 1  # SYNC ran the physics in Pre-operational ...
        assert not [m for m in probe.drain() if m.arbitration_id in (0x182, 0x282)]  # ... no TPDO
        probe.nmt(NmtCommand.START)
        assert probe.sync_and_collect([0x182, 0x282])
        probe.nmt(NmtCommand.STOP)
        rig.sdo.sdo.RESPONSE_TIMEOUT = 0.1
        with pytest.raises(SdoCommunicationError):
            rig.sdo.sdo[0x2103].raw  # noqa: B018  (no SDO in Stopped)
        assert rig.drive.nmt_state is NmtState.STOPPED
        probe.nmt(NmtCommand.ENTER_PRE_OPERATIONAL, node_id=0)  # broadcast
        assert rig.sdo.sdo[0x2103].raw == 2
        probe.nmt(NmtCommand.START, node_id=3)  # another node: ignored
        assert rig.sdo.sdo[0x2103].raw == 2
        assert rig.drive.nmt_state is NmtState.PRE_OPERATIONAL


def test_reset_node_and_reset_communication(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        probe, sdo = rig.probe, rig.sdo.sdo
        probe.expect(0x702)
        sdo[0x6072].raw = 100
        sdo[0x1800][1].raw = 0x80000182  # TPDO1 invalid
        sdo[0x2100].raw = 1234
        write_cw(rig, SHUTDOWN)
        probe.nmt(NmtCommand.RESET_COMMUNICATION)
        assert bytes(probe.expect(0x702).data) == b"\x00"
        assert sdo[0x1800][1].raw == 0x182  # communication area back to defaults
        assert sdo[0x6072].raw == 100  # application area kept
        assert rig.drive.state is S.READY_TO_SWITCH_ON
        probe.nmt(NmtCommand.RESET_NODE)
        assert bytes(probe.expect(0x702).data) == b"\x00"
        assert sdo[0x6072].raw == 3000  # application area back to defaults
        assert sdo[0x2100].raw == 1234  # the simulation input is kept
        assert rig.drive.state is S.SWITCH_ON_DISABLED
        assert rig.drive.nmt_state is NmtState.PRE_OPERATIONAL


def test_statusword_patterns_are_unique() -> None:
    """Each state's statusword as the drive codes it matches exactly its own pattern."""
    from plant_sim.drive.cia402 import STATUS_PATTERNS

    for state, (_mask, value) in STATUS_PATTERNS.items():
        assert matching_states(value) == [state]


def test_drive_on_a_canopen_network(axis: AxisConfig) -> None:
    """Given a connected canopen Network, the drive joins it and leaves it (no own thread)."""
    channel = f"drive-{uuid.uuid4().hex[:12]}"
    with can.Bus(interface="virtual", channel=channel) as master_bus:
        network = canopen.Network(can.Bus(interface="virtual", channel=channel))
        network.NOTIFIER_CYCLE = 0.05
        network.connect()
        try:
            drive = SimulatedDrive(network, 5, axis)
            with drive:
                probe = BusProbe(master_bus, node_id=5)
                assert bytes(probe.expect(0x705).data) == b"\x00"
                probe.nmt(NmtCommand.START)
                probe.setpoint(0x06, 0)
                got = probe.sync_and_collect([0x185, 0x285])
                assert struct.unpack_from("<H", got[0x285])[0] & 0x6F == 0x21
                assert 5 in network
            assert 5 not in network
            drive.check()
        finally:
            network.disconnect()

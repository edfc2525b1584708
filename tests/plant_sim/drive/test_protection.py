"""Drive-side protection: set point timeout (6007h reactions, EMCY 0x8250), motor encoder vs
load scale discrepancy (paper section II.B, EMCY 0x7300, fault reset only when the cause is
gone), torque limit 6072h, the disturbance input 2100h, and bad inputs."""

from __future__ import annotations

import math
import struct
import uuid
from dataclasses import replace

import can
import pytest

from plant_sim.drive import (
    DriveConfig,
    DriveConfigError,
    DriveInputError,
    NmtCommand,
    SimulatedDrive,
    State402,
)
from plant_sim.drive.rig import Rig, virtual_rig
from plant_sim.physics.model import AxisPlant
from tests.paths import ROOT
from virtual_bus.formats.axis import AxisConfig, load_axis

REPO = ROOT
S = State402
TPDO2, EMCY = 0x282, 0x082
INC_PER_REV = 2**20


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(REPO / "config" / "paper_axis.toml")


def increments(rad: float) -> int:
    return round(rad / (2 * math.pi) * INC_PER_REV)


def state_of(statusword: int) -> State402:
    low = statusword & 0x6F
    for state, (mask, value) in {
        S.SWITCH_ON_DISABLED: (0x4F, 0x40),
        S.READY_TO_SWITCH_ON: (0x6F, 0x21),
        S.SWITCHED_ON: (0x6F, 0x23),
        S.OPERATION_ENABLED: (0x6F, 0x27),
        S.QUICK_STOP_ACTIVE: (0x6F, 0x07),
        S.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
        S.FAULT: (0x4F, 0x08),
    }.items():
        if statusword & mask == value:
            return state
    raise AssertionError(f"statusword 0x{statusword:04X} (low 0x{low:02X}) codes no state")


def emcy(rig: Rig) -> tuple[int, int, bytes]:
    data = bytes(rig.probe.expect(EMCY).data)
    code, register = struct.unpack_from("<HB", data)
    return code, register, data[3:]


def enable_and_run(rig: Rig, target: int, cycles: int) -> list[State402]:
    rig.probe.nmt(NmtCommand.START)
    states = []
    for k in range(cycles):
        rig.probe.setpoint(0x06 if k == 0 else 0x0F, target)
        got = rig.probe.sync_and_collect([TPDO2])
        states.append(state_of(struct.unpack_from("<H", got[TPDO2])[0]))
    return states


# ------------------------------------------------------------------------------------------
# set point timeout
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("option", "first_state", "final_state"),
    [
        (0, S.OPERATION_ENABLED, S.OPERATION_ENABLED),
        (1, S.FAULT_REACTION_ACTIVE, S.FAULT),
        (2, S.SWITCH_ON_DISABLED, S.SWITCH_ON_DISABLED),
        (3, S.QUICK_STOP_ACTIVE, S.SWITCH_ON_DISABLED),
    ],
    ids=["6007h=0-none", "6007h=1-fault", "6007h=2-disable-voltage", "6007h=3-quick-stop"],
)
def test_setpoint_timeout(
    axis: AxisConfig, option: int, first_state: State402, final_state: State402
) -> None:
    with virtual_rig(axis) as rig:
        rig.sdo.sdo[0x6007].raw = option
        assert rig.sdo.sdo[0x2102].raw == 0  # default: off
        rig.sdo.sdo[0x2102].raw = 3
        states = enable_and_run(rig, increments(10.0), 100)
        assert states[-1] is S.OPERATION_ENABLED
        seen = []
        for _ in range(3):  # SYNCs without an RPDO
            got = rig.probe.sync_and_collect([TPDO2])
            seen.append(state_of(struct.unpack_from("<H", got[TPDO2])[0]))
        assert seen[:2] == [S.OPERATION_ENABLED, S.OPERATION_ENABLED]
        assert seen[2] is first_state  # the 3rd missed SYNC reacts before its TPDO
        assert emcy(rig) == (0x8250, 0x11, bytes([0x02, 0x21, 3, option, 0]))
        for _ in range(100):
            got = rig.probe.sync_and_collect([TPDO2])
        assert state_of(struct.unpack_from("<H", got[TPDO2])[0]) is final_state
        assert rig.drive.error_code == 0x8250
        rig.probe.setpoint(0x00, 0)  # set points again: the error goes
        rig.probe.sync()
        assert emcy(rig)[:2] == (0x0000, 0x00)
        assert rig.sdo.sdo[0x603F].raw == 0


def test_setpoint_timeout_off_with_zero(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.sdo.sdo[0x2102].raw = 0
        enable_and_run(rig, increments(5.0), 5)
        for _ in range(20):
            got = rig.probe.sync_and_collect([TPDO2])
        assert state_of(struct.unpack_from("<H", got[TPDO2])[0]) is S.OPERATION_ENABLED
        assert not rig.probe.frames(EMCY)


def test_quick_stop_after_timeout_ramps_to_standstill(axis: AxisConfig) -> None:
    """605Ah = 2: the quick stop ramp (6085h) lasts at least speed / deceleration; the drive
    switches to Switch on disabled only at standstill (|606Ch| <= 0.1 rad/s)."""
    with virtual_rig(axis) as rig:
        rig.sdo.sdo[0x2102].raw = 3
        enable_and_run(rig, increments(15.0), 150)
        decel = rig.sdo.sdo[0x6085].raw * 2 * math.pi / INC_PER_REV  # rad/s^2
        trace = []
        for _ in range(300):
            got = rig.probe.sync_and_collect([TPDO2])
            statusword, _torque, speed = struct.unpack("<Hhl", got[TPDO2])
            trace.append((state_of(statusword), speed))
        states = [state for state, _ in trace]
        quick = states.index(S.QUICK_STOP_ACTIVE)
        done = states.index(S.SWITCH_ON_DISABLED)
        assert quick == 2  # the 3rd SYNC without RPDO
        assert set(states[quick:done]) == {S.QUICK_STOP_ACTIVE}
        assert done - quick >= 15.0 / decel / axis.control.position_cycle
        assert abs(trace[done][1]) <= increments(0.1)
        assert max(abs(v) for _, v in trace[quick + 5 : done]) < increments(15.0)


# ------------------------------------------------------------------------------------------
# motor encoder vs load scale
# ------------------------------------------------------------------------------------------
def test_encoder_discrepancy_by_backlash_faults_and_reset_needs_the_cause_gone(
    axis: AxisConfig,
) -> None:
    """2 mm of free play: the motor runs through the gap while the load sticks (friction), so
    the measuring systems drift apart beyond the paper's 0.5 mm (section II.B)."""
    loose = replace(axis, mechanics=replace(axis.mechanics, backlash=0.002))
    with virtual_rig(loose) as rig:
        states = enable_and_run(rig, increments(5.0), 80)
        assert S.FAULT_REACTION_ACTIVE in states
        code, register, data = emcy(rig)
        assert (code, register) == (0x7300, 0x21)
        (difference_nm,) = struct.unpack("<l", data[:4])
        assert 500_000 < abs(difference_nm) < 1_100_000
        assert states[-1] is S.FAULT
        sdo = rig.sdo.sdo
        assert abs(sdo[0x2104].raw) > 500_000
        sdo[0x6040].raw = 0x00
        sdo[0x6040].raw = 0x80  # fault reset: cause still there
        assert rig.drive.state is S.FAULT
        assert sdo[0x603F].raw == 0x7300
        assert sdo[0x1001].raw == 0x21
        sdo[0x2101].raw = 2_000_000  # 2 mm tolerance: the cause is gone
        sdo[0x6040].raw = 0x00
        sdo[0x6040].raw = 0x80
        assert rig.drive.state is S.SWITCH_ON_DISABLED
        assert emcy(rig)[:2] == (0x0000, 0x00)
        assert sdo[0x603F].raw == 0
        assert sdo[0x1001].raw == 0


def test_encoder_discrepancy_by_tightened_tolerance(axis: AxisConfig) -> None:
    """The paper axis is elastic: while accelerating, screw deflection shows between the two
    measuring systems; a 1 nm tolerance makes that a fault at the next SYNC."""
    with virtual_rig(axis) as rig:
        enable_and_run(rig, increments(10.0), 20)
        assert abs(rig.sdo.sdo[0x2104].raw) > 1
        rig.sdo.sdo[0x2101].raw = 1
        got = rig.probe.sync_and_collect([TPDO2])
        assert state_of(struct.unpack_from("<H", got[TPDO2])[0]) is S.FAULT_REACTION_ACTIVE
        assert emcy(rig)[:2] == (0x7300, 0x21)


# ------------------------------------------------------------------------------------------
# torque limit
# ------------------------------------------------------------------------------------------
def test_torque_limit_6072h_matches_an_axis_with_that_limit(axis: AxisConfig) -> None:
    """6072h = 200 ‰ of 50 N·m: the drive behaves like an AxisPlant whose axis file says
    torque_limit = 10 N·m, and sets statusword bit 11 while it is at the limit."""
    limited = replace(axis, control=replace(axis.control, torque_limit=10.0))
    reference = AxisPlant(limited)
    target = increments(5.0)
    with virtual_rig(axis) as rig:
        rig.sdo.sdo[0x6072].raw = 200
        assert rig.drive.torque_limit_nm == 10.0
        rig.probe.nmt(NmtCommand.START)
        torques, at_limit = [], []
        for k in range(400):
            rig.probe.setpoint(0x06 if k == 0 else 0x0F, target)
            got = rig.probe.sync_and_collect([TPDO2])
            statusword, torque, speed = struct.unpack("<Hhl", got[TPDO2])
            assert speed == increments(reference.motor_speed_rad_s), f"SYNC {k}"
            torques.append(torque)
            at_limit.append(bool(statusword & 0x0800))
            if k == 0:
                reference.advance_torque(0.0)
            else:
                reference.advance(target * 2 * math.pi / INC_PER_REV)
    assert max(abs(t) for t in torques) == 200
    assert any(at_limit) and not at_limit[-1]
    assert all(abs(t) >= 199 for t, flag in zip(torques, at_limit, strict=True) if flag)


# ------------------------------------------------------------------------------------------
# disturbance
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("route", ["sdo", "api"])
def test_disturbance_input(axis: AxisConfig, route: str) -> None:
    """20 N·m (the paper's section X step) through 2100h or set_disturbance_nm acts like the
    disturbance argument of AxisPlant.advance."""
    reference = AxisPlant(axis)
    with virtual_rig(axis) as rig:
        if route == "sdo":
            rig.sdo.sdo[0x2100].raw = 20000
        else:
            rig.drive.set_disturbance_nm(20.0)
        assert rig.drive.disturbance_nm == 20.0
        for _ in range(50):  # Switch on disabled: the load is pushed, the motor coasts
            rig.drive.on_sync()
            reference.advance_torque(0.0, 20.0)
        assert rig.drive.plant.load_position == reference.load_position
        assert rig.drive.plant.load_position > 0.0


def test_bad_disturbance_changes_nothing(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.drive.set_disturbance_nm(1.5)
        for bad in (math.nan, math.inf, 3e6):
            with pytest.raises(DriveInputError, match="disturbance"):
                rig.drive.set_disturbance_nm(bad)
        assert rig.drive.disturbance_nm == 1.5


def test_bad_configuration_is_refused(axis: AxisConfig) -> None:
    with pytest.raises(DriveConfigError, match="rated_torque_nm"):
        DriveConfig(rated_torque_nm=0.0)
    with pytest.raises(DriveConfigError, match="node_id"):
        SimulatedDrive(object(), 0, axis)  # type: ignore[arg-type]
    with pytest.raises(DriveConfigError, match="network_or_bus"):
        SimulatedDrive(object(), 2, axis)  # type: ignore[arg-type]
    odd = replace(axis, control=replace(axis.control, position_cycle=256e-6, speed_cycle=128e-6))
    channel = f"drive-{uuid.uuid4().hex[:12]}"
    with (
        can.Bus(interface="virtual", channel=channel) as bus,
        pytest.raises(DriveConfigError, match="60C2h"),
    ):
        SimulatedDrive(bus, 2, odd)


# ------------------------------------------------------------------------------------------
# acceleration feed-forward (axis file control.acceleration_feedforward)
# ------------------------------------------------------------------------------------------
def _ramp_speed_errors(axis: AxisConfig) -> list[float]:
    """Target velocity ramped 0 -> 50 rad/s in 0.5 s over RPDOs; |target - actual| during it."""
    errors = []
    with virtual_rig(axis) as rig:
        rig.probe.nmt(NmtCommand.START)
        for k in range(700):
            target = increments(min(max(k - 100, 0), 500) * 0.1)
            rig.probe.setpoint(0x06 if k == 0 else 0x0F, target)
            got = rig.probe.sync_and_collect([TPDO2])
            _, _, speed = struct.unpack("<Hhl", got[TPDO2])
            if 100 <= k < 130:  # the start of the ramp, before the PI integral has caught up
                errors.append(abs(target - speed) * 2 * math.pi / INC_PER_REV)
    return errors


def test_drive_acceleration_feedforward_removes_the_ramp_lag(axis: AxisConfig) -> None:
    """With J_ff = the axis's total inertia the drive adds J·dω_set/dt to the torque: the
    PI speed loop no longer needs a ramp error to produce the acceleration torque (what
    remains is the sampling offset, half a position cycle of the ramp: 0.05 rad/s). Without
    backlash and Coulomb friction, so that the ramp start is not a gap crossing."""
    tight = axis.with_values({"mechanics.backlash": None, "friction.coulomb": None})
    without = _ramp_speed_errors(tight)
    exact = tight.with_values({"control.acceleration_feedforward": tight.total_inertia})
    with_ff = _ramp_speed_errors(exact)
    assert max(with_ff) < 0.4 * max(without)
    assert max(without) > 0.25  # rad/s: the lag is there without feed-forward

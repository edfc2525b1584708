"""PDOs of the simulated drive: TPDOs on SYNC against an AxisPlant stepped here, RPDO latching
at the next SYNC, remapping over SDO (raw and with canopen's PdoMap.save) and the CiA 301
abort codes."""

from __future__ import annotations

import math
import struct

import can
import pytest
from canopen.sdo import SdoAbortedError

from plant_sim.drive import NmtCommand
from plant_sim.drive.rig import Rig, virtual_rig
from plant_sim.physics.model import AxisPlant
from tests.paths import ROOT
from virtual_bus.formats.axis import AxisConfig, load_axis
from virtual_bus.frame_guard import FrameFault

REPO = ROOT
TPDO1, TPDO2, TPDO3, TPDO4 = 0x182, 0x282, 0x382, 0x482
EMCY = 0x082
INC_PER_REV = 2**20
# statusword of the drive in a state: state bits | voltage enabled (4) | remote (9) | csv (12)
SW_READY = 0x0021 | 0x0010 | 0x0200
SW_ENABLED = 0x0027 | 0x0010 | 0x0200 | 0x1000
SW_DISABLED = 0x0040 | 0x0200


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(REPO / "config" / "paper_axis.toml")


def wrap32(n: int) -> int:
    return (n + 2**31) % 2**32 - 2**31


def increments(rad: float) -> int:
    return round(rad / (2 * math.pi) * INC_PER_REV)


def expected_tpdo1(plant: AxisPlant) -> bytes:
    """6064h (motor encoder) + 60E4h:01 (load scale, nm): docs/canopen_layout.md."""
    return struct.pack(
        "<ll",
        wrap32(increments(plant.motor_position_rad)),
        wrap32(round(plant.load_position * 1e9)),
    )


def decode_tpdo2(data: bytes) -> tuple[int, int, int]:
    """6041h, 6077h (‰ of 50 N·m), 606Ch (increments/s)."""
    return struct.unpack("<Hhl", data)


def test_tpdos_match_an_axis_plant_stepped_here(axis: AxisConfig) -> None:
    """200 SYNCs: enable, a speed ramp, the section X disturbance step; every TPDO equals the
    sampled state of a second AxisPlant run with the same set points (set point of SYNC k acts
    in cycle k, TPDO of SYNC k shows the state before cycle k)."""
    reference = AxisPlant(axis)
    disturbance = 0.0
    with virtual_rig(axis) as rig:
        probe = rig.probe
        probe.nmt(NmtCommand.START)
        for k in range(200):
            target = increments(min(k, 80) * 0.2)  # ramp to 16 rad/s motor (0.05 m/s load)
            controlword = 0x06 if k == 0 else 0x0F
            if k == 120:
                disturbance = 20.0  # N·m at the motor, paper section X
                rig.drive.set_disturbance_nm(disturbance)
            probe.setpoint(controlword, target)
            got = probe.sync_and_collect([TPDO1, TPDO2])
            assert got[TPDO1] == expected_tpdo1(reference), f"TPDO1 at SYNC {k}"
            statusword, torque, speed = decode_tpdo2(got[TPDO2])
            assert statusword == (SW_READY if k == 0 else SW_ENABLED), f"SYNC {k}"
            assert torque == pytest.approx(reference.motor_torque_nm / 50.0 * 1000, abs=0.5001)
            assert speed == increments(reference.motor_speed_rad_s), f"606Ch at SYNC {k}"
            if k == 0:
                reference.advance_torque(0.0, disturbance)
            else:
                reference.advance(target * 2 * math.pi / INC_PER_REV, disturbance)
        assert reference.motor_speed_rad_s == pytest.approx(16.0, rel=0.05)
        assert rig.drive.time_s == pytest.approx(reference.time_s)  # waits for the cycle


def enable_by_rpdo(rig: Rig) -> None:
    rig.probe.nmt(NmtCommand.START)
    for cw in (0x06, 0x0F):
        rig.probe.setpoint(cw, 0)
        rig.probe.sync_and_collect([TPDO2])


def test_rpdo_takes_effect_at_the_next_sync(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        enable_by_rpdo(rig)
        sdo = rig.sdo.sdo
        rig.probe.setpoint(0x0F, 11111)
        rig.probe.setpoint(0x0F, 22222)  # the last RPDO before the SYNC wins
        assert sdo[0x60FF].raw == 0  # received, not yet in force
        moving_before = rig.drive.plant.motor_speed_rad_s
        got = rig.probe.sync_and_collect([TPDO2])
        assert decode_tpdo2(got[TPDO2])[2] == increments(moving_before)  # sampled before
        assert sdo[0x60FF].raw == 22222
        assert rig.drive.plant.motor_speed_rad_s > 0.0  # ran one cycle with it
        got = rig.probe.sync_and_collect([TPDO2])  # no new RPDO: the latched value stays
        assert sdo[0x60FF].raw == 22222


def test_rpdo_ignored_outside_operational(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.probe.setpoint(0x06, 5000)
        rig.probe.sync()
        assert rig.sdo.sdo[0x2103].raw == 1
        assert rig.sdo.sdo[0x6040].raw == 0
        assert rig.sdo.sdo[0x60FF].raw == 0


def test_short_rpdo_is_discarded_with_emcy_8210(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        enable_by_rpdo(rig)
        rig.probe.rpdo(1, struct.pack("<Hh", 0x0F, 1000))  # 4 bytes, mapping needs 6
        rig.probe.sync()
        emcy = rig.probe.expect(EMCY)
        code, register = struct.unpack_from("<HB", emcy.data)
        assert (code, register) == (0x8210, 0x11)
        assert rig.sdo.sdo[0x60FF].raw == 0
        rig.probe.setpoint(0x0F, 1000)
        rig.probe.sync()
        assert struct.unpack_from("<HB", rig.probe.expect(EMCY).data) == (0x0000, 0x00)
        assert rig.sdo.sdo[0x60FF].raw == 1000


def test_sync_with_data_is_ignored_with_emcy_8240(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        rig.probe.send(0x080, b"\x01\x02")
        code, register = struct.unpack_from("<HB", rig.probe.expect(EMCY).data)
        assert (code, register) == (0x8240, 0x11)
        assert rig.sdo.sdo[0x2103].raw == 0  # no cycle ran
        rig.probe.sync(counter=7)  # a SYNC counter byte is fine
        assert struct.unpack_from("<HB", rig.probe.expect(EMCY).data) == (0x0000, 0x00)
        assert rig.sdo.sdo[0x2103].raw == 1


def test_remap_tpdo_over_sdo_every_third_sync(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        assert sdo[0x1802][1].raw == 0x80000382  # TPDO3 is invalid by default
        sdo[0x1A02][0].raw = 0
        sdo[0x1A02][1].raw = 0x21030020  # 2103h SYNC cycles run
        sdo[0x1A02][2].raw = 0x60410010  # 6041h statusword
        sdo[0x1A02][0].raw = 2
        sdo[0x1802][2].raw = 3
        sdo[0x1802][1].raw = 0x382
        rig.probe.nmt(NmtCommand.START)
        for _ in range(9):
            rig.probe.sync()
        assert sdo[0x2103].raw == 9
        frames = [bytes(m.data) for m in rig.probe.drain() if m.arbitration_id == TPDO3]
        assert frames == [struct.pack("<LH", n, SW_DISABLED) for n in (2, 5, 8)]


def test_tpdo_type_0_sent_when_the_data_changes(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        sdo[0x1A03][1].raw = 0x60410010
        sdo[0x1A03][0].raw = 1
        sdo[0x1803][2].raw = 0
        sdo[0x1803][1].raw = 0x482
        rig.probe.nmt(NmtCommand.START)
        for _ in range(3):
            rig.probe.sync()
        sdo[0x6040].raw = 0x06
        for _ in range(3):
            rig.probe.sync()
        assert sdo[0x2103].raw == 6
        frames = [bytes(m.data) for m in rig.probe.drain() if m.arbitration_id == TPDO4]
        assert frames == [struct.pack("<H", SW_DISABLED), struct.pack("<H", SW_READY)]


def test_remap_with_canopen_pdo_api(axis: AxisConfig) -> None:
    """What a master using canopen's RemoteNode.tpdo/rpdo (read, edit, save) does works."""
    with virtual_rig(axis) as rig:
        node = rig.sdo
        node.tpdo.read()
        node.rpdo.read()
        tpdo = node.tpdo[4]
        tpdo.clear()
        tpdo.add_variable(0x6064)
        tpdo.add_variable(0x6077)
        tpdo.trans_type = 2
        tpdo.enabled = True
        tpdo.save()
        rpdo = node.rpdo[2]
        rpdo.clear()
        rpdo.add_variable(0x2100)
        rpdo.enabled = True
        rpdo.save()
        assert node.sdo[0x1803][1].raw == 0x482
        assert node.sdo[0x1401][1].raw == 0x302
        rig.probe.nmt(NmtCommand.START)
        rig.probe.rpdo(2, struct.pack("<l", 20000))  # 20 N·m disturbance through RPDO2
        for _ in range(4):
            rig.probe.sync()
        assert node.sdo[0x2103].raw == 4
        frames = [m for m in rig.probe.drain() if m.arbitration_id == TPDO4]
        assert len(frames) == 2  # every 2nd SYNC
        assert all(len(m.data) == 6 for m in frames)
        assert rig.drive.disturbance_nm == 20.0


def download(rig: Rig, index: int, sub: int, value: int, fmt: str = "<L") -> None:
    rig.sdo.sdo.download(index, sub, struct.pack(fmt, value))


# (case, [(index, sub, value, struct format) written first], (index, sub, value, fmt), abort)
ABORT_CASES = [
    ("map entry while valid", [], (0x1A00, 1, 0x60410010, "<L"), 0x06090030),
    ("map count while valid", [], (0x1A00, 0, 1, "<B"), 0x06090030),
    (
        "map entry while count != 0",
        [(0x1800, 1, 0x80000182, "<L")],
        (0x1A00, 1, 0x60410010, "<L"),
        0x06090030,
    ),
    ("object not mappable", [], (0x1A02, 1, 0x60760020, "<L"), 0x06040041),
    ("read-only object in an RPDO", [], (0x1601, 1, 0x60410010, "<L"), 0x06040041),
    ("partial object", [], (0x1A02, 1, 0x60410008, "<L"), 0x06040041),
    ("object does not exist", [], (0x1A02, 1, 0x22000020, "<L"), 0x06020000),
    (
        "more than 64 bits",
        [
            (0x1A02, 1, 0x60640020, "<L"),
            (0x1A02, 2, 0x606C0020, "<L"),
            (0x1A02, 3, 0x60410010, "<L"),
        ],
        (0x1A02, 0, 3, "<B"),
        0x06040042,
    ),
    ("count with an empty entry", [], (0x1A02, 0, 1, "<B"), 0x06040041),
    ("more than 8 entries", [], (0x1A02, 0, 9, "<B"), 0x06090031),
    ("TPDO event-driven type", [], (0x1800, 2, 255, "<B"), 0x06090030),
    ("RPDO reserved type", [], (0x1400, 2, 241, "<B"), 0x06090030),
    ("CAN id change while valid", [], (0x1800, 1, 0x183, "<L"), 0x06090030),
    ("restricted CAN id", [], (0x1802, 1, 0x702, "<L"), 0x06090030),
    ("29-bit CAN id", [], (0x1802, 1, 0x20000382, "<L"), 0x06090030),
    ("CAN id of another RPDO", [], (0x1401, 1, 0x202, "<L"), 0x06090030),
]


@pytest.mark.parametrize(
    ("prepare", "write", "code"),
    [case[1:] for case in ABORT_CASES],
    ids=[case[0] for case in ABORT_CASES],
)
def test_pdo_parameter_abort_codes(
    axis: AxisConfig,
    prepare: list[tuple[int, int, int, str]],
    write: tuple[int, int, int, str],
    code: int,
) -> None:
    with virtual_rig(axis) as rig:
        for index, sub, value, fmt in prepare:
            download(rig, index, sub, value, fmt)
        index, sub, value, fmt = write
        before = rig.sdo.sdo.upload(index, sub)
        with pytest.raises(SdoAbortedError) as info:
            download(rig, index, sub, value, fmt)
        assert info.value.code == code
        assert rig.sdo.sdo.upload(index, sub) == before  # nothing changed


def test_rewriting_the_present_value_is_accepted_while_valid(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        for sub in range(9):
            sdo[0x1A01][sub].raw = sdo[0x1A01][sub].raw
        sdo[0x1801][1].raw = 0x282
        assert sdo[0x1A01][0].raw == 3


def test_polled_drive_answers_only_when_polled_and_resumes_its_thread(axis: AxisConfig) -> None:
    """SimulatedDrive.polled(): the notifier pauses (a SYNC stays unanswered), poll() hands
    the waiting frames to the drive (TPDOs come back, one physics cycle ran), and on exit the
    drive answers on its own thread again."""
    with virtual_rig(axis) as rig:
        probe = rig.probe
        probe.nmt(NmtCommand.START)
        probe.sync_and_collect([TPDO1, TPDO2])
        cycles = rig.drive.sync_count
        with rig.drive.polled() as poll:
            probe.drain()
            probe.sync()
            assert probe.bus.recv(0.05) is None  # nobody received the SYNC
            assert poll() == 1
            got = {m.arbitration_id for m in probe.drain()}
            assert {TPDO1, TPDO2} <= got
            assert rig.drive.sync_count == cycles + 1
            assert poll() == 0
        assert set(probe.sync_and_collect([TPDO1, TPDO2])) == {TPDO1, TPDO2}
        assert rig.drive.sync_count == cycles + 2


class _Watcher(can.Listener):
    """A second listener on the drive's network: every frame then takes canopen's way."""

    def __init__(self) -> None:
        self.seen = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.seen += 1


def _scripted(axis: AxisConfig, second_listener: bool) -> tuple[object, ...]:
    """TPDOs and EMCYs of a scripted run through polled(), the guard's counts, SYNCs run."""
    with virtual_rig(axis) as rig:
        probe, drive = rig.probe, rig.drive
        watcher = _Watcher()
        if second_listener:
            drive.network.listeners.append(watcher)
        got: list[tuple[int, bytes]] = []
        with drive.polled() as poll:

            def answer() -> None:
                poll()
                got.extend((m.arbitration_id, bytes(m.data)) for m in probe.drain())

            probe.setpoint(0x06, 5000)  # Pre-operational: refused, counted
            probe.sync()
            answer()
            probe.nmt(NmtCommand.START)
            answer()
            for cw, speed in ((0x06, 0), (0x0F, 0), (0x0F, 20000), (0x0F, 20000), (0x0F, -300)):
                probe.setpoint(cw, speed)
                probe.sync()
                answer()
            probe.rpdo(1, struct.pack("<Hh", 0x0F, 1000))  # too short: EMCY 8210
            probe.sync()
            answer()
            probe.send(0x080, b"\x01\x02")  # a SYNC with data: EMCY 8240
            answer()
            probe.sync()
            answer()
        return got, drive.guard.accepted, dict(drive.guard.counts), drive.sync_count, watcher.seen


def test_sync_and_rpdo_straight_to_the_drive_do_what_canopens_dispatch_does(
    axis: AxisConfig,
) -> None:
    """SimulatedDrive.take hands a SYNC and an RPDO to the drive without a message when only
    the drive listens; with a second listener the same frames go through the frame guard and
    canopen's Network.notify. Both: the same TPDOs and EMCYs, the same counts of the guard
    (an RPDO outside Operational refused as not in state, a short RPDO, a SYNC with data)."""
    direct = _scripted(axis, second_listener=False)
    dispatched = _scripted(axis, second_listener=True)
    assert direct[-1] == 0 and dispatched[-1] > 0
    assert direct[:-1] == dispatched[:-1]
    got, accepted, counts, syncs = direct[:-1]
    tpdo2s = [f for f in got if f[0] == TPDO2]  # type: ignore[union-attr]
    emcys = {f[1][:2] for f in got if f[0] == EMCY}  # type: ignore[union-attr, index]
    assert syncs == 8 and len(tpdo2s) == 7  # none in Pre-operational
    assert emcys >= {b"\x10\x82", b"\x40\x82"} and accepted > 8  # type: ignore[operator]
    assert counts[FrameFault.NOT_IN_STATE] == 1  # type: ignore[index]
    assert counts[FrameFault.BAD_LENGTH] == 2  # type: ignore[index]

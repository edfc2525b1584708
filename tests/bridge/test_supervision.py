"""How the drive supervises the bridge (``bridge.supervision``, written by the start-up) and how
the end of a run brings the stop to the drive (``bridge.halt``).

Against drives the project did not write: python canopen ``LocalNode``\\ s built from the
vendor EDS files (the objects each offers: Yiyou and Faulhaber MCBL CO have 1016h, Technosoft
iPOS 6007h, none has both), read back after the start-up wrote; the stop path against the
simulated drive served in a thread of its own with the real-time clock (its own clock runs
when SYNC stops), the drive's state read from the drive itself.
"""

from __future__ import annotations

import dataclasses
import struct
import threading
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from bridge.cycle import BridgeState, Drive402State, StopReason
from bridge.errors import DriveSetupError
from bridge.halt import HaltWay, halt
from bridge.interpolator import Move
from bridge.node import Bridge
from bridge.params import BridgeParams
from bridge.timing import LockstepPacer
from hil.harness import simulated_axis
from plant_sim.drive import State402
from tests.adapt_helpers import FAULHABER_CO_EDS, TECHNOSOFT_EDS, YIYOU_EDS, local_rig
from tests.bridge.conftest import BOUND_S, SIM_EDS
from tests.bridge_helpers import AXIS, controller
from tests.paths import ROOT
from virtual_bus.formats.drive_profile import DriveProfile, load_profile

BRIDGE_ENTRY = (1 << 16) | 250  # node 1, 250 ms: 2.5 x the bridge's 100 ms heartbeat


def _configured(eds: Path, profile: DriveProfile | None = None, before: dict | None = None):
    """The supervision the start-up plans and writes for a LocalNode of ``eds`` (``before``:
    values written to the LocalNode first), what the node holds then, and after the bridge
    gave the objects back."""
    with local_rig(eds, profile) as rig:
        node = rig.nodes[2]
        for (index, sub), value in (before or {}).items():
            node.set_data(index, sub, value.to_bytes(4, "little"))
        master = rig.master
        master.bridge_id, master.heartbeat_ms = 1, 100
        supervision = master.plan_supervision(master.read_facts())
        master.configure_supervision(supervision)
        held = {key: rig.stored(2, *key) for key in supervision.keys}
        assert master.restore(master.restored) == []
        back = {key: rig.stored(2, *key) for key in supervision.keys}
    return supervision, held, back


@pytest.mark.parametrize(
    ("eds", "written", "watched"),
    [
        (SIM_EDS, {(0x1016, 1): BRIDGE_ENTRY, (0x6007, 0): 3, (0x2102, 0): 3}, True),
        (YIYOU_EDS, {(0x1016, 1): BRIDGE_ENTRY}, True),
        (FAULHABER_CO_EDS, {(0x1016, 1): BRIDGE_ENTRY}, True),
        (TECHNOSOFT_EDS, {(0x6007, 0): 3}, False),
    ],
    ids=["simulated drive", "Yiyou", "Faulhaber CO", "Technosoft"],
)
def test_the_drive_is_set_to_watch_the_bridge_with_what_its_eds_offers(
    eds: Path, written: dict[tuple[int, int], int], watched: bool
) -> None:
    """1016h where the EDS has it (the contract's drive: 2102h too), 6007h = 3 where it has
    that; what a drive lacks is said; the values are given back at the end."""
    supervision, held, back = _configured(eds)
    assert held == written
    assert supervision.watched is watched
    notes = " ".join(supervision.notes)
    assert ("no heartbeat consumer (1016h)" in notes) is ((0x1016, 1) not in written)
    assert ("no 6007h" in notes) is ((0x6007, 0) not in written)
    assert ("does not supervise the bridge at all" in notes) is not watched
    with local_rig(eds) as rig:  # the EDS defaults: what the bridge gives back
        assert back == {key: rig.stored(2, *key) for key in written}


def test_an_entry_watching_another_node_is_kept() -> None:
    """Yiyou's 1016h has five entries; the first watches node 7: the bridge takes the next."""
    other = (7 << 16) | 500
    supervision, held, _ = _configured(YIYOU_EDS, before={(0x1016, 1): other})
    assert supervision.keys == ((0x1016, 2),)
    assert held == {(0x1016, 2): BRIDGE_ENTRY}


def test_the_entry_already_watching_the_bridge_is_reused() -> None:
    _, held, _ = _configured(YIYOU_EDS, before={(0x1016, 3): (1 << 16) | 900})
    assert held == {(0x1016, 3): BRIDGE_ENTRY}


def test_a_profile_naming_what_the_drive_lacks_stops_before_anything_is_written() -> None:
    profile = dataclasses.replace(
        load_profile(ROOT / "config" / "drives" / "yiyou_euservo.toml"),
        setpoint_timeout_object=(0x2FFF, 0),
    )
    with local_rig(YIYOU_EDS, profile) as rig:
        rig.master.bridge_id, rig.master.heartbeat_ms = 1, 100
        with pytest.raises(DriveSetupError, match="2FFFh:00 does not exist"):
            rig.master.configure()
        assert rig.nodes[2].data_store == {}


# --- the controller -----------------------------------------------------------------------------
def test_a_late_pre_operational_heartbeat_of_the_start_up_does_not_stop_the_axis() -> None:
    """The drive's NMT state is supervised from its first Operational heartbeat after the
    start-up on; after that, a Pre-operational one stops the axis (DRIVE_NMT)."""
    c = controller()
    c.restart_supervision()
    c.on_heartbeat(0x7F, 0.0)  # sent before it took the NMT start, read late
    assert c.drive_watch.state == 0x05
    c.on_heartbeat(0x05, 0.1)
    c.on_heartbeat(0x7F, 0.2)
    assert c.drive_watch.state == 0x7F  # supervised now: the next cycle stops the axis


def test_enabling_enters_running_only_on_a_cycle_with_every_frame() -> None:
    """The drive in Operation Enabled, but its TPDO1 (the positions) late: the move would
    start from a position never measured; the controller waits for a complete cycle."""
    c = controller()
    c.state = BridgeState.ENABLING
    position = 0.0123
    tpdo1 = struct.pack("<ii", round(position * 314.159 * 2**20 / 6.2832), round(position * 1e9))
    tpdo2 = struct.pack("<HhI", 0x1237, 0, 0)  # Operation Enabled
    c.step(0.0, None, tpdo2)
    assert c.state is BridgeState.ENABLING
    c.step(0.001, tpdo1, tpdo2)
    assert c.state is BridgeState.RUNNING
    assert c.position_reference == pytest.approx(position, abs=1e-9)


# --- the stop path ------------------------------------------------------------------------------
def test_a_stop_reaches_the_drive_by_sync_and_is_confirmed() -> None:
    """A following error mid-move (in lockstep against the simulated drive): the quick stop
    in the RPDO, SYNCs until the drive reports it out of Operation Enabled at rest."""
    params = BridgeParams.for_axis(AXIS)
    with simulated_axis(AXIS, params) as sim:
        bridge = sim.bridge
        bridge.controller.queue_move(Move(0.5, 0.3))  # needs 12 mm following error, limit 5
        bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED, cycles=2000)
        assert bridge.controller.stop_reason is StopReason.FOLLOWING_ERROR
        result = halt(bridge)
        assert result.way is HaltWay.SYNC and result.confirmed
        assert result.state in (Drive402State.QUICK_STOP_ACTIVE, Drive402State.SWITCH_ON_DISABLED)
        assert abs(sim.drive.plant.motor_speed_rad_s) <= 0.1
        assert sim.drive.state is not State402.OPERATION_ENABLED
        # the ramp of 6085h, not a coasting motor (power off: seconds from this speed)
        assert result.cycles < 200


def test_the_end_of_a_run_mid_move_ramps_the_motor_down() -> None:
    """``halt()`` (a signal, --seconds in a move): DISABLED with the quick stop, never the
    power stage switched off under a moving motor."""
    with simulated_axis(AXIS, BridgeParams.for_axis(AXIS)) as sim:
        bridge = sim.bridge
        bridge.controller.queue_move(Move(0.05, 0.05))
        bridge.run(cycles=400)
        assert sim.drive.plant.motor_speed_rad_s > 10.0
        bridge.controller.halt()
        result = halt(bridge)
        assert result.way is HaltWay.SYNC and result.confirmed
        assert sim.drive.state is State402.SWITCH_ON_DISABLED  # quick stop done (605Ah = 2)


@pytest.fixture
def bridge(served: tuple[str, threading.Event, list]) -> Iterator[Bridge]:
    bus = can.Bus(interface="virtual", channel=served[0])
    # lockstep, waiting 10 ms for a missing TPDO (not 250): a PDO loss comes within the
    # drive's consumer time of the bridge's heartbeat, which is once a cycle
    b = Bridge(bus, BridgeParams.for_axis(AXIS), AXIS.kind, LockstepPacer(0.001, wait_s=0.01))
    # a 4 s heartbeat (the drive watches it within 10 s): these tests provoke the stop paths;
    # with 100 ms, a host that starves this lockstep bridge for 250 ms (seen with both CPUs
    # busy) lets the drive's consumer stop the axis first (EMCY 8130h), a path of its own test
    b.nmt.set_period_ms(4000)
    try:
        b.start()
        b.controller.queue_move(Move(0.05, 0.02))
        b.run(cycles=300)
        assert b.controller.state is BridgeState.RUNNING
        yield b
    finally:
        b.close()
        bus.shutdown()


def test_without_tpdos_the_stop_reaches_the_drive_by_sdo(
    bridge: Bridge, tool: canopen.RemoteNode, served: tuple[str, threading.Event, list]
) -> None:
    """A tool switches the drive's TPDO1 off: PDO loss; no TPDO confirms the stop, so the
    bridge asks the drive over SDO (6041h, 606Ch) until it is at rest."""
    tool.sdo[0x1800][1].raw = 0x8000_0182
    bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED, cycles=1000)
    assert bridge.controller.stop_reason is StopReason.PDO_LOSS
    result = halt(bridge)
    assert result.way is HaltWay.SDO and result.confirmed, result
    assert result.sdo_reads >= 2
    drive = served[2][0]
    assert drive.state is not State402.OPERATION_ENABLED
    assert abs(drive.plant.motor_speed_rad_s) <= 0.1


def test_without_sdo_the_stop_is_left_to_the_drive_by_nmt(
    bridge: Bridge, tool: canopen.RemoteNode, served: tuple[str, threading.Event, list]
) -> None:
    """A tool puts the drive into NMT Stopped (no PDO, no SDO): the bridge stops the axis, no
    TPDO and no SDO answer come, so its last way is NMT Stop; the drive's own 6007h reaction
    (quick stop, on its own clock) brings the motor to rest, and its heartbeat says Stopped."""
    drive = served[2][0]
    tool.nmt.state = "STOPPED"
    bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED, cycles=1000)
    result = halt(bridge)
    assert result.way is HaltWay.NMT and not result.confirmed
    assert "its heartbeat shows stopped" in result.detail, result
    assert "NOT confirmed stopped by NMT" in result.describe(2)
    # the drive stopped itself: its quick stop on its own clock, then Switch On Disabled
    for _ in range(int(BOUND_S * 10)):
        if drive.state is State402.SWITCH_ON_DISABLED:
            break
        tool.nmt.wait_for_heartbeat(timeout=1.0)  # a heartbeat of it: its clock went on
    assert drive.state is State402.SWITCH_ON_DISABLED


def test_a_bridge_that_dies_in_its_first_cycles_is_watched_already(
    served: tuple[str, threading.Event, list], tool: canopen.RemoteNode
) -> None:
    """CiA 301: a consumer watches from the first heartbeat it receives. The start-up sends
    one right after it configured the drive's consumer, before it enables the drive: a bridge
    gone after a few cycles -- before its first periodic heartbeat -- is still watched, and
    the drive (its own clock, real time) stops itself."""
    drive = served[2][0]
    bus = can.Bus(interface="virtual", channel=served[0])
    # heartbeats on the simulated time only: a busy host's slow cycles send no periodic one
    pacer = LockstepPacer(0.001, wait_s=0.01)
    b = Bridge(bus, BridgeParams.for_axis(AXIS), AXIS.kind, pacer, wall_heartbeat=False)
    try:
        b.start()
        b.controller.queue_move(Move(0.05, 0.02))
        b.run(cycles=20)  # 20 ms of simulated time: no periodic heartbeat yet
        assert b.nmt.heartbeats_sent == 1  # the one of the start-up
        assert drive.state is State402.OPERATION_ENABLED
    finally:
        b.close()
        bus.shutdown()  # the bridge is gone: nothing of it on the bus any more
    for _ in range(int(BOUND_S * 10)):  # the drive's heartbeats: its clock goes on
        if drive.state is not State402.OPERATION_ENABLED:
            break
        tool.nmt.wait_for_heartbeat(timeout=1.0)
    assert drive.state in (State402.QUICK_STOP_ACTIVE, State402.SWITCH_ON_DISABLED)
    assert drive.error_code == 0x8130

"""Neither node dies on a bad frame: every frame is checked before a handler sees it, a
refused one is counted in the object dictionary (bridge 2110h, drive 2105h) and nothing is
raised into the loop.

The first tests reproduce the crashes of canopen's own handlers (``struct.error`` on a
0-byte heartbeat, NMT or SDO frame); the last one pours 20,000 random frames (random COB-IDs,
lengths 0..8, random data, RTR, 29-bit ids) into a running bridge + drive loop.
"""

from __future__ import annotations

import random
import struct
import uuid
from collections.abc import Iterator

import can
import pytest

from bridge import od as objdict
from bridge.cycle import BridgeState, Command, StopReason
from bridge.layout import TPDO1_STRUCT, TPDO2_STRUCT
from bridge.node import Bridge
from bridge.params import BridgeParams
from hil.harness import simulated_axis
from plant_sim.drive.rig import virtual_rig
from tests.bridge_helpers import paper_bridge
from virtual_bus import FaultConfig
from virtual_bus.formats.axis import load_axis
from virtual_bus.frame_guard import FrameFault

AXIS = load_axis("config/paper_axis.toml")


def frame(cob_id: int, data: bytes = b"", **flags: bool) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, **flags)


def bridge_count(b: Bridge, fault: FrameFault) -> int:
    """2110h:sub as an SDO upload would give it (the node's own SDO server, locally)."""
    return struct.unpack("<I", b.node.sdo.upload(objdict.FRAME_COUNTERS, fault.value))[0]


@pytest.fixture
def bridge() -> Iterator[Bridge]:
    bus = can.Bus(interface="virtual", channel=f"frames-{uuid.uuid4().hex[:12]}")
    b = paper_bridge(bus)
    try:
        b.start(configure_drive=False)
        yield b
    finally:
        b.close()
        bus.shutdown()


# --- the known crashes ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "cob_id",
    [0x702, 0x000, 0x601, 0x582, 0x082, 0x182],
    ids=["heartbeat", "nmt", "sdo-server", "sdo-client", "emcy", "tpdo1"],
)
def test_empty_frames_do_not_reach_the_bridge_handlers(bridge: Bridge, cob_id: int) -> None:
    bridge.dispatch(frame(cob_id))  # canopen's handlers raised struct.error here
    assert bridge.guard.count(FrameFault.BAD_LENGTH) == 1
    assert bridge_count(bridge, FrameFault.BAD_LENGTH) == 1
    # and the service still works: a proper heartbeat / SDO request passes
    bridge.dispatch(frame(0x702, b"\x05"))
    assert bridge.guard.count(FrameFault.BAD_LENGTH) == 1


def test_rtr_extended_error_and_unknown_frames_are_counted(bridge: Bridge) -> None:
    bridge.dispatch(frame(0x702, is_remote_frame=True))
    bridge.dispatch(can.Message(arbitration_id=0x000, data=b"\x02\x00", is_extended_id=True))
    bridge.dispatch(can.Message(is_error_frame=True))
    bridge.dispatch(frame(0x123, b"\x01"))
    for fault in (
        FrameFault.REMOTE,
        FrameFault.EXTENDED_ID,
        FrameFault.ERROR_FRAME,
        FrameFault.UNKNOWN_COB_ID,
    ):
        assert bridge_count(bridge, fault) == 1, fault


def test_a_second_sync_producer_stops_the_axis(bridge: Bridge) -> None:
    c = bridge.controller
    c.step(0.0, TPDO1_STRUCT.pack(0, 0), TPDO2_STRUCT.pack(0x0027, 0, 0))
    assert c.state is BridgeState.RUNNING
    bridge.dispatch(frame(0x080))
    assert bridge_count(bridge, FrameFault.SECOND_SYNC_PRODUCER) == 1
    assert c.state is BridgeState.STOPPED and c.stop_reason is StopReason.SYNC_CONFLICT
    assert "second SYNC producer" in c.stop_message
    c.command(Command.RESET)  # a reset clears it like any other stop
    assert c.state is BridgeState.DISABLED


def test_bad_tpdo_length_counts_in_the_pdo_counters_too(bridge: Bridge) -> None:
    bridge.dispatch(frame(0x182, bytes(5)))
    assert bridge.counters.invalid == 1
    assert bridge_count(bridge, FrameFault.BAD_LENGTH) == 1


@pytest.mark.parametrize("cob_id", [0x000, 0x602], ids=["nmt", "sdo-server"])
def test_empty_frames_do_not_reach_the_drive_handlers(cob_id: int) -> None:
    with virtual_rig(AXIS) as rig:
        bus = rig.probe.bus
        bus.send(frame(cob_id))
        bus.send(frame(0x702, is_remote_frame=True))
        bus.send(can.Message(arbitration_id=0x000, data=b"\x02\x00", is_extended_id=True))
        assert rig.sdo.sdo.upload(0x2105, FrameFault.BAD_LENGTH.value) == b"\x01\0\0\0"
        assert rig.sdo.sdo.upload(0x2105, FrameFault.REMOTE.value) == b"\x01\0\0\0"
        # the 29-bit frame with id 0 is no NMT stop command
        assert rig.sdo.sdo.upload(0x2105, FrameFault.EXTENDED_ID.value) == b"\x01\0\0\0"
        assert rig.drive.nmt_state.name == "PRE_OPERATIONAL"
    # virtual_rig raised the drive's callback errors at exit if there were any


# --- fault injection and random frames into a running loop -------------------------------------
def test_zero_length_bursts_kill_nothing() -> None:
    fault = FaultConfig(seed=3, burst_p=0.2, burst_dlc=0, burst_ids=(0x000, 0x7FF))
    with simulated_axis(AXIS, BridgeParams.for_axis(AXIS), fault=fault) as sim:
        sim.bridge.run(cycles=300)
        sim.drive.check()
        bursts = sim.bridge_bus.counters.count()
        assert bursts > 100
        refused = sim.bridge.guard.refused
        assert refused > 0
        assert sim.bridge.controller.state is not BridgeState.CONFIGURING


def test_twenty_thousand_random_frames_kill_nothing_and_are_counted() -> None:
    rng = random.Random(7)
    with simulated_axis(AXIS, BridgeParams.for_axis(AXIS)) as sim:
        injector = can.Bus(interface="virtual", channel=sim.channel)
        try:
            bridge, drive = sim.bridge, sim.drive
            seen_bridge = bridge.guard.accepted + bridge.guard.refused
            sent = 0
            for _ in range(200):
                for _ in range(100):
                    extended = rng.random() < 0.05
                    remote = rng.random() < 0.05
                    length = rng.randrange(9)
                    injector.send(
                        can.Message(
                            arbitration_id=rng.randrange(1 << 29 if extended else 1 << 11),
                            is_extended_id=extended,
                            is_remote_frame=remote,
                            dlc=length,
                            data=b"" if remote else rng.randbytes(length),
                        )
                    )
                    sent += 1
                bridge.run_cycle()
            bridge.drain()
            drive.check()  # no callback of the drive raised
            bridge_frames = bridge.guard.accepted + bridge.guard.refused - seen_bridge
            assert bridge_frames >= sent  # every injected frame passed the guard
            assert bridge.guard.refused > sent // 2
            assert drive.guard.refused > sent // 2
            # both object dictionaries still answer
            assert bridge.node.sdo.upload(objdict.STATE, 0)
            assert drive.read_object(0x2105, FrameFault.UNKNOWN_COB_ID.value) > 0
        finally:
            injector.shutdown()

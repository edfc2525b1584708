"""The bridge as an NMT slave (bridge.nmt): its heartbeat (1017h), the NMT commands of another
master, no SDO in Stopped (CiA 301 table 46), boot-up after a reset (CiA 301 figure 48), and an
enabled axis stopped when an NMT command takes the bridge out of Operational.

Independent ends: python canopen's SDO client and NMT master on a second python-can end of
the bus (``RemoteNode.nmt`` reads the heartbeats), raw frames on that end, and the simulated
drive for the stop. The heartbeat runs on the bridge's injected wall clock, stepped here.
"""

from __future__ import annotations

import struct
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import can
import canopen
import pytest

from bridge.cycle import BridgeState, StopReason
from bridge.interpolator import Move
from bridge.node import Bridge
from bridge.params import BridgeParams
from hil.harness import simulated_axis
from tests.bridge_helpers import idle_bridge, sdo_tool
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")
#: Bound of the waits for a frame (a stuck thread, never reached when all is well).
BOUND_S = 30.0


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@dataclass
class Rig:
    bridge: Bridge
    clock: Clock
    master: canopen.RemoteNode
    tool_bus: can.BusABC

    def frame(self, can_id: int) -> can.Message:
        """The next frame ``can_id`` on the tool's end (others are skipped)."""
        while True:
            msg = self.tool_bus.recv(BOUND_S)
            assert msg is not None, f"no frame 0x{can_id:03X}"
            if msg.arbitration_id == can_id:
                return msg

    def heartbeat(self) -> int:
        """Step the clock by one heartbeat period and take the heartbeat that follows."""
        self.clock.now += 0.1
        return self.frame(0x701).data[0]


@pytest.fixture
def rig() -> Iterator[Rig]:
    channel = f"nmt-{uuid.uuid4().hex[:10]}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
    bridge_bus, master_bus, tool_bus = buses
    clock = Clock()
    try:
        with idle_bridge(bridge_bus, wall=clock) as bridge, sdo_tool(master_bus, BOUND_S) as m:
            yield Rig(bridge, clock, m, tool_bus)
    finally:
        for bus in buses:
            bus.shutdown()


def test_boot_up_then_heartbeat_from_1017h_carries_the_nmt_state(rig: Rig) -> None:
    """The bridge announces itself (boot-up when it starts) and sends its heartbeat every
    100 ms by default: a drive's heartbeat consumer, or any watching node, sees it alive."""
    assert bytes(rig.frame(0x701).data) == b"\x00"  # the boot-up of Bridge.start()
    assert rig.master.sdo[0x1017].raw == 100
    assert rig.heartbeat() == 5  # operational: the bridge runs its network
    for command, state in (("PRE-OPERATIONAL", 127), ("STOPPED", 4), ("OPERATIONAL", 5)):
        rig.master.nmt.state = command
        assert rig.heartbeat() == state, command
    rig.master.sdo[0x1017].raw = 0
    assert rig.bridge.nmt.heartbeats_sent == 4
    rig.clock.now += 1.0  # no heartbeat with 1017h = 0
    rig.bridge.nmt.tick(rig.clock.now)
    assert rig.bridge.nmt.heartbeats_sent == 4


def test_no_sdo_answer_in_stopped(rig: Rig) -> None:
    def upload(index: int) -> None:
        request = struct.pack("<BHB4x", 0x40, index, 0)
        rig.tool_bus.send(can.Message(arbitration_id=0x601, data=request, is_extended_id=False))

    rig.master.nmt.state = "STOPPED"
    upload(0x1000)
    rig.master.nmt.state = "PRE-OPERATIONAL"
    upload(0x1000)
    upload(0x1018)
    # one thread handles the frames in order: the answers up to the one for 1018h show
    # whether the request sent in Stopped was answered
    answered = []
    while not answered or answered[-1] != 0x1018:
        answered.append(struct.unpack_from("<H", rig.frame(0x581).data, 1)[0])
    assert answered == [0x1000, 0x1018]


def test_reset_communication_sends_boot_up_and_enters_pre_operational(rig: Rig) -> None:
    assert bytes(rig.frame(0x701).data) == b"\x00"  # the boot-up of Bridge.start()
    rig.master.nmt.send_command(0x82)  # reset communication
    assert bytes(rig.frame(0x701).data) == b"\x00"  # boot-up
    rig.clock.now += 0.1
    assert rig.heartbeat() == 127
    assert rig.master.sdo[0x2000].raw == pytest.approx(AXIS.control.kv)  # parameters kept


def test_nmt_stop_while_running_stops_the_axis() -> None:
    with simulated_axis(AXIS, BridgeParams.for_axis(AXIS)) as sim:
        bridge = sim.bridge
        bridge.controller.queue_move(Move(0.01, 0.05))
        bridge.run(cycles=200)
        assert bridge.controller.state is BridgeState.RUNNING
        bridge.dispatch(can.Message(arbitration_id=0, data=b"\x02\x01", is_extended_id=False))
        bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED, cycles=5)
        assert bridge.controller.stop_reason is StopReason.NMT_COMMAND
        assert "NMT stopped" in bridge.controller.stop_message
        assert struct.unpack("<H", bridge.controller.rpdo_payload[:2])[0] == 0x0002  # quick stop

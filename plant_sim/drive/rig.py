"""A frame-level CANopen master for driving the simulated drive in tests and benchmarks.

:class:`BusProbe` sends NMT, SYNC and RPDO frames on its own bus and waits for the drive's
frames with a bounded timeout (no sleeps): ``expect`` returns the next frame with a CAN id;
frames received while waiting for others stay in ``seen`` until taken. :func:`virtual_rig`
puts a started drive, a probe and (on demand) a canopen SDO client on one fresh python-can
``virtual`` channel and shuts all of it down afterwards.
"""

from __future__ import annotations

import struct
import time
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import can
import canopen

from virtual_bus.contract import (
    NMT_COB_ID,
    SYNC_COB_ID,
    emcy_cob_id,
    heartbeat_cob_id,
    rpdo_cob_id,
    tpdo_cob_id,
)
from virtual_bus.formats.axis import AxisConfig

from ..plant import Plant
from .drive import DriveConfig, SimulatedDrive
from .node import NmtCommand


class BusProbe:
    """Master side of a frame exchange with one drive (node ``node_id``) on ``bus``."""

    def __init__(self, bus: can.BusABC, node_id: int = 2, timeout_s: float = 2.0) -> None:
        self.bus = bus
        self.node_id = node_id
        self.timeout_s = timeout_s
        self.seen: list[can.Message] = []  # received, not yet taken by expect()

    # --- sending -------------------------------------------------------------------------------
    def send(self, can_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def nmt(self, command: NmtCommand, node_id: int | None = None) -> None:
        target = self.node_id if node_id is None else node_id
        self.send(NMT_COB_ID, bytes([command, target]))

    def sync(self, counter: int | None = None) -> None:
        self.send(SYNC_COB_ID, b"" if counter is None else bytes([counter]))

    def rpdo(self, number: int, data: bytes) -> None:
        self.send(rpdo_cob_id(number, self.node_id), data)

    def setpoint(self, controlword: int, target_velocity: int) -> None:
        """RPDO1 of the default layout: 6040h (16) + 60FFh (32)."""
        self.rpdo(1, struct.pack("<Hl", controlword, target_velocity))

    # --- receiving -----------------------------------------------------------------------------
    def tpdo_id(self, number: int) -> int:
        return tpdo_cob_id(number, self.node_id)

    @property
    def emcy_id(self) -> int:
        return emcy_cob_id(self.node_id)

    @property
    def heartbeat_id(self) -> int:
        return heartbeat_cob_id(self.node_id)

    def expect(self, can_id: int, timeout_s: float | None = None) -> can.Message:
        """The oldest frame with ``can_id`` not taken yet: from ``seen`` (frames received
        while waiting for others), else from the bus, putting other frames into ``seen``.
        TimeoutError if none comes within the timeout."""
        for i, msg in enumerate(self.seen):
            if msg.arbitration_id == can_id:
                return self.seen.pop(i)
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            left = deadline - time.monotonic()
            msg = self.bus.recv(max(0.0, left)) if left > 0 else None
            if msg is None:
                raise TimeoutError(f"no frame 0x{can_id:03X} within the timeout")
            if msg.arbitration_id == can_id:
                return msg
            self.seen.append(msg)

    def drain(self) -> list[can.Message]:
        """Take every frame not taken yet: ``seen`` and what waits on the bus (no blocking)."""
        got, self.seen = self.seen, []
        while (msg := self.bus.recv(0.0)) is not None:
            got.append(msg)
        return got

    def sync_and_collect(self, can_ids: Iterable[int]) -> dict[int, bytes]:
        """Send SYNC and return the data of one frame of each of ``can_ids`` (in any order)."""
        wanted = set(can_ids)
        self.sync()
        got: dict[int, bytes] = {}
        deadline = time.monotonic() + self.timeout_s
        while wanted - got.keys():
            left = deadline - time.monotonic()
            msg = self.bus.recv(left) if left > 0 else None
            if msg is None:
                missing = ", ".join(f"0x{c:03X}" for c in sorted(wanted - got.keys()))
                raise TimeoutError(f"after SYNC no frame {missing} within the timeout")
            if msg.arbitration_id in wanted and msg.arbitration_id not in got:
                got[msg.arbitration_id] = bytes(msg.data)
            else:
                self.seen.append(msg)
        return got

    def frames(self, can_id: int) -> list[can.Message]:
        """The frames with ``can_id`` in ``seen``."""
        return [m for m in self.seen if m.arbitration_id == can_id]


@dataclass
class Rig:
    """A started drive and the master side on one virtual channel (see :func:`virtual_rig`)."""

    drive: SimulatedDrive
    probe: BusProbe
    channel: str
    _client: canopen.Network | None = field(default=None, repr=False)
    _remote: canopen.RemoteNode | None = field(default=None, repr=False)

    @property
    def sdo(self) -> canopen.RemoteNode:
        """A canopen RemoteNode of the drive (own bus and notifier), made on first use."""
        if self._remote is None:
            bus = can.Bus(interface="virtual", channel=self.channel)
            network = canopen.Network(bus)
            network.NOTIFIER_CYCLE = 0.05
            network.connect()
            self._client = network
            self._remote = network.add_node(self.drive.node_id, str(self.drive.config.eds_path))
        return self._remote

    def close(self) -> None:
        if self._client is not None:
            self._client.disconnect()
            self._client = None
            self._remote = None


@contextmanager
def virtual_rig(
    axis: AxisConfig,
    *,
    node_id: int = 2,
    config: DriveConfig | None = None,
    plant: Plant | None = None,
) -> Iterator[Rig]:
    """A drive started on a fresh python-can virtual channel with a :class:`BusProbe`;
    everything (drive, notifiers, buses) is stopped at exit and the drive's callback errors
    are raised (:meth:`SimulatedDrive.check`)."""
    channel = f"drive-{uuid.uuid4().hex[:12]}"
    drive_bus = can.Bus(interface="virtual", channel=channel)
    master_bus = can.Bus(interface="virtual", channel=channel)
    rig: Rig | None = None
    try:
        drive = SimulatedDrive(drive_bus, node_id, axis, config, plant)
        rig = Rig(drive, BusProbe(master_bus, node_id), channel)
        drive.start()
        yield rig
    finally:
        try:
            if rig is not None:
                rig.drive.stop()
                rig.close()
        finally:
            drive_bus.shutdown()
            master_bus.shutdown()
    rig.drive.check()

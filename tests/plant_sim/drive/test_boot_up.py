"""The boot-up message means "ready for SDO" (CiA 301: it is sent on the transition to
Pre-operational, and a master may answer it at once with an SDO request).

On a busy one-CPU guest a master's request reached the drive before the drive had changed
its state after sending the boot-up, and the frame guard refused it ("not in state"): the
master's SDO timed out. Checked without a clock: at the instant the boot-up leaves, the
drive's own frame guard admits an SDO request, and no heartbeat went out before it.
"""

from __future__ import annotations

import uuid

import can

from plant_sim.drive import SimulatedDrive
from plant_sim.drive.node import NmtState
from virtual_bus.formats.axis import load_axis
from virtual_bus.frame_guard import FrameFault
from virtual_bus.inprocess import InProcessBus

AXIS = load_axis("config/paper_axis.toml")


class Watching(InProcessBus):
    """The drive's end of the bus: at each frame it sends, what its guard would say to an
    SDO request (0x602, 8 bytes) and its NMT state."""

    def __init__(self, channel: str) -> None:
        super().__init__(channel)
        self.drive: SimulatedDrive | None = None
        self.seen: list[tuple[int, bytes, FrameFault | None, NmtState]] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        assert self.drive is not None
        verdict = self.drive.guard.classify(0x602, 8)
        self.seen.append((msg.arbitration_id, bytes(msg.data), verdict, self.drive.nmt_state))
        super().send(msg, timeout)


def test_an_sdo_request_answering_the_boot_up_is_admitted() -> None:
    channel = f"boot-{uuid.uuid4().hex[:10]}"
    bus = Watching(channel)
    try:
        drive = SimulatedDrive(bus, 2, AXIS)
        bus.drive = drive
        drive.start()
        try:
            first = bus.seen[0]
            assert first[:2] == (0x702, b"\x00")  # the boot-up is the drive's first frame
            assert first[2] is None  # an SDO request now is admitted ...
            assert first[3] is NmtState.PRE_OPERATIONAL  # ... in Pre-operational
        finally:
            drive.stop()
    finally:
        bus.shutdown()


def _upload_request(index: int, subindex: int) -> can.Message:
    """CiA 301 SDO initiate upload request (command specifier 0x40) to node 2."""
    data = bytes([0x40, index & 0xFF, index >> 8, subindex, 0, 0, 0, 0])
    return can.Message(arbitration_id=0x602, data=data, is_extended_id=False)


def test_requests_sent_before_the_boot_up_are_not_answered_after_it() -> None:
    """A master asking 1000h while the drive still boots (compiles) gets no late answers:
    the first SDO answer after the boot-up is the one to the request sent after it."""
    channel = f"boot-{uuid.uuid4().hex[:10]}"
    drive_bus, master = InProcessBus(channel), InProcessBus(channel)
    try:
        drive = SimulatedDrive(drive_bus, 2, AXIS)
        for _ in range(3):  # a master's tries while nobody answers
            master.send(_upload_request(0x1000, 0))
        drive.start()
        try:
            boot = master.recv(10.0)
            assert boot is not None and (boot.arbitration_id, bytes(boot.data)) == (0x702, b"\0")
            master.send(_upload_request(0x1018, 1))
            answer = master.recv(10.0)
            while answer is not None and answer.arbitration_id != 0x582:
                answer = master.recv(10.0)
            assert answer is not None
            assert bytes(answer.data[1:4]) == bytes([0x18, 0x10, 0x01])  # 1018h:01, not 1000h
            assert drive.guard.refused == 0  # they were not the drive's to refuse either
        finally:
            drive.stop()
    finally:
        drive_bus.shutdown()
        master.shutdown()

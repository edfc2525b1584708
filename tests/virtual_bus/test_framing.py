"""The frame ports of a real-time loop (virtual_bus.framing) against python-can's own code.

python-can's udp_multicast wire format (``pack_message`` / ``unpack_message``, code this
project did not write) is the oracle of the in-place reader and of the frame templates; its
own ``UdpMulticastBus`` sends to our port and receives from it in a private network
namespace, and the kernel's socket filter that drops our own frames is checked at the
socket, below python-can. SocketCAN: python-can's socketcan bus against the raw port on
vcan0 (marker ``vcan``; run in a guest with a CAN stack where the host has none).
"""

from __future__ import annotations

import random
from collections.abc import Callable

import can
import pytest
from can.interfaces.udp_multicast.utils import pack_message, unpack_message

from virtual_bus.config import BusConfig, Interface
from virtual_bus.framing import NOTHING, OTHER, MessagePort, SocketCanPort, frame_port
from virtual_bus.open import open_bus
from virtual_bus.udp import own_frame_filter, parse_plain

CHANNELS = (None, "239.74.163.2", "own-" + "0123456789abcdef" * 2, "x" * 31, "y" * 40)


def _messages(seed: int, n: int) -> list[can.Message]:
    rng = random.Random(seed)
    out = []
    for _ in range(n):
        dlc = rng.randint(0, 8)
        out.append(
            can.Message(
                timestamp=rng.uniform(0.0, 2e9),
                arbitration_id=rng.randint(0, 0x7FF),
                is_extended_id=False,
                data=bytes(rng.randrange(256) for _ in range(dlc)),
                channel=rng.choice(CHANNELS),
            )
        )
    return out


def test_a_plain_frame_is_read_where_python_cans_pack_message_put_it() -> None:
    for msg in _messages(seed=3, n=2000):
        packed = bytearray(pack_message(msg)) + bytes(50)  # a receive buffer is longer
        size = len(packed) - 50
        found = parse_plain(packed, size)
        theirs = unpack_message(bytes(packed[:size]), check=True)
        assert found is not None, msg
        cob_id, length, offset, _ = found
        assert (cob_id, length) == (theirs.arbitration_id, theirs.dlc)
        assert bytes(packed[offset : offset + length]) == bytes(theirs.data)


@pytest.mark.parametrize(
    "fields",
    [
        {"is_remote_frame": True, "dlc": 2},
        {"is_extended_id": True, "arbitration_id": 0x1ABCDE01},
        {"is_error_frame": True},
        {"is_fd": True, "data": bytes(12)},
        {"arbitration_id": 0x800, "is_extended_id": True},
        {"channel": 7},
    ],
)
def test_anything_else_is_left_to_msgpack(fields: dict[str, object]) -> None:
    base: dict[str, object] = {"arbitration_id": 0x181, "is_extended_id": False, "data": b"\1"}
    msg = can.Message(**{**base, **fields})
    packed = bytearray(pack_message(msg))
    assert parse_plain(packed, len(packed)) is None
    assert parse_plain(bytearray(b"\x93not a frame"), 12) is None


def test_the_own_frame_filter_is_a_classic_bpf_program_that_ends_in_returns() -> None:
    program = own_frame_filter(b"own-" + b"f" * 32)
    assert len(program) < 64 and program[-1] == (0x06, 0, 0, 0xFFFFFFFF)
    for at, (code, jt, jf, _k) in enumerate(program):  # jumps stay inside, forward
        if code & 0x07 == 0x05:
            assert at + 1 + max(jt, jf) < len(program)
    with pytest.raises(ValueError):
        own_frame_filter(b"short")


def test_a_message_port_reads_python_cans_virtual_bus() -> None:
    config = BusConfig(interface=Interface.VIRTUAL, channel="framing-test")
    ours, theirs = open_bus(config), open_bus(config)
    try:
        port = frame_port(ours)
        assert isinstance(port, MessagePort)
        theirs.send(can.Message(arbitration_id=0x182, data=b"\1\2\3", is_extended_id=False))
        theirs.send(can.Message(arbitration_id=0x702, is_remote_frame=True, is_extended_id=False))
        assert port.receive(1.0) == 0x182 == port.cob_id and port.length == 3
        assert bytes(port.buffer[port.offset : port.offset + 3]) == b"\1\2\3"
        assert port.receive(1.0) == OTHER == port.cob_id
        assert port.message().is_remote_frame
        frame = port.frame(0x202, 6)
        frame.buffer[frame.offset : frame.offset + 6] = b"abcdef"
        port.send(frame)
        got = theirs.recv(1.0)
        assert got is not None and (got.arbitration_id, bytes(got.data)) == (0x202, b"abcdef")
        assert port.receive(0.0) == NOTHING
    finally:
        ours.shutdown()
        theirs.shutdown()


UDP_SCRIPT = r"""
import json, socket

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.utils import pack_message

from virtual_bus.framing import NOTHING, OTHER, UdpPort, frame_port
from virtual_bus.netns import UDP_GROUP
from virtual_bus.udp import LoopbackUdpBus

out = {}
theirs = UdpMulticastBus(channel=UDP_GROUP, fd=False)
ours = LoopbackUdpBus(UDP_GROUP)
port = frame_port(ours)
out["kind"] = type(port).__name__
out["filters_own_frames"] = ours.filters_own_frames
try:
    # the same kinds of frames twice (the second time recognised by its bytes), then others
    sent = []
    for payload in (b"\x01\x02\x03\x04\x05\x06\x07\x08", b"\x10\x20\x30\x40\x50\x60\x70\x80"):
        for cob_id in (0x182, 0x282, 0x005, 0x7FF):
            msg = can.Message(arbitration_id=cob_id, data=payload[: cob_id % 9],
                              is_extended_id=False)
            theirs.send(msg)
            sent.append([cob_id, payload[: cob_id % 9].hex()])
    got = []
    for _ in sent:
        assert port.receive(5.0) >= 0
        got.append([port.cob_id, bytes(port.buffer[port.offset:port.offset + port.length]).hex()])
    out["plain"] = got == sent
    theirs.send(can.Message(arbitration_id=0x1ABCDE01, data=b"\x09", is_extended_id=True))
    assert port.receive(5.0) == OTHER
    m = port.message()
    out["extended"] = [port.cob_id, m.arbitration_id, m.is_extended_id, m.data.hex()]
    # frames our port sends are python-can's format, with our token as channel
    frame = port.frame(0x202, 6)
    frame.buffer[frame.offset:frame.offset + 6] = b"\x0f\x00\x10\x20\x30\x40"
    port.send(frame)
    back = theirs.recv(5.0)
    while back.arbitration_id != 0x202:  # python-can's bus gets its own frames too
        back = theirs.recv(5.0)
    out["theirs_got"] = [back.arbitration_id, back.dlc, back.data.hex()]
    tagged = can.Message(arbitration_id=0x202, data=b"\x0f\x00\x10\x20\x30\x40",
                         is_extended_id=False, channel=ours._token)
    out["template_is_pack_message"] = bytes(frame.wire) == pack_message(tagged)
    # the kernel drops our own frames: a marker sent by the other bus after our own frame
    # is the first thing the socket holds (datagrams on one host arrive in sending order)
    ours.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
    theirs.send(can.Message(arbitration_id=0x7FE, data=b"\x7e", is_extended_id=False))
    kind = port.receive(5.0)
    assert kind >= 0 or kind == OTHER
    first = port.message().arbitration_id if kind == OTHER else port.cob_id
    out["own_at_socket"] = first != 0x7FE
    # a datagram that is no frame still arrives, and is python-can's error
    plain = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plain.sendto(b"\x93not a frame", ours.destination)
    assert port.receive(5.0) == OTHER
    try:
        port.message()
        out["garbage"] = "accepted"
    except can.CanOperationError as exc:
        out["garbage"] = type(exc).__name__
    out["nothing_left"] = port.receive(0.05) == NOTHING
finally:
    ours.shutdown()
    theirs.shutdown()
print(json.dumps(out))
"""


def test_the_udp_port_against_python_cans_udp_multicast(
    netns_script: Callable[[str], dict],
) -> None:
    out = netns_script(UDP_SCRIPT)
    assert out["kind"] == "UdpPort" and out["filters_own_frames"] is True
    assert out["plain"] is True
    assert out["extended"] == [-1, 0x1ABCDE01, True, "09"]
    assert out["theirs_got"] == [0x202, 6, "0f0010203040"]
    assert out["template_is_pack_message"] is True
    assert out["own_at_socket"] is False
    assert out["garbage"] == "CanOperationError"
    assert out["nothing_left"] is True


@pytest.mark.vcan
def test_the_socketcan_port_against_python_cans_socketcan_bus() -> None:
    config = BusConfig(interface=Interface.SOCKETCAN, channel="vcan0")
    ours, theirs = open_bus(config), open_bus(config)
    try:
        port = frame_port(ours)
        assert isinstance(port, SocketCanPort)
        theirs.send(can.Message(arbitration_id=0x182, data=b"\1\2\3\4", is_extended_id=False))
        theirs.send(can.Message(arbitration_id=0x1ABCDE01, data=b"\5", is_extended_id=True))
        theirs.send(can.Message(arbitration_id=0x702, is_remote_frame=True, is_extended_id=False))
        assert port.receive(2.0) == 0x182 and port.length == 4
        assert bytes(port.buffer[port.offset : port.offset + 4]) == b"\1\2\3\4"
        assert port.receive(2.0) == OTHER
        m = port.message()
        assert (m.arbitration_id, m.is_extended_id, bytes(m.data)) == (0x1ABCDE01, True, b"\5")
        assert port.receive(2.0) == OTHER and port.message().is_remote_frame
        frame = port.frame(0x202, 6)
        frame.buffer[frame.offset : frame.offset + 6] = b"\x0f\x00\x01\x02\x03\x04"
        port.send(frame)
        got = theirs.recv(2.0)
        assert got is not None
        assert (got.arbitration_id, got.is_extended_id, bytes(got.data)) == (
            0x202,
            False,
            b"\x0f\x00\x01\x02\x03\x04",
        )
        assert port.receive(0.0) == NOTHING  # a CAN socket does not receive its own frames
    finally:
        ours.shutdown()
        theirs.shutdown()


TEMPLATES_SCRIPT = r"""
import json, random

from can.interfaces.udp_multicast.utils import unpack_message

from virtual_bus.framing import frame_port
from virtual_bus.netns import UDP_GROUP
from virtual_bus.udp import LoopbackUdpBus

ours = LoopbackUdpBus(UDP_GROUP)
port = frame_port(ours)
senders = [LoopbackUdpBus(UDP_GROUP), LoopbackUdpBus(UDP_GROUP)]
sending = [frame_port(bus) for bus in senders]
# frames of one size: COB-IDs told apart by their bytes (0x182 / 0x282 / 0x082), and kinds
# that share the recogniser's place (0x005 / 0x006: one-byte COB-IDs; 0x182 from a second
# sender), which are parsed every time
kinds = [(0, 0x182), (0, 0x282), (0, 0x082), (0, 0x005), (0, 0x006), (1, 0x182)]
frames = [sending[s].frame(cob_id, 8) for s, cob_id in kinds]
rng = random.Random(19)
mismatches = []
count = 0
try:
    for _ in range(5):
        order = list(range(len(kinds)))
        rng.shuffle(order)
        for i in order:
            frame = frames[i]
            payload = bytes(rng.randrange(256) for _ in range(8))
            frame.buffer[frame.offset : frame.offset + 8] = payload
            frame.send()
            cob_id = port.receive(5.0)
            oracle = unpack_message(bytes(port.buffer[: port.size]))
            got = [cob_id, bytes(port.buffer[port.offset : port.offset + port.length]).hex()]
            want = [kinds[i][1], payload.hex()]
            if got != want or [oracle.arbitration_id, oracle.data.hex()] != want:
                mismatches.append([got, want])
            count += 1
    out = {"count": count, "mismatches": mismatches, "nothing_left": port.receive(0.05) < -1}
finally:
    ours.shutdown()
    for bus in senders:
        bus.shutdown()
print(json.dumps(out))
"""


def test_the_udp_port_tells_same_size_frames_of_templates_apart(
    netns_script: Callable[[str], dict],
) -> None:
    """Frames sent from templates (timestamp 0.0: recognised by their bytes after the first)
    of one size and different COB-IDs and senders, in random order: every one is read with
    its own COB-ID and payload, as python-can's ``unpack_message`` reads the datagram."""
    out = netns_script(TEMPLATES_SCRIPT)
    assert out == {"count": 30, "mismatches": [], "nothing_left": True}

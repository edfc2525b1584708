"""virtual_bus.udp.LoopbackUdpBus against python-can's own ``UdpMulticastBus`` and its own
``pack_message`` (code this project did not write), inside a private network namespace the
test creates and removes: the same bytes on the wire, frames cross both ways, our own frames
never come back, a datagram that is no frame is one CanOperationError (as python-can's)."""

from __future__ import annotations

from collections.abc import Callable

INTEROP = r"""
import json, socket, struct, time

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.utils import pack_message

from virtual_bus.netns import UDP_GROUP
from virtual_bus.udp import LoopbackUdpBus

out = {}
raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # a plain listener on the group
raw.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
raw.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
raw.bind(("", 43113))
raw.setsockopt(
    socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
    socket.inet_aton(UDP_GROUP) + struct.pack("@I", socket.INADDR_ANY),
)
raw.settimeout(5.0)
theirs = UdpMulticastBus(channel=UDP_GROUP, fd=False)
ours = LoopbackUdpBus(UDP_GROUP)
try:
    sent = can.Message(
        arbitration_id=0x1ABCDE01, data=b"\x01\x02\x03", is_extended_id=True, timestamp=12.5
    )
    ours.send(sent)
    datagram = raw.recv(4096)
    tagged = can.Message(
        arbitration_id=0x1ABCDE01, data=b"\x01\x02\x03", is_extended_id=True, timestamp=12.5,
        channel=ours._token,
    )
    out["same_bytes_as_pack_message"] = datagram == pack_message(tagged)
    got = theirs.recv(5.0)
    out["theirs_got"] = [got.arbitration_id, got.is_extended_id, got.dlc, got.data.hex()]
    out["ours_own_frame"] = ours.recv(0.0) is None and ours.recv(0.05) is None
    before = time.time()
    theirs.send(can.Message(arbitration_id=0x182, data=bytes(range(8)), is_extended_id=False))
    back = ours.recv(5.0)
    out["ours_got"] = [back.arbitration_id, back.is_extended_id, back.dlc, back.data.hex(),
                       back.channel, before - 1.0 <= back.timestamp <= time.time() + 1.0]
    remote = can.Message(arbitration_id=0x702, is_remote_frame=True, dlc=1, is_extended_id=False)
    theirs.send(remote)
    back = ours.recv(5.0)
    out["remote"] = [back.arbitration_id, back.is_remote_frame, back.dlc]
    # an FD frame on a classic bus is dropped (python-can's rule), then the next one comes
    theirs_fd = UdpMulticastBus(channel=UDP_GROUP, fd=True)
    theirs_fd.send(can.Message(arbitration_id=0x300, data=bytes(12), is_fd=True,
                               is_extended_id=False))
    theirs.send(can.Message(arbitration_id=0x301, data=b"", is_extended_id=False))
    out["after_fd"] = hex(ours.recv(5.0).arbitration_id)
    theirs_fd.shutdown()
    raw.sendto(b"\x93not a frame", (UDP_GROUP, 43113))
    try:
        ours.recv(5.0)
        out["garbage"] = "accepted"
    except can.CanOperationError as exc:
        out["garbage"] = type(exc).__name__
    theirs.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
    out["after_garbage"] = hex(ours.recv(5.0).arbitration_id)
finally:
    ours.shutdown()
    theirs.shutdown()
    raw.close()
print(json.dumps(out))
"""


def test_loopback_bus_speaks_python_cans_udp_multicast_format(
    netns_script: Callable[[str], dict],
) -> None:
    out = netns_script(INTEROP)
    assert out["same_bytes_as_pack_message"] is True
    assert out["theirs_got"] == [0x1ABCDE01, True, 3, "010203"]
    assert out["ours_own_frame"] is True
    assert out["ours_got"] == [0x182, False, 8, "0001020304050607", "239.74.163.2", True]
    assert out["remote"] == [0x702, True, 1]
    assert out["after_fd"] == "0x301"
    assert out["garbage"] == "CanOperationError"
    assert out["after_garbage"] == "0x80"

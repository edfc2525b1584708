"""python-can's ``udp_multicast`` bus, confined to a private network namespace, without the
echo of its own frames, and with a short receive and send path.

Multicast is looped back to every socket of the host that joined the group, the sender's
own included (``IP_MULTICAST_LOOP``; python-can's ``UdpMulticastBus`` says
``receive_own_messages`` is unsupported, and in fact always receives its own frames). A CAN
controller does not receive its own frames, and the bridge and the drive rely on that (a
master would see its own SYNC as a second SYNC producer). :class:`LoopbackUdpBus` puts a
token of its own in the ``channel`` field python-can packs with each frame it sends, and
drops a received datagram that carries that token before it is decoded.

The wire format is python-can's, field for field (``can.interfaces.udp_multicast.utils``:
a msgpack map of the :class:`can.Message` fields, the timestamp taken from the kernel's
``SO_TIMESTAMPNS``), so python-can's own ``UdpMulticastBus`` and this class talk to each
other (``tests/virtual_bus/test_udp.py`` checks it against python-can's class). Only the path is
shorter, for a loop that sends and receives a few frames every millisecond:

* send: the frame's fields go straight into the map (python-can's ``pack_message`` of a
  copy of the message carrying the token did the same with two more object copies);
* receive: into one buffer allocated when the bus is opened (``recvmsg_into``); without a
  timeout a non-blocking read with no ``select`` first (a poll is one system call); the
  own-frame check looks at the raw datagram, so an own frame is never unpacked.
"""

from __future__ import annotations

import select
import socket
import struct
import time
import uuid

import can
import msgpack
from can.interfaces.udp_multicast import UdpMulticastBus

from virtual_bus.errors import BusConfigError
from virtual_bus.netns import UDP_GROUP, private_namespace_problem

#: python-can's receive buffer size (GeneralPurposeUdpMulticastBus.max_buffer), bytes.
MAX_DATAGRAM = 4096
#: struct timespec of SO_TIMESTAMPNS (linux).
_TIMESPEC = struct.Struct("@ll")
_SO_TIMESTAMPNS = 35
_ANCILLARY_SIZE = socket.CMSG_SPACE(_TIMESPEC.size)


class LoopbackUdpBus(UdpMulticastBus):
    """``UdpMulticastBus`` on ``channel`` (default :data:`UDP_GROUP`) that refuses to open
    outside a private network namespace (:func:`private_namespace_problem`) and never
    returns its own frames. Received frames carry ``channel`` = the group.

    One thread receives at a time (the receive buffer is the bus's; the bridge and the drive
    hand the bus from their start-up thread to their loop, never share it); any thread may
    send."""

    def __init__(self, channel: str = UDP_GROUP, *, fd: bool = False) -> None:
        problem = private_namespace_problem()
        if problem is not None:
            raise BusConfigError(
                f"interface 'udp_multicast' is not allowed here: it sends frames to a real "
                f"network interface ({problem}); use it only inside a private network "
                "namespace (virtual_bus.netns), or use 'virtual' or 'socketcan'"
            )
        super().__init__(channel=channel, fd=fd)
        self.group = channel
        self._fd = fd
        self._token = f"own-{uuid.uuid4().hex}"
        # how the token appears in a packed frame: the key, a str8 header, the text
        token = self._token.encode()
        self._own_marker = msgpack.packb("channel") + msgpack.packb(self._token)
        assert self._own_marker.endswith(token)
        self._socket: socket.socket = self._multicast._socket
        self._destination = (self._multicast.group, self._multicast.port)
        self._timestamps = self._multicast.timestamp_nanosecond
        self._buffer = bytearray(MAX_DATAGRAM)
        self._view = memoryview(self._buffer)
        self._buffers = [self._buffer]
        self.channel_info = f"udp_multicast group {channel}"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd and not self._fd:
            raise can.CanOperationError("cannot send FD message over bus with CAN FD disabled")
        packed = msgpack.packb(
            {  # python-can's pack_message, field for field, with our token as channel
                "timestamp": msg.timestamp,
                "arbitration_id": msg.arbitration_id,
                "is_extended_id": msg.is_extended_id,
                "is_remote_frame": msg.is_remote_frame,
                "is_error_frame": msg.is_error_frame,
                "channel": self._token,
                "dlc": msg.dlc,
                "data": msg.data,
                "is_fd": msg.is_fd,
                "bitrate_switch": msg.bitrate_switch,
                "error_state_indicator": msg.error_state_indicator,
            },
            use_bin_type=True,
        )
        if timeout is None:
            try:
                sent = self._socket.sendto(packed, self._destination)
            except OSError as error:
                raise can.CanOperationError("failed to send via socket") from error
            if sent < len(packed):
                raise can.CanTimeoutError()
        else:
            self._multicast.send(packed, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        sock = self._socket
        try:
            if timeout is not None and timeout <= 0.0:
                try:
                    size, ancillary, _, _ = sock.recvmsg_into(
                        self._buffers, _ANCILLARY_SIZE, socket.MSG_DONTWAIT
                    )
                except BlockingIOError:
                    return None, False
            else:
                ready, _, _ = select.select((sock,), (), (), timeout)
                if not ready:
                    return None, False
                size, ancillary, _, _ = sock.recvmsg_into(self._buffers, _ANCILLARY_SIZE)
        except OSError as exc:
            raise can.CanOperationError(f"Failed to receive from IP/UDP socket: {exc}") from exc
        if self._buffer.find(self._own_marker, 0, size) >= 0:
            return None, False  # our own frame, looped back by the kernel
        return self._decode(self._view[:size], ancillary), False

    def _decode(
        self, datagram: memoryview, ancillary: list[tuple[int, int, bytes]]
    ) -> can.Message | None:
        """One received frame (python-can's unpack_message, check=True), or None for an FD
        frame on a classic bus (as python-can)."""
        try:
            fields = msgpack.unpackb(datagram, raw=False)
            if self._timestamps:
                seconds, nanoseconds = _TIMESPEC.unpack_from(ancillary[0][2])
                fields["timestamp"] = seconds + nanoseconds * 1e-9
            else:
                fields["timestamp"] = time.time()
            fields["channel"] = self.group
            msg = can.Message(check=True, **fields)
        except Exception as exc:
            raise can.CanOperationError("could not unpack received message") from exc
        if msg.is_fd and not self._fd:
            return None
        return msg

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

For a loop without a Python object per frame (:class:`virtual_bus.framing.UdpPort`) the bus
also reads a classic standard data frame in place (:func:`parse_plain`: the
fields at the positions python-can's ``pack_message`` puts them; anything else is left to
msgpack and python-can's checks) and gives templates of the frames such a loop sends
(:meth:`LoopbackUdpBus.template`: the datagram ``send`` would make, with the payload's
offset). tests/virtual_bus/test_framing.py checks both against python-can's ``pack_message`` and
``unpack_message``.
"""

from __future__ import annotations

import ctypes
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

# python-can's pack_message: a map of 11 fields in this order (msgpack, use_bin_type); what a
# classic standard data frame looks like around its identifier, channel, dlc and data
HEAD = b"\x8b\xa9timestamp\xcb"  # fixmap 11, "timestamp": float 64
#: where the timestamp's 8 bytes end
TIMESTAMP_END = len(HEAD) + 8
_ID_KEY = b"\xaearbitration_id"
_ID_AT = TIMESTAMP_END
_VALUE_AT = _ID_AT + len(_ID_KEY)
#: Where a plain frame's COB-ID above 0x7F has its byte(s) (after msgpack's type byte): two
#: bytes there tell most kinds of frame of one size apart (virtual_bus.framing.UdpPort).
KIND_AT = _VALUE_AT + 1
_PLAIN_FLAGS = b"\xaeis_extended_id\xc2\xafis_remote_frame\xc2\xaeis_error_frame\xc2\xa7channel"
_CHANNEL_KEY_SIZE = 8  # "\xa7channel"
_DLC_KEY = b"\xa3dlc"
_DATA_KEY = b"\xa4data\xc4"  # bin 8
_PLAIN_TAIL = b"\xa5is_fd\xc2\xaebitrate_switch\xc2\xb5error_state_indicator\xc2"


def parse_plain(buffer: bytearray, size: int) -> tuple[int, int, int, int] | None:
    """A classic standard data frame in python-can's wire format, read where
    ``pack_message`` puts its fields: (COB-ID, length, payload offset, channel offset), or
    None for anything else (other frame kinds, other encodings, garbage: msgpack decides)."""
    if not buffer.startswith(HEAD) or not buffer.startswith(_ID_KEY, _ID_AT):
        return None
    pos = _VALUE_AT
    kind = buffer[pos]
    if kind < 0x80:  # positive fixint
        cob_id = kind
        pos += 1
    elif kind == 0xCC:  # uint 8
        cob_id = buffer[pos + 1]
        pos += 2
    elif kind == 0xCD:  # uint 16, big endian
        cob_id = buffer[pos + 1] << 8 | buffer[pos + 2]
        pos += 3
    else:
        return None
    if cob_id > 0x7FF or not buffer.startswith(_PLAIN_FLAGS, pos):
        return None
    pos += len(_PLAIN_FLAGS)
    channel_at = pos - _CHANNEL_KEY_SIZE
    kind = buffer[pos]
    if 0xA0 <= kind <= 0xBF:  # fixstr
        pos += 1 + kind - 0xA0
    elif kind == 0xD9:  # str 8
        pos += 2 + buffer[pos + 1]
    elif kind == 0xC0:  # nil
        pos += 1
    else:
        return None
    if not buffer.startswith(_DLC_KEY, pos):
        return None
    dlc = buffer[pos + 4]
    pos += 5
    if dlc > 8 or not buffer.startswith(_DATA_KEY, pos) or buffer[pos + 6] != dlc:
        return None
    offset = pos + 7
    pos = offset + dlc
    if pos + len(_PLAIN_TAIL) != size or not buffer.startswith(_PLAIN_TAIL, pos):
        return None
    return cob_id, dlc, offset, channel_at


#: setsockopt option of a classic BPF socket filter (linux/asm-generic/socket.h).
SO_ATTACH_FILTER = 26
#: where the token's text starts in a frame this bus sends, after an identifier of 1, 2 or 3
#: bytes: the channel key and a str 8 header after the three flags
_TOKEN_AFTER_ID = len(_PLAIN_FLAGS) + 2
_UDP_HEADER = 8


class _SockFilter(ctypes.Structure):
    _fields_ = (
        ("code", ctypes.c_uint16),
        ("jt", ctypes.c_uint8),
        ("jf", ctypes.c_uint8),
        ("k", ctypes.c_uint32),
    )


class _SockFprog(ctypes.Structure):
    _fields_ = (("len", ctypes.c_ushort), ("filter", ctypes.POINTER(_SockFilter)))


def own_frame_filter(token: bytes) -> list[tuple[int, int, int, int]]:
    """A classic BPF program (code, jt, jf, k) for a UDP socket that drops the datagrams of
    python-can's format carrying ``token`` as a str 8 channel where :meth:`LoopbackUdpBus.
    send` puts it, and keeps everything else (other layouts, short or foreign datagrams: the
    bus still drops an own frame it finds in user space). Offsets count from the UDP header.
    """
    if len(token) % 4 or not 32 <= len(token) <= 255:
        raise ValueError("token: 32..255 bytes, a multiple of 4")
    ld_len, ldb_abs, ld_ind, ldh_ind, ldx_imm = 0x80, 0x30, 0x40, 0x48, 0x01
    jeq, jge, ja, ret = 0x15, 0x35, 0x05, 0x06
    head = _UDP_HEADER
    # the token's str 8 header (d9, length), after an identifier of L bytes: + L (classic BPF
    # has no negative offsets to reach back from the text)
    header_at = head + _VALUE_AT + _TOKEN_AFTER_ID - 2
    # (code, jump if true, jump if false, k); jumps name labels, None: the next instruction
    asm: list[tuple[int, str | None, str | None, int | str]] = [
        (ld_len, None, None, 0),
        (jge, None, "keep", header_at + 5 + len(token)),  # too short for an own frame
        (ldb_abs, None, None, head + len(HEAD) - 1),  # the timestamp's type: float 64
        (jeq, None, "keep", 0xCB),
        (ldb_abs, None, None, head + _VALUE_AT),  # the identifier's type
        (jge, None, "id1", 0x80),  # below 0x80: positive fixint, one byte
        (jeq, "id2", None, 0xCC),  # uint 8: two bytes
        (jeq, "id3", "keep", 0xCD),  # uint 16: three bytes
        ("id1", None, None, 0),
        (ldx_imm, None, None, header_at + 1),
        (ja, None, None, "text"),
        ("id2", None, None, 0),
        (ldx_imm, None, None, header_at + 2),
        (ja, None, None, "text"),
        ("id3", None, None, 0),
        (ldx_imm, None, None, header_at + 3),
        ("text", None, None, 0),
        (ldh_ind, None, None, 0),  # the str 8 header: d9, the length
        (jeq, None, "keep", 0xD900 | len(token)),
    ]
    for i in range(0, len(token), 4):
        asm.append((ld_ind, None, None, 2 + i))
        asm.append((jeq, None, "keep", int.from_bytes(token[i : i + 4], "big")))
    asm.append((ret, None, None, 0))  # an own frame: dropped
    asm.append(("keep", None, None, 0))
    asm.append((ret, None, None, 0xFFFFFFFF))  # everything else, whole
    labels: dict[str, int] = {}
    code_only: list[tuple[int, str | None, str | None, int | str]] = []
    for entry in asm:
        if isinstance(entry[0], str):
            labels[entry[0]] = len(code_only)
        else:
            code_only.append(entry)

    def skip(at: int, target: str | None) -> int:
        return 0 if target is None else labels[target] - at - 1

    program = []
    for at, (code, jt, jf, k) in enumerate(code_only):
        if code == ja:
            program.append((code, 0, 0, skip(at, str(k))))
        else:
            assert isinstance(k, int)
            program.append((code, skip(at, jt), skip(at, jf), k))
    return program


def attach_own_frame_filter(sock: socket.socket, token: bytes) -> bool:
    """Attach :func:`own_frame_filter` to ``sock``; False where the kernel refuses it."""
    program = own_frame_filter(token)
    instructions = (_SockFilter * len(program))(*(_SockFilter(*i) for i in program))
    fprog = _SockFprog(len(program), instructions)
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, bytes(fprog))  # type: ignore[call-overload]
    except OSError:
        return False
    return True


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
        #: the kernel drops this bus's own frames before they reach its socket (a BPF filter;
        #: False: refused here, they are dropped after they are read)
        self.filters_own_frames = attach_own_frame_filter(self._socket, token)
        #: a socket connected to the group, for a loop's frames (send without an address)
        self.sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            ttl = self._socket.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL)
            self.sender.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
            self.sender.connect(self._destination)
        except OSError:
            self.sender.close()
            raise

    # --- what a loop without a message per frame needs (virtual_bus.framing.UdpPort) --------
    @property
    def udp_socket(self) -> socket.socket:
        """The bus's socket (one thread receives at a time, see the class docstring)."""
        return self._socket

    @property
    def destination(self) -> tuple[str, int]:
        """Where a frame is sent (the group and port)."""
        return self._destination

    @property
    def own_marker(self) -> bytes:
        """The bytes of this bus's token as every frame it sends carries them."""
        return self._own_marker

    def is_own(self, buffer: bytearray, size: int) -> bool:
        """Whether a datagram is one of this bus's own frames (looped back by the kernel)."""
        return buffer.find(self._own_marker, 0, size) >= 0

    def decode_datagram(self, datagram: memoryview, timestamp: float) -> can.Message | None:
        """A received datagram as python-can decodes it (python-can's unpack_message, check
        True), with ``timestamp``; None for an FD frame on a classic bus (as python-can).
        Raises ``can.CanOperationError`` for a datagram that is no frame."""
        try:
            fields = msgpack.unpackb(datagram, raw=False)
            fields["timestamp"] = timestamp
            fields["channel"] = self.group
            msg = can.Message(check=True, **fields)
        except Exception as exc:
            raise can.CanOperationError("could not unpack received message") from exc
        if msg.is_fd and not self._fd:
            return None
        return msg

    def template(self, cob_id: int, length: int) -> tuple[bytearray, int]:
        """The datagram :meth:`send` makes of a classic standard data frame ``cob_id`` with
        ``length`` zero bytes (timestamp 0.0), and the offset of its payload in it: rewrite
        the payload in place and send the datagram again and again."""
        if not (0 <= cob_id <= 0x7FF and 0 <= length <= 8):
            raise BusConfigError(f"frame 0x{cob_id:X} with {length} bytes: not a classic one")
        msg = can.Message(arbitration_id=cob_id, data=bytes(length), is_extended_id=False)
        wire = bytearray(self._pack(msg))
        found = parse_plain(wire, len(wire))
        assert found is not None and found[:2] == (cob_id, length)
        return wire, found[2]

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd and not self._fd:
            raise can.CanOperationError("cannot send FD message over bus with CAN FD disabled")
        packed = self._pack(msg)
        if timeout is None:
            try:
                sent = self._socket.sendto(packed, self._destination)
            except OSError as error:
                raise can.CanOperationError("failed to send via socket") from error
            if sent < len(packed):
                raise can.CanTimeoutError()
        else:
            self._multicast.send(packed, timeout)

    def shutdown(self) -> None:
        self.sender.close()
        super().shutdown()

    def _pack(self, msg: can.Message) -> bytes:
        return msgpack.packb(  # type: ignore[no-any-return]
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
        if self.is_own(self._buffer, size):
            return None, False  # our own frame, looped back by the kernel
        if self._timestamps and ancillary:
            seconds, nanoseconds = _TIMESPEC.unpack_from(ancillary[0][2])
            timestamp = seconds + nanoseconds * 1e-9
        else:
            timestamp = time.time()
        return self.decode_datagram(self._view[:size], timestamp), False

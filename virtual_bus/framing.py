"""Frames for a real-time loop without a Python object per frame.

A loop that exchanges a few frames every millisecond (the bridge's cycle, the simulated
drive's SYNC answer) needs from the bus only: read the next frame into a buffer it already
has, tell its COB-ID and length, and send a frame it built once and rewrites in place.
python-can's ``recv``/``send`` build a :class:`can.Message` per frame (and python-can's
``udp_multicast`` a msgpack map and a dict each way): on a slow host that was most of the
cycle (docs/bridge.md, "Hot path"). A :class:`FramePort` gives the loop that narrow interface
over the bus's own socket; everything else about the bus stays python-can's (opening,
filters, canopen's SDO and NMT services, which the loop hands a :class:`can.Message` built
only for the rare frame that is not on its cycle: :meth:`FramePort.message`).

* :class:`SocketCanPort`: python-can's ``socketcan`` bus; its raw CAN socket read with
  ``recv_into`` into one ``struct can_frame`` buffer (72 bytes: a CAN FD frame fits), frames
  sent as preallocated 16-byte ``struct can_frame``\\ s (non-blocking, as python-can's ``send``
  without a timeout: a full transmit queue is an error, never a wait).
* :class:`UdpPort`: :class:`virtual_bus.udp.LoopbackUdpBus`; python-can's msgpack wire format
  read in place and written from templates (:mod:`virtual_bus.udp`).
* :class:`MessagePort`: any other python-can bus (the in-process virtual bus, a fault
  injecting or recording wrapper, vendor interfaces): ``recv``/``send`` with messages, the
  same interface.

:meth:`FramePort.receive` returns the frame's 11-bit identifier when it is a classic standard
data frame (the only kind a CANopen cycle uses), :data:`OTHER` for anything else (remote,
29-bit, error, CAN FD: :meth:`FramePort.message` has it) and :data:`NOTHING` when no frame
came; :attr:`cob_id` keeps what it returned, :attr:`length` and the payload at
``buffer[offset:offset + length]`` are valid until the next receive. :func:`frame_port`
picks the port for a bus.
"""

from __future__ import annotations

import functools
import os
import select
import socket
import struct
import time
from collections.abc import Callable

import can

from virtual_bus.udp import KIND_AT, MAX_DATAGRAM, LoopbackUdpBus, parse_plain

#: What :meth:`FramePort.receive` returns for no frame, and for a frame that is not a classic
#: standard data frame.
NOTHING = -2
OTHER = -1
#: struct can_frame / canfd_frame sizes (linux/can.h): CAN_MTU, CANFD_MTU.
CAN_MTU = 16
CANFD_MTU = 72
#: can_id flags of struct can_frame.
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_FLAGS = CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG
#: canfd_frame.flags bits.
CANFD_BRS = 0x01
CANFD_ESI = 0x02
#: can_id, len, flags, len8_dlc: the head of struct can_frame / canfd_frame.
_CAN_HEAD = struct.Struct("=IBB1xB")
_CAN_ID = struct.Struct("=I")
_CAN_ID_UNPACK = _CAN_ID.unpack_from
_TIMESPEC = struct.Struct("@ll")
_ANCILLARY_SIZE = socket.CMSG_SPACE(_TIMESPEC.size)


class OutFrame:
    """A frame a loop sends again and again: its payload is ``buffer[offset:offset +
    length]``, rewritten in place (e.g. with ``Struct.pack_into``) before each send.
    :attr:`send` sends it as it stands (the same as ``port.send(frame)``, without a Python
    call: the port's socket or bus method bound to the frame's bytes; raises like
    :meth:`FramePort.send`)."""

    __slots__ = ("buffer", "cob_id", "length", "message", "offset", "send", "wire")

    def __init__(
        self,
        cob_id: int,
        length: int,
        buffer: bytearray,
        offset: int,
        send: Callable[[], object],
        wire: bytearray | None = None,
        message: can.Message | None = None,
    ) -> None:
        self.cob_id = cob_id
        self.length = length
        self.buffer = buffer
        self.offset = offset
        self.send = send
        self.wire = wire  # what the socket sends (raw ports)
        self.message = message  # what the bus sends (MessagePort)


class FramePort:
    """The interface of every port (module docstring); this base is the python-can path,
    :class:`MessagePort`."""

    #: what the port reads and writes (for the bench's report)
    kind = "python-can messages"

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.cob_id = -1
        self.length = 0
        self.offset = 0
        self.buffer: bytearray = bytearray(CANFD_MTU)
        #: receive time of the last frame, s since the epoch (the kernel's where the port
        #: is stamped; python-can's convention)
        self.timestamp = 0.0

    def receive(self, timeout_s: float | None, due: bool = False) -> int:
        """Wait at most ``timeout_s`` (0: do not wait; None: forever) for the next frame:
        its COB-ID, :data:`OTHER` or :data:`NOTHING` (see the module docstring). ``due``: a
        frame is due now (the TPDOs after a SYNC), so a port may read before it polls (one
        system call a frame that is there; a miss costs more than a poll that finds
        nothing, so not for a look with timeout 0 or a wait for what may not come)."""
        raise NotImplementedError

    def message(self) -> can.Message:
        """The last frame received, as python-can's :class:`can.Message` (built now)."""
        raise NotImplementedError

    def frame(self, cob_id: int, length: int) -> OutFrame:
        """A preallocated classic standard data frame to send with :meth:`send`."""
        raise NotImplementedError

    def send(self, frame: OutFrame) -> None:
        """Send ``frame`` as it stands; raises ``can.CanError`` or ``OSError`` when the bus
        refuses it."""
        raise NotImplementedError

    def send_message(self, msg: can.Message) -> None:
        """Send any frame (the rare ones: python-can's path)."""
        self.bus.send(msg)


class MessagePort(FramePort):
    """Any python-can bus, one :class:`can.Message` per frame (module docstring)."""

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(bus)
        self._msg: can.Message | None = None

    def receive(self, timeout_s: float | None, due: bool = False) -> int:
        msg = self.bus.recv(timeout_s)
        if msg is None:
            return NOTHING
        self._msg = msg
        self.timestamp = msg.timestamp
        if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or msg.is_fd:
            self.cob_id = OTHER
            return OTHER
        self.buffer = data = msg.data
        self.length = len(data)
        self.cob_id = cob_id = msg.arbitration_id
        return cob_id  # type: ignore[no-any-return]

    def message(self) -> can.Message:
        assert self._msg is not None, "message() before a frame was received"
        return self._msg

    def frame(self, cob_id: int, length: int) -> OutFrame:
        msg = ReusedMessage(arbitration_id=cob_id, data=bytearray(length), is_extended_id=False)
        return OutFrame(
            cob_id, length, msg.data, 0, functools.partial(self.bus.send, msg), message=msg
        )

    def send(self, frame: OutFrame) -> None:
        self.bus.send(frame.message)


_MESSAGE_FIELDS = tuple(name for name in can.Message.__slots__ if not name.startswith("__"))


class ReusedMessage(can.Message):
    """A frame sent every cycle, built once and rewritten in place.

    python-can's own virtual bus deep-copies every frame it delivers; ``Message.__deepcopy__``
    runs the full constructor (about 7 µs). This copy sets the fields of a plain
    :class:`can.Message` directly (the data is copied)."""

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, object] | None) -> can.Message:
        new = can.Message.__new__(can.Message)
        for name in _MESSAGE_FIELDS:
            setattr(new, name, getattr(self, name))
        new.data = bytearray(self.data)
        return new


class _SocketPort(FramePort):
    """A port on a socket the bus owns: readiness by ``poll`` (no exception when nothing is
    there) or ``select`` (µs timeouts), reads into :attr:`buffer`; with ``stamped`` the
    kernel's receive time of each frame (``SO_TIMESTAMPNS``, set by the bus) in
    :attr:`timestamp`, else the wall clock's when it is asked for."""

    def __init__(
        self, bus: can.BusABC, sock: socket.socket, stamped: bool, size: int = CANFD_MTU
    ) -> None:
        super().__init__(bus)
        self.buffer = bytearray(size)
        self.sock = sock
        self.stamped = stamped
        self.size = 0
        self._poll = select.poll()
        self._poll.register(sock, select.POLLIN)
        self._ready = self._poll.poll
        self._buffers = [self.buffer]
        self._ancillary: list[tuple[int, int, bytes]] = []
        #: one frame into the buffer, its size: read(2) (os.readv parses its arguments faster
        #: than recv_into, callgrind: ~270 instructions a frame less), or recvmsg stamped
        self._read_one: Callable[[], int] = (
            self._read_stamped
            if stamped
            else functools.partial(os.readv, sock.fileno(), self._buffers)
        )
        #: the same without waiting: BlockingIOError when nothing is there
        self._read_now: Callable[[], int] = (
            self._read_stamped_now
            if stamped
            else functools.partial(sock.recv_into, self.buffer, 0, socket.MSG_DONTWAIT)
        )

    @property  # type: ignore[override]
    def timestamp(self) -> float:
        """Receive time of the last frame, s since the epoch: the kernel's if stamped (read
        with every frame by ``recvmsg``, which also formats the sender's address: ~6,000
        instructions a frame, callgrind), else the wall clock's now."""
        if self.stamped and self._ancillary:
            seconds, nanoseconds = _TIMESPEC.unpack_from(self._ancillary[0][2])
            return seconds + nanoseconds * 1e-9  # type: ignore[no-any-return]
        return time.time()

    @timestamp.setter
    def timestamp(self, value: float) -> None:  # the base class's initial value
        pass

    def _wait(self, timeout_s: float | None) -> bool:
        """Whether a datagram / frame is there within ``timeout_s``. A wait of a millisecond
        or more is a ``poll`` (milliseconds, cheaper), a shorter one ``select`` (microseconds:
        the wait for a SYNC's instant ends on time)."""
        if timeout_s is None or timeout_s >= 0.001:
            # milliseconds rounded down: never later than asked
            return bool(self._ready(None if timeout_s is None else int(timeout_s * 1000.0)))
        if timeout_s > 0.0:
            return bool(select.select((self.sock,), (), (), timeout_s)[0])
        return bool(self._ready(0))

    def _read(self, timeout_s: float | None) -> bool:
        """One datagram / frame into the buffer (``self.size``), False if none came."""
        if not self._wait(timeout_s):
            return False
        self.size = self._read_one()
        return True

    def _read_stamped(self, flags: int = 0) -> int:
        """``_read_one`` of a stamped port: the frame and its kernel receive time."""
        size, self._ancillary, _, _ = self.sock.recvmsg_into(self._buffers, _ANCILLARY_SIZE, flags)
        return size  # type: ignore[no-any-return]

    def _read_stamped_now(self) -> int:
        """``_read_now`` of a stamped port."""
        return self._read_stamped(socket.MSG_DONTWAIT)


class SocketCanPort(_SocketPort):
    """python-can's ``socketcan`` bus through its raw CAN socket (module docstring)."""

    kind = "raw SocketCAN socket, preallocated struct can_frame"

    def __init__(self, bus: can.BusABC, stamped: bool = False) -> None:
        super().__init__(bus, bus.socket, stamped)  # type: ignore[attr-defined]
        self.offset = 8
        self._channel = getattr(bus, "channel", None)

    def receive(self, timeout_s: float | None, due: bool = False) -> int:
        size = -1
        if due and timeout_s != 0.0:  # read it if it is there (see UdpPort.receive)
            read_now = self._read_now
            try:
                size = read_now()
            except BlockingIOError:
                size = -1
        if size >= 0:
            self.size = size
        elif not self._read(timeout_s):
            return NOTHING
        buf = self.buffer
        (can_id,) = _CAN_ID_UNPACK(buf)  # host byte order
        if self.size == CAN_MTU and not can_id & CAN_FLAGS and buf[4] <= 8:
            self.length = buf[4]
            self.cob_id = can_id
            return can_id  # type: ignore[no-any-return]
        self.cob_id = OTHER
        return OTHER

    def message(self) -> can.Message:
        can_id, length, flags, _ = _CAN_HEAD.unpack_from(self.buffer)
        fd = self.size == CANFD_MTU
        return can.Message(
            timestamp=self.timestamp,
            arbitration_id=can_id & 0x1FFFFFFF,
            is_extended_id=bool(can_id & CAN_EFF_FLAG),
            is_remote_frame=bool(can_id & CAN_RTR_FLAG),
            is_error_frame=bool(can_id & CAN_ERR_FLAG),
            is_fd=fd,
            bitrate_switch=bool(flags & CANFD_BRS),
            error_state_indicator=bool(flags & CANFD_ESI),
            dlc=length,
            data=bytes(self.buffer[8 : 8 + length]),
            channel=self._channel,
            is_rx=True,
            check=False,
        )

    def frame(self, cob_id: int, length: int) -> OutFrame:
        if not (0 <= cob_id <= 0x7FF and 0 <= length <= 8):
            raise ValueError(f"frame 0x{cob_id:X} with {length} bytes: not a classic 11-bit one")
        wire = bytearray(CAN_MTU)
        _CAN_HEAD.pack_into(wire, 0, cob_id, length, 0, 0)
        send = functools.partial(self.sock.send, wire, socket.MSG_DONTWAIT)
        return OutFrame(cob_id, length, wire, 8, send, wire=wire)

    def send(self, frame: OutFrame) -> None:
        self.sock.send(frame.wire, socket.MSG_DONTWAIT)  # type: ignore[arg-type]


class UdpPort(_SocketPort):
    """:class:`~virtual_bus.udp.LoopbackUdpBus` in python-can's wire format, read in place
    and written from templates (module docstring); the bus's own frames, which the kernel
    loops back, are never returned.

    A datagram that equals one read before except for its payload is that frame again
    (python-can packs the same fields in the same order every time, and a loop's frame
    templates and canopen's messages carry the timestamp 0.0): after the first frame of each
    kind (COB-ID, length, sender) is parsed (:func:`virtual_bus.udp.parse_plain`), its bytes
    before and after the payload are kept and the next ones are recognised by two
    comparisons (one kind per size and the COB-ID's bytes, at most :data:`KNOWN_FRAMES`; a
    kind that finds its place taken, e.g. the same frame from a second sender, and a sender
    whose timestamps change, python-can's own bus, are parsed every time)."""

    kind = "raw UDP socket, python-can's msgpack format parsed in place, frame templates"

    #: Kinds of frames remembered (a cycle has a handful; garbage cannot grow the table).
    KNOWN_FRAMES = 32

    def __init__(self, bus: LoopbackUdpBus, stamped: bool = False) -> None:
        super().__init__(bus, bus.udp_socket, stamped, MAX_DATAGRAM)
        self._udp = bus
        self._own = bus.own_marker
        # write(2) on the sender, connected to the group: no address to parse per frame, and
        # os.write parses its arguments faster than socket.send (callgrind: ~500 instructions
        # a frame less); the same system call on the same blocking socket as its send()
        self._send = functools.partial(os.write, bus.sender.fileno())
        # by datagram size and the two bytes at KIND_AT (the COB-ID's where it is above
        # 0x7F): (COB-ID, length, payload offset, bytes before the payload, bytes after it)
        self._known: dict[int, tuple[int, int, int, bytes, bytes]] = {}
        self._known_count = 0

    def receive(self, timeout_s: float | None, due: bool = False) -> int:
        # _read without its call; the callables in instance attributes are called from
        # locals (CPython 3.11 specialises no method call of an instance attribute: ~300
        # instructions each, callgrind)
        size = -1
        if due and timeout_s != 0.0:  # read it if it is there: no poll (~950 instructions)
            read_now = self._read_now
            try:
                size = read_now()
            except BlockingIOError:  # a miss costs ~6,900: only where a frame is due
                size = -1
        if size < 0:
            if timeout_s == 0.0:
                poll = self._ready
                ready = poll(0)
            elif timeout_s is not None and timeout_s >= 0.001:
                poll = self._ready
                ready = poll(int(timeout_s * 1000.0))  # ms rounded down: never later
            else:
                ready = self._wait(timeout_s)
            if not ready:
                return NOTHING
            read_one = self._read_one
            size = read_one()
        self.size = size
        buffer = self.buffer
        while True:
            # a kind of frame of another bus read before (its token is in ``before``)
            known = self._known.get(size << 16 | buffer[KIND_AT] << 8 | buffer[KIND_AT + 1])
            if known is not None:
                cob_id, length, offset, before, after = known
                if buffer.startswith(before) and buffer.startswith(after, offset + length):
                    self.length = length
                    self.offset = offset
                    self.cob_id = cob_id
                    return cob_id
            if buffer.find(self._own, 0, size) < 0:
                break
            if not self._read(0.0):  # ours, looped back (the kernel's filter drops most)
                return NOTHING
            size = self.size
        found = parse_plain(buffer, size)
        if found is None:  # not a plain frame: msgpack and python-can's checks decide
            self.cob_id = OTHER
            return OTHER
        cob_id, length, offset, _ = found
        self.cob_id = cob_id
        self.length = length
        self.offset = offset
        key = size << 16 | buffer[KIND_AT] << 8 | buffer[KIND_AT + 1]
        if self._known_count < self.KNOWN_FRAMES and key not in self._known:
            self._known[key] = (
                cob_id,
                length,
                offset,
                bytes(buffer[:offset]),
                bytes(buffer[offset + length : size]),
            )
            self._known_count += 1
        return cob_id

    def message(self) -> can.Message:
        msg = self._udp.decode_datagram(memoryview(self.buffer)[: self.size], self.timestamp)
        if msg is None:  # an FD frame on a classic bus: python-can drops it
            raise can.CanOperationError("a CAN FD frame on a classic bus (dropped)")
        return msg

    def frame(self, cob_id: int, length: int) -> OutFrame:
        wire, offset = self._udp.template(cob_id, length)
        return OutFrame(
            cob_id, length, wire, offset, functools.partial(self._send, wire), wire=wire
        )

    def send(self, frame: OutFrame) -> None:
        self._send(frame.wire)


def frame_port(bus: can.BusABC, *, stamped: bool = False) -> FramePort:
    """The fastest port for ``bus``: its raw socket for python-can's ``socketcan`` bus and
    for :class:`LoopbackUdpBus` (exactly those classes: a subclass or wrapper may change what
    goes over the wire), :class:`MessagePort` for anything else. ``stamped``: the kernel's
    receive time of each frame in :attr:`FramePort.timestamp`."""
    if type(bus) is LoopbackUdpBus:
        return UdpPort(bus, stamped)
    kind = type(bus)
    if kind.__name__ == "SocketcanBus" and kind.__module__.startswith("can.interfaces.socketcan"):
        return SocketCanPort(bus, stamped)
    return MessagePort(bus)

"""Which received frames are a node's own: the one place that decides, for every bus.

A CAN controller never hands its node the frames the node sent. The ways processes share a
bus here can, and a node that took its own SYNC for another producer's, or its own RPDO or
heartbeat for foreign traffic, would stop an axis for nothing or count frames no other node
sent (docs/virtual_bus.md, "Own frames"). Per bus:

* **SocketCAN** (``vcan0``, ``can0``): every frame is looped back to the *other* sockets on
  the host (``CAN_RAW_LOOPBACK``); to the socket that sent it only with
  ``receive_own_messages`` (``CAN_RAW_RECV_OWN_MSGS``), in the bus's order. The kernel marks
  that echo, and only that one, with ``MSG_CONFIRM`` in the flags ``recvmsg`` returns
  (linux/net/can/raw.c, ``raw_rcv``: "the frame was sent by this very socket";
  Documentation/networking/can.rst). ``MSG_DONTROUTE`` only says "sent on this host", which
  on ``vcan`` every frame is: python-can's ``Message.is_rx`` reads that flag and cannot tell
  (:func:`socketcan_own`). Hence two rules:

  - a node sends every frame through the socket it reads (never a second one: python-can's
    ``send_periodic`` on SocketCAN is the kernel's broadcast manager, a socket of its own
    whose frames the node's raw socket receives like another node's -- the simulated drive's
    heartbeat goes through its own socket, ``plant_sim.drive.node.WallClockHeartbeat``), and
    without ``receive_own_messages`` it is never handed one of them;
  - a node that wants its own frames back in the bus's order (the bridge's bus log, which
    must be the wire as ``candump`` records it) opens its socket with
    ``receive_own_messages`` and reads it through :class:`EchoSortingBus`, which takes every
    echo by ``MSG_CONFIRM`` out of what the node receives -- also when the kernel dropped
    echoes from a full receive queue under a flood (the previous rule, "a frame equal to the
    oldest one sent and not yet back is that one", took a node's own SYNC and RPDO for
    foreign ones after one lost echo: a second SYNC producer, and the axis stopped);

* **udp_multicast** (two processes in a private network namespace): the group loops every
  datagram back to every socket that joined it, the sender's included;
  :class:`virtual_bus.udp.LoopbackUdpBus` tags what it sends with a token of its own and
  drops its own datagrams (a kernel socket filter, and the check in user space behind it),
  so no reader above it ever sees them (:func:`udp_own`);

* **python-can's virtual bus** (one process): no echo unless ``receive_own_messages``.

:func:`echo_of` says which of these a bus is.
"""

from __future__ import annotations

import select
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from enum import Enum

import can

from virtual_bus.udp import LoopbackUdpBus

#: The flag the kernel sets on a frame looped back to the SocketCAN socket that sent it.
MSG_CONFIRM = socket.MSG_CONFIRM
#: struct can_frame / canfd_frame (linux/can.h): sizes and the flags of can_id.
CAN_MTU, CANFD_MTU = 16, 72
CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG = 0x80000000, 0x40000000, 0x20000000
_CAN_HEAD = struct.Struct("=IBB2x")
_TIMESPEC = struct.Struct("@ll")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size)
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)


class Echo(Enum):
    """How a bus hands a node its own frames (module docstring)."""

    NONE = "never"  # SocketCAN without receive_own_messages, python-can's virtual bus
    FLAGGED = "every one, flagged MSG_CONFIRM"  # SocketCAN with receive_own_messages
    FILTERED = "every one, dropped by the bus itself"  # LoopbackUdpBus (token)


def socketcan_own(msg_flags: int) -> bool:
    """Whether a frame read by ``recvmsg`` from a SocketCAN socket is that socket's own."""
    return bool(msg_flags & MSG_CONFIRM)


def udp_own(bus: LoopbackUdpBus, datagram: bytes) -> bool:
    """Whether a datagram of the group is ``bus``'s own (the token it sends with)."""
    return bus.own_marker in datagram


def echo_of(bus: can.BusABC) -> Echo:
    """How ``bus`` hands its node the node's own frames (python-can's virtual bus and any
    other interface: as its ``receive_own_messages`` says)."""
    if isinstance(bus, EchoSortingBus | LoopbackUdpBus):
        return Echo.FILTERED
    sock = getattr(bus, "socket", None)
    if isinstance(sock, socket.socket) and sock.family == getattr(socket, "AF_CAN", -1):
        own = sock.getsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_RECV_OWN_MSGS)
        return Echo.FLAGGED if own else Echo.NONE
    return Echo.FLAGGED if getattr(bus, "receive_own_messages", False) else Echo.NONE


def frame_key(msg: can.Message) -> tuple[int, bool, bool, int, bytes]:
    """What tells two frames apart on the wire (identifier, kind, length, data): a frame
    read back equals one sent when their keys are equal."""
    return (
        msg.arbitration_id,
        msg.is_extended_id,
        msg.is_remote_frame,
        msg.dlc,
        bytes(msg.data),
    )


class EchoSortingBus(can.BusABC):
    """A python-can ``socketcan`` bus opened with ``receive_own_messages``, read in the bus's
    order with the node's own frames sorted out by the kernel's ``MSG_CONFIRM``.

    ``own(msg)`` is called once for every frame sent through this bus, when the bus carried
    it (its echo came back); a frame whose echo the kernel dropped (a full receive queue) is
    given to ``own`` when a later echo shows it was lost, and at :meth:`shutdown` those
    still waiting (after the echoes still queued are read). ``other(msg)`` is called for
    every frame of another node, which is also returned by ``recv``; an own frame never is.
    ``inner``: the bus (its ``socket`` attribute is read); it stays the caller's to shut
    down. Thread-safe like python-can's socketcan bus (one reader, any senders).
    """

    def __init__(
        self,
        inner: can.BusABC,
        own: Callable[[can.Message], None],
        other: Callable[[can.Message], None] | None = None,
    ) -> None:
        sock = getattr(inner, "socket", None)
        if not isinstance(sock, socket.socket) or sock.family != getattr(socket, "AF_CAN", -1):
            raise ValueError("EchoSortingBus needs python-can's socketcan bus (a raw CAN socket)")
        self._inner = inner
        self._sock = sock
        self._own = own
        self._other = other
        self._pending: deque[tuple[tuple[int, bool, bool, int, bytes], can.Message]] = deque()
        self._lock = threading.Lock()
        self.channel_info = getattr(inner, "channel_info", "")
        self.channel = getattr(inner, "channel", None)
        #: echoes the kernel dropped (their frames were given to ``own`` unechoed)
        self.lost_echoes = 0
        super().__init__(channel=None)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        entry = (frame_key(msg), _copy(msg))
        # queued and sent under one lock: the queue is in the order the kernel got the frames
        # from the node's threads (the loop, the SDO client, the heartbeat), and the echo may
        # be read by another thread at once
        with self._lock:
            self._pending.append(entry)
            try:
                self._inner.send(msg, timeout)
            except BaseException:
                self._pending.pop()  # it never went out: no echo will come
                raise

    def fileno(self) -> int:
        return self._sock.fileno()

    def _read(self, timeout: float | None) -> tuple[can.Message, bool] | None:
        """The next frame and whether it is the node's own (None: none within ``timeout``)."""
        if timeout is not None and timeout <= 0.0:
            ready = select.select([self._sock], [], [], 0.0)[0]
        else:
            ready = select.select([self._sock], [], [], timeout)[0]
        if not ready:
            return None
        data, ancillary, flags, _addr = self._sock.recvmsg(CANFD_MTU, _ANCILLARY)
        timestamp = time.time()
        for level, kind, raw in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                seconds, nanoseconds = _TIMESPEC.unpack_from(raw)
                timestamp = seconds + nanoseconds * 1e-9
        can_id, length, fd_flags = _CAN_HEAD.unpack_from(data)
        msg = can.Message(
            timestamp=timestamp,
            arbitration_id=can_id & 0x1FFFFFFF,
            is_extended_id=bool(can_id & CAN_EFF_FLAG),
            is_remote_frame=bool(can_id & CAN_RTR_FLAG),
            is_error_frame=bool(can_id & CAN_ERR_FLAG),
            is_fd=len(data) == CANFD_MTU,
            bitrate_switch=bool(fd_flags & 0x01) if len(data) == CANFD_MTU else False,
            error_state_indicator=bool(fd_flags & 0x02) if len(data) == CANFD_MTU else False,
            dlc=length,
            data=bytes(data[8 : 8 + length]),
            channel=self.channel,
            is_rx=not socketcan_own(flags),
            check=False,
        )
        return msg, socketcan_own(flags)

    def _echo(self, msg: can.Message) -> None:
        """An echo of a frame sent: the frames sent before it whose echo was lost, then it."""
        key = frame_key(msg)
        lost = []
        with self._lock:
            if any(sent_key == key for sent_key, _ in self._pending):
                while self._pending:
                    sent_key, sent = self._pending.popleft()
                    if sent_key == key:
                        break
                    lost.append(sent)
        self.lost_echoes += len(lost)
        for sent in lost:
            self._own(sent)
        self._own(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        wait = timeout
        while True:
            got = self._read(wait)
            if got is None:
                return None, False
            msg, own = got
            if not own:
                if self._other is not None:
                    self._other(msg)
                return msg, False
            self._echo(msg)
            if deadline is not None:
                wait = max(0.0, deadline - time.monotonic())

    def shutdown(self) -> None:
        """Read the echoes still queued (frames of other nodes read meanwhile go to
        ``other``), give ``own`` the frames whose echo never came, then stop."""
        while self._pending and self._recv_internal(0.0)[0] is not None:
            pass
        with self._lock:
            left = [sent for _key_, sent in self._pending]
            self._pending.clear()
        self.lost_echoes += len(left)
        for sent in left:
            self._own(sent)
        super().shutdown()


def _copy(msg: can.Message) -> can.Message:
    """The frame as sent (the caller may rewrite its message in place afterwards)."""
    return can.Message(
        arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id,
        is_remote_frame=msg.is_remote_frame,
        is_error_frame=msg.is_error_frame,
        is_fd=msg.is_fd,
        dlc=msg.dlc,
        data=bytes(msg.data),
        channel=msg.channel,
        check=False,
    )

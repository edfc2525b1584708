"""python-can's in-process ``virtual`` bus with a short send and receive path.

:class:`InProcessBus` is python-can's :class:`~can.interfaces.virtual.VirtualBus` -- same
channel registry, same delivery rules, interoperable with plain ``can.Bus(interface=
"virtual")`` ends on the same channel -- for a loop that passes four frames a cycle through
it thousands of times a second (lockstep, docs/bridge.md). Only the path is shorter:

* send: each receiver gets a copy of the frame made field by field (python-can's ``send``
  goes through ``copy.deepcopy`` and ``Message.__deepcopy__``: the full constructor, a memo
  dictionary, about 7 µs a frame); the copy is the same -- a plain :class:`can.Message`, its
  data a new ``bytearray`` (empty for a remote frame), the timestamp of the send, the
  channel, ``is_rx`` set for the receivers;
* receive queue: a :class:`queue.SimpleQueue` (C, no ``Condition`` and its locks) instead of a
  :class:`queue.Queue`; unbounded, as python-can's with its default ``rx_queue_size = 0``;
* receive: without filters, the queue is read directly (``BusABC.recv`` reads the clock twice
  and checks the filters for every frame); with filters, python-can's ``recv``.

``tests/virtual_bus/test_inprocess.py`` checks frames against python-can's own ``VirtualBus``
both ways.
"""

from __future__ import annotations

import logging
import queue
import time

import can
from can.interfaces.virtual import VirtualBus, channels_lock

_CAN_BUS_LOG = logging.getLogger("can.bus")


def copy_message(msg: can.Message) -> can.Message:
    """What ``copy.deepcopy(msg)`` gives for a :class:`can.Message` (``Message.__deepcopy__``
    runs the constructor: data as a new bytearray, none for a remote frame), without the
    constructor and the memo."""
    new = can.Message.__new__(can.Message)
    new.timestamp = msg.timestamp
    new.arbitration_id = msg.arbitration_id
    new.is_extended_id = msg.is_extended_id
    new.is_remote_frame = msg.is_remote_frame
    new.is_error_frame = msg.is_error_frame
    new.channel = msg.channel
    new.is_fd = msg.is_fd
    new.is_rx = msg.is_rx
    new.bitrate_switch = msg.bitrate_switch
    new.error_state_indicator = msg.error_state_indicator
    data = msg.data
    new.data = bytearray() if data is None or msg.is_remote_frame else bytearray(data)
    new.dlc = msg.dlc
    return new


class InProcessBus(VirtualBus):
    """python-can's virtual bus on ``channel`` with the short path of the module docstring."""

    def __init__(
        self,
        channel: str,
        receive_own_messages: bool = False,
        preserve_timestamps: bool = False,
    ) -> None:
        super().__init__(
            channel=channel,
            receive_own_messages=receive_own_messages,
            preserve_timestamps=preserve_timestamps,
        )
        fast: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        with channels_lock:  # replace python-can's Queue in the channel's list by this one
            listeners = self.channel
            index = next(i for i, q in enumerate(listeners) if q is self.queue)
            listeners[index] = fast
            self.queue = fast  # type: ignore[assignment]

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        own = self.queue
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            msg_copy = copy_message(msg)
            msg_copy.timestamp = timestamp
            msg_copy.channel = self.channel_id
            msg_copy.is_rx = bus_queue is not own
            try:  # a plain VirtualBus end may have a bounded queue.Queue
                bus_queue.put(msg_copy, True, timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._filters is not None:
            return super().recv(timeout)
        self._check_if_open()
        try:
            if timeout is not None and timeout <= 0.0:
                msg = self.queue.get(False)
            else:
                msg = self.queue.get(True, timeout)
        except queue.Empty:
            return None
        if _CAN_BUS_LOG.isEnabledFor(self.RECV_LOGGING_LEVEL):
            _CAN_BUS_LOG.log(self.RECV_LOGGING_LEVEL, "Received: %s", msg)
        return msg

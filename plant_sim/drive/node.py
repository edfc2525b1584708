"""The drive's CANopen node: canopen's LocalNode with its own NMT slave, heartbeat producers
for both time modes and an SDO server that is silent in NMT Stopped.

What canopen's LocalNode / NmtSlave lack and this module adds:

- after an NMT reset node / reset communication the slave sends its boot-up message and
  enters Pre-operational by itself (CiA 301 figure 48); NmtSlave stays in Initialising;
- the reset hooks (application / communication parameters back to their defaults);
- a heartbeat clocked by the simulated time (lockstep: one position cycle per SYNC), since
  NmtSlave's heartbeat always runs on the wall clock in a python-can thread;
- no SDO service in Stopped (CiA 301 table 46), and an SDO server that answers as CiA 301
  says (:class:`virtual_bus.sdo_server.CheckedSdoServer`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Protocol

import can
import canopen.network
from canopen import LocalNode
from canopen.objectdictionary import ObjectDictionary

from virtual_bus.contract import (
    HEARTBEAT_BASE,
    NMT_COB_ID,
    NMT_TARGET_STATE,
    NmtCommand,
    NmtState,
    nmt_command_for,
)
from virtual_bus.sdo_server import CheckedSdoServer

logger = logging.getLogger(__name__)


class HeartbeatProducer(Protocol):
    """Sends the heartbeat (0x700 + node id, one byte: the NMT state)."""

    def start(self, period_ms: int, state: NmtState, now_us: int) -> None: ...

    def set_state(self, state: NmtState) -> None: ...

    def tick(self, now_us: int) -> None: ...

    def stop(self) -> None: ...


class SimulatedHeartbeat:
    """Heartbeat on the simulated time (lockstep): :meth:`tick` with the time after each
    position cycle sends one frame whenever a multiple of the period has passed."""

    def __init__(self, send: Callable[[int, bytes], None], node_id: int) -> None:
        self._send = send
        self._can_id = HEARTBEAT_BASE + node_id
        self._period_us = 0
        self._due_us = 0
        self._state = NmtState.INITIALISING

    def start(self, period_ms: int, state: NmtState, now_us: int) -> None:
        self._period_us = 1000 * period_ms
        self._due_us = now_us + self._period_us
        self._state = state

    def set_state(self, state: NmtState) -> None:
        self._state = state

    def tick(self, now_us: int) -> None:
        if self._period_us <= 0 or now_us < self._due_us:
            return
        while self._due_us <= now_us:
            self._due_us += self._period_us
        self._send(self._can_id, bytes([self._state]))

    def stop(self) -> None:
        self._period_us = 0


class WallClockHeartbeat:
    """Heartbeat on the wall clock (real time): python-can's thread-based periodic send task,
    through the bus's own ``send``. Not the bus's ``send_periodic``: on SocketCAN that is the
    kernel's broadcast manager, a socket of its own, whose frames the drive's raw socket
    receives as another node's (docs/virtual_bus.md, "Own frames"): the drive counted its own
    heartbeat as an unknown COB-ID. A socket is never handed its own frames back."""

    def __init__(self, bus: Callable[[], can.BusABC], node_id: int) -> None:
        self._bus = bus
        self._can_id = HEARTBEAT_BASE + node_id
        self._task: can.broadcastmanager.CyclicSendTaskABC | None = None
        self._message: can.Message | None = None

    def start(self, period_ms: int, state: NmtState, now_us: int) -> None:
        self.stop()
        if period_ms <= 0:
            return
        self._message = can.Message(
            arbitration_id=self._can_id, data=bytes([state]), is_extended_id=False
        )
        self._task = can.broadcastmanager.ThreadBasedCyclicSendTask(
            self._bus(),
            threading.Lock(),
            self._message,
            period_ms / 1000.0,
            on_error=lambda _exc: True,  # a bus that refuses one frame gets the next
        )

    def set_state(self, state: NmtState) -> None:
        if self._task is not None and self._message is not None:
            self._message = can.Message(
                arbitration_id=self._can_id, data=bytes([state]), is_extended_id=False
            )
            if isinstance(self._task, can.broadcastmanager.ModifiableCyclicTaskABC):
                self._task.modify_data(self._message)

    def tick(self, now_us: int) -> None:
        pass

    def stop(self) -> None:
        if self._task is None:
            return
        self._task.stop()
        thread = getattr(self._task, "thread", None)  # python-can's thread-based task
        if isinstance(thread, threading.Thread) and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        self._task = None


class DriveNmt:
    """NMT slave of the drive (replaces canopen's NmtSlave on the LocalNode).

    on_reset(command): called in Initialising for RESET_NODE / RESET_COMMUNICATION, before
    the boot-up message. on_state(old, new): after every state change.
    """

    def __init__(
        self,
        node_id: int,
        *,
        lock: threading.RLock,
        on_reset: Callable[[NmtCommand], None],
        on_state: Callable[[NmtState, NmtState], None],
    ) -> None:
        self.id = node_id
        self.network: canopen.network.Network = canopen.network._UNINITIALIZED_NETWORK
        self._lock = lock
        self._on_reset = on_reset
        self._on_state = on_state
        self.state = NmtState.INITIALISING

    def _set(self, new: NmtState) -> None:
        old, self.state = self.state, new
        if old is not new:
            self._on_state(old, new)

    def boot(self) -> None:
        """Enter Pre-operational, announced by the boot-up message.

        The state is Pre-operational before the boot-up message leaves: a master may answer
        it at once with an SDO request, and the frame guard reads the state as the request
        arrives (on a busy one-CPU guest a request came before the state changed and was
        refused "not in state"). The transition's actions (the heartbeat starts) follow the
        message, so that the boot-up is the node's first frame (CiA 301)."""
        with self._lock:
            self._set(NmtState.INITIALISING)
            self.state = NmtState.PRE_OPERATIONAL
            self.network.send_message(HEARTBEAT_BASE + self.id, b"\x00")
            self._on_state(NmtState.INITIALISING, NmtState.PRE_OPERATIONAL)

    def execute(self, command: NmtCommand) -> None:
        with self._lock:
            if command in (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION):
                self._set(NmtState.INITIALISING)
                self._on_reset(command)
                self.boot()
            else:
                self._set(NMT_TARGET_STATE[command])

    def on_command(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Network callback for COB-ID 0: two bytes, command specifier and node id (0: all)."""
        try:
            command = nmt_command_for(data, self.id)
        except ValueError as exc:
            logger.warning("%s", exc)
            return
        if command is not None:
            self.execute(command)


class _GatedSdoServer(CheckedSdoServer):
    """The CiA 301 SDO server, silent while ``blocked()`` (NMT Stopped), serialised by
    ``lock``."""

    def __init__(
        self,
        node: LocalNode,
        *,
        lock: threading.RLock,
        blocked: Callable[[], bool],
    ) -> None:
        super().__init__(node)
        self._lock = lock
        self._blocked = blocked

    def on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self._blocked():
                return
            super().on_request(can_id, data, timestamp)


class DriveNode(LocalNode):
    """LocalNode with :class:`DriveNmt` and the gated SDO server.

    Must be built before it joins a network: ``LocalNode.associate_network`` subscribes
    ``self.sdo.on_request`` and ``self.nmt.on_command``.
    """

    def __init__(
        self,
        node_id: int,
        od: ObjectDictionary,
        *,
        nmt: DriveNmt,
        lock: threading.RLock,
        gate: Callable[[int, int], bool] | None = None,
    ) -> None:
        self._gate = gate
        self._gated_subscriptions: list[tuple[int, FrameCallback, FrameCallback]] = []
        super().__init__(node_id, od)
        # LocalNode registered its NmtSlave's heartbeat writer for 1017h; the drive handles
        # 1017h itself (time-mode dependent heartbeat), so drop it with the NmtSlave.
        self._write_callbacks.remove(self.nmt.on_write)
        self.nmt = nmt  # type: ignore[assignment]
        self.sdo = _GatedSdoServer(self, lock=lock, blocked=lambda: nmt.state is NmtState.STOPPED)

    def associate_network(self, network: canopen.network.Network) -> None:
        """As LocalNode's, but SDO and NMT frames pass ``gate(cob_id, length)`` first (the
        drive's frame guard when it shares a Network it does not own)."""
        super().associate_network(network)
        if self._gate is None:
            return
        plain = ((self.sdo.rx_cobid, self.sdo.on_request), (NMT_COB_ID, self.nmt.on_command))
        for cob_id, callback in plain:
            wrapped = gated(self._gate, callback)
            network.unsubscribe(cob_id, callback)
            network.subscribe(cob_id, wrapped)
            self._gated_subscriptions.append((cob_id, callback, wrapped))

    def remove_network(self) -> None:
        if self.has_network():  # LocalNode unsubscribes the plain callbacks: put them back
            for cob_id, callback, wrapped in self._gated_subscriptions:
                self.network.unsubscribe(cob_id, wrapped)
                self.network.subscribe(cob_id, callback)
        self._gated_subscriptions.clear()
        super().remove_network()


FrameCallback = Callable[[int, bytearray, float], None]


def gated(gate: Callable[[int, int], bool], callback: FrameCallback) -> FrameCallback:
    """``callback`` called only for frames ``gate(cob_id, length)`` admits."""

    def run(can_id: int, data: bytearray, timestamp: float) -> None:
        if gate(can_id, len(data)):
            callback(can_id, data, timestamp)

    return run


class GuardedListener(can.Listener):
    """Replaces canopen's MessageListener on a Network the drive owns: every frame passes the
    frame guard (RTR, 29-bit ids, error frames, COB-ID, length, NMT state) first."""

    def __init__(self, network: canopen.network.Network, check: Callable[[can.Message], bool]):
        self.network = network
        self._check = check

    def on_message_received(self, msg: can.Message) -> None:
        if self._check(msg):
            try:
                self.network.notify(msg.arbitration_id, msg.data, msg.timestamp)
            except Exception:  # canopen's listener does the same: never kill the receive thread
                logger.exception("handler of frame 0x%03X failed", msg.arbitration_id)

    def stop(self) -> None:
        pass

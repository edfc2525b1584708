"""The bridge's own NMT slave: its NMT state, the heartbeat it produces (1017h) and what the
state allows (CiA 301 7.3.2, table 46: no SDO in Stopped).

The bridge is the NMT master of its drive; as every CANopen device it is an NMT slave too, so
a tool's NMT commands reach it. canopen's ``NmtSlave`` (which ``LocalNode`` brings) keeps the
state but stays in Initialising after a reset command, sends its heartbeat from a python-can
thread that bypasses the bridge's bus log, and lets the SDO server answer in Stopped. This
replaces it:

- the state starts Operational (the bridge starts its network as NMT master and produces
  SYNC from the start); :meth:`BridgeNmt.boot` announces it with the boot-up message when
  the bridge starts (so a drive that watched a bridge before sees it restarted, and a
  watching node -- CANopenNode, Lely -- sees it come); start / stop / enter pre-operational
  switch it; reset node and reset communication send the boot-up message and enter
  Pre-operational (CiA 301 figure 48; the bridge does not restart its application, its
  parameters stay);
- the heartbeat (0x700 + node-ID, one byte: the state) is sent by :meth:`BridgeNmt.tick` from
  the bridge's own thread through the bridge's port (so the bus log has it), every 1017h ms
  of the clock ``tick`` is given (the loop's pacer; the service thread's wall clock between
  runs); default 100 ms, 1017h = 0 sends none;
- ``on_state(new)`` lets the node react: the loop stops the axis when the bridge leaves
  Operational while the axis is enabled (docs/peers.md).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable

import canopen

from virtual_bus.contract import (
    HEARTBEAT_BASE,
    NMT_TARGET_STATE,
    NmtCommand,
    NmtState,
    nmt_command_for,
)

from .od import HEARTBEAT_PRODUCER

log = logging.getLogger("bridge")


class BridgeNmt:
    """NMT slave state and heartbeat producer of the bridge's LocalNode (see module doc).

    send(can_id, data): sends one frame through the bridge's port. on_state(new): called
    after every change of state (not for a command that leaves it unchanged).
    """

    def __init__(
        self,
        node: canopen.LocalNode,
        send: Callable[[int, bytes], None],
        on_state: Callable[[NmtState], None] | None = None,
    ) -> None:
        self.id = node.id
        self.state = NmtState.OPERATIONAL
        self._send = send
        self._on_state = on_state
        self._can_id = HEARTBEAT_BASE + node.id
        self._period_s = 0.0
        self._due_s: float | None = None
        self._wall_due_s: float | None = None
        self.heartbeats_sent = 0
        # LocalNode's NmtSlave handles 1017h writes with a python-can periodic task; the
        # bridge sends its heartbeat itself, so that handler goes with the NmtSlave
        node._write_callbacks.remove(node.nmt.on_write)  # canopen 2.4 has no public remover
        node.add_write_callback(self._on_write)
        period = node.object_dictionary[HEARTBEAT_PRODUCER].default
        self.set_period_ms(int(period or 0))

    # --- NMT commands (COB-ID 0, subscribed in place of NmtSlave.on_command) ----------------
    def on_command(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            command = nmt_command_for(data, self.id)  # the frame guard admits 2 bytes only
        except ValueError as exc:
            log.warning("%s", exc)
            return
        if command is not None:
            self.execute(command)

    def boot(self) -> None:
        """The boot-up message (0x700 + node-ID, 00h) of a bridge that starts; the heartbeat
        period starts anew with the next tick."""
        self._send(self._can_id, bytes([NmtState.INITIALISING]))
        self._due_s = None

    def beat(self) -> None:
        """A heartbeat now (when 1017h is not 0), the period starting anew: CiA 301 lets a
        consumer start watching only with the first heartbeat it receives, so the start-up
        sends one right after it configured the drive's consumer, before it enables the
        drive (a bridge killed within the first period would otherwise never be watched)."""
        if self._period_s > 0.0:
            self._send(self._can_id, bytes([self.state]))
            self.heartbeats_sent += 1
            self._due_s = None

    def execute(self, command: NmtCommand) -> None:
        if command in (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION):
            self._set(NmtState.INITIALISING)
            self._send(self._can_id, bytes([NmtState.INITIALISING]))  # boot-up
            self._due_s = None  # the heartbeat starts anew with the next tick
            self._set(NmtState.PRE_OPERATIONAL)
        else:
            self._set(NMT_TARGET_STATE[command])

    def _set(self, new: NmtState) -> None:
        if new is self.state:
            return
        log.info("bridge %d: NMT %s -> %s", self.id, self.state.name, new.name)
        self.state = new
        if self._on_state is not None:
            self._on_state(new)

    @property
    def sdo_blocked(self) -> bool:
        """CiA 301 table 46: no SDO service in Stopped."""
        return self.state is NmtState.STOPPED

    # --- heartbeat producer (1017h) ---------------------------------------------------------
    def _on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if index == HEARTBEAT_PRODUCER:
            self.set_period_ms(struct.unpack("<H", bytes(data))[0])

    @property
    def period_ms(self) -> int:
        """The heartbeat period in force (1017h, ms; 0: none)."""
        return round(self._period_s * 1000.0)

    def set_period_ms(self, period_ms: int) -> None:
        self._period_s = period_ms / 1000.0
        self._due_s = None

    def tick(self, now_s: float, wall_s: float | None = None) -> None:
        """Send the heartbeat if one is due at ``now_s`` (seconds of any clock; called at
        least every period, the loop's cycle or the service thread's few ms). ``wall_s``: a
        second clock (lockstep: the wall clock beside the simulated time): the heartbeat
        also goes out when a period of it has passed, so that a drive watching on either
        clock -- a lockstep drive on SYNC time, a real-time one on its own -- sees it in
        time however fast the loop runs."""
        period = self._period_s
        if period <= 0.0:
            return
        due = self._due_s
        if due is None or not due - period <= now_s <= due + period:
            # the first tick, or another clock (the loop's pacer after the service thread's
            # wall clock, or back): the period starts now
            self._due_s = now_s + period
            self._wall_due_s = None if wall_s is None else wall_s + period
            return
        wall_due = self._wall_due_s
        wall_late = wall_s is not None and wall_due is not None and wall_s >= wall_due
        if now_s < due and not wall_late:
            return
        self._due_s = due + period if now_s >= due else now_s + period
        self._wall_due_s = None if wall_s is None else wall_s + period
        self._send(self._can_id, bytes([self.state]))
        self.heartbeats_sent += 1

"""The bridge on the bus: its CANopen node, the start-up, and the loop that runs the cycle.

One thread does everything during the loop: it sends SYNC, reads frames until the drive's
TPDOs of that SYNC are in (or the window of the time mode is over), hands them to the pure
:class:`~bridge.cycle.CycleController`, sends the RPDO and records the row. Frames that are not
TPDOs are dispatched on the way: the drive's heartbeat and EMCY to the controller, SDO requests
of any CANopen tool to the bridge's own SDO server (a canopen LocalNode with
``config/bridge.eds``), everything else to canopen's network dispatch. canopen's PDO
machinery is not used on the cycle path: the TPDO payloads are unpacked with precompiled
structs and the RPDO message object is reused.

During start-up (:meth:`Bridge.start`) a service thread feeds received frames to canopen so
that the blocking SDO client of :mod:`bridge.master` gets its answers; it ends before the loop
starts.
"""

from __future__ import annotations

import contextlib
import logging
import struct
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import canopen
import numpy as np

from plant_sim.axis import AxisKind
from virtual_bus.contract import (
    EMCY_LENGTH,
    HEARTBEAT_LENGTH,
    NMT_LENGTH,
    SDO_LENGTH,
    sdo_rx_cob_id,
)
from virtual_bus.frame_guard import FrameFault, FrameGuard
from virtual_bus.sdo_server import CheckedSdoServer

from .cycle import BridgeState, CycleController, StopReason
from .errors import BridgeConfigError, PdoFrameError
from .layout import NMT_COB_ID, RPDO1, SYNC_COB_ID, TPDO1, TPDO2, CobIds, check_node_id
from .master import DriveInfo, DriveMaster, DriveSetup
from .objects import ObjectServer, PdoCounters
from .od import DEFAULT_DRIVE_ID, DEFAULT_EDS_PATH, DEFAULT_NODE_ID, load_od
from .params import BridgeParams
from .recorder import BusLog, TraceRecorder
from .scaling import Scaling
from .timing import Pacer, RealTimePacer

log = logging.getLogger("bridge")

_EMCY = struct.Struct("<HB")


_MESSAGE_FIELDS = tuple(name for name in can.Message.__slots__ if not name.startswith("__"))


class CycleMessage(can.Message):
    """A frame the loop sends every cycle (SYNC, RPDO), built once and reused.

    python-can's virtual bus deep-copies every frame it delivers; ``Message.__deepcopy__``
    runs the full constructor (about 7 µs). This copy sets the fields of a plain
    :class:`can.Message` directly (the data is copied), the only hot-path change to a
    python-can object."""

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, object] | None) -> can.Message:
        new = can.Message.__new__(can.Message)
        for name in _MESSAGE_FIELDS:
            setattr(new, name, getattr(self, name))
        new.data = bytearray(self.data)
        return new


class BusPort:
    """The bridge's side of the bus: every frame sent or received passes here and goes to the
    bus log (if any). canopen's Network sends through :meth:`send` too."""

    def __init__(self, bus: can.BusABC, bus_log: BusLog | None = None) -> None:
        self.bus = bus
        self.bus_log = bus_log
        self.channel_info = getattr(bus, "channel_info", "")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.bus_log is not None:
            self.bus_log.log(msg, received=False)
        self.bus.send(msg, timeout)

    def recv(self, timeout: float | None) -> can.Message | None:
        msg = self.bus.recv(timeout)
        if msg is not None and self.bus_log is not None:
            self.bus_log.log(msg, received=True)
        return msg


@dataclass(frozen=True)
class BridgeConfig:
    """Identity of the bridge on the bus and how it starts the drive."""

    node_id: int = DEFAULT_NODE_ID
    drive_id: int = DEFAULT_DRIVE_ID
    eds_path: Path = DEFAULT_EDS_PATH
    drive_setup: DriveSetup = field(default_factory=DriveSetup)

    def __post_init__(self) -> None:
        check_node_id("node_id", self.node_id)
        check_node_id("drive_id", self.drive_id)
        if self.node_id == self.drive_id:
            raise BridgeConfigError(
                f"node_id = drive_id = {self.node_id}: bridge and drive need different node-IDs"
            )


@dataclass
class Timing:
    """Real-time statistics of the loop (wall clock): SYNC-to-set-point latency per cycle (s)
    and SYNCs that had to be skipped because the loop fell behind."""

    latencies_s: list[float] = field(default_factory=list)
    skipped_syncs: int = 0
    sync_late_s: list[float] = field(default_factory=list)


class Bridge:
    """The bridge node on ``bus`` (see the module docstring).

    params: the controller's parameters. kind: linear or rotary (scaling of the load scale).
    pacer: time mode (lockstep or real time). recorder / bus_log: optional recording.
    keep_timing: collect per-cycle latencies (for benchmarks).
    """

    def __init__(
        self,
        bus: can.BusABC,
        params: BridgeParams,
        kind: AxisKind,
        pacer: Pacer,
        *,
        config: BridgeConfig = BridgeConfig(),
        recorder: TraceRecorder | None = None,
        bus_log: BusLog | None = None,
        keep_timing: bool = False,
        wall: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.pacer = pacer
        self.recorder = recorder
        self.bus_log = bus_log
        self.ids = CobIds(config.drive_id)
        self.port = BusPort(bus, bus_log)
        self.network = canopen.Network(self.port)  # type: ignore[arg-type]
        self.node = canopen.LocalNode(config.node_id, load_od(config.eds_path, config.node_id))
        self.node.sdo = CheckedSdoServer(self.node)  # before the node joins the network
        self.network.add_node(self.node)
        self.drive = canopen.RemoteNode(config.drive_id, canopen.ObjectDictionary())
        self.network.add_node(self.drive)
        self.counters = PdoCounters()
        self.scaling = Scaling.for_kind(kind)
        self.controller = CycleController(params, self.scaling, state=BridgeState.CONFIGURING)
        #: every received frame passes it before a handler sees it (docs/bridge.md)
        self.guard = FrameGuard(f"bridge {config.node_id}", self._classify, self._refused)
        self._lengths = {
            self.ids.tpdo1: TPDO1.dlc,
            self.ids.tpdo2: TPDO2.dlc,
            self.ids.emcy: EMCY_LENGTH,
            self.ids.heartbeat: HEARTBEAT_LENGTH,
            self.ids.sdo_tx: SDO_LENGTH,
            sdo_rx_cob_id(config.node_id): SDO_LENGTH,
            NMT_COB_ID: NMT_LENGTH,
        }
        self.objects = ObjectServer(
            self.controller,
            self.counters,
            self.scaling.load_increments_per_unit,
            config.drive_id,
            self.guard,
        )
        self.objects.attach(self.node)
        self.timing = Timing() if keep_timing else None
        self._wall = wall
        self._k = 0
        self._slots: list[bytearray | None] = [None, None]
        self._window_open = False
        self._record_pending = False
        self._sync_msg = CycleMessage(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
        self._sync_msg.is_rx = False
        self._rpdo_msg = CycleMessage(
            arbitration_id=self.ids.rpdo1, data=bytes(RPDO1.dlc), is_extended_id=False
        )
        self._rpdo_msg.is_rx = False
        self._rpdo_msg.data = self.controller.rpdo_payload  # rewritten in place every cycle
        self._tpdo_ids = (self.ids.tpdo1, self.ids.tpdo2)
        self._tpdo_dlc = (TPDO1.dlc, TPDO2.dlc)
        self.drive_info: DriveInfo | None = None
        #: Called with k before SYNC k is sent (a harness hook, e.g. the simulated drive's
        #: disturbance input in the demo); None: nothing.
        self.before_sync: Callable[[int], None] | None = None
        #: lockstep with a simulated peer in this thread (SimulatedDrive.polled): called right
        #: after the SYNC has gone out, so the peer answers before the bridge waits
        self.peer_poll: Callable[[], int] | None = None

    # --- frames -----------------------------------------------------------------------------
    def _classify(self, cob_id: int, length: int) -> FrameFault | None:
        need = self._lengths.get(cob_id)
        if need is None:
            # the bridge produces SYNC (1005h bit 30): a SYNC it receives came from another node
            if cob_id == SYNC_COB_ID:
                return FrameFault.SECOND_SYNC_PRODUCER
            return FrameFault.UNKNOWN_COB_ID
        return None if length == need else FrameFault.BAD_LENGTH

    def _refused(self, fault: FrameFault, cob_id: int) -> None:
        if fault is FrameFault.BAD_LENGTH and cob_id in self._tpdo_ids:
            self.counters.invalid += 1  # 2107h:03 counts TPDOs of the wrong length
        elif fault is FrameFault.SECOND_SYNC_PRODUCER:
            self.controller.stop_for(
                StopReason.SYNC_CONFLICT,
                f"a SYNC (0x{cob_id:03X}) the bridge did not send: a second SYNC producer "
                "on the bus would run the drive on a time base the bridge does not know",
            )

    def dispatch(self, msg: can.Message) -> None:
        """Handle one received frame (TPDO slots, heartbeat, EMCY, canopen services) after
        the frame guard has admitted it."""
        if not self.guard.check(msg):
            return
        cid = msg.arbitration_id
        if cid == self._tpdo_ids[0]:
            self._tpdo(0, msg.data)
        elif cid == self._tpdo_ids[1]:
            self._tpdo(1, msg.data)
        elif cid == self.ids.heartbeat:
            self.controller.on_heartbeat(msg.data[0], self.pacer.now())
            self.network.notify(cid, msg.data, msg.timestamp)
        elif cid == self.ids.emcy:
            code, register = _EMCY.unpack_from(msg.data)
            self.controller.on_emcy(code, register)
        else:
            self.network.notify(cid, msg.data, msg.timestamp)

    def _tpdo(self, slot: int, data: bytearray) -> None:
        if len(data) != self._tpdo_dlc[slot]:
            self.counters.invalid += 1
            err = PdoFrameError(
                f"TPDO{slot + 1} (0x{self._tpdo_ids[slot]:03X}) with {len(data)} bytes; the "
                f"mapping has {self._tpdo_dlc[slot]}; frame ignored",
                can_id=self._tpdo_ids[slot],
                length=len(data),
                expected=self._tpdo_dlc[slot],
            )
            log.warning("%s", err)
            return
        if not self._window_open:
            self.counters.late += 1
            return
        if self._slots[slot] is not None:
            self.counters.late += 1  # an extra frame in this window: the newest one is used
        self._slots[slot] = data

    @contextlib.contextmanager
    def serving(self) -> Iterator[None]:
        """Feed received frames to canopen from a thread (SDO client/server while not
        cycling); the thread ends when the block ends."""
        stop = threading.Event()

        def pump() -> None:
            while not stop.is_set():
                msg = self.port.recv(0.005)
                if msg is not None:
                    self.dispatch(msg)

        thread = threading.Thread(target=pump, name="bridge-service", daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()

    # --- start-up ---------------------------------------------------------------------------
    def start(self, configure_drive: bool = True) -> DriveInfo | None:
        """Configure the drive over SDO and bring it to Operation Enabled (blocking), then make
        the controller ready to enable the axis at the first cycle."""
        if configure_drive:
            with self.serving():
                info = DriveMaster(self.drive, self.config.drive_setup).run()
            self.drive_info = info
            self.scaling = Scaling(self.scaling.load_increments_per_unit, info.rated_torque_nm)
            self.controller.set_scaling(self.scaling)
        self.controller.restart_supervision()
        self.controller.state = BridgeState.ENABLING
        return self.drive_info

    # --- the loop ---------------------------------------------------------------------------
    def _pump_until(self, wall_deadline: float | None) -> None:
        """Dispatch frames until ``wall_deadline``; ``None``: only those already waiting.
        Between windows, a TPDO is late (counted, not used)."""
        wall = self._wall
        recv = self.port.recv
        spin = self.pacer.spin_s
        while True:
            remaining = 0.0 if wall_deadline is None else wall_deadline - wall()
            msg = recv(remaining - spin if remaining > spin else 0.0)
            if msg is None:
                if remaining <= 0.0:
                    return
                continue
            self.dispatch(msg)

    def drain(self) -> None:
        """Dispatch the frames already received, outside any cycle (TPDOs count as late)."""
        self._pump_until(None)

    def run_cycle(self) -> None:
        """One SYNC: send it, collect the TPDOs, step the controller, send the RPDO, record."""
        k = self._k
        pacer = self.pacer
        due = pacer.begin_cycle(k)
        # real time: wait for the SYNC instant; lockstep: take what is already there. Either
        # way TPDOs that come now belong to an earlier SYNC and are counted late, so a drive
        # that answered after the window cannot shift the data of the following cycles.
        self._pump_until(due)
        if self.before_sync is not None:
            self.before_sync(k)
        wall = self._wall
        slots = self._slots
        slots[0] = slots[1] = None
        sync_wall = wall()
        self._window_open = True
        self.port.send(self._sync_msg)
        if self.peer_poll is not None:
            self.peer_poll()
        end = pacer.window_end(sync_wall)
        if self._record_pending:  # the previous row, while the drive answers the SYNC
            self.flush_record()
        recv = self.port.recv
        while slots[0] is None or slots[1] is None:
            remaining = end - wall()
            if remaining <= 0.0:
                break
            msg = recv(remaining)
            if msg is not None:
                self.dispatch(msg)
        self._window_open = False
        counters = self.counters
        counters.cycles += 1
        first, second = slots
        if first is None or second is None:
            counters.missed_cycles += 1
            counters.missed += (first is None) + (second is None)
        self.controller.step(pacer.now(), first, second)
        self.port.send(self._rpdo_msg)
        if self.timing is not None:
            self.timing.latencies_s.append(wall() - sync_wall)
            if due is not None:
                self.timing.sync_late_s.append(sync_wall - due)
        self._record_pending = self.recorder is not None
        self._k = k + 1
        if isinstance(pacer, RealTimePacer):
            behind = pacer.cycles_behind(self._k)
            if behind:
                self._k += behind
                if self.timing is not None:
                    self.timing.skipped_syncs += behind

    def run(self, cycles: int | None = None, until: Callable[[Bridge], bool] | None = None) -> int:
        """Run cycles until ``cycles`` are done or ``until(bridge)`` is true (checked after each
        cycle); returns the number of cycles run."""
        if cycles is None and until is None:
            raise BridgeConfigError("run() needs cycles or until")
        n = 0
        try:
            while cycles is None or n < cycles:
                self.run_cycle()
                n += 1
                if until is not None and until(self):
                    break
        finally:
            self.flush_record()
        return n

    def flush_record(self) -> None:
        """Record the row of the last cycle if it is still pending (the loop records a cycle's
        row right after the next SYNC has gone out, while the drive works on it)."""
        if self._record_pending and self.recorder is not None:
            self.recorder.record(self.controller)
        self._record_pending = False

    @property
    def cycle_index(self) -> int:
        """Index of the next SYNC."""
        return self._k

    def latencies(self) -> np.ndarray:
        """SYNC-to-set-point latencies (s) collected with ``keep_timing``."""
        return np.asarray(self.timing.latencies_s if self.timing else [], dtype=float)

    def close(self) -> None:
        """Flush and close the recording (the bus itself belongs to the caller)."""
        self.flush_record()
        if self.recorder is not None:
            self.recorder.close()
        if self.bus_log is not None:
            self.bus_log.close()

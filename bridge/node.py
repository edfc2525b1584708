"""The bridge on the bus: its CANopen node, the start-up, and the loop that runs the cycle.

One thread does everything during the loop, without hand-offs (no notifier thread, no queue
between threads): it sends SYNC on its slot, reads frames until the drive's TPDOs of that SYNC
are in (or the window of the time mode is over), hands them to the pure
:class:`~bridge.cycle.CycleController`, sends the RPDO and records the row. On the cycle path
only the two TPDOs are decoded (precompiled structs, payloads kept as received); every other
frame -- the drive's heartbeat and EMCY, SDO requests of any CANopen tool to the bridge's own
SDO server (a canopen LocalNode with ``config/bridge.eds``), NMT, everything canopen handles --
is put in a bounded ring and handled between cycles, after the RPDO has gone out and only while
the next SYNC is more than ``service_guard_s`` away: a long SDO transfer takes more cycles, it
never delays a SYNC. The SYNC and RPDO message objects and the RPDO payload are built once and
rewritten in place.

Nothing on the cycle path raises into the loop: a send or receive error of the bus, an
exception while handling a frame between cycles or while recording is logged and counted
(:class:`~bridge.loopstats.Timing`); an exception of the controller itself stops the axis.
A SYNC slot the loop cannot meet is skipped (see :mod:`bridge.timing`), and ``overrun_limit``
overrunning cycles in a row stop the axis (:attr:`StopReason.CYCLE_OVERRUN`).

During start-up (:meth:`Bridge.start`) a service thread feeds received frames to canopen so
that the blocking SDO client of :mod:`bridge.master` gets its answers; it ends before the loop
starts.
"""

from __future__ import annotations

import contextlib
import logging
import math
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import canopen
import numpy as np

from virtual_bus.contract import (
    EMCY_LENGTH,
    HEARTBEAT_LENGTH,
    NMT_LENGTH,
    SDO_LENGTH,
    SDO_TX_BASE,
    NmtState,
    emcy_cob_id,
    heartbeat_cob_id,
    sdo_rx_cob_id,
)
from virtual_bus.formats.axis import AxisKind
from virtual_bus.formats.drive_profile import DriveProfile
from virtual_bus.frame_guard import FrameFault, FrameGuard
from virtual_bus.framing import (
    NOTHING,
    FramePort,
    MessagePort,
    OutFrame,
    frame_port,
)
from virtual_bus.realtime import GcBetweenCycles
from virtual_bus.sdo_server import CheckedSdoServer

from .cycle import CW_RUNNING, BridgeState, CycleController, StopReason
from .errors import BridgeConfigError
from .layout import NMT_COB_ID, SYNC_COB_ID, CobIds, CycleLayout, check_node_id, contract_layout
from .loopstats import Timing
from .master import DriveInfo, DriveMaster, DriveSetup
from .nmt import BridgeNmt
from .objects import ObjectServer, PdoCounters
from .od import DEFAULT_DRIVE_ID, DEFAULT_EDS_PATH, DEFAULT_NODE_ID, load_od
from .params import BridgeParams
from .recorder import BusLog, TraceRecorder
from .scaling import Scaling
from .store import ParameterStore
from .timing import Pacer, TimeMode

log = logging.getLogger("bridge")

_EMCY = struct.Struct("<HB")

#: Frames other than the TPDOs held for handling between cycles; beyond this they are dropped
#: (counted in Timing.service_dropped; an SDO client repeats, a heartbeat comes again).
SERVICE_RING_FRAMES = 256
#: Between cycles, frames are handled only while the next SYNC is more than this share of the
#: cycle away (real time).
DEFAULT_SERVICE_GUARD_FRACTION = 0.25
#: Frames read without waiting at the end of a wait (SYNC instant, end of the TPDO window).
LATE_READ_FRAMES = 16
#: Cycles in a row that overrun (a SYNC slot after them skipped) before the axis is stopped.
DEFAULT_OVERRUN_LIMIT = 3


@contextlib.contextmanager
def pumping(
    recv: Callable[[float | None], can.Message | None],
    handle: Callable[[can.Message], None],
    name: str,
    idle: Callable[[], None] | None = None,
) -> Iterator[None]:
    """A thread that hands every received frame to ``handle`` while the block runs (the SDO
    client's answers during start-up and ``bridge probe``); ``idle`` is called between frames
    (at least every 5 ms)."""
    stop = threading.Event()

    def pump() -> None:
        while not stop.is_set():
            msg = recv(0.005)
            if msg is not None:
                handle(msg)
            if idle is not None:
                idle()

    thread = threading.Thread(target=pump, name=name, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


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
    """Identity of the bridge on the bus, how it starts the drive, where it stores its
    parameters (1010h; loaded when the bridge is built, over the given params).

    profile: the drive profile (:mod:`virtual_bus.formats.drive_profile`,
    ``--drive-profile``); ``None``: the
    start-up adapts to what the drive reports, with the contract's scaling as the default.
    """

    node_id: int = DEFAULT_NODE_ID
    drive_id: int = DEFAULT_DRIVE_ID
    eds_path: Path = DEFAULT_EDS_PATH
    drive_setup: DriveSetup = field(default_factory=DriveSetup)
    #: Parameter store of 1010h/1011h (bridge.store); None: the bridge stores nothing.
    store_path: Path | None = None
    profile: DriveProfile | None = None

    def __post_init__(self) -> None:
        check_node_id("node_id", self.node_id)
        check_node_id("drive_id", self.drive_id)
        if self.node_id == self.drive_id:
            raise BridgeConfigError(
                f"node_id = drive_id = {self.node_id}: bridge and drive need different node-IDs"
            )


class Bridge:
    """The bridge node on ``bus`` (see the module docstring).

    params: the controller's parameters. kind: linear or rotary (scaling of the load scale).
    pacer: time mode (lockstep or real time). recorder / bus_log: optional recording.
    keep_timing: keep per-cycle timing (:class:`~bridge.loopstats.Timing`, for benchmarks);
    the counts (skipped SYNCs, overruns, errors) are kept either way in :attr:`timing`.
    overrun_limit: overrunning cycles in a row that stop the axis (None: only counted).
    gc_control: the garbage collector frozen after start-up and run between cycles.
    busy_poll: poll the bus (no blocking wait) while waiting for the TPDOs: no wake-up
    latency, a core kept busy during the window (for an isolated CPU).
    compiled: the cycle's arithmetic compiled by numba (None: where numba is installed;
    bridge.cyclecore), compiled before the first cycle.
    cpu: the loop thread's CPU clock (with ``keep_timing``: the CPU time of its work per
    cycle, and whether a skipped SYNC slot was its own work's or the host's,
    :mod:`bridge.loopstats`).
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
        overrun_limit: int | None = DEFAULT_OVERRUN_LIMIT,
        service_guard_fraction: float = DEFAULT_SERVICE_GUARD_FRACTION,
        gc_control: GcBetweenCycles | None = None,
        busy_poll: bool = False,
        compiled: bool | None = None,
        cpu: Callable[[], float] = time.thread_time,
        wall_heartbeat: bool = True,
    ) -> None:
        self.config = config
        #: False: every node watching the bridge runs on the loop's simulated time (an
        #: in-process drive in lockstep), so the heartbeat follows that time only and a
        #: recording is the same frame for frame whatever the host's speed
        self.wall_heartbeat = wall_heartbeat
        self.pacer = pacer
        self.recorder = recorder
        self.bus_log = bus_log
        self.ids = CobIds(config.drive_id)
        self.port = BusPort(bus, bus_log)
        self.network = canopen.Network(self.port)  # type: ignore[arg-type]
        self.node = canopen.LocalNode(config.node_id, load_od(config.eds_path, config.node_id))
        # before the node joins the network; silent in NMT Stopped (bridge.nmt)
        self.node.sdo = CheckedSdoServer(self.node, blocked=lambda: self.nmt.sdo_blocked)
        self.network.add_node(self.node)
        self.nmt = BridgeNmt(self.node, self._send_frame, self._nmt_changed)
        self.network.unsubscribe(NMT_COB_ID, self.node.nmt.on_command)
        self.network.subscribe(NMT_COB_ID, self.nmt.on_command)
        self.drive = canopen.RemoteNode(config.drive_id, canopen.ObjectDictionary())
        self.network.add_node(self.drive)
        self.counters = PdoCounters()
        self.scaling = Scaling.for_kind(kind)
        self.controller = CycleController(
            params, self.scaling, state=BridgeState.CONFIGURING, compiled=compiled
        )
        #: the loop's frames: the bus's raw socket where python-can's socketcan or our
        #: udp_multicast bus is used and nothing is logged, else python-can's messages
        self.frames: FramePort = frame_port(bus) if bus_log is None else MessagePort(self.port)
        store = None if config.store_path is None else ParameterStore(config.store_path)
        #: every received frame passes it before a handler sees it (docs/bridge.md)
        self.guard = FrameGuard(f"bridge {config.node_id}", self._classify, self._refused)
        #: lengths of the frames that are not the layout's (those are added by use_layout)
        self._fixed_lengths = {
            self.ids.emcy: EMCY_LENGTH,
            self.ids.heartbeat: HEARTBEAT_LENGTH,
            self.ids.sdo_tx: SDO_LENGTH,
            sdo_rx_cob_id(config.node_id): SDO_LENGTH,
            NMT_COB_ID: NMT_LENGTH,
        }
        self._lengths = dict(self._fixed_lengths)
        self.objects = ObjectServer(
            self.controller,
            self.counters,
            self.scaling.load_increments_per_unit,
            config.drive_id,
            store,
            self.guard,
        )
        if store is not None and (stored := store.load()) is not None:
            self.controller.set_params(self.objects.apply_stored(stored, str(store.path)))
            log.info("parameters loaded from %s", store.path)
        self.objects.attach(self.node)
        self.timing = Timing(16 if not keep_timing else 65536)
        self._keep_timing = keep_timing
        self._wall = wall
        self._cpu = cpu
        # the cycle since the last SYNC (keep_timing; bridge.loopstats, "which floor binds"):
        # its wall instant, the wait for the TPDOs up to the window's end, the loop's own work
        # (CPU time of the cycle's work and of frames and garbage between cycles)
        self._sync_wall = -math.inf
        self._waited = 0.0
        self._own = 0.0
        if overrun_limit is not None and overrun_limit < 1:
            raise BridgeConfigError(f"overrun_limit = {overrun_limit!r}: must be >= 1 or None")
        if not 0.0 <= service_guard_fraction < 1.0:
            raise BridgeConfigError(
                f"service_guard_fraction = {service_guard_fraction!r}: must be in [0, 1)"
            )
        self.overrun_limit = overrun_limit
        self._lockstep = pacer.mode is TimeMode.LOCKSTEP
        self.service_guard_s = service_guard_fraction * pacer.cycle_s
        self.gc_control = gc_control
        self.busy_poll = busy_poll
        self._service: deque[can.Message] = deque()
        self._k = 0
        self._window_open = False
        self._record_pending = False
        self._sync_frame = self.frames.frame(SYNC_COB_ID, 0)
        self._encoder_heartbeat = -1
        self._encoder_emcy = -1
        self._supervision_ids = frozenset((self.ids.emcy, self.ids.heartbeat))
        self.use_layout(contract_layout(config.drive_id))
        self.drive_info: DriveInfo | None = None
        #: Called with k before SYNC k is sent (a harness hook, e.g. the simulated drive's
        #: disturbance input in the demo); None: nothing.
        self.before_sync: Callable[[int], None] | None = None
        #: lockstep with a simulated peer in this thread (SimulatedDrive.polled): called right
        #: after the SYNC has gone out, so the peer answers before the bridge waits
        self.peer_poll: Callable[[], int] | None = None
        #: called with the bridge after every cycle of :meth:`run` (``bridge run``'s status,
        #: bridge.status); None: nothing
        self.after_cycle: Callable[[Bridge], None] | None = None

    def use_layout(self, layout: CycleLayout) -> None:
        """Expect the frames of ``layout`` after every SYNC and send its RPDO (start-up)."""
        self.layout = layout
        self.controller.set_layout(layout)
        self._tpdo_ids = layout.can_ids
        self._slot_of = {cid: i for i, cid in enumerate(self._tpdo_ids)}
        #: COB-ID -> (bit, length, slot) of each TPDO of the layout (the loop's window)
        self._tpdos = {f.can_id: (1 << i, f.dlc, i) for i, f in enumerate(layout.frames)}
        self._lengths = self._fixed_lengths | {f.can_id: f.dlc for f in layout.frames}
        if self._encoder_heartbeat >= 0:
            self._lengths[self._encoder_heartbeat] = HEARTBEAT_LENGTH
            self._lengths[self._encoder_emcy] = EMCY_LENGTH
        self._present = 0  # a bit per slot whose TPDO came in this window
        self._all_slots = (1 << len(self._tpdo_ids)) - 1
        self._rpdo_frame = self.frames.frame(layout.rpdo_can_id, layout.rpdo_dlc)
        # the controller packs the set point straight into the frame that goes out
        self.controller.set_rpdo_target(self._rpdo_frame.buffer, self._rpdo_frame.offset)

    # --- frames -----------------------------------------------------------------------------
    def _classify(self, cob_id: int, length: int) -> FrameFault | None:
        need = self._lengths.get(cob_id)
        if need is None and SDO_TX_BASE < cob_id <= SDO_TX_BASE + 0x7F:
            need = SDO_LENGTH  # an SDO answer to the bridge's client (drive, encoder node)
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
        if self.guard.check(msg):
            self._handle(msg)

    def _handle(self, msg: can.Message) -> None:
        """A frame the guard has admitted (see :meth:`dispatch`)."""
        cid = msg.arbitration_id
        slot = self._slot_of.get(cid)
        if slot is not None:
            self._tpdo(slot, msg.data, 0)
        elif cid == self._encoder_heartbeat:
            self.controller.on_encoder_heartbeat(msg.data[0], self.pacer.now())
        elif cid == self._encoder_emcy:
            code, register = _EMCY.unpack_from(msg.data)
            self.controller.on_encoder_emcy(code, register)
        elif cid == self.ids.heartbeat:
            self.controller.on_heartbeat(msg.data[0], self.pacer.now())
            self.network.notify(cid, msg.data, msg.timestamp)
        elif cid == self.ids.emcy:
            code, register = _EMCY.unpack_from(msg.data)
            self.controller.on_emcy(code, register)
        else:
            self.network.notify(cid, msg.data, msg.timestamp)

    def _tpdo(self, slot: int, buffer: bytes | bytearray | memoryview, offset: int) -> None:
        """A TPDO of the layout, admitted by the frame guard (standard ID, not RTR, the
        mapping's length; a wrong length is counted in 2107h:03 by :meth:`_refused`):
        decoded now if its window is open (the newest frame of a window is the one used)."""
        if not self._window_open:
            self.counters.late += 1
            return
        bit = 1 << slot
        if self._present & bit:
            self.counters.late += 1  # an extra frame in this window: the newest one is used
        self._present |= bit
        self.controller.decoders[slot](buffer, offset)

    @contextlib.contextmanager
    def serving(self) -> Iterator[None]:
        """Feed received frames to canopen from a thread (SDO client/server while not
        cycling; the heartbeat on the wall clock); the thread ends when the block ends."""
        idle = (lambda: self.nmt.tick(self._wall())) if self.wall_heartbeat else None
        with pumping(self.port.recv, self.dispatch, "bridge-service", idle):
            yield

    # --- the bridge's own NMT slave (bridge.nmt) ------------------------------------------
    def _send_frame(self, can_id: int, data: bytes) -> None:
        try:
            self.port.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        except (can.CanError, OSError) as exc:
            self.timing.errors += 1
            log.error("send of 0x%03X failed: %s", can_id, exc)

    def _nmt_changed(self, state: NmtState) -> None:
        """Outside Operational the bridge may not exchange PDOs (CiA 301 table 46): an
        enabled axis is stopped (its quick stop still goes out with the next RPDO)."""
        if state is not NmtState.OPERATIONAL:
            self.controller.stop_for(
                StopReason.NMT_COMMAND,
                f"NMT {state.name.lower().replace('_', '-')} commanded to the bridge",
            )

    # --- start-up ---------------------------------------------------------------------------
    def start(self, configure_drive: bool = True) -> DriveInfo | None:
        """Announce the bridge (its boot-up message, then its heartbeat), configure the drive
        over SDO -- its supervision of the bridge included (bridge.supervision) -- and bring
        it to Operation Enabled (blocking), then make the controller ready to enable the
        axis at the first cycle."""
        self.nmt.boot()  # a drive that watched a bridge before sees this one restarted
        if configure_drive:
            with self.serving():
                master = DriveMaster(
                    self.drive,
                    self.config.drive_setup,
                    profile=self.config.profile,
                    load_increments_per_unit=self.scaling.load_increments_per_unit,
                    bridge_id=self.config.node_id,
                    heartbeat_ms=self.nmt.period_ms,
                    heartbeat_now=self.nmt.beat,
                )
                info = master.run()
            self.drive_info = info
            # the start-up left the drive in Operation Enabled: 000Fh keeps it there, also
            # when the first cycles bring no statusword (the controller repeats it then)
            self.controller.controlword = CW_RUNNING
            self.scaling = info.scaling
            self.controller.set_scaling(self.scaling)
            if info.encoder_id is not None:  # before use_layout, which admits its frames
                self.controller.encoder_id = info.encoder_id
                self._encoder_heartbeat = heartbeat_cob_id(info.encoder_id)
                self._encoder_emcy = emcy_cob_id(info.encoder_id)  # CiA 301 default 1014h
                self._supervision_ids = self._supervision_ids | {
                    self._encoder_heartbeat,
                    self._encoder_emcy,
                }
            self.use_layout(info.layout)
            self.objects.set_load_scaling(self.scaling.load_increments_per_unit)
        self.controller.restart_supervision()
        self.controller.state = BridgeState.ENABLING
        return self.drive_info

    # --- the loop ---------------------------------------------------------------------------
    def _receive(self, msg: can.Message) -> None:
        """A frame received by the loop as a message: a TPDO of the layout goes to its slot
        now (or counts late outside a window); the drive's EMCY and heartbeat (and an
        encoder's heartbeat and EMCY) are supervision inputs of this very cycle and cheap (a
        few assignments): handled now; anything else (SDO, NMT, what canopen handles) waits
        in the service ring for the time between cycles."""
        if not self.guard.check(msg):  # counted and logged by the guard; never raised
            return
        cid = msg.arbitration_id
        slot = self._slot_of.get(cid)
        if slot is not None:
            self._tpdo(slot, msg.data, 0)
        elif cid in self._supervision_ids:
            try:
                self._handle(msg)
            except Exception:
                self.timing.errors += 1
                log.exception("frame 0x%03X: handling failed; ignored", cid)
        elif len(self._service) < SERVICE_RING_FRAMES:
            self._service.append(msg)
        else:
            self.timing.service_dropped += 1

    def _take(self, cob_id: int) -> None:
        """The frame the port just received (``cob_id``: what ``receive`` returned): a TPDO
        of the layout with its mapping's length (what the frame guard admits at that COB-ID;
        counted as it counts) is decoded where it lies; anything else becomes a message and
        goes :meth:`_receive`'s way."""
        frames = self.frames
        tpdo = self._tpdos.get(cob_id)
        if tpdo is not None and frames.length == tpdo[1]:
            self.guard.accepted += 1
            self._tpdo(tpdo[2], frames.buffer, frames.offset)
            return
        try:
            msg = frames.message()
        except (can.CanError, OSError) as exc:  # e.g. a datagram that is no frame
            self._receive_failed(exc)
            return
        self._receive(msg)

    def _serve_one(self) -> None:
        msg = self._service.popleft()  # admitted by the guard in _receive
        try:
            self._handle(msg)
        except Exception:  # a tool's bad request must not end the loop
            self.timing.errors += 1
            log.exception("frame 0x%03X: handling failed; ignored", msg.arbitration_id)

    def _poll(self, timeout: float) -> int:
        """Wait at most ``timeout`` s for a frame (0: do not wait): what the port's
        ``receive`` returns (NOTHING also after a receive error, counted and logged)."""
        try:
            return self.frames.receive(timeout)
        except (can.CanError, OSError) as exc:
            self._receive_failed(exc)
            return NOTHING

    def _receive_failed(self, exc: Exception) -> None:
        self.timing.errors += 1
        log.error("receive failed: %s", exc)

    def _send_failed(self, frame: OutFrame, exc: Exception) -> None:
        self.timing.errors += 1
        log.error("send of 0x%03X failed: %s", frame.cob_id, exc)

    def _between_cycles(self, due: float | None) -> None:
        """Until the wall instant ``due`` (``None``: lockstep, no waiting): handle the frames
        in the service ring and those arriving, and collect garbage (``gc_control``), each
        only while ``due`` is more than ``service_guard_s`` away; the last ``spin_s`` are
        polled. TPDOs arriving now belong to an earlier SYNC: counted late, never used."""
        service = self._service
        poll = self._poll
        take = self._take
        if due is None:
            receive = self.frames.receive
            while True:
                while service:
                    self._serve_one()
                try:  # _poll(0.0) without the call
                    cob_id = receive(0.0)
                except (can.CanError, OSError) as exc:
                    self._receive_failed(exc)
                    break
                if cob_id == NOTHING:
                    break
                take(cob_id)
            gc_control = self.gc_control
            if gc_control is not None and gc_control.due():
                gc_control.collect()
            return
        wall = self._wall
        guard = self.service_guard_s
        spin = self.pacer.spin_s
        gc_control = self.gc_control
        keep = self._keep_timing
        while True:
            remaining = due - wall()
            if remaining <= spin:
                break
            if remaining > guard:
                if service:
                    started = self._cpu() if keep else 0.0
                    self._serve_one()
                    self._own += self._cpu() - started if keep else 0.0
                    continue
                if gc_control is not None and gc_control.due():
                    started = self._cpu() if keep else 0.0
                    gc_control.collect()
                    self._own += self._cpu() - started if keep else 0.0
                    continue
            cob_id = poll(remaining - spin)
            if cob_id == NOTHING:
                continue
            if keep:
                started = self._cpu()
                take(cob_id)
                self._own += self._cpu() - started
            else:
                take(cob_id)
        # the last spin_s: poll the clock, not the bus (a blocking wait wakes late, a bus poll
        # is a system call); then take what arrived meanwhile, so that a TPDO of an earlier
        # SYNC is counted late and never used for the next one
        while wall() < due:
            pass
        for _ in range(LATE_READ_FRAMES):  # bounded: a flood of frames cannot hold the SYNC
            cob_id = poll(0.0)
            if cob_id == NOTHING:
                break
            take(cob_id)

    def _host_missed(self, due: float) -> bool:
        """Whether the SYNC slot ``due``, found missed now, was missed because the host kept
        the loop from running: its cycle -- the wait for the TPDOs up to the window's end,
        then its own work (bridge.loopstats) -- would have ended in time for the slot."""
        if self._sync_wall == -math.inf:  # before the first SYNC: nothing of a cycle ran
            return True
        ready = self._sync_wall + self._waited + self._own
        host = ready <= due + self.pacer.late_s
        details = self.timing.overrun_details
        if len(details) < 16:
            details.append(
                {
                    "since_sync_us": round(1e6 * (self._wall() - self._sync_wall)),
                    "tpdo_wait_us": round(1e6 * self._waited),
                    "own_work_us": round(1e6 * self._own),
                    "slot_after_sync_us": round(1e6 * (due - self._sync_wall)),
                    "host": host,
                }
            )
        return host

    def keep_clock(self) -> None:
        """SYNC and the RPDO as they stand, without a cycle (nothing is received): the stop
        path asks a drive over SDO meanwhile (bridge.halt), and a drive whose clock is SYNC
        runs its ramp only on SYNC."""
        for frame in (self._sync_frame, self._rpdo_frame):
            try:
                frame.send()
            except (can.CanError, OSError) as exc:
                self._send_failed(frame, exc)

    def drain(self) -> None:
        """Handle the frames already received, outside any cycle (TPDOs count as late)."""
        self._between_cycles(None)

    def run_cycle(self) -> None:
        """One SYNC: wait for its slot (handling other frames), send it, collect the TPDOs
        (each decoded as it arrives), step the controller, send the RPDO, record."""
        pacer = self.pacer
        wall = self._wall
        timing = self.timing
        keep = self._keep_timing
        k = self._k
        skipped = 0
        by_host: bool | None = None
        while True:
            slot, due = pacer.slot(k)
            if slot != k:  # the cycle before ran past this slot
                if keep and by_host is None:
                    by_host = self._host_missed(due - (slot - k) * pacer.cycle_s)
                skipped += slot - k
                k = slot
            self._between_cycles(due)
            if due is None:
                break
            sync_wall = wall()
            if pacer.on_time(due, sync_wall):
                break
            if keep and by_host is None:
                by_host = self._host_missed(due)
            k += 1  # preempted past the slot while waiting: skip it, never send it late
            skipped += 1
        if skipped:
            in_a_row = timing.overran(skipped, by_host)
            limit = self.overrun_limit
            if limit is not None and in_a_row >= limit:
                self.controller.stop(
                    StopReason.CYCLE_OVERRUN,
                    f"{in_a_row} cycles in a row overran the {pacer.cycle_s * 1e3:g} ms cycle "
                    f"({skipped} SYNC slot(s) skipped before SYNC {k}; limit {limit})",
                )
        else:
            timing.consecutive_overruns = 0
        if self.before_sync is not None:
            self.before_sync(k)
        self._present = 0
        self._window_open = True
        sync_wall = wall()
        if keep:
            self._sync_wall = sync_wall
            cpu_sync = self._cpu()
        frames = self.frames
        send = self._sync_frame.send  # from a local: see UdpPort.receive
        try:
            send()
        except (can.CanError, OSError) as exc:
            self._send_failed(self._sync_frame, exc)
        if self.peer_poll is not None:
            self.peer_poll()
        end = pacer.window_end(sync_wall)
        if self._record_pending:  # the previous row, while the drive answers the SYNC
            self.flush_record()
        if keep:
            cpu_window = self._cpu()
        receive = frames.receive
        tpdos = self._tpdos
        decoders = self.controller.decoders
        busy_poll = self.busy_poll
        full = self._all_slots
        # until all TPDOs are in or the window is over; frames already received when it is
        # over still count (the loop may have been preempted while they were waiting), at
        # most LATE_READ_FRAMES of them (a flood of frames cannot hold the cycle)
        late_reads = LATE_READ_FRAMES
        present = accepted = extra = 0  # in locals while the window is open: fewer bytecodes
        while present != full:
            remaining = end - wall()
            if remaining <= 0.0:
                late_reads -= 1
                if late_reads < 0:
                    break
            try:
                cob_id = receive(remaining if remaining > 0.0 and not busy_poll else 0.0, True)
            except (can.CanError, OSError) as exc:
                self._receive_failed(exc)
                cob_id = NOTHING
            tpdo = tpdos.get(cob_id)  # (bit, length, slot) of a TPDO of the layout
            if tpdo is not None:
                bit, length, slot = tpdo
                if frames.length == length:
                    # _take and _tpdo for a TPDO in its window, without the two calls
                    accepted += 1
                    if present & bit:
                        extra += 1  # an extra frame: the newest one is used
                    present |= bit
                    decoders[slot](frames.buffer, frames.offset)
                    continue
            if cob_id != NOTHING:
                self._present = present
                self._take(cob_id)  # may decode a TPDO (_tpdo)
                present = self._present
            elif remaining <= 0.0:
                break
        self._present = present
        if accepted:
            self.guard.accepted += accepted
            if extra:
                self.counters.late += extra
        self._window_open = False
        inputs_wall = wall()
        if keep:
            cpu_inputs = self._cpu()
            self._waited = min(inputs_wall, end) - sync_wall
        counters = self.counters
        counters.cycles += 1
        if present != full:
            counters.missed_cycles += 1
            counters.missed += (full & ~present).bit_count()
        now_s = pacer.now()
        try:
            self.controller.step_decoded(now_s, present)
        except Exception as exc:  # a bug must not leave the last set point standing
            timing.errors += 1
            log.exception("controller step failed")
            self.controller.stop(StopReason.INTERNAL_ERROR, f"controller step failed: {exc!r}")
        send = self._rpdo_frame.send
        try:
            send()
        except (can.CanError, OSError) as exc:
            self._send_failed(self._rpdo_frame, exc)
        if keep:
            now = wall()
            work = (cpu_window - cpu_sync) + (self._cpu() - cpu_inputs)  # not the TPDO wait
            self._own = work
            timing.record(
                0.0 if due is None else sync_wall - due, now - sync_wall, now - inputs_wall, work
            )
        self._record_pending = self.recorder is not None
        # the heartbeat (1017h): on the wall clock in real time, as between runs (no gap);
        # in lockstep on the simulated time and the wall clock, whichever is due first (a
        # drive watches on SYNC time or on its own clock, bridge.nmt)
        if self._lockstep:
            self.nmt.tick(now_s, wall() if self.wall_heartbeat else None)
        else:
            self.nmt.tick(wall())
        self._k = k + 1

    def run(self, cycles: int | None = None, until: Callable[[Bridge], bool] | None = None) -> int:
        """Run cycles until ``cycles`` are done or ``until(bridge)`` is true (checked after each
        cycle); returns the number of cycles run."""
        if cycles is None and until is None:
            raise BridgeConfigError("run() needs cycles or until")
        n = 0
        gc_control = self.gc_control
        if gc_control is not None:
            gc_control.start()
        if self.pacer.mode is TimeMode.REAL_TIME and self.counters.cycles == 0:
            # what queued up during the start-up (heartbeats, echoes) is handled before the
            # schedule starts, not in the first slot's last microseconds
            self._between_cycles(None)
        try:
            while cycles is None or n < cycles:
                self.run_cycle()
                n += 1
                if self.after_cycle is not None:
                    self.after_cycle(self)
                if until is not None and until(self):
                    break
        finally:
            if gc_control is not None:
                gc_control.stop()
            self.flush_record()
        return n

    def flush_record(self) -> None:
        """Record the row of the last cycle if it is still pending (the loop records a cycle's
        row right after the next SYNC has gone out, while the drive works on it). A recorder
        that fails (disk full, file gone) is logged and dropped; the loop goes on."""
        if self._record_pending and self.recorder is not None:
            try:
                self.recorder.record(self.controller)
            except (OSError, ValueError) as exc:
                self.timing.errors += 1
                log.error("trace recording failed, recording stops: %s", exc)
                self.recorder = None
        self._record_pending = False

    @property
    def cycle_index(self) -> int:
        """Index of the next SYNC."""
        return self._k

    def latencies(self) -> np.ndarray:
        """SYNC-to-set-point latencies (s) collected with ``keep_timing``."""
        return self.timing.latencies_s.copy()

    def close(self) -> None:
        """Flush and close the recording (the bus itself belongs to the caller)."""
        self.flush_record()
        if self.recorder is not None:
            self.recorder.close()
        if self.bus_log is not None:
            self.bus_log.close()

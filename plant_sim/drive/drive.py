"""The simulated CiA 402 servo drive: a CANopen slave that runs a :class:`plant_sim.plant.Plant`.

The plant is the axis physics plus the drive's own loops (PI speed controller, current loop;
the paper's Fig. 1 below the position controller, section V): the compiled kernel's
:class:`~plant_sim.physics.model.AxisPlant` by default, or any FMI 2.0 co-simulation FMU
(:class:`plant_sim.fmu.FmuPlant`, docs/fmu.md). The drive adds what a real
servo drive in cyclic synchronous velocity mode (6060h = 9) adds around it: NMT, heartbeat,
EMCY, the CiA 402 state machine, the PDO exchange on SYNC and its protections.

Per SYNC k (``docs/canopen_layout.md``; lockstep and real time alike):

1. latch: the RPDOs received before SYNC k are written to their objects (controlword ->
   state machine, 60FFh -> speed set point); then the supervision (set point watchdog,
   encoder discrepancy, end of a quick stop / fault reaction ramp) acts;
2. the TPDOs go out with the values sampled now (t_k);
3. the physics runs one position cycle: Operation enabled -> speed loop at 60FFh; Quick stop
   active / Fault reaction active -> speed loop on a ramp to zero; every other state ->
   ``advance_torque(0)`` (power stage off, the axis coasts; a plant that cannot coast, an
   FMU with a speed input only, holds a speed set point of zero instead).

A plant that fails while it steps (an FMU call returning an error) faults the drive like a
device error: EMCY 6100h (internal software) naming the call, Fault, and the plant is not
stepped again until the drive is reset (NMT reset node does not revive it: a new drive does).

So a set point computed from the measurements of SYNC k acts from SYNC k+1 on: the one-cycle
PDO delay of ``KernelOptions(setpoint_delay_cycles=1)``. In ``TimeMode.LOCKSTEP`` SYNC is the
drive's only clock: time is the number of SYNCs times the position cycle, the heartbeat and
the heartbeat consumer follow it. In ``TimeMode.REAL_TIME`` (SYNC from a wall clock elsewhere)
the heartbeat is sent on the wall clock, the consumer watches the master on it
(:attr:`SimulatedDrive.wall`), and a drive served in a loop of its own keeps its own clock:
when SYNC stops, the loop runs position cycles without it (:meth:`SimulatedDrive.free_cycle`,
``plant_sim.drive.process``), so the motor goes on as a real one would, on its last set point,
until a supervision stops it.

The master is supervised as CiA 301/402 say: the heartbeat consumer 1016h:01 watches its
heartbeat, and a lost heartbeat, the master's boot-up, or an NMT command that takes the
enabled drive out of Operational act through 6007h with an EMCY naming the cause.

SDO writes act at once (e.g. a controlword written by SDO changes the state immediately);
only RPDO contents wait for the next SYNC.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from types import TracebackType

import can
import canopen
from canopen.network import NodeScanner

from virtual_bus.contract import (
    CAN_ID_MASK,
    COB_ID_INVALID,
    COB_ID_NO_RTR,
    COMMUNICATION_AREA,
    EMCY_COMMUNICATION,
    EMCY_HEARTBEAT,
    HEARTBEAT_BASE,
    HEARTBEAT_CONSUMER_INDEX,
    HEARTBEAT_LENGTH,
    NMT_COB_ID,
    NMT_LENGTH,
    SDO_LENGTH,
    SdoAbort,
)
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.frame_guard import FrameFault, FrameGuard
from virtual_bus.framing import NOTHING, FramePort, OutFrame, frame_port

from ..physics.model import AxisPlant
from ..plant import Plant
from . import od as O
from .cia402 import State402
from .config import DriveConfig, TimeMode
from .errors import DriveConfigError, DriveInputError, DriveSdoAbort, DriveStateError
from .node import (
    DriveNmt,
    DriveNode,
    FrameCallback,
    GuardedListener,
    NmtCommand,
    NmtState,
    SimulatedHeartbeat,
    WallClockHeartbeat,
    gated,
)
from .pdo import PdoEngine, PdoKind
from .protection import (
    EMCY_PDO_LENGTH,
    EMCY_SYNC_LENGTH,
    ErrorList,
    HeartbeatConsumer,
    connection_lost_data,
    emcy_data_int32,
)
from .servo import ServoAxis

logger = logging.getLogger(__name__)

__all__ = ["DriveConfig", "SimulatedDrive", "TimeMode", "warm_up"]


#: The services whose COB-IDs canopen's NodeScanner notes a node from.
_SCANNED = frozenset(NodeScanner.SERVICES)
# Enum members the per-SYNC code compares with, as module globals: CPython 3.11's EnumType has
# a __getattr__, so reading a member off its class costs ~1,000 instructions, a global ~50
# (callgrind).
_OPERATIONAL = NmtState.OPERATIONAL


#: The NMT command that leads from Operational to each state (the EMCY of a lost connection
#: names it): stop, enter pre-operational, a reset (communication or node).
_NMT_COMMAND_OF = {
    NmtState.STOPPED: NmtCommand.STOP,
    NmtState.PRE_OPERATIONAL: NmtCommand.ENTER_PRE_OPERATIONAL,
    NmtState.INITIALISING: NmtCommand.RESET_COMMUNICATION,
}

#: At most this many frames received before the boot-up are dropped by :meth:`start`
#: (bounded: traffic that goes on cannot hold the boot).
STALE_FRAMES_MAX = 100_000


def warm_up(axis: AxisConfig) -> None:
    """Load (or compile, on an empty numba cache) every compiled function a drive of the
    kernel's plant calls (:meth:`AxisPlant.warm_up`)."""
    AxisPlant(axis).warm_up()


class SimulatedDrive:
    """A CiA 402 servo drive (cyclic synchronous velocity) on a CANopen bus.

    network_or_bus: a connected :class:`canopen.Network` (the drive adds its node to it), or
        a python-can bus (the drive makes a Network and runs its notifier thread; the bus
        stays the caller's and is not shut down).
    node_id: 1..127 (the contract's default is 2).
    axis: the axis the drive is configured from (cycle, k_r, kind, torque limit); plant: the
        :class:`plant_sim.plant.Plant` it runs, configured from that axis (default: a new
        :class:`AxisPlant` of the axis at rest at position 0; an FMU's
        :class:`plant_sim.fmu.FmuPlant`).

    Use :meth:`start` / :meth:`stop` or ``with SimulatedDrive(...) as drive:``.
    """

    def __init__(
        self,
        network_or_bus: canopen.Network | can.BusABC,
        node_id: int,
        axis: AxisConfig,
        config: DriveConfig | None = None,
        plant: Plant | None = None,
    ) -> None:
        if not isinstance(node_id, int) or not 1 <= node_id <= 127:
            raise DriveConfigError(f"node_id = {node_id!r}: allowed 1..127")
        if plant is not None and plant.axis != axis:
            raise DriveConfigError("plant was built for another axis than the one given")
        self.config = config or DriveConfig()
        self.axis = axis
        self.node_id = node_id
        self._lock = threading.RLock()
        if isinstance(network_or_bus, canopen.Network):
            self._network = network_or_bus
            self._own_network = False
        elif isinstance(network_or_bus, can.BusABC):
            self._network = canopen.Network(network_or_bus)
            self._own_network = True
        else:
            raise DriveConfigError(
                f"network_or_bus is a {type(network_or_bus).__name__}; "
                "give a canopen.Network or a can.BusABC"
            )
        self._plant = plant if plant is not None else AxisPlant(axis)
        self._own_heartbeat = HEARTBEAT_BASE + node_id
        self._cycle_us = round(axis.control.position_cycle * 1e6)
        self._callback_errors: list[BaseException] = []
        self._started = False
        self._sync_count = 0
        self._sync_cob_id = 0
        self._rpdo_seen = False
        self._tx_messages: dict[int, can.Message] = {}
        #: the loop's port while a caller's thread receives (receiving_here), its frames
        self.port: FramePort | None = None
        self._tx_frames: dict[int, OutFrame] = {}

        od = O.load_drive_od(self.config.eds_path, node_id)
        self._table = O.ObjectTable(od)
        self._errors = ErrorList(self._send_emcy)
        self._servo = ServoAxis(axis, self._plant, self._table, self._errors, self.config)
        self._nmt = DriveNmt(
            node_id, lock=self._lock, on_reset=self._nmt_reset, on_state=self._nmt_state
        )
        #: every received frame passes it before a handler (docs/drive.md): on a Network the
        #: drive owns at the listener, on a shared one at each of the drive's subscriptions
        self.guard = FrameGuard(f"drive {node_id}", self._classify, remote=self._answer_remote)
        self._gate = None if self._own_network else self.guard.admit
        if self._own_network:
            self._network.listeners[:] = [GuardedListener(self._network, self.guard.check)]
        self._node = DriveNode(node_id, od, nmt=self._nmt, lock=self._lock, gate=self._gate)
        self._node.add_read_callback(self._table.sdo_read)
        self._node.add_write_callback(self._table.sdo_write)
        if self.config.time_mode is TimeMode.LOCKSTEP:
            self._heartbeat: SimulatedHeartbeat | WallClockHeartbeat = SimulatedHeartbeat(
                self._send, node_id
            )
        else:
            self._heartbeat = WallClockHeartbeat(lambda: self._network.bus, node_id)
        self._on_rpdo_frame_cb = self._gated(self._guarded(self._on_rpdo_frame))
        self._pdo = PdoEngine(
            self._table,
            send=self._send,
            subscriber=self._network,
            on_frame=self._on_rpdo_frame_cb,
        )
        self._on_sync_frame_cb = self._gated(self._guarded(self._on_sync_frame))
        for fault in FrameFault:
            self._table.on(
                (O.FRAME_COUNTERS, fault.value),
                read=lambda f=fault: self.guard.count(f) & 0xFFFFFFFF,
            )
        self._table.on(O.SYNC_CYCLES, read=lambda: self._sync_count & 0xFFFFFFFF)
        self._table.on(
            O.COB_ID_SYNC, validate=self._check_sync_cob_id, changed=self._sync_cob_id_changed
        )
        self._table.on(O.HEARTBEAT_TIME, changed=self._heartbeat_time_changed)
        #: the master's heartbeat, watched (1016h:01); its clock: simulated time in lockstep,
        #: :attr:`wall` in real time
        self._consumer = HeartbeatConsumer()
        self._consumer_cob_id = 0
        self._lockstep = self.config.time_mode is TimeMode.LOCKSTEP
        #: the real-time clock of the heartbeat consumer (s; a harness may inject its own)
        self.wall: Callable[[], float] = time.monotonic
        #: position cycles of the drive's own clock, run while no SYNC came (real time)
        self.free_cycles = 0
        self._on_master_heartbeat_cb = self._gated(self._guarded(self._on_master_heartbeat))
        self._table.on(O.HEARTBEAT_CONSUMER, changed=self._consumer_changed)

    # ------------------------------------------------------------------------------------------
    # set-up
    # ------------------------------------------------------------------------------------------
    def _guarded(
        self, callback: Callable[[int, bytearray, float], None]
    ) -> Callable[[int, bytearray, float], None]:
        """Network callback that records exceptions (canopen only logs them); see check()."""

        def run(can_id: int, data: bytearray, timestamp: float) -> None:
            try:
                callback(can_id, data, timestamp)
            except Exception as exc:
                logger.exception("drive %d: callback for 0x%03X failed", self.node_id, can_id)
                self._callback_errors.append(exc)

        return run

    def _answer_remote(self, cob_id: int) -> bool:
        """An RTR on the CAN id of a valid TPDO whose 18xxh:01 bit 30 is 0 (CiA 301: RTR
        allowed), in NMT Operational: the TPDO with its objects' present values (those of the
        last SYNC). Anything else is refused by the frame guard (2105h:05). Only where the
        drive owns its network: canopen's listener drops remote frames before any callback."""
        if self._nmt.state is not NmtState.OPERATIONAL:
            return False
        with self._lock:
            for number in range(1, O.PDO_CHANNELS + 1):
                channel = self._pdo.channel(PdoKind.TRANSMIT, number)
                cob = self._pdo.cob_id(channel)
                if not cob & (COB_ID_INVALID | COB_ID_NO_RTR) and cob & CAN_ID_MASK == cob_id:
                    self._send(cob_id, self._pdo.frame(channel))
                    return True
        return False

    def _gated(self, callback: FrameCallback) -> FrameCallback:
        return callback if self._gate is None else gated(self._gate, callback)

    def _classify(self, cob_id: int, length: int) -> FrameFault | None:
        """The frame guard's rules (CiA 301 lengths, table 46 services per NMT state)."""
        nmt = self._nmt.state
        if cob_id == NMT_COB_ID:
            return None if length == NMT_LENGTH else FrameFault.BAD_LENGTH
        if cob_id == self._sync_cob_id:
            return None  # a SYNC with data > 1 byte: EMCY 8240 in _on_sync_frame, counted there
        if cob_id == self._node.sdo.rx_cobid:
            if length != SDO_LENGTH:
                return FrameFault.BAD_LENGTH
            if nmt in (NmtState.STOPPED, NmtState.INITIALISING):
                return FrameFault.NOT_IN_STATE
            return None
        if cob_id in self._pdo.rpdo_cob_ids():
            # the length against the mapping is checked at the SYNC (EMCY 8210, counted then)
            return None if nmt is NmtState.OPERATIONAL else FrameFault.NOT_IN_STATE
        if HEARTBEAT_BASE < cob_id <= HEARTBEAT_BASE + 0x7F and cob_id != self._own_heartbeat:
            # NMT error control of any other node is broadcast traffic a heartbeat consumer
            # listens to (1016h names the one it watches), not a frame it does not know
            return None if length == HEARTBEAT_LENGTH else FrameFault.BAD_LENGTH
        return FrameFault.UNKNOWN_COB_ID

    # ------------------------------------------------------------------------------------------
    # lifecycle
    # ------------------------------------------------------------------------------------------
    def start(self) -> SimulatedDrive:
        """Join the bus, finish initialisation (CiA 402 transition 1), send the boot-up
        message and enter NMT Pre-operational with the heartbeat running.

        Like a real drive, it finishes booting before it announces itself: the plant loads
        what its first step needs first (:meth:`plant_sim.plant.Plant.warm_up`: the compiled
        kernel's functions from the numba cache, or compiled on a fresh checkout, seconds), so
        neither the first SYNC nor an SDO request waiting behind it is held up by it."""
        self._plant.warm_up()
        with self._lock:
            if self._started:
                raise DriveStateError(f"drive {self.node_id} is already started")
            if self.node_id in self._network:
                raise DriveStateError(f"node {self.node_id} is already on this network")
            if not self._own_network and self._network.bus is None:
                raise DriveStateError("the canopen Network is not connected (no bus)")
            self._network[self.node_id] = self._node
            self._subscribe_sync()
            self._pdo.refresh_subscriptions()
            self._started = True
            self._servo.initialised()
        if self._own_network:
            bus = self._network.bus
            assert bus is not None
            # What came while it booted was sent to no node: a drive joins the bus with its
            # boot-up message. Answered late, a master's earlier requests (1000h asked while
            # the physics compiled) reached it as answers to its later ones.
            with contextlib.suppress(can.CanError, OSError):  # a bad one ends it: no matter
                for _ in range(STALE_FRAMES_MAX):
                    if bus.recv(0.0) is None:
                        break
            self._network.notifier = can.Notifier(
                bus, self._network.listeners, self.config.notifier_timeout_s
            )
        self._nmt.boot()
        return self

    @contextlib.contextmanager
    def receiving_here(self) -> Iterator[Callable[[can.Message], None]]:
        """Receive in the caller's thread instead of the notifier thread.

        Pauses the drive's own notifier and yields ``handle(msg)``, which hands one frame the
        caller received from the drive's end of the bus to the same canopen listeners the
        notifier would (frame guard first). Only for a drive that owns its network (built on
        a bus); the notifier restarts on exit. The one-thread loop of a drive process
        (:func:`plant_sim.drive.process.serve`) and :meth:`polled` are built on it.
        """
        if not self._own_network or not self._started:
            raise DriveStateError("receiving_here() needs a started drive built on its own bus")
        network = self._network
        bus = network.bus
        assert bus is not None
        if network.notifier is not None:
            network.notifier.stop(timeout=5.0)
            network.notifier = None
        listeners = tuple(network.listeners)

        def handle(msg: can.Message) -> None:
            for listener in listeners:
                listener.on_message_received(msg)

        # no kernel timestamp per frame (recvmsg: ~6,000 instructions each): the loop that
        # dates its SYNC from it polls around the SYNC (--busy-poll) and reads it at once
        self.port = port = frame_port(bus)
        self._tx_frames.clear()
        self._pdo.use_frames(port.frame, port.send)
        try:
            yield handle
        finally:
            self._pdo.use_frames(None)
            self.port = None
            self._tx_frames.clear()
            if self._started:
                network.notifier = can.Notifier(
                    bus, network.listeners, self.config.notifier_timeout_s
                )

    @contextlib.contextmanager
    def polled(self) -> Iterator[Callable[[], int]]:
        """Lockstep harnesses: receive in the caller's thread instead of the notifier thread.

        Pauses the drive's own notifier (:meth:`receiving_here`) and yields ``poll()``, which
        hands every frame waiting on the drive's end of the bus to the same canopen listeners
        the notifier would and returns how many it handled. Frames still travel over the bus;
        only the thread that receives them changes, which removes two thread wake-ups per
        cycle (~80 µs each on a small VM). Only for a drive that owns its network (built on a
        bus); the notifier restarts on exit.
        """
        with self.receiving_here() as handle:
            port = self.port
            assert port is not None
            take = self.take

            def poll() -> int:
                n = 0
                while (cob_id := port.receive(0.0)) != NOTHING:
                    take(cob_id, port, handle)
                    n += 1
                return n

            yield poll

    def take(self, cob_id: int, port: FramePort, handle: Callable[[can.Message], None]) -> bool:
        """One frame the caller's thread received on the drive's end of the bus (``port``,
        :meth:`receiving_here`; ``cob_id``: what its ``receive`` returned): a SYNC or an RPDO
        goes straight to the drive's handler, as the frame guard and canopen's dispatch would
        hand it over (counted as the guard counts) when nothing but the drive listens to it;
        anything else as a message to ``handle``. True when a SYNC cycle ran."""
        if cob_id >= 0:
            network = self._network
            subscribers = network.subscribers.get(cob_id)
            if subscribers is not None and len(subscribers) == 1 and len(network.listeners) == 1:
                callback = subscribers[0]
                if callback is self._on_sync_frame_cb:
                    if port.length <= 1:
                        self.guard.accepted += 1
                        self._sync_direct(cob_id)
                        return True
                elif callback is self._on_rpdo_frame_cb and self._rpdo_direct(cob_id, port):
                    return False
        syncs = self._sync_count
        handle(port.message())
        return self._sync_count != syncs

    def _sync_direct(self, cob_id: int) -> None:
        """A SYNC of 0 or 1 byte, admitted: what its callback does (and its wrapper)."""
        try:
            with self._lock:
                if self._errors.codes:
                    self._errors.clear(EMCY_SYNC_LENGTH)
                self._sync()
        except Exception as exc:  # as the callback's wrapper: kept for check()
            logger.exception("drive %d: callback for 0x%03X failed", self.node_id, cob_id)
            self._callback_errors.append(exc)

    def _rpdo_direct(self, cob_id: int, port: FramePort) -> bool:
        """An RPDO in NMT Operational: kept for the next SYNC; False (nothing done) where
        the guard refuses it or the network's scanner would note its node."""
        if self._nmt.state is not _OPERATIONAL:
            return False
        node = cob_id & 0x7F
        if (cob_id & 0x780) in _SCANNED and node and node not in self._network.scanner.nodes:
            return False
        self.guard.accepted += 1
        offset = port.offset
        with self._lock:
            self._pdo.receive(cob_id, memoryview(port.buffer)[offset : offset + port.length])
        return True

    def stop(self) -> None:
        """Leave the bus: heartbeat, subscriptions and (own) notifier thread stop. The bus
        itself is not shut down. Idempotent."""
        if not self._started:
            return
        if self._own_network and self._network.notifier is not None:
            self._network.notifier.stop(timeout=5.0)
            self._network.notifier = None
        with self._lock:
            self._heartbeat.stop()
            self._unsubscribe_sync()
            self._pdo.unsubscribe_all()
            if self._consumer_cob_id:
                self._network.unsubscribe(self._consumer_cob_id, self._on_master_heartbeat_cb)
                self._consumer_cob_id = 0
            del self._network[self.node_id]
            self._started = False

    def __enter__(self) -> SimulatedDrive:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def check(self) -> None:
        """Raise the first exception a bus callback of the drive hit (canopen only logs)."""
        if self._callback_errors:
            raise self._callback_errors[0]

    # ------------------------------------------------------------------------------------------
    # harness API
    # ------------------------------------------------------------------------------------------
    @property
    def plant(self) -> Plant:
        """The simulated axis (read it; stepping it behind the drive's back breaks lockstep)."""
        return self._plant

    @property
    def node(self) -> DriveNode:
        return self._node

    @property
    def network(self) -> canopen.Network:
        return self._network

    @property
    def state(self) -> State402:
        with self._lock:
            return self._servo.state

    @property
    def nmt_state(self) -> NmtState:
        with self._lock:
            return self._nmt.state

    @property
    def statusword(self) -> int:
        with self._lock:
            return self._servo.statusword()

    @property
    def error_code(self) -> int:
        with self._lock:
            return self._errors.error_code

    @property
    def error_register(self) -> int:
        with self._lock:
            return self._errors.register

    @property
    def active_errors(self) -> tuple[int, ...]:
        with self._lock:
            return self._errors.active

    @property
    def sync_count(self) -> int:
        """SYNCs (position cycles) run since the drive was built; reading it waits for a
        SYNC cycle in progress to finish."""
        with self._lock:
            return self._sync_count

    @property
    def time_s(self) -> float:
        with self._lock:
            return self._plant.time_s

    @property
    def disturbance_nm(self) -> float:
        with self._lock:
            return self._table.value(O.DISTURBANCE) / 1000.0

    @property
    def torque_limit_nm(self) -> float:
        """The torque limit in force: min(axis file limit, 6072h · 6076h)."""
        with self._lock:
            return self._servo.torque_limit_nm

    def set_disturbance_nm(self, torque_nm: float) -> None:
        """External load disturbance (N·m at the motor, positive pushes the load towards +x;
        the paper's section X step). Held in 2100h as mN·m (rounded), from the next cycle."""
        if not math.isfinite(torque_nm):
            raise DriveInputError(f"disturbance {torque_nm} N·m: must be finite")
        value = round(torque_nm * 1000)
        if not O.INT32_MIN <= value <= O.INT32_MAX:
            raise DriveInputError(
                f"disturbance {torque_nm} N·m: allowed ±{O.INT32_MAX / 1000:.0f} N·m (2100h)"
            )
        with self._lock:
            self._table.write(O.DISTURBANCE, value)

    def read_object(self, index: int, subindex: int = 0) -> int:
        """Current value of an integer object, as an SDO upload would give it."""
        with self._lock:
            return self._table.read((index, subindex))

    def write_object(self, index: int, subindex: int, value: int) -> None:
        """Write an integer object with the SDO rules (raises DriveSdoAbort)."""
        with self._lock:
            key = (index, subindex)
            if key not in self._table or not self._table.variable(key).writable:
                raise DriveSdoAbort(SdoAbort.READ_ONLY, "object is not writable", key=key)
            self._table.write(key, value)

    # ------------------------------------------------------------------------------------------
    # SYNC cycle
    # ------------------------------------------------------------------------------------------
    def on_sync(self) -> None:
        """One SYNC: latch RPDOs, supervise, send TPDOs, run the physics one position cycle
        (what the drive does on a SYNC frame; callable directly in unit tests)."""
        with self._lock:
            self._sync()

    def _sync(self) -> None:
        """:meth:`on_sync` with the lock held."""
        operational = self._nmt.state is _OPERATIONAL
        self._rpdo_seen = False
        if operational and (applied := self._pdo.latch_quiet(self._unchanged)) is not None:
            if applied:  # the set point a master repeats every SYNC: stored, no hook
                self._rpdo_arrived()
        elif operational:
            result = self._pdo.latch(before_apply=self._rpdo_arrived)
            if result.short_frames:
                self._errors.set(EMCY_PDO_LENGTH, emcy_data_int32(result.short_frames[0]))
                for can_id in result.short_frames:
                    self.guard.refuse(FrameFault.BAD_LENGTH, can_id, -1)
        servo = self._servo
        servo.hold_measurements()  # read after the last step (the first SYNC: now)
        servo.supervise(self._rpdo_seen)
        if operational:
            self._pdo.transmit()
        servo.advance()
        self._sync_count += 1
        self._heartbeat.tick(self._sync_count * self._cycle_us)
        if self._consumer.last_us is not None:  # watching the master
            self._check_master(self._now_us())

    # ------------------------------------------------------------------------------------------
    # the drive's own clock and its master (real time)
    # ------------------------------------------------------------------------------------------
    def free_cycle(self) -> bool:
        """One position cycle of the drive's own clock, where no SYNC came (real time; the
        serving loop calls it, ``plant_sim.drive.process``): the last set point held, the
        encoder monitor and the ramps supervised, the physics stepped -- no PDOs (they go on
        SYNC), the set point watchdog untouched (it counts SYNCs), 2103h unchanged. True when
        the axis moved (a measuring system changed)."""
        with self._lock:
            servo = self._servo
            servo.hold_measurements()
            before = (self._table.read(O.POSITION_ACTUAL), self._table.read(O.LOAD_POSITION_ACTUAL))
            servo.supervise_without_sync()
            servo.advance()
            self.free_cycles += 1
            after = (self._table.read(O.POSITION_ACTUAL), self._table.read(O.LOAD_POSITION_ACTUAL))
            return after != before

    @property
    def holding(self) -> bool:
        """The power stage holds the axis, or a disturbance acts on it: its physics must go
        on between SYNCs (power off and at rest, nothing changes)."""
        with self._lock:
            return self._servo.holding

    def watch_master(self, now_s: float) -> float | None:
        """Real time: check the master's heartbeat at the wall instant ``now_s``
        (:attr:`wall`'s clock); returns when the watch runs out next (None: not watching)."""
        with self._lock:
            consumer = self._consumer
            if consumer.last_us is None:
                return None
            self._check_master(round(now_s * 1e6))
            deadline = consumer.deadline_us()
            return None if deadline is None else deadline / 1e6

    def _now_us(self) -> int:
        """The drive's clock in µs: simulated time (lockstep) or :attr:`wall`."""
        if self._lockstep:
            return self._sync_count * self._cycle_us
        return round(self.wall() * 1e6)

    def _check_master(self, now_us: int) -> None:
        consumer = self._consumer
        last = consumer.last_us
        if consumer.check(now_us):
            assert last is not None
            self._master_lost(
                extra=0,
                why=f"did not come: {(now_us - last) / 1000:g} ms after the last one on the "
                f"drive's clock (consumer time {consumer.time_us / 1000:g} ms)",
            )

    def _master_lost(self, extra: int, why: str) -> None:
        """The master's heartbeat ran out (``extra`` 0) or it booted (1): EMCY 8130h and the
        6007h reaction (lock held)."""
        option = self._table.value(O.ABORT_CONNECTION_OPTION)
        data = connection_lost_data(HEARTBEAT_CONSUMER_INDEX, self._consumer.node_id, option, extra)
        logger.warning(
            "drive %d: the heartbeat of master %d %s; EMCY 8130h, 6007h = %d in %s",
            self.node_id,
            self._consumer.node_id,
            why,
            option,
            self._servo.state.value,
        )
        self._servo.abort_connection(EMCY_HEARTBEAT, data)

    def _on_master_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self._consumer.received(data[0], self._now_us()):
                self._master_lost(extra=1, why="announced its boot-up: it restarted")
            elif data[0]:
                self._servo.connection_restored(EMCY_HEARTBEAT)

    def _consumer_changed(self, entry: int) -> None:
        """1016h:01 written: watch that node (a new watch; an old heartbeat error clears)."""
        consumer = self._consumer
        consumer.configure(entry)
        if self._consumer_cob_id:
            self._network.unsubscribe(self._consumer_cob_id, self._on_master_heartbeat_cb)
            self._consumer_cob_id = 0
        if consumer.node_id:
            self._consumer_cob_id = HEARTBEAT_BASE + consumer.node_id
            self._network.subscribe(self._consumer_cob_id, self._on_master_heartbeat_cb)
        self._servo.connection_restored(EMCY_HEARTBEAT)

    def _unchanged(self, key: O.ObjectKey, value: int) -> bool:
        """Whether writing ``value`` to ``key`` would do nothing beyond storing it: the
        controlword the CiA 402 machine already has, with no transition
        (:meth:`ServoAxis.controlword_unchanged`)."""
        return key == O.CONTROLWORD and self._servo.controlword_unchanged(value)

    def _rpdo_arrived(self) -> None:
        self._rpdo_seen = True
        self._servo.rpdo_arrived()

    # ------------------------------------------------------------------------------------------
    # bus glue
    # ------------------------------------------------------------------------------------------
    def _check_sync_cob_id(self, value: int) -> None:
        if value & 0x7FFFF800:
            raise DriveSdoAbort(
                SdoAbort.VALUE_RANGE,
                f"COB-ID SYNC 0x{value:08X}: the drive only consumes SYNC (bit 30 = 0) on an "
                "11-bit CAN id (bits 11..29 = 0)",
                key=O.COB_ID_SYNC,
            )
        if value & 0x7FF == 0:
            raise DriveSdoAbort(
                SdoAbort.VALUE_RANGE, "COB-ID SYNC: CAN id 0 is the NMT service", key=O.COB_ID_SYNC
            )

    def _send(self, can_id: int, data: bytes) -> None:
        """Send one frame the drive produces (TPDOs, a SYNC-time heartbeat): canopen's
        ``Network.send_message`` (same lock, same check of the notifier), with one
        :class:`can.Message` per COB-ID built once and rewritten, not one per frame."""
        port = self.port
        if port is not None:  # the loop's own frames, rewritten in place
            frame = self._tx_frames.get(can_id)
            if frame is None or frame.length != len(data):
                frame = self._tx_frames[can_id] = port.frame(can_id, len(data))
            offset = frame.offset
            frame.buffer[offset : offset + frame.length] = data
            port.send(frame)
            return
        network = self._network
        bus = network.bus
        if bus is None:
            raise DriveStateError(f"drive {self.node_id}: not connected to a CAN bus")
        with network.send_lock:
            msg = self._tx_messages.get(can_id)
            if msg is None:
                msg = can.Message(arbitration_id=can_id, is_extended_id=can_id > 0x7FF, data=data)
                self._tx_messages[can_id] = msg
            else:
                msg.data[:] = data
                msg.dlc = len(data)
            bus.send(msg)
        network.check()

    def _send_emcy(self, code: int, register: int, data: bytes) -> None:
        if self._started and self._nmt.state in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL):
            self._node.emcy.send(code, register, data)

    def _subscribe_sync(self) -> None:
        self._sync_cob_id = self._table.value(O.COB_ID_SYNC) & 0x7FF
        self._network.subscribe(self._sync_cob_id, self._on_sync_frame_cb)

    def _unsubscribe_sync(self) -> None:
        self._network.unsubscribe(self._sync_cob_id, self._on_sync_frame_cb)

    def _sync_cob_id_changed(self, _value: int) -> None:
        if self._started:
            self._unsubscribe_sync()
            self._subscribe_sync()

    def _heartbeat_time_changed(self, period_ms: int) -> None:
        if self._started and self._nmt.state is not NmtState.INITIALISING:
            now_us = self._sync_count * self._cycle_us
            self._heartbeat.start(period_ms, self._nmt.state, now_us)

    def _on_sync_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if len(data) > 1:  # CiA 301: SYNC carries no data or the 1-byte counter
                self.guard.refuse(FrameFault.BAD_LENGTH, can_id, len(data))
                self._errors.set(EMCY_SYNC_LENGTH, emcy_data_int32(len(data)))
                return
            self._errors.clear(EMCY_SYNC_LENGTH)
            self.on_sync()

    def _on_rpdo_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self._nmt.state is _OPERATIONAL:
                self._pdo.receive(can_id, bytes(data))

    def _nmt_state(self, old: NmtState, new: NmtState) -> None:
        if old is NmtState.OPERATIONAL:
            # CiA 402 6007h: NMT Stopped entered, reset communication (and Pre-operational: no
            # set points any more) while enabled is a lost connection
            if self._servo.state is State402.OPERATION_ENABLED:
                option = self._table.value(O.ABORT_CONNECTION_OPTION)
                data = connection_lost_data(0, _NMT_COMMAND_OF.get(new, 0), option)
                self._servo.abort_connection(EMCY_COMMUNICATION, data)
        elif new is NmtState.OPERATIONAL:
            self._servo.connection_restored(EMCY_COMMUNICATION)
        if new is NmtState.INITIALISING:
            self._heartbeat.stop()
        elif old is NmtState.INITIALISING:
            now_us = self._sync_count * self._cycle_us
            self._heartbeat.start(self._table.value(O.HEARTBEAT_TIME), new, now_us)
        else:
            self._heartbeat.set_state(new)
        if old is NmtState.OPERATIONAL:
            self._pdo.clear_pending()

    def _nmt_reset(self, command: NmtCommand) -> None:
        """NMT reset node: application (2000h-9FFFh but the 2100h simulation input) and
        communication parameters to their defaults, errors forgotten, CiA 402 transitions
        0 and 1; reset communication: 1000h-1FFFh only."""
        if command is NmtCommand.RESET_NODE:
            self._table.restore_defaults(0x2000, 0x9FFF, keep=(O.DISTURBANCE,))
            self._servo.reset_application()
        self._table.restore_defaults(COMMUNICATION_AREA.start, COMMUNICATION_AREA.stop - 1)
        if self._started:
            self._unsubscribe_sync()
            self._subscribe_sync()
            self._pdo.reset()
            self._consumer_changed(self._table.value(O.HEARTBEAT_CONSUMER))  # 1016h: default

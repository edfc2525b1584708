"""Start-up: read the drive, adapt to it, configure it over SDO (blocking, off the cycle).

Sequence (docs/canopen_layout.md, CiA 301 PDO configuration procedure, CiA 402):

1. NMT "enter pre-operational" to the drive;
2. reads only: 1000h, 1018h, 6502h, the PDO parameters (COB-IDs, transmission types, number
   of mapping entries of 1800h-1803h/1A00h-1A03h, 1400h-1403h) and the candidate objects of
   :data:`bridge.adapt.CANDIDATES` (60E4h, 608Fh, 6091h, 6092h, factor groups, 6076h, ...);
3. :func:`bridge.adapt.plan` builds layout, mode and scaling from those facts and the drive
   profile -- a missing object fails here, before anything is written;
4. each PDO of the plan: COB-ID invalid (bit 31), transmission type, mapping count 0,
   entries, count, COB-ID valid; a mapping entry the drive refuses as not mappable
   (0604 0041 / 0604 0042) is left out and the layout planned again; the drive's other PDOs
   are switched off (objects the drive lacks are skipped);
5. 6060h = 9 (cyclic synchronous velocity) or 3 (profile velocity, with 6083h/6084h opened),
   checked in 6061h; 1017h producer heartbeat time; the drive's supervision of the bridge
   (:mod:`bridge.supervision`: 1016h heartbeat consumer, 6007h, a set-point watchdog), each
   object's value read first, to be written back at the end (:meth:`DriveMaster.restore`);
6. a CiA 406 encoder node supplying the load position: its TPDO1 = 6004h on every SYNC,
   its heartbeat; NMT start of encoder and drive;
7. CiA 402 state machine to Operation Enabled through 6040h/6041h (paths of
   ``canopen.profiles.p402.State402``), after a fault reset if the drive is in Fault.

Every step names the object that failed (:class:`~bridge.errors.DriveSetupError`, with the
drive's abort code) or timed out (:class:`~bridge.errors.DriveTimeoutError`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import canopen
from canopen.nmt import NmtError
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from virtual_bus.contract import (
    COB_ID_INVALID,
    Cia301,
    Cia402,
    Cia406,
    NmtCommand,
    pdo_cob_id,
    pdo_comm_index,
    pdo_mapping_index,
    tpdo_cob_id,
)
from virtual_bus.formats.axis import AxisKind
from virtual_bus.formats.drive_profile import DriveProfile, ObjectKey

from .adapt import (
    CANDIDATES,
    ENCODER_POSITION,
    DriveFacts,
    Item,
    PdoFacts,
    PdoPlan,
    Plan,
    VelocityMode,
    plan,
)
from .cycle import Drive402State, drive_state, enable_controlword
from .errors import BridgeConfigError, DriveSetupError, DriveTimeoutError, SdoAbort
from .layout import CycleLayout, Signal, check_node_id
from .scaling import LOAD_INCREMENTS_PER_UNIT, Scaling
from .supervision import SUPERVISION_OBJECTS, Supervision, plan_supervision

log = logging.getLogger("bridge")

_U8 = struct.Struct("<B")
_I8 = struct.Struct("<b")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class DriveSetup:
    """How to configure the drive.

    heartbeat_producer_ms: 1017h of the drive, ms (1..65535), below the bridge's consumer
    time. sdo_timeout_s / sdo_retries: per SDO request. state_timeout_s: wall time for each
    CiA 402 transition. disable_other_pdos: switch off the drive's PDOs outside the layout.
    wait_for_drive: before anything else wait for the drive itself, with no time limit
    (:meth:`DriveMaster.await_drive`; lockstep, where a simulated drive may still be
    compiling its physics when the bridge starts).
    """

    heartbeat_producer_ms: int = 100
    sdo_timeout_s: float = 0.3
    sdo_retries: int = 3
    state_timeout_s: float = 2.0
    disable_other_pdos: bool = True
    wait_for_drive: bool = False

    def __post_init__(self) -> None:
        hb = self.heartbeat_producer_ms
        if isinstance(hb, bool) or not isinstance(hb, int) or not 1 <= hb <= 65535:
            raise BridgeConfigError(f"heartbeat_producer_ms = {hb!r}: must be an integer 1..65535")
        for name in ("sdo_timeout_s", "state_timeout_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and 0 < value <= 60):
                raise BridgeConfigError(f"{name} = {value!r}: must be in (0, 60] s")
        if not isinstance(self.sdo_retries, int) or not 1 <= self.sdo_retries <= 10:
            raise BridgeConfigError(f"sdo_retries = {self.sdo_retries!r}: must be 1..10")


#: While the start-up waits for a drive that does not answer yet, how long each wait for its
#: boot-up message lasts before 1000h is asked again (s; not a limit: the wait goes on).
AWAIT_DRIVE_POLL_S = 1.0


@dataclass(frozen=True)
class DriveInfo:
    """What start-up learned: rated torque (6076h, N·m; None: 0 or absent, torque shown in
    per mille), statusword and mode at the end, and the plan the cycle runs with."""

    rated_torque_nm: float | None
    statusword: int
    mode_display: int
    sdo_transfers: int
    layout: CycleLayout
    scaling: Scaling
    encoder_id: int | None = None
    notes: tuple[str, ...] = ()
    #: the drive's supervision of the bridge as configured, and the values it replaced
    supervision: Supervision | None = None
    restore: tuple[tuple[ObjectKey, bytes], ...] = ()


#: SDO abort codes that mean "this object / sub-index is not there".
_ABSENT = (SdoAbort.NO_OBJECT, SdoAbort.NO_SUBINDEX)
#: 060A 0023 resource not available: the object exists but has no value to give.
_NO_DATA = 0x060A_0023
#: Answers to a mapping entry that mean "not this object": 0604 0041 object cannot be mapped,
#: 0604 0042 mapping exceeds the PDO length, 0602 0000 object does not exist.
_NOT_MAPPABLE = (0x0604_0041, 0x0604_0042, SdoAbort.NO_OBJECT)


class UnmappableError(DriveSetupError):
    """The drive refused a mapping entry (:data:`_NOT_MAPPABLE`); the start-up plans again
    without that object."""


class DriveMaster:
    """SDO client side of the start-up for one drive (a canopen RemoteNode on the network).

    Someone must feed received frames to the network meanwhile (the bridge's service thread).
    ``sleep`` is injected for the polling of the state machine.
    """

    def __init__(
        self,
        drive: canopen.RemoteNode,
        setup: DriveSetup = DriveSetup(),
        sleep: Callable[[float], None] = time.sleep,
        wall: Callable[[], float] = time.monotonic,
        *,
        profile: DriveProfile | None = None,
        load_increments_per_unit: float = LOAD_INCREMENTS_PER_UNIT[AxisKind.LINEAR],
        bridge_id: int | None = None,
        heartbeat_ms: int = 0,
        heartbeat_now: Callable[[], None] | None = None,
    ) -> None:
        self.drive = drive
        #: the bridge's node-ID and heartbeat period (1017h): the drive is set to watch them
        #: (None: no supervision planned, e.g. an encoder node)
        self.bridge_id = bridge_id
        self.heartbeat_ms = heartbeat_ms
        #: sends the bridge's heartbeat at once: the drive's consumer starts watching with it
        self.heartbeat_now = heartbeat_now
        self.supervision: Supervision | None = None
        #: (object, value before the start-up wrote it) of the supervision objects
        self.restored: tuple[tuple[ObjectKey, bytes], ...] = ()
        self.setup = setup
        self.profile = profile or DriveProfile()
        self.load_increments_per_unit = load_increments_per_unit
        self._unmappable: set[tuple[int, int]] = set()
        self._sleep = sleep
        self._wall = wall
        drive.sdo.RESPONSE_TIMEOUT = setup.sdo_timeout_s
        drive.sdo.MAX_RETRIES = setup.sdo_retries
        self.transfers = 0

    # --- SDO with context ---------------------------------------------------------------------
    def _what(self, index: int, subindex: int) -> str:
        return f"drive {self.drive.id} object {index:04X}h:{subindex:02X}"

    @contextlib.contextmanager
    def _sdo(self, verb: str, index: int, subindex: int, what: str) -> Iterator[None]:
        """Count one transfer; turn canopen's SDO errors into the bridge's, with context."""
        self.transfers += 1
        where = f"{self._what(index, subindex)}{what}"
        try:
            yield
        except SdoAbortedError as exc:
            raise DriveSetupError(
                f"{where}: {verb} refused, SDO abort {exc}",
                index=index,
                subindex=subindex,
                abort_code=exc.code,
            ) from None
        except SdoCommunicationError as exc:
            raise DriveTimeoutError(
                f"{where}: no SDO answer ({exc}) after {self.setup.sdo_retries} tries of "
                f"{self.setup.sdo_timeout_s:g} s",
                index=index,
                subindex=subindex,
            ) from None

    def write(self, index: int, subindex: int, data: bytes, what: str = "") -> None:
        with self._sdo("write", index, subindex, what):
            self.drive.sdo.download(index, subindex, data)

    def read(self, index: int, subindex: int, what: str = "") -> bytes:
        data = b""
        with self._sdo("read", index, subindex, what):
            data = self.drive.sdo.upload(index, subindex)
        return data

    def try_read(self, index: int, subindex: int, what: str = "") -> bytes | None:
        """Read, or None when the drive has no such object/sub-index (b"" when it exists but
        has no value to give, 060A 0023)."""
        try:
            return self.read(index, subindex, what)
        except DriveSetupError as exc:
            if exc.abort_code in _ABSENT:
                return None
            if exc.abort_code in (_NO_DATA, SdoAbort.WRITE_ONLY):
                return b""  # there, but nothing to read
            raise

    # --- reading the drive ------------------------------------------------------------------
    def _u32(self, index: int, subindex: int) -> int | None:
        raw = self.try_read(index, subindex)
        return int.from_bytes(raw[:4], "little") if raw and len(raw) >= 4 else None

    def _pdo_facts(self, transmit: bool) -> tuple[PdoFacts, ...]:
        found = []
        for n in range(1, 5):
            comm, mapping = pdo_comm_index(transmit, n), pdo_mapping_index(transmit, n)
            cob = self._u32(comm, 1)
            if cob is None:
                continue
            tt_raw = self.try_read(comm, 2)
            entries = 0
            for sub in (8, 4, 3, 2, 1):  # highest mapping entry the record has
                if self.try_read(mapping, sub) is not None:
                    entries = sub
                    break
            found.append(PdoFacts(n, cob, tt_raw[0] if tt_raw else None, entries))
        return tuple(found)

    def await_drive(self) -> None:
        """Wait on the drive, not on the clock (``DriveSetup.wait_for_drive``): a drive that
        answers 1000h (or refuses it) is there; until it does, its boot-up message (any
        frame of its NMT error control, 700h + node-ID) is awaited and 1000h asked again,
        with no time limit (Ctrl-C ends it). A simulated drive compiles its physics before
        it sends its boot-up message: on an empty numba cache and a busy machine that takes
        longer than any SDO timeout, and a bridge started beside it must not give up."""
        said = False
        while True:
            try:
                self.read(Cia301.DEVICE_TYPE, 0, " (device type)")
                return
            except DriveTimeoutError:
                pass
            except DriveSetupError:
                return  # refused: the drive is there
            if not said:
                log.warning(
                    "drive %d does not answer yet: waiting for its boot-up message (the "
                    "lockstep start-up waits on the drive, not the clock; Ctrl-C stops)",
                    self.drive.id,
                )
                said = True
            with contextlib.suppress(NmtError):
                self.drive.nmt.wait_for_heartbeat(timeout=AWAIT_DRIVE_POLL_S)

    def read_facts(self) -> DriveFacts:
        """Step 2 of the module docstring: reads only, nothing is written."""
        device_type = self._u32(
            Cia301.DEVICE_TYPE, 0
        )  # first: a node that is not there times out here
        vendor_id, product_code = self._u32(Cia301.IDENTITY, 1), self._u32(Cia301.IDENTITY, 2)
        objects: dict[tuple[int, int], bytes] = {}
        keys = [*CANDIDATES, *SUPERVISION_OBJECTS]
        for extra in (self.profile.load_object, self.profile.setpoint_timeout_object):
            if extra is not None:
                keys.append(extra)
        for key in keys:
            raw = self.try_read(*key)
            if raw is not None:
                objects[key] = raw
        modes_raw = self.try_read(Cia402.SUPPORTED_DRIVE_MODES, 0, " (supported drive modes)")
        entries = self.profile.heartbeat_consumer_entries
        if entries is None:
            raw_count = objects.get(SUPERVISION_OBJECTS[0])
            entries = raw_count[0] if raw_count else 0
        for sub in range(1, min(entries, 127) + 1):  # the 1016h entries: which one is free
            raw = self.try_read(SUPERVISION_OBJECTS[0][0], sub, " (consumer heartbeat time)")
            if raw is not None:
                objects[(SUPERVISION_OBJECTS[0][0], sub)] = raw
        return DriveFacts(
            device_type=device_type,
            vendor_id=vendor_id,
            product_code=product_code,
            supported_modes=int.from_bytes(modes_raw[:4], "little") if modes_raw else None,
            objects=objects,
            tpdos=self._pdo_facts(True),
            rpdos=self._pdo_facts(False),
        )

    # --- steps ----------------------------------------------------------------------------
    def configure_pdo(self, spec: PdoPlan) -> None:
        """CiA 301 PDO (re)configuration of one PDO of the plan. A mapping entry the drive
        refuses as not mappable is remembered (:attr:`unmappable`) and re-raised."""
        cob = spec.cob_id
        name = f" ({spec.name})"
        self.write(spec.comm_index, 1, _U32.pack(COB_ID_INVALID | cob), name)
        self.write(spec.comm_index, 2, _U8.pack(spec.transmission_type), name)
        self.write(spec.mapping_index, 0, _U8.pack(0), name)
        for i, mapped in enumerate(spec.mapping, start=1):
            try:
                self.write(spec.mapping_index, i, _U32.pack(mapped.entry), name)
            except DriveSetupError as exc:
                if exc.abort_code not in _NOT_MAPPABLE:
                    raise
                self._unmappable.add((mapped.index, mapped.subindex))
                raise UnmappableError(
                    f"{exc} ({mapped.index:04X}h:{mapped.subindex:02X} not mappable)",
                    index=exc.index,
                    subindex=exc.subindex,
                    abort_code=exc.abort_code,
                ) from None
        self.write(spec.mapping_index, 0, _U8.pack(len(spec.mapping)), name)
        self.write(spec.comm_index, 1, _U32.pack(cob), name)

    @property
    def unmappable(self) -> frozenset[tuple[int, int]]:
        """Objects the drive refused to map during this start-up."""
        return frozenset(self._unmappable)

    def disable_pdo(self, transmit: bool, number: int) -> None:
        """Mark a PDO outside the layout invalid; a drive without it is fine."""
        index = pdo_comm_index(transmit, number)
        cob = pdo_cob_id(transmit, number, self.drive.id)
        current = self._u32(index, 1)
        if current is None:
            return
        if current & COB_ID_INVALID:
            return  # already off
        try:
            self.write(index, 1, _U32.pack(COB_ID_INVALID | (current & 0x7FF or cob)))
        except DriveSetupError as exc:
            if exc.abort_code not in (SdoAbort.NO_OBJECT, SdoAbort.NO_SUBINDEX):
                raise

    def set_mode(self, mode: VelocityMode) -> int:
        """6060h = ``mode``, waiting for 6061h to show it."""
        self.write(Cia402.MODES_OF_OPERATION, 0, _I8.pack(mode), " (modes of operation)")
        deadline = self._wall() + self.setup.state_timeout_s
        while True:
            shown = _I8.unpack(
                self.read(Cia402.MODES_OF_OPERATION_DISPLAY, 0, " (modes of operation display)")[:1]
            )[0]
            if shown == mode:
                return shown
            if self._wall() > deadline:
                raise DriveTimeoutError(
                    f"drive {self.drive.id}: 6061h shows mode {shown}, not {int(mode)} "
                    f"({mode.name}), {self.setup.state_timeout_s:g} s after 6060h = {int(mode)}",
                    index=Cia402.MODES_OF_OPERATION_DISPLAY,
                    subindex=0,
                )
            self._sleep(0.005)

    def set_mode_csv(self) -> int:
        return self.set_mode(VelocityMode.CYCLIC_SYNCHRONOUS_VELOCITY)

    def open_ramps(self, facts: DriveFacts) -> None:
        """Profile velocity: 6083h/6084h at the profile's ramp or the UNSIGNED32 maximum so
        that the drive follows the set points (its own ramp stays the limit)."""
        value = self.profile.ramp or 0xFFFF_FFFF
        for index, name in (
            (Cia402.PROFILE_ACCELERATION, "profile acceleration"),
            (Cia402.PROFILE_DECELERATION, "profile deceleration"),
        ):
            if not facts.has((index, 0)):
                continue
            try:
                self.write(index, 0, _U32.pack(value), f" ({name})")
            except DriveSetupError as exc:
                if exc.abort_code in (SdoAbort.VALUE_RANGE, SdoAbort.TOO_HIGH):
                    raise DriveSetupError(
                        f"{exc}; set mode.ramp in the drive profile to a value the drive takes",
                        index=index,
                        subindex=0,
                        abort_code=exc.abort_code,
                    ) from None
                raise

    def statusword(self) -> int:
        return _U16.unpack(self.read(Cia402.STATUSWORD, 0, " (statusword)")[:2])[0]

    def enable_operation(self) -> int:
        """Walk the CiA 402 state machine to Operation Enabled; return the final statusword."""
        last_cw = 0
        for _ in range(12):  # longest path: fault -> ... -> operation enabled is 5 steps
            sw = self.statusword()
            state = drive_state(sw)
            if state is Drive402State.OPERATION_ENABLED:
                return sw
            cw = enable_controlword(state, last_cw)
            self.write(
                Cia402.CONTROLWORD, 0, _U16.pack(cw), f" (controlword, drive in {state.value})"
            )
            last_cw = cw
            self._wait_for_change(state)
        sw = self.statusword()
        raise DriveTimeoutError(
            f"drive {self.drive.id}: not in Operation Enabled after the CiA 402 sequence "
            f"(statusword 0x{sw:04X}, {drive_state(sw).value})",
            index=Cia402.STATUSWORD,
            subindex=0,
        )

    def _wait_for_change(self, before: Drive402State) -> None:
        deadline = self._wall() + self.setup.state_timeout_s
        while self._wall() <= deadline:
            if drive_state(self.statusword()) is not before:
                return
            self._sleep(0.002)
        raise DriveTimeoutError(
            f"drive {self.drive.id}: statusword stays in {before.value} for "
            f"{self.setup.state_timeout_s:g} s after the controlword",
            index=Cia402.STATUSWORD,
            subindex=0,
        )

    def plan(self, facts: DriveFacts) -> Plan:
        """:func:`bridge.adapt.plan` with the objects found not mappable left out."""
        profile = self.profile
        if self._unmappable:
            known = profile.mappable
            if known is None:
                known = frozenset(
                    k
                    for k in (
                        *facts.objects,
                        (Cia402.POSITION_ACTUAL_VALUE, 0),
                        (Cia402.STATUSWORD, 0),
                    )
                    if k not in self._unmappable
                )
            profile = replace(profile, mappable=known - self._unmappable)
        return plan(facts, profile, self.drive.id, self.load_increments_per_unit)

    def configure(self) -> tuple[Plan, DriveFacts, int]:
        """Steps 1-5 of the module docstring (the drive stays pre-operational); returns the
        plan, the facts and the mode shown in 6061h."""
        if self.setup.wait_for_drive:
            self.await_drive()
        self.drive.nmt.send_command(NmtCommand.ENTER_PRE_OPERATIONAL)
        facts = self.read_facts()
        the_plan = self.plan(facts)
        # planned before anything is written: a profile naming what the drive lacks stops here
        supervision = None if self.bridge_id is None else self.plan_supervision(facts)
        while True:  # each round leaves out one more object the drive refused to map
            try:
                for spec in the_plan.tpdos:
                    self.configure_pdo(spec)
                break
            except UnmappableError as exc:
                log.warning("%s; planning without it", exc)
                the_plan = self.plan(facts)
        self.configure_pdo(the_plan.rpdo)
        if self.setup.disable_other_pdos:
            used = {(p.transmit, p.number) for p in (*the_plan.tpdos, the_plan.rpdo)}
            for pdo in facts.tpdos:
                if (True, pdo.number) not in used:
                    self.disable_pdo(True, pdo.number)
            for pdo in facts.rpdos:
                if (False, pdo.number) not in used:
                    self.disable_pdo(False, pdo.number)
        if the_plan.mode is VelocityMode.PROFILE_VELOCITY:
            self.open_ramps(facts)
        mode = self.set_mode(the_plan.mode)
        self.write(
            Cia301.PRODUCER_HEARTBEAT_TIME,
            0,
            _U16.pack(self.setup.heartbeat_producer_ms),
            " (producer heartbeat)",
        )
        if supervision is not None:
            self.configure_supervision(supervision)
            if self.heartbeat_now is not None and supervision.consumer_ms is not None:
                # CiA 301: the watch starts with the first heartbeat after the entry was
                # written; one now, before the drive is enabled
                self.heartbeat_now()
        return the_plan, facts, mode

    def plan_supervision(self, facts: DriveFacts) -> Supervision:
        """:func:`bridge.supervision.plan_supervision` for this bridge."""
        assert self.bridge_id is not None
        return plan_supervision(
            facts, self.profile, self.drive.id, self.bridge_id, self.heartbeat_ms
        )

    def configure_supervision(self, supervision: Supervision) -> None:
        """Write the drive's supervision of the bridge, each object's value read first
        (:attr:`restored`, for :meth:`restore`)."""
        restored = []
        for write in supervision.writes:
            before = self.try_read(*write.key)
            if before:
                restored.append((write.key, before))
            self.write(*write.key, write.data, f" ({write.what})")
        self.supervision = supervision
        self.restored = tuple(restored)
        for line in supervision.describe():
            log.info("drive %d: %s", self.drive.id, line)
        for note in supervision.notes:
            log.warning("drive %d: %s", self.drive.id, note)

    def restore(self, restored: tuple[tuple[ObjectKey, bytes], ...]) -> list[str]:
        """Write back the values the supervision objects had before the start-up (the
        bridge ends in order: nothing watches it any more); the objects not written back,
        each with why (an empty list: all)."""
        failed = []
        for key, data in restored:
            try:
                self.write(*key, data, " (as it was before the start-up)")
            except DriveSetupError as exc:
                failed.append(str(exc))
        return failed

    def configure_encoder(self, encoder_id: int) -> None:
        """CiA 406 encoder node: TPDO1 = 6004h position value on every SYNC, heartbeat."""
        check_node_id("encoder_id", encoder_id)
        network = self.drive.network
        if encoder_id in network:
            encoder = network[encoder_id]
        else:
            encoder = canopen.RemoteNode(encoder_id, canopen.ObjectDictionary())
            network.add_node(encoder)
        encoder.sdo.RESPONSE_TIMEOUT = self.setup.sdo_timeout_s
        encoder.sdo.MAX_RETRIES = self.setup.sdo_retries
        sub = DriveMaster(encoder, self.setup, self._sleep, self._wall)
        encoder.nmt.send_command(NmtCommand.ENTER_PRE_OPERATIONAL)
        device_type = sub._u32(Cia301.DEVICE_TYPE, 0)
        if device_type is not None and device_type & 0xFFFF != 406:
            raise DriveSetupError(
                f"node {encoder_id}: 1000h device type 0x{device_type:08X} is not a CiA 406 "
                "encoder (low word 406 = 0x196); check load.encoder_id",
                index=Cia301.DEVICE_TYPE,
                subindex=0,
            )
        if sub.try_read(*ENCODER_POSITION) is None:
            raise DriveSetupError(
                f"node {encoder_id}: no 6004h position value: not a CiA 406 encoder",
                index=Cia406.POSITION_VALUE,
                subindex=0,
            )
        position = Item(Signal.LOAD_POSITION, ENCODER_POSITION, "u32")
        tpdo = PdoPlan(1, tpdo_cob_id(1, encoder_id), True, 1, (position,))
        sub.configure_pdo(tpdo)
        sub.write(
            Cia301.PRODUCER_HEARTBEAT_TIME,
            0,
            _U16.pack(self.setup.heartbeat_producer_ms),
            " (producer heartbeat)",
        )
        self.transfers += sub.transfers
        encoder.nmt.send_command(NmtCommand.START)

    def run(self) -> DriveInfo:
        """The whole start-up sequence (module docstring); returns what it learned."""
        the_plan, _facts, mode = self.configure()
        for note in the_plan.notes:
            log.warning("drive %d: %s", self.drive.id, note)
        if the_plan.encoder_id is not None:
            self.configure_encoder(the_plan.encoder_id)
        self.drive.nmt.send_command(NmtCommand.START)
        sw = self.enable_operation()
        log.info(
            "drive %d configured: %s, rated torque %s, statusword 0x%04X; layout:\n%s",
            self.drive.id,
            the_plan.mode.name,
            "unknown (per mille)"
            if the_plan.rated_torque_mnm is None
            else f"{the_plan.rated_torque_mnm} mN·m",
            sw,
            the_plan.layout.describe(),
        )
        return DriveInfo(
            the_plan.scaling.rated_torque_nm,
            sw,
            mode,
            self.transfers,
            the_plan.layout,
            the_plan.scaling,
            the_plan.encoder_id,
            the_plan.notes,
            self.supervision,
            self.restored,
        )

"""PDOs of the simulated drive: TPDOs sent on SYNC, RPDOs latched at the next SYNC, and the
CiA 301 rules for configuring them over SDO (1400h-1403h, 1600h-1603h, 1800h-1803h,
1A00h-1A03h).

canopen's LocalNode neither sends TPDOs on SYNC nor applies received RPDOs to its object
dictionary, so this module does both on top of :class:`plant_sim.drive.od.ObjectTable`.

Configuration rules (CiA 301, 7.5.2.35-7.5.2.38; abort codes as CANopenNode / Lely use them):

- COB-ID (sub 1): bit 31 = 1 makes the PDO invalid ("does not exist"); bits 0..10 are the
  CAN id, bit 29 (29-bit id) and bits 11..28 must be 0; while the PDO is valid its CAN id can
  not change (abort 0609 0030) - write it together with bit 31 = 1 first. A valid PDO may not
  use a restricted COB-ID (CiA 301 table 7.3) or the CAN id of another valid RPDO.
- transmission type (sub 2): TPDO 0 (acyclic synchronous: on SYNC when the data changed) or
  1..240 (every n-th SYNC); RPDO 0..240, 254, 255 - an RPDO's contents always take effect at
  the next SYNC, since the drive's control cycle is the SYNC (docs/canopen_layout.md).
  Other values abort 0609 0030.
- mapping (1600h/1A00h): entries can only be written while the PDO is invalid and sub 0 is 0
  (abort 0609 0030); an entry must name an existing (0602 0000), PDO-mappable object that an
  RPDO can write / a TPDO can read, with its full bit length (0604 0041); writing sub 0 = n
  checks entries 1..n and their total length <= 64 bits (0604 0042). Writing a value equal to
  the present one is always accepted (nothing changes).

Per SYNC the engine works from compiled plans (:class:`_Plan`): for each valid PDO its CAN id,
transmission type, one precompiled ``struct`` for the whole payload and the getters of the
mapped objects, built on first use and dropped whenever a PDO parameter changes (the write
hooks above, :meth:`PdoEngine.reset`). Mappings with a type ``struct`` cannot hold (24-bit
integers, ...) fall back to object-by-object encoding.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol

from virtual_bus.contract import CAN_ID_MASK as CAN_ID_MASK
from virtual_bus.contract import COB_ID_EXTENDED as COB_ID_EXTENDED
from virtual_bus.contract import COB_ID_INVALID as COB_ID_INVALID
from virtual_bus.contract import COB_ID_NO_RTR as COB_ID_NO_RTR
from virtual_bus.contract import SdoAbort, restricted_cob_id, split_mapping_entry
from virtual_bus.framing import OutFrame

from .errors import DriveSdoAbort
from .od import (
    PDO_CHANNELS,
    PDO_MAP_ENTRIES,
    RPDO_COMM,
    RPDO_MAP,
    TPDO_COMM,
    TPDO_MAP,
    ObjectKey,
    ObjectTable,
)

logger = logging.getLogger(__name__)

MAX_PDO_BITS = 64

FrameCallback = Callable[[int, bytearray, float], None]


class Subscriber(Protocol):
    """What the engine needs of :class:`canopen.Network` to receive RPDO frames."""

    def subscribe(self, can_id: int, callback: FrameCallback) -> None: ...

    def unsubscribe(self, can_id: int, callback: FrameCallback | None = None) -> None: ...


class PdoKind(Enum):
    RECEIVE = "RPDO"
    TRANSMIT = "TPDO"


@dataclass(frozen=True)
class MappedObject:
    """One mapping entry: object key and length in bits."""

    key: ObjectKey
    bits: int

    @staticmethod
    def decode(entry: int) -> MappedObject:
        index, subindex, bits = split_mapping_entry(entry)
        return MappedObject((index, subindex), bits)


@dataclass
class LatchResult:
    """What :meth:`PdoEngine.latch` did at one SYNC."""

    applied: int = 0  # RPDOs whose contents were written to the objects
    short_frames: list[int] = field(default_factory=list)  # CAN ids of too short RPDOs


#: What a latch without pending RPDOs did (nothing; shared, never changed).
_NOTHING_LATCHED = LatchResult()


@dataclass
class _Channel:
    kind: PdoKind
    number: int  # 1..4
    sync_count: int = 0  # TPDO: SYNCs since the last transmission
    last_sent: bytes | None = None  # TPDO type 0: data of the last transmission

    @property
    def comm(self) -> int:
        base = RPDO_COMM if self.kind is PdoKind.RECEIVE else TPDO_COMM
        return base + self.number - 1

    @property
    def map(self) -> int:
        base = RPDO_MAP if self.kind is PdoKind.RECEIVE else TPDO_MAP
        return base + self.number - 1

    @property
    def name(self) -> str:
        return f"{self.kind.value}{self.number}"


@dataclass(frozen=True)
class _Plan:
    """A valid PDO compiled for the cycle (see the module docstring)."""

    channel: _Channel
    can_id: int
    transmission_type: int
    keys: tuple[ObjectKey, ...]
    getters: tuple[Callable[[], int], ...]
    layout: struct.Struct | None  # None: encode object by object
    size: int  # bytes of the mapping
    pack: Callable[[], bytes] | None = None  # the payload now (layout and getters; None: no layout)
    #: RPDO: store its values when the latch only stores (see PdoEngine.latch_quiet)
    quiet: Callable[[bytes, Callable[[ObjectKey, int], bool]], bool] | None = None
    #: TPDO: pack into the loop's own frame and send it (PdoEngine.use_frames; None: bytes)
    emit: Callable[[], None] | None = None


def _quiet_writer(
    table: ObjectTable, keys: tuple[ObjectKey, ...], layout: struct.Struct
) -> Callable[[bytes, Callable[[ObjectKey, int], bool]], bool] | None:
    """``write(data, unchanged)`` for a compiled RPDO of two objects (the usual set point
    mapping): if both values are in their objects' range and each object has no hooks or
    ``unchanged(key, value)``, store them and return True; else False, nothing stored. None
    for other mappings (the general latch)."""
    if len(keys) != 2:
        return None
    unpack = layout.unpack_from
    k0, k1 = keys
    (lo0, hi0), (lo1, hi1) = table.limits(k0), table.limits(k1)
    plain0, plain1 = table.quiet(k0), table.quiet(k1)
    store = table.store

    def write(data: bytes, unchanged: Callable[[ObjectKey, int], bool]) -> bool:
        v0, v1 = unpack(data)
        if (lo0 is not None and v0 < lo0) or (hi0 is not None and v0 > hi0):
            return False
        if (lo1 is not None and v1 < lo1) or (hi1 is not None and v1 > hi1):
            return False
        if not (plain0 or unchanged(k0, v0)) or not (plain1 or unchanged(k1, v1)):
            return False
        store(k0, v0)
        store(k1, v1)
        return True

    return write


def _emitter(
    layout: struct.Struct,
    getters: tuple[Callable[[], int], ...],
    frame: OutFrame,
    send: Callable[[OutFrame], None],
) -> Callable[[], None]:
    """``emit()``: the PDO's values now packed straight into ``frame`` and ``frame`` sent
    (the usual sizes without building a list or a bytes object)."""
    pack_into = layout.pack_into
    buffer, offset = frame.buffer, frame.offset
    if len(getters) == 2:
        g0, g1 = getters

        def emit2() -> None:
            pack_into(buffer, offset, g0(), g1())
            send(frame)

        return emit2
    if len(getters) == 3:
        g0, g1, g2 = getters

        def emit3() -> None:
            pack_into(buffer, offset, g0(), g1(), g2())
            send(frame)

        return emit3

    def emit() -> None:
        pack_into(buffer, offset, *[get() for get in getters])
        send(frame)

    return emit


def _packer(layout: struct.Struct, getters: tuple[Callable[[], int], ...]) -> Callable[[], bytes]:
    """The payload of a compiled PDO now: ``layout.pack`` of its getters' values (the usual
    sizes without building a list)."""
    pack = layout.pack
    if len(getters) == 2:
        g0, g1 = getters
        return lambda: pack(g0(), g1())
    if len(getters) == 3:
        g0, g1, g2 = getters
        return lambda: pack(g0(), g1(), g2())
    return lambda: pack(*[get() for get in getters])


class PdoEngine:
    """The 4 RPDOs and 4 TPDOs of the drive.

    table: the object table holding the PDO parameters and the mapped objects.
    send: sends one CAN frame (can_id, data).
    subscriber: where RPDO CAN ids are subscribed with ``on_frame`` (a canopen Network).
    """

    def __init__(
        self,
        table: ObjectTable,
        *,
        send: Callable[[int, bytes], None],
        subscriber: Subscriber,
        on_frame: FrameCallback,
    ) -> None:
        self._table = table
        self._send = send
        self._subscriber = subscriber
        self._on_frame = on_frame
        self._rx = [_Channel(PdoKind.RECEIVE, n + 1) for n in range(PDO_CHANNELS)]
        self._tx = [_Channel(PdoKind.TRANSMIT, n + 1) for n in range(PDO_CHANNELS)]
        self._subscribed: dict[int, _Channel] = {}
        self._rpdo_ids: frozenset[int] = frozenset()  # keys of _subscribed, for the guard
        self._pending: dict[int, bytes] = {}  # RPDO number -> data received since last SYNC
        self._tx_plans: tuple[_Plan, ...] | None = None
        self._rx_plans: dict[int, _Plan] | None = None
        # the loop's frames for TPDOs (use_frames): make one, send one
        self._frame_for: Callable[[int, int], OutFrame] | None = None
        self._send_frame: Callable[[OutFrame], None] | None = None
        for ch in self._rx + self._tx:
            table.on((ch.comm, 1), validate=self._cob_id_validator(ch), changed=self._changed(ch))
            table.on((ch.comm, 2), validate=self._type_validator(ch), changed=self._changed(ch))
            table.on((ch.map, 0), validate=self._count_validator(ch), changed=self._changed(ch))
            for sub in range(1, PDO_MAP_ENTRIES + 1):
                table.on((ch.map, sub), validate=self._entry_validator(ch, sub))

    # --- configuration view ----------------------------------------------------------------
    def cob_id(self, ch: _Channel) -> int:
        return self._table.value((ch.comm, 1))

    def is_valid(self, ch: _Channel) -> bool:
        return not self.cob_id(ch) & COB_ID_INVALID

    def can_id(self, ch: _Channel) -> int:
        return self.cob_id(ch) & CAN_ID_MASK

    def mapping(self, ch: _Channel) -> list[MappedObject]:
        count = self._table.value((ch.map, 0))
        return [MappedObject.decode(self._table.value((ch.map, s))) for s in range(1, count + 1)]

    def channel(self, kind: PdoKind, number: int) -> _Channel:
        return (self._rx if kind is PdoKind.RECEIVE else self._tx)[number - 1]

    # --- validators ----------------------------------------------------------------------------
    def _abort(self, code: int, ch: _Channel, key: ObjectKey, message: str) -> DriveSdoAbort:
        return DriveSdoAbort(code, f"{ch.name}: {message}", key=key)

    def _cob_id_validator(self, ch: _Channel) -> Callable[[int], None]:
        key = (ch.comm, 1)

        def validate(new: int) -> None:
            old = self.cob_id(ch)
            if new == old:
                return
            if new & COB_ID_EXTENDED or new & 0x1FFFF800:
                raise self._abort(
                    SdoAbort.VALUE_RANGE,
                    ch,
                    key,
                    f"COB-ID 0x{new:08X}: only 11-bit CAN ids (bits 11..29 = 0) are supported",
                )
            if new & COB_ID_INVALID:
                return
            can_id = new & CAN_ID_MASK
            if not old & COB_ID_INVALID and can_id != old & CAN_ID_MASK:
                raise self._abort(
                    SdoAbort.VALUE_RANGE,
                    ch,
                    key,
                    f"COB-ID 0x{new:08X}: the CAN id of a valid PDO cannot change; "
                    "write it with bit 31 = 1 (PDO invalid) first",
                )
            if restricted_cob_id(can_id):
                raise self._abort(
                    SdoAbort.VALUE_RANGE, ch, key, f"CAN id 0x{can_id:03X} is a restricted COB-ID"
                )
            if ch.kind is PdoKind.RECEIVE:
                for other in self._rx:
                    if other is not ch and self.is_valid(other) and self.can_id(other) == can_id:
                        raise self._abort(
                            SdoAbort.VALUE_RANGE,
                            ch,
                            key,
                            f"CAN id 0x{can_id:03X} is already used by {other.name}",
                        )

        return validate

    def _type_validator(self, ch: _Channel) -> Callable[[int], None]:
        key = (ch.comm, 2)
        allowed = "0..240" if ch.kind is PdoKind.TRANSMIT else "0..240, 254, 255"

        def validate(new: int) -> None:
            ok = new <= 240 or (ch.kind is PdoKind.RECEIVE and new in (254, 255))
            if not ok:
                raise self._abort(
                    SdoAbort.VALUE_RANGE,
                    ch,
                    key,
                    f"transmission type {new} is not supported; allowed {allowed}",
                )

        return validate

    def _check_mappable(self, ch: _Channel, key: ObjectKey, entry: int, sub: int) -> int:
        """Bits of a valid mapping entry (raises DriveSdoAbort otherwise)."""
        obj = MappedObject.decode(entry)
        where = f"mapping entry {sub} = 0x{entry:08X}"
        if obj.key not in self._table:
            raise self._abort(
                SdoAbort.NO_OBJECT,
                ch,
                key,
                f"{where}: {obj.key[0]:04X}h:{obj.key[1]:02X} does not exist",
            )
        var = self._table.variable(obj.key)
        usable = var.writable if ch.kind is PdoKind.RECEIVE else var.readable
        if not var.pdo_mappable or not usable:
            what = "written by an RPDO" if ch.kind is PdoKind.RECEIVE else "sent by a TPDO"
            raise self._abort(
                SdoAbort.NOT_MAPPABLE, ch, key, f"{where}: {var.name} cannot be {what}"
            )
        if obj.bits != len(var):
            raise self._abort(
                SdoAbort.NOT_MAPPABLE,
                ch,
                key,
                f"{where}: {var.name} is {len(var)} bits, only whole objects can be mapped",
            )
        return obj.bits

    def _entry_validator(self, ch: _Channel, sub: int) -> Callable[[int], None]:
        key = (ch.map, sub)

        def validate(new: int) -> None:
            if new == self._table.value(key):
                return
            if self.is_valid(ch) or self._table.value((ch.map, 0)) != 0:
                raise self._abort(
                    SdoAbort.VALUE_RANGE,
                    ch,
                    key,
                    f"mapping can change only while the PDO is invalid ({ch.comm:04X}h:01 bit 31"
                    f" = 1) and {ch.map:04X}h:00 = 0",
                )
            if new != 0:
                self._check_mappable(ch, key, new, sub)

        return validate

    def _count_validator(self, ch: _Channel) -> Callable[[int], None]:
        key = (ch.map, 0)

        def validate(new: int) -> None:
            if new == self._table.value(key):
                return
            if self.is_valid(ch):
                raise self._abort(
                    SdoAbort.VALUE_RANGE,
                    ch,
                    key,
                    f"the number of mapped objects can change only while the PDO is invalid "
                    f"({ch.comm:04X}h:01 bit 31 = 1)",
                )
            total = 0
            for sub in range(1, new + 1):
                entry = self._table.value((ch.map, sub))
                if entry == 0:
                    raise self._abort(
                        SdoAbort.NOT_MAPPABLE, ch, key, f"mapping entry {sub} is empty"
                    )
                total += self._check_mappable(ch, key, entry, sub)
            if total > MAX_PDO_BITS:
                raise self._abort(
                    SdoAbort.PDO_LENGTH,
                    ch,
                    key,
                    f"{new} mapped objects are {total} bits; a PDO holds at most {MAX_PDO_BITS}",
                )

        return validate

    def _changed(self, ch: _Channel) -> Callable[[int], None]:
        def changed(_value: int) -> None:
            self._tx_plans = self._rx_plans = None
            ch.sync_count = 0
            ch.last_sent = None
            if ch.kind is PdoKind.RECEIVE:
                self._pending.pop(ch.number, None)
                self.refresh_subscriptions()

        return changed

    # --- compiled plans ----------------------------------------------------------------------
    def _plan(self, ch: _Channel) -> _Plan | None:
        if not self.is_valid(ch):
            return None
        mapping = self.mapping(ch)
        if not mapping:
            return None
        keys = tuple(m.key for m in mapping)
        formats = [self._table.struct_format(k) for k in keys]
        layout = None
        if all(f is not None for f in formats):
            layout = struct.Struct("<" + "".join(f for f in formats if f is not None))
            if layout.size * 8 != sum(m.bits for m in mapping):
                layout = None
        getters = tuple(self._table.getter(k) for k in keys)
        can_id = self.can_id(ch)
        transmission_type = self._table.value((ch.comm, 2))
        emit = None
        framed = self._frame_for is not None and self._send_frame is not None
        if layout is not None and ch.kind is PdoKind.TRANSMIT and transmission_type and framed:
            frame = self._frame_for(can_id, layout.size)  # type: ignore[misc]
            emit = _emitter(layout, getters, frame, self._send_frame)  # type: ignore[arg-type]
        return _Plan(
            ch,
            can_id,
            transmission_type,
            keys,
            getters,
            layout,
            sum(m.bits for m in mapping) // 8,
            None if layout is None else _packer(layout, getters),
            None
            if layout is None or ch.kind is not PdoKind.RECEIVE
            else _quiet_writer(self._table, keys, layout),
            emit,
        )

    def use_frames(
        self,
        frame_for: Callable[[int, int], OutFrame] | None,
        send_frame: Callable[[OutFrame], None] | None = None,
    ) -> None:
        """Send cyclic TPDOs (transmission types 1..240) as the loop's own preallocated frames
        (``frame_for(cob_id, length)``, ``send_frame(frame)``: a FramePort's) packed in place,
        from the next SYNC on; None: as bytes through ``send`` again."""
        self._frame_for = frame_for
        self._send_frame = send_frame
        self._tx_plans = None

    def _compile(self) -> None:
        self._tx_plans = tuple(p for ch in self._tx if (p := self._plan(ch)) is not None)
        self._rx_plans = {ch.number: p for ch in self._rx if (p := self._plan(ch)) is not None}

    # --- runtime -------------------------------------------------------------------------------
    def refresh_subscriptions(self) -> None:
        """Subscribe exactly the CAN ids of the valid RPDOs (after configuration changes)."""
        wanted = {self.can_id(ch): ch for ch in self._rx if self.is_valid(ch)}
        for can_id in list(self._subscribed):
            if wanted.get(can_id) is not self._subscribed[can_id]:
                self._subscriber.unsubscribe(can_id, self._on_frame)
                del self._subscribed[can_id]
        for can_id, ch in wanted.items():
            if can_id not in self._subscribed:
                self._subscriber.subscribe(can_id, self._on_frame)
                self._subscribed[can_id] = ch
        self._rpdo_ids = frozenset(self._subscribed)

    def rpdo_cob_ids(self) -> frozenset[int]:
        """CAN ids of the valid RPDOs (subscribed)."""
        return self._rpdo_ids

    def unsubscribe_all(self) -> None:
        for can_id in list(self._subscribed):
            self._subscriber.unsubscribe(can_id, self._on_frame)
        self._subscribed.clear()
        self._rpdo_ids = frozenset()

    def reset(self) -> None:
        """After a communication reset: counters, pending data and subscriptions anew."""
        self._tx_plans = self._rx_plans = None
        for ch in self._rx + self._tx:
            ch.sync_count = 0
            ch.last_sent = None
        self._pending.clear()
        self.refresh_subscriptions()

    def receive(self, can_id: int, data: bytes) -> None:
        """Keep an RPDO frame until the next SYNC (a later frame replaces an earlier one)."""
        ch = self._subscribed.get(can_id)
        if ch is not None:
            self._pending[ch.number] = bytes(data)

    def clear_pending(self) -> None:
        self._pending.clear()

    def latch(self, before_apply: Callable[[], None] | None = None) -> LatchResult:
        """At SYNC: write the contents of the RPDOs received since the previous SYNC to their
        mapped objects, in mapping order. A frame shorter than its mapping is discarded
        (CiA 301: EMCY 0x8210, reported in the result); a longer one is used up to its
        mapped length. A value an object refuses is logged and skipped. ``before_apply`` is
        called before the objects of each accepted RPDO are written."""
        if not self._pending:
            return _NOTHING_LATCHED
        result = LatchResult()
        pending, self._pending = self._pending, {}
        if self._rx_plans is None:
            self._compile()
        plans = self._rx_plans
        assert plans is not None
        write = self._table.write
        for number, data in sorted(pending.items()) if len(pending) > 1 else pending.items():
            plan = plans.get(number)
            if plan is None:
                continue
            if len(data) < plan.size:
                logger.warning(
                    "%s: %d bytes received, mapping needs %d",
                    plan.channel.name,
                    len(data),
                    plan.size,
                )
                result.short_frames.append(plan.can_id)
                continue
            if before_apply is not None:
                before_apply()
            if plan.layout is not None:
                values = plan.layout.unpack_from(data)
            else:
                values = self._decode_each(plan, data)
            for key, value in zip(plan.keys, values, strict=True):
                try:
                    write(key, value)
                except DriveSdoAbort as exc:
                    logger.warning("%s: %s", plan.channel.name, exc)
            result.applied += 1
        return result

    def latch_quiet(self, unchanged: Callable[[ObjectKey, int], bool]) -> bool | None:
        """The latch of a SYNC at which it only stores values: at most one RPDO pending, of a
        compiled mapping and its full length, whose every value is in its object's range and
        either goes to an object without hooks or is one ``unchanged(key, value)`` says its
        hooks would do nothing with (the controlword a master repeats). Then the values are
        stored, as :meth:`latch` would write them; True: an RPDO was applied, False: none was
        pending. None: not such a SYNC, nothing done (use :meth:`latch`)."""
        pending = self._pending
        if not pending:
            return False
        plans = self._rx_plans
        if len(pending) != 1 or plans is None:
            return None
        ((number, data),) = pending.items()
        plan = plans.get(number)
        if plan is None or plan.quiet is None or len(data) < plan.size:
            return None
        if not plan.quiet(data, unchanged):
            return None
        pending.clear()
        return True

    def _decode_each(self, plan: _Plan, data: bytes) -> list[int]:
        values = []
        offset = 0
        for key in plan.keys:
            size = self._table.bit_length(key) // 8
            values.append(self._table.decode(key, data[offset : offset + size]))
            offset += size
        return values

    def frame(self, ch: _Channel) -> bytes:
        """The TPDO's data with the values of its mapped objects now."""
        return b"".join(
            self._table.encode(m.key, self._table.read(m.key)) for m in self.mapping(ch)
        )

    def transmit(self) -> int:
        """At SYNC: send the valid TPDOs that are due (type n: every n-th SYNC; type 0: when
        the data changed). Returns the number of frames sent."""
        if self._tx_plans is None:
            self._compile()
        plans = self._tx_plans
        assert plans is not None
        sent = 0
        send = self._send
        for plan in plans:
            ch = plan.channel
            if plan.transmission_type == 0:
                data = self._plan_frame(plan)
                if data == ch.last_sent:
                    continue
                ch.last_sent = data
            else:
                ch.sync_count += 1
                if ch.sync_count < plan.transmission_type:
                    continue
                ch.sync_count = 0
                if plan.emit is not None:
                    plan.emit()
                    sent += 1
                    continue
                data = self._plan_frame(plan)
            send(plan.can_id, data)
            sent += 1
        return sent

    def _plan_frame(self, plan: _Plan) -> bytes:
        if plan.pack is not None:
            return plan.pack()
        return self.frame(plan.channel)

"""The bridge's objects served over SDO: the canopen LocalNode's read/write callbacks.

Reads of bound objects come from the running controller (parameters, live values,
counters); everything else from the EDS defaults. A write is decoded, validated by
:mod:`bridge.params` (or by the controller for commands and moves) and applied only if valid;
a refused write raises ``canopen.SdoAbortedError`` with the code of the refusal, which the SDO
server sends as the abort (the LocalNode stores nothing after a raising callback). Read-only
and write-only objects, unknown objects and wrong lengths are refused by canopen's LocalNode
itself (0601 0002, 0601 0001, 0602 0000 / 0609 0011, 0607 0010).
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, replace

import canopen
from canopen.objectdictionary import datatypes as dt
from canopen.sdo import SdoAbortedError

from virtual_bus.frame_guard import FrameFault, FrameGuard

from . import od as objdict
from .cycle import BridgeState, Command, CycleController
from .errors import ParameterError, SdoAbort, StoreError
from .interpolator import Move
from .params import BridgeParams, check_field
from .scaling import Scaling
from .store import ParameterStore, RawValues

log = logging.getLogger("bridge")

_F32 = struct.Struct("<f")
_U8 = struct.Struct("<B")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_I32 = struct.Struct("<i")
#: How the store's readable table unpacks a value, by CiA 301 data type.
_READABLE = {
    dt.BOOLEAN: _U8,
    dt.UNSIGNED8: _U8,
    dt.UNSIGNED16: _U16,
    dt.UNSIGNED32: _U32,
    dt.INTEGER16: struct.Struct("<h"),
    dt.INTEGER32: _I32,
    dt.REAL32: _F32,
}


@dataclass
class PdoCounters:
    """What the loop counted about the drive's TPDOs (2107h).

    missed: TPDO slots (one per TPDO per cycle) without a valid frame at the end of their
    cycle; late: valid TPDO frames not used for their cycle (arrived outside the window, or an
    extra one in a window -- the newest is used); invalid: frames of the wrong length.
    Invariant: missed - late = TPDO frames sent by the drive - valid frames received.
    """

    missed: int = 0
    late: int = 0
    invalid: int = 0
    cycles: int = 0
    missed_cycles: int = 0


def _f32(value: float) -> bytes:
    if not math.isfinite(value):
        value = 0.0
    return _F32.pack(max(-3.4e38, min(3.4e38, value)))


# parameter objects: index -> (BridgeParams field, decode raw -> value, encode value -> raw)
Codec = tuple[str, Callable[[bytes], object], Callable[[object], bytes]]


def _real(field: str) -> Codec:
    return field, lambda raw: _F32.unpack(raw)[0], lambda v: _f32(v)  # type: ignore[arg-type]


def _u8(field: str) -> Codec:
    return field, lambda raw: _U8.unpack(raw)[0], lambda v: _U8.pack(v)  # type: ignore[arg-type]


def _bool_decode(raw: bytes) -> object:
    value = raw[0]
    return bool(value) if value in (0, 1) else value  # 2..255 fail the bool check (0609 0030)


def _tv_decode(raw: bytes) -> object:
    value = _F32.unpack(raw)[0]
    return None if value == 0.0 else value  # 0: eq. 14 default


_PARAMS: dict[tuple[int, int], Codec] = {
    (objdict.KV, 0): _real("kv_per_s"),
    (objdict.REG_ENABLE, 0): ("regulator_enabled", _bool_decode, lambda v: _U8.pack(int(v))),  # type: ignore[arg-type]
    (objdict.BETA_T, 0): _real("beta_t_rad_s"),
    (objdict.WINDOW_N, 0): _u8("n"),
    (objdict.TV, 0): ("tv_s", _tv_decode, lambda v: _f32(0.0 if v is None else v)),  # type: ignore[arg-type]
    (objdict.TF, 0): _real("tf_s"),
    (objdict.KR, 0): _real("transmission_ratio"),
    (objdict.SPEED_LIMIT, 0): _real("speed_limit_rad_s"),
    (objdict.FE_LIMIT, 0): _real("following_error_limit"),
    (objdict.DISC_LIMIT, 0): _real("discrepancy_limit"),
    (objdict.PDO_TOLERANCE, 0): _u8("pdo_loss_tolerance"),
    (objdict.VELOCITY_FF, 0): _real("velocity_feedforward"),
    (objdict.POSITION_LIMITS, 1): _real("position_limit_min"),
    (objdict.POSITION_LIMITS, 2): _real("position_limit_max"),
    (objdict.CYCLE_PERIOD, 0): (
        "cycle_s",
        lambda raw: _U32.unpack(raw)[0] / 1e6,
        lambda v: _U32.pack(round(v * 1e6)),  # type: ignore[operator]
    ),
}


def _check_subindex(subindex: int, var: object) -> None:
    """canopen's LocalNode serves a plain VAR at any sub-index; only sub-index 0 exists."""
    if subindex and not isinstance(
        getattr(var, "parent", None),
        canopen.objectdictionary.ODRecord | canopen.objectdictionary.ODArray,
    ):
        raise SdoAbortedError(int(SdoAbort.NO_SUBINDEX))


class ObjectServer:
    """Binds a :class:`canopen.LocalNode` to a :class:`CycleController` (see module doc).

    load_increments_per_unit: scaling of the move objects 2010h-2012h (nm or µrad per load
    unit). drive_id: the node whose heartbeat 1016h:01 must name. store: where 1010h saves
    the parameters (None: 1010h:01/1011h:01 read 0 and refuse with 0800 0020).
    """

    def __init__(
        self,
        controller: CycleController,
        counters: PdoCounters,
        load_increments_per_unit: float,
        drive_id: int,
        store: ParameterStore | None = None,
        guard: FrameGuard | None = None,
    ) -> None:
        self.store = store
        self.controller = controller
        self.counters = counters
        self._inc_per_unit = load_increments_per_unit
        self.drive_id = drive_id
        self.guard = guard
        self._last_target = 0
        self.writes_refused = 0

    def set_load_scaling(self, load_increments_per_unit: float) -> None:
        """Scale 2010h-2012h like the load position the start-up found (increments/unit)."""
        self._inc_per_unit = load_increments_per_unit

    def attach(self, node: canopen.LocalNode) -> None:
        node.add_read_callback(self.on_read)
        node.add_write_callback(self.on_write)

    # --- reads ---------------------------------------------------------------------------------
    def on_read(self, index: int, subindex: int, od: object = None) -> bytes | None:
        """Raw value of a bound object, or None for the LocalNode to use the EDS default
        (``od`` None: a call from the bridge itself, no SDO sub-index check)."""
        if od is not None:
            _check_subindex(subindex, od)
        c = self.controller
        codec = _PARAMS.get((index, subindex))
        if codec is not None:
            return codec[2](getattr(c.params, codec[0]))
        if index == objdict.HEARTBEAT_CONSUMER and subindex == 1:
            return _U32.pack((self.drive_id << 16) | c.params.heartbeat_consumer_ms)
        if index in (objdict.STORE_PARAMETERS, objdict.RESTORE_DEFAULTS) and subindex == 1:
            return _U32.pack(objdict.STORE_ON_COMMAND if self.store is not None else 0)
        if index == objdict.PDO_COUNTERS and subindex:
            k = self.counters
            values = (k.missed, k.late, k.invalid, k.cycles, k.missed_cycles)
            return _U32.pack(values[subindex - 1] & 0xFFFF_FFFF) if subindex <= 5 else None
        if index == objdict.FRAME_COUNTERS and subindex:
            count = self.guard.count(FrameFault(subindex)) if self.guard is not None else 0
            return _U32.pack(count & 0xFFFF_FFFF)
        reader = _LIVE.get(index)
        return None if reader is None or subindex else reader(self, c)

    # --- writes --------------------------------------------------------------------------------
    def on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        """Validate and apply a write; raise SdoAbortedError (nothing changed) if refused."""
        _check_subindex(subindex, od)
        try:
            self.write(index, subindex, bytes(data))
        except ParameterError as exc:
            self.writes_refused += 1
            log.warning(
                "SDO write %04Xh:%02X refused (0x%08X): %s",
                index,
                subindex,
                int(exc.abort_code),
                exc,
            )
            raise SdoAbortedError(int(exc.abort_code)) from None

    def write(self, index: int, subindex: int, raw: bytes) -> None:
        """Apply a raw write to a bound object (ParameterError with the abort code if refused).

        Lengths are checked by the LocalNode before this is called over SDO."""
        c = self.controller
        if index == objdict.TARGET:
            target = _I32.unpack(raw)[0]
            p = c.params
            try:
                move = Move(target / self._inc_per_unit, p.feed, p.accel)
            except ValueError as exc:
                raise ParameterError(
                    f"target = {target}: {exc}",
                    field="target",
                    value=target,
                    abort_code=SdoAbort.VALUE_RANGE,
                ) from None
            c.start_move(move)
            self._last_target = target
        elif index == objdict.COMMAND:
            self._command(_U8.unpack(raw)[0])
        elif index == objdict.COB_ID_SYNC:
            value = _U32.unpack(raw)[0]
            if value != objdict.SYNC_COB_ID_VALUE:
                raise ParameterError(
                    f"1005h = 0x{value:08X}: the bridge is the SYNC producer on 0x080; "
                    f"allowed only 0x{objdict.SYNC_COB_ID_VALUE:08X}",
                    field="cob_id_sync",
                    value=value,
                    abort_code=SdoAbort.VALUE_RANGE,
                )
        elif index in (objdict.STORE_PARAMETERS, objdict.RESTORE_DEFAULTS) and subindex == 1:
            self._store_command(index, _U32.unpack(raw)[0])
        else:
            decoded = self.field_value(index, subindex, raw)
            if decoded is not None:
                field, value = decoded
                if self.on_read(index, subindex) == raw:
                    # the value read back (REAL32 of a double): keep the exact one, so a tool
                    # restoring what it read changes nothing
                    value = getattr(c.params, field)
                self._set(field, value)
        # other writable objects: none (all others are ro/const in the EDS)

    def field_value(self, index: int, subindex: int, raw: bytes) -> tuple[str, object] | None:
        """The :class:`BridgeParams` field and value a raw parameter write means (None for
        objects that are not parameters); ParameterError for a malformed 1016h:01."""
        codec = _PARAMS.get((index, subindex))
        if codec is not None:
            field, decode, _ = codec
            return field, decode(raw)
        if index == objdict.HEARTBEAT_CONSUMER and subindex == 1:
            value = _U32.unpack(raw)[0]
            node, ms = (value >> 16) & 0xFF, value & 0xFFFF
            if value >> 24 or node != self.drive_id:
                raise ParameterError(
                    f"1016h:01 = 0x{value:08X}: must be (drive node-ID {self.drive_id} << 16) "
                    f"| timeout in ms; bits 24-31 reserved (0)",
                    field="heartbeat_consumer_ms",
                    value=value,
                    abort_code=SdoAbort.VALUE_RANGE,
                )
            return "heartbeat_consumer_ms", ms
        if index in (objdict.FEED, objdict.ACCEL):
            field = "feed" if index == objdict.FEED else "accel"
            return field, _U32.unpack(raw)[0] / self._inc_per_unit
        return None

    # --- 1010h / 1011h: the parameter store ------------------------------------------------
    def stored_values(self) -> RawValues:
        """Raw values of the objects 1010h saves (:data:`bridge.od.STORED`)."""
        values = {}
        for index, subindex in sorted(objdict.STORED):
            raw = self.on_read(index, subindex)
            assert raw is not None, f"{index:04X}h:{subindex:02X} is stored but not bound"
            values[(index, subindex)] = raw
        return values

    def stored_readable(self, values: RawValues) -> dict[tuple[int, int], str]:
        """``values`` as a person reads them: 'name = value unit' by object (the store's
        ``readable`` table, bridge.store)."""
        by_key = {(e.index, e.subindex): e for e in objdict.entries()}
        readable = {}
        for key, raw in values.items():
            entry = by_key.get(key)
            packing = None if entry is None else _READABLE.get(entry.data_type)
            if entry is None or packing is None or packing.size != len(raw):
                continue
            value = packing.unpack(raw)[0]
            if key == (objdict.HEARTBEAT_CONSUMER, 1):  # CiA 301: node-ID << 16 | time in ms
                readable[key] = f"{entry.name} = node {value >> 16} within {value & 0xFFFF} ms"
                continue
            unit = f" {entry.unit}" if entry.unit else ""
            readable[key] = f"{entry.name} = {value:.7g}{unit}"
        return readable

    def _store_command(self, index: int, value: int) -> None:
        save = index == objdict.STORE_PARAMETERS
        signature = objdict.SAVE_SIGNATURE if save else objdict.LOAD_SIGNATURE
        name = "'save' 0x65766173" if save else "'load' 0x64616F6C"
        if value != signature:
            raise ParameterError(
                f"{index:04X}h:01 = 0x{value:08X}: wrong signature; write {name}",
                field="store" if save else "restore",
                value=value,
                abort_code=SdoAbort.NOT_STORED,
            )
        if self.store is None:
            raise ParameterError(
                f"{index:04X}h:01: this bridge has no parameter store file (BridgeConfig."
                "store_path / --store)",
                field="store" if save else "restore",
                value=value,
                abort_code=SdoAbort.NOT_STORED,
            )
        try:
            if save:
                values = self.stored_values()
                self.store.save(values, self.stored_readable(values))
                log.info("parameters stored in %s", self.store.path)
            else:
                self.store.clear()
                log.info("%s removed: defaults at the next start", self.store.path)
        except OSError as exc:
            raise ParameterError(
                f"parameter store {self.store.path}: {exc}",
                field="store" if save else "restore",
                value=value,
                abort_code=SdoAbort.HARDWARE,
            ) from None

    def apply_stored(self, values: RawValues, where: str) -> BridgeParams:
        """Parameters with the stored raw ``values`` applied over the current ones, checked
        together (one :class:`BridgeParams`); StoreError naming ``where`` if refused."""
        changes: dict[str, object] = {}
        try:
            for (index, subindex), raw in sorted(values.items()):
                what = f"{where}: {index:04X}h:{subindex:02X}"
                if (index, subindex) not in objdict.STORED:
                    raise StoreError(f"{what}: not a stored object of this bridge", path=where)
                size = len(self.on_read(index, subindex) or b"")
                if len(raw) != size:
                    raise StoreError(f"{what}: {len(raw)} bytes, expected {size}", path=where)
                decoded = self.field_value(index, subindex, raw)
                assert decoded is not None
                changes[decoded[0]] = decoded[1]
            for field, value in changes.items():
                check_field(field, value)
            return replace(self.controller.params, **changes)
        except ParameterError as exc:
            raise StoreError(f"{where}: stored value refused: {exc}", path=where) from None

    def _command(self, value: int) -> None:
        """2020h: 0 idle (nothing), 1 enable, 2 disable, 3 reset; the EDS range 0..3 is
        checked by the SDO server. A command the state does not allow (enable while enabled,
        disable while disabled, reset without a stop) is refused with 0800 0022."""
        if value == 0:
            return
        c = self.controller
        command = Command(value)
        if (command is Command.ENABLE and c.axis_enabled) or (
            command is Command.DISABLE and c.state is BridgeState.DISABLED
        ):
            raise ParameterError(
                f"command {command.name}: the axis is already "
                f"{'enabled' if command is Command.ENABLE else 'disabled'} "
                f"(state {c.state.name})",
                field="command",
                value=value,
                abort_code=SdoAbort.DEVICE_STATE,
            )
        c.command(command)

    def _set(self, field: str, value: object) -> None:
        c = self.controller
        new = c.params.with_value(field, value, axis_enabled=c.axis_enabled)
        c.set_params(new)


def _live_table() -> dict[int, Callable[[ObjectServer, CycleController], bytes]]:
    return {
        objdict.ERROR_REGISTER: lambda s, c: _U8.pack(c.error_register),
        objdict.TARGET: lambda s, c: _I32.pack(s._last_target),
        objdict.FEED: lambda s, c: _U32.pack(round(c.params.feed * s._inc_per_unit)),
        objdict.ACCEL: lambda s, c: _U32.pack(
            min(0xFFFF_FFFF, round(c.params.accel * s._inc_per_unit))
        ),
        objdict.MOVE_STATUS: lambda s, c: _U8.pack(1 if c.moving else 0),
        objdict.BETA: lambda s, c: _f32(c.vibration_level),
        objdict.LAMBDA: lambda s, c: _f32(c.switching_factor),
        objdict.FOLLOWING_ERROR: lambda s, c: _f32(c.following_error),
        objdict.MOTOR_LOAD_DIFF: lambda s, c: _f32(c.motor_load_difference),
        objdict.STATE: lambda s, c: _U8.pack(c.state.value),
        objdict.STOP_REASON: lambda s, c: _U8.pack(c.stop_reason.value),
        objdict.STOP_MESSAGE: lambda s, c: (c.stop_message or "none").encode("ascii", "replace"),
        objdict.SPEED_SETPOINT: lambda s, c: _f32(c.omega_r),
        objdict.POSITION_REFERENCE: lambda s, c: _f32(c.position_reference),
        objdict.DRIVE_ERROR: lambda s, c: _U16.pack(c.drive_error_code & 0xFFFF),
    }


_LIVE = _live_table()


def params_with_store(
    params: BridgeParams, load_increments_per_unit: float, drive_id: int, store: ParameterStore
) -> BridgeParams:
    """``params`` with the store file's values applied, as a bridge built with that store
    would run (for what must be known before the bridge exists, e.g. the cycle of the pacer).
    StoreError if the file is malformed or refused."""
    values = store.load()
    if values is None:
        return params
    server = ObjectServer(
        CycleController(params, Scaling(load_increments_per_unit, 1.0)),
        PdoCounters(),
        load_increments_per_unit,
        drive_id,
    )
    return server.apply_stored(values, str(store.path))

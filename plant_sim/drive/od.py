"""The drive's object dictionary: object keys, scaling (``docs/canopen_layout.md``), the EDS
check and :class:`ObjectTable`, which serves SDO and PDO access on top of canopen's LocalNode.

Scaling (also in the ``[Comments]`` of ``config/drive.eds``):

| object    | value                                   | formula                                   |
| --------- | --------------------------------------- | ----------------------------------------- |
| 6064h     | motor encoder, INTEGER32                | wrap32(round(θ_m · 2^20 / 2π))            |
| 606Ch     | motor speed, INTEGER32                  | sat32(round(ω_m · 2^20 / 2π))             |
| 60FFh     | target velocity, INTEGER32              | ω_set = v · 2π / 2^20 (rad/s)             |
| 60E4h:01  | load scale, INTEGER32                   | wrap32(round(x_l · 1e9)) nm, 1e6 µrad     |
| 6077h     | torque actual, INTEGER16                | sat16(round(τ_m · 1e6 / 6076h))           |
| 6072h     | torque limit, UNSIGNED16                | τ_lim = 6072h · 6076h / 1e6 (N·m)         |
| 6076h     | rated torque, UNSIGNED32                | mN·m                                      |
| 2100h     | disturbance, INTEGER32                  | τ_dist = 2100h / 1000 (N·m at the motor)  |
| 2104h     | load minus motor position, INTEGER32    | sat32(round((x_l − θ_m/k_r) · 1e9 or 1e6))|

round() is Python's: to the nearest integer, ties to even. wrap32 is two's complement modulo
2^32 (encoder counters wrap; differences stay right), sat32/sat16 clamp to the type's range.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen import objectdictionary as cod
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.sdo import SdoAbortedError

from virtual_bus.contract import (
    ABORT_CONNECTION_INDEX,
    HEARTBEAT_CONSUMER_INDEX,
    HEARTBEAT_PRODUCER_INDEX,
    LOAD_INCREMENTS_PER_M,
    LOAD_INCREMENTS_PER_RAD,
    MNM_PER_NM,
    MOTOR_INCREMENTS_PER_REV,
    PERMILLE,
    Cia301,
    Cia402,
    SdoAbort,
)
from virtual_bus.contract import INT16_MAX as INT16_MAX
from virtual_bus.contract import INT16_MIN as INT16_MIN
from virtual_bus.contract import INT32_MAX as INT32_MAX
from virtual_bus.contract import INT32_MIN as INT32_MIN
from virtual_bus.contract import MODE_CSV as MODE_CSV
from virtual_bus.formats.axis import AxisKind
from virtual_bus.shipped import DRIVE_EDS

from .errors import DriveEdsError, DriveSdoAbort

ObjectKey = tuple[int, int]

# --- CiA 301 communication area -------------------------------------------------------------
DEVICE_TYPE: ObjectKey = (Cia301.DEVICE_TYPE, 0)
ERROR_REGISTER: ObjectKey = (Cia301.ERROR_REGISTER, 0)
COB_ID_SYNC: ObjectKey = (Cia301.COB_ID_SYNC, 0)
#: the one heartbeat consumer entry (1016h:01): the master the drive watches
HEARTBEAT_CONSUMER: ObjectKey = (HEARTBEAT_CONSUMER_INDEX, 1)
HEARTBEAT_TIME: ObjectKey = (HEARTBEAT_PRODUCER_INDEX, 0)
RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = (
    Cia301.RPDO_COMMUNICATION,
    Cia301.RPDO_MAPPING,
    Cia301.TPDO_COMMUNICATION,
    Cia301.TPDO_MAPPING,
)
PDO_CHANNELS = 4
PDO_MAP_ENTRIES = 8
# --- manufacturer area ----------------------------------------------------------------------
DISTURBANCE: ObjectKey = (0x2100, 0)
ENCODER_TOLERANCE: ObjectKey = (0x2101, 0)
SETPOINT_TIMEOUT: ObjectKey = (0x2102, 0)
SYNC_CYCLES: ObjectKey = (0x2103, 0)
LOAD_MINUS_MOTOR: ObjectKey = (0x2104, 0)
#: 2105h:01..07 refused frames by kind (virtual_bus.frame_guard.FrameFault values)
FRAME_COUNTERS = 0x2105
# --- CiA 402 --------------------------------------------------------------------------------
ABORT_CONNECTION_OPTION: ObjectKey = (ABORT_CONNECTION_INDEX, 0)
ERROR_CODE: ObjectKey = (Cia402.ERROR_CODE, 0)
CONTROLWORD: ObjectKey = (Cia402.CONTROLWORD, 0)
STATUSWORD: ObjectKey = (Cia402.STATUSWORD, 0)
QUICK_STOP_OPTION: ObjectKey = (Cia402.QUICK_STOP_OPTION, 0)
FAULT_REACTION_OPTION: ObjectKey = (Cia402.FAULT_REACTION_OPTION, 0)
MODES_OF_OPERATION: ObjectKey = (Cia402.MODES_OF_OPERATION, 0)
MODES_OF_OPERATION_DISPLAY: ObjectKey = (Cia402.MODES_OF_OPERATION_DISPLAY, 0)
POSITION_ACTUAL: ObjectKey = (Cia402.POSITION_ACTUAL_VALUE, 0)
VELOCITY_ACTUAL: ObjectKey = (Cia402.VELOCITY_ACTUAL_VALUE, 0)
MAX_TORQUE: ObjectKey = (Cia402.MAX_TORQUE, 0)
RATED_TORQUE: ObjectKey = (Cia402.MOTOR_RATED_TORQUE, 0)
TORQUE_ACTUAL: ObjectKey = (Cia402.TORQUE_ACTUAL_VALUE, 0)
PROFILE_DECELERATION: ObjectKey = (Cia402.PROFILE_DECELERATION, 0)
QUICK_STOP_DECELERATION: ObjectKey = (Cia402.QUICK_STOP_DECELERATION, 0)
INTERPOLATION_PERIOD_VALUE: ObjectKey = (Cia402.INTERPOLATION_TIME_PERIOD, 1)
INTERPOLATION_PERIOD_INDEX: ObjectKey = (Cia402.INTERPOLATION_TIME_PERIOD, 2)
LOAD_POSITION_ACTUAL: ObjectKey = (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 1)
TARGET_VELOCITY: ObjectKey = (Cia402.TARGET_VELOCITY, 0)
SUPPORTED_DRIVE_MODES: ObjectKey = (Cia402.SUPPORTED_DRIVE_MODES, 0)

#: Motor encoder increments per motor revolution (6064h, 606Ch, 60FFh); MODE_CSV (6060h = 9)
#: is the only mode of this drive.
INCREMENTS_PER_REV = MOTOR_INCREMENTS_PER_REV
INCREMENTS_PER_RAD = INCREMENTS_PER_REV / (2.0 * math.pi)
RAD_PER_INCREMENT = (2.0 * math.pi) / INCREMENTS_PER_REV
#: The paper's tolerance between motor and direct measuring system (section II.B).
PAPER_ENCODER_TOLERANCE_M = 0.5e-3
PAPER_ENCODER_TOLERANCE_RAD = math.radians(0.5)


# --------------------------------------------------------------------------------------------
# scaling
# --------------------------------------------------------------------------------------------
def wrap_int32(value: int) -> int:
    """Two's complement wrap into INTEGER32."""
    return ((value - INT32_MIN) % 2**32) + INT32_MIN


def saturate(value: int, low: int, high: int) -> int:
    return low if value < low else high if value > high else value


_LINEAR = AxisKind.LINEAR  # a global: reading an Enum member off its class is slow (3.11)


def load_units_per_unit(kind: AxisKind) -> float:
    """Integer units of 60E4h:01 / 2101h / 2104h per load unit: nm per m or µrad per rad."""
    return LOAD_INCREMENTS_PER_M if kind is _LINEAR else LOAD_INCREMENTS_PER_RAD


def motor_position_increments(theta_rad: float) -> int:
    """6064h from the motor angle (rad)."""
    return wrap_int32(round(theta_rad * INCREMENTS_PER_RAD))


def motor_speed_increments_s(omega_rad_s: float) -> int:
    """606Ch from the motor speed (rad/s)."""
    return saturate(round(omega_rad_s * INCREMENTS_PER_RAD), INT32_MIN, INT32_MAX)


def increments_to_rad(increments: float) -> float:
    """Motor rad (or rad/s, rad/s²) of encoder increments (per s, per s²): 60FFh, 6084h, 6085h."""
    return increments * RAD_PER_INCREMENT


def load_position_units(x_load: float, kind: AxisKind) -> int:
    """60E4h:01 from the load position (m or rad)."""
    return wrap_int32(round(x_load * load_units_per_unit(kind)))


def load_difference_units(difference: float, kind: AxisKind) -> int:
    """2104h from a load-side position difference (m or rad), saturated."""
    return saturate(round(difference * load_units_per_unit(kind)), INT32_MIN, INT32_MAX)


def torque_permille(torque_nm: float, rated_torque_mnm: int) -> int:
    """6077h from the motor torque (N·m): ‰ of the rated torque 6076h (mN·m)."""
    return saturate(
        round(torque_nm * MNM_PER_NM * PERMILLE / rated_torque_mnm), INT16_MIN, INT16_MAX
    )


def torque_limit_nm(max_torque_permille: int, rated_torque_mnm: int) -> float:
    """The torque limit (N·m) of 6072h (‰ of 6076h)."""
    return max_torque_permille * rated_torque_mnm / (MNM_PER_NM * PERMILLE)


def interpolation_period(cycle_s: float) -> tuple[int, int]:
    """60C2h (value 1..255, index -6..0) with value · 10^index = ``cycle_s``."""
    for index in range(0, -7, -1):
        value = cycle_s / 10.0**index
        if 1 <= round(value) <= 255 and math.isclose(value, round(value), rel_tol=1e-9):
            return round(value), index
    raise ValueError(
        f"position cycle {cycle_s} s is not value*10^index (value 1..255, index -6..0)"
    )


# --------------------------------------------------------------------------------------------
# the objects the drive implements (the EDS must declare exactly these)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ObjectSpec:
    """Data type (CiA 301 code) and access ("ro", "rw", "const") the drive expects."""

    data_type: int
    access: str


def _known_objects() -> dict[ObjectKey, ObjectSpec]:
    u8, u16, u32 = cod.UNSIGNED8, cod.UNSIGNED16, cod.UNSIGNED32
    i8, i16, i32 = cod.INTEGER8, cod.INTEGER16, cod.INTEGER32
    ro, rw, const = "ro", "rw", "const"
    spec = {
        DEVICE_TYPE: (u32, ro),
        ERROR_REGISTER: (u8, ro),
        COB_ID_SYNC: (u32, rw),
        (Cia301.MANUFACTURER_DEVICE_NAME, 0): (cod.VISIBLE_STRING, const),
        (HEARTBEAT_CONSUMER_INDEX, 0): (u8, const),
        HEARTBEAT_CONSUMER: (u32, rw),
        HEARTBEAT_TIME: (u16, rw),
        (Cia301.IDENTITY, 0): (u8, const),
        **{(Cia301.IDENTITY, s): (u32, ro) for s in range(1, 5)},
        (Cia301.SDO_SERVER_PARAMETER, 0): (u8, const),
        (Cia301.SDO_SERVER_PARAMETER, 1): (u32, const),
        (Cia301.SDO_SERVER_PARAMETER, 2): (u32, const),
        DISTURBANCE: (i32, rw),
        ENCODER_TOLERANCE: (u32, rw),
        SETPOINT_TIMEOUT: (u8, rw),
        SYNC_CYCLES: (u32, ro),
        LOAD_MINUS_MOTOR: (i32, ro),
        (FRAME_COUNTERS, 0): (u8, const),
        **{(FRAME_COUNTERS, s): (u32, ro) for s in range(1, 8)},
        ABORT_CONNECTION_OPTION: (i16, rw),
        ERROR_CODE: (u16, ro),
        CONTROLWORD: (u16, rw),
        STATUSWORD: (u16, ro),
        QUICK_STOP_OPTION: (i16, rw),
        FAULT_REACTION_OPTION: (i16, rw),
        MODES_OF_OPERATION: (i8, rw),
        MODES_OF_OPERATION_DISPLAY: (i8, ro),
        POSITION_ACTUAL: (i32, ro),
        VELOCITY_ACTUAL: (i32, ro),
        MAX_TORQUE: (u16, rw),
        RATED_TORQUE: (u32, ro),
        TORQUE_ACTUAL: (i16, ro),
        PROFILE_DECELERATION: (u32, rw),
        QUICK_STOP_DECELERATION: (u32, rw),
        (Cia402.INTERPOLATION_TIME_PERIOD, 0): (u8, const),
        INTERPOLATION_PERIOD_VALUE: (u8, ro),
        INTERPOLATION_PERIOD_INDEX: (i8, ro),
        (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0): (u8, const),
        LOAD_POSITION_ACTUAL: (i32, ro),
        TARGET_VELOCITY: (i32, rw),
        SUPPORTED_DRIVE_MODES: (u32, ro),
    }
    for n in range(PDO_CHANNELS):
        for comm in (RPDO_COMM, TPDO_COMM):
            spec[(comm + n, 0)] = (u8, const)
            spec[(comm + n, 1)] = (u32, rw)
            spec[(comm + n, 2)] = (u8, rw)
        for mapping in (RPDO_MAP, TPDO_MAP):
            spec[(mapping + n, 0)] = (u8, rw)
            for s in range(1, PDO_MAP_ENTRIES + 1):
                spec[(mapping + n, s)] = (u32, rw)
    return {key: ObjectSpec(*value) for key, value in spec.items()}


#: Every object of the drive with its data type and access.
KNOWN_OBJECTS: dict[ObjectKey, ObjectSpec] = _known_objects()

#: Default EDS of the drive.
DEFAULT_EDS_PATH = DRIVE_EDS


def iter_variables(od: ObjectDictionary) -> Iterator[ODVariable]:
    """Every variable (sub-objects of records and arrays included) of an object dictionary."""
    for index in od:
        obj = od[index]
        if isinstance(obj, ODVariable):
            yield obj
        else:
            for sub in obj:
                yield obj[sub]


def key_of(var: ODVariable) -> ObjectKey:
    return (var.index, var.subindex)


def load_drive_od(path: str | Path, node_id: int) -> ObjectDictionary:
    """Import the drive's EDS (``canopen.import_od``) and check that it declares exactly
    :data:`KNOWN_OBJECTS` with their data types and access, each with a default value.
    Raises :class:`DriveEdsError` naming the object."""
    path = Path(path)
    if not path.is_file():
        raise DriveEdsError(f"{path}: no such EDS file")
    try:
        od = canopen.import_od(str(path), node_id)
    except Exception as exc:  # the EDS parser raises many kinds
        raise DriveEdsError(f"{path}: cannot import EDS ({exc})") from exc
    seen: set[ObjectKey] = set()
    for var in iter_variables(od):
        key = key_of(var)
        where = f"{path.name}: {key[0]:04X}h:{key[1]:02X} ({var.name})"
        spec = KNOWN_OBJECTS.get(key)
        if spec is None:
            raise DriveEdsError(f"{where}: the drive does not implement this object", key=key)
        if var.data_type != spec.data_type or var.access_type != spec.access:
            raise DriveEdsError(
                f"{where}: data type 0x{var.data_type or 0:04X} access {var.access_type!r}; "
                f"the drive needs data type 0x{spec.data_type:04X} access {spec.access!r}",
                key=key,
            )
        if var.default is None:
            raise DriveEdsError(f"{where}: needs a DefaultValue", key=key)
        seen.add(key)
    missing = sorted(set(KNOWN_OBJECTS) - seen)
    if missing:
        names = ", ".join(f"{i:04X}h:{s:02X}" for i, s in missing[:8])
        raise DriveEdsError(f"{path.name}: missing objects {names}", key=missing[0])
    return od


# --------------------------------------------------------------------------------------------
# object access
# --------------------------------------------------------------------------------------------
ReadFn = Callable[[], int]
ValidateFn = Callable[[int], None]
ChangedFn = Callable[[int], None]


class ObjectTable:
    """Values of the integer objects and their access rules, served to canopen's LocalNode.

    Each object is either *stored* (a parameter, initialised from the EDS default or an
    override) or *live* (``read`` computes it, e.g. 6064h from the plant). A write runs the
    EDS range check (LowLimit/HighLimit, abort 0609 0031/0032), then ``validate`` (raises
    :class:`DriveSdoAbort`, nothing changes), stores the value, then ``changed``.
    """

    def __init__(self, od: ObjectDictionary) -> None:
        self.od = od
        self._vars: dict[ObjectKey, ODVariable] = {key_of(v): v for v in iter_variables(od)}
        self._values: dict[ObjectKey, int] = {}
        self._overrides: dict[ObjectKey, int] = {}
        self._readers: dict[ObjectKey, ReadFn] = {}
        self._validators: dict[ObjectKey, ValidateFn] = {}
        self._changed: dict[ObjectKey, ChangedFn] = {}
        #: the stored values by key, for reading them where every instruction counts (the
        #: per-SYNC code); written only through write/store/set_default/restore_defaults
        self.stored = self._values
        self.restore_defaults(0x0000, 0xFFFF)

    def variable(self, key: ObjectKey) -> ODVariable:
        return self._vars[key]

    def __contains__(self, key: object) -> bool:
        return key in self._vars

    def set_default(self, key: ObjectKey, value: int) -> None:
        """Override the EDS default of ``key`` (checked against the EDS limits) and store it."""
        self.check_range(key, value)
        self._overrides[key] = value
        self._values[key] = value

    def restore_defaults(self, first: int, last: int, keep: tuple[ObjectKey, ...] = ()) -> None:
        """Reset the stored integer objects with index in first..last to their defaults
        (without ``changed`` hooks; the caller re-applies what depends on them)."""
        for key, var in self._vars.items():
            if first <= key[0] <= last and key not in keep and isinstance(var.default, int):
                self._values[key] = self._overrides.get(key, var.default)

    def on(
        self,
        key: ObjectKey,
        *,
        read: ReadFn | None = None,
        validate: ValidateFn | None = None,
        changed: ChangedFn | None = None,
    ) -> None:
        """Attach the live getter and/or the write hooks of ``key``."""
        if key not in self._vars:
            raise DriveEdsError(f"{key[0]:04X}h:{key[1]:02X} is not in the object dictionary")
        if read is not None:
            self._readers[key] = read
        if validate is not None:
            self._validators[key] = validate
        if changed is not None:
            self._changed[key] = changed

    def value(self, key: ObjectKey) -> int:
        """Stored value of a parameter."""
        return self._values[key]

    def store(self, key: ObjectKey, value: int) -> None:
        """Store without checks or hooks (the drive's own bookkeeping)."""
        self._values[key] = value

    def read(self, key: ObjectKey) -> int:
        """Current value: live getter, else stored."""
        reader = self._readers.get(key)
        return reader() if reader is not None else self._values[key]

    def getter(self, key: ObjectKey) -> Callable[[], int]:
        """A function giving the current value of ``key`` like :meth:`read` (for the PDO
        engine's compiled mappings)."""
        reader = self._readers.get(key)
        if reader is not None:
            return reader
        values = self._values
        return lambda: values[key]

    def struct_format(self, key: ObjectKey) -> str | None:
        """The ``struct`` format of ``key``'s data type without byte order (e.g. ``"i"``),
        or None for types struct cannot hold (24-, 40-, 48-, 56-bit integers, strings)."""
        var = self._vars[key]
        packer = var.STRUCT_TYPES.get(var.data_type)
        if not isinstance(packer, struct.Struct):
            return None
        return packer.format.lstrip("<>=!@")

    def quiet(self, key: ObjectKey) -> bool:
        """Whether a write of ``key`` is a range check and a store and nothing else (no
        ``validate``, no ``changed`` hook)."""
        return key not in self._validators and key not in self._changed

    def limits(self, key: ObjectKey) -> tuple[int | None, int | None]:
        """The EDS limits :meth:`check_range` applies to ``key`` (None: none)."""
        var = self._vars[key]
        return var.min, var.max

    def changed_hook(self, key: ObjectKey) -> ChangedFn | None:
        """The ``changed`` hook of ``key`` (None: none)."""
        return self._changed.get(key)

    def check_range(self, key: ObjectKey, value: int) -> None:
        var = self._vars[key]
        if var.min is not None and value < var.min:
            raise DriveSdoAbort(
                SdoAbort.TOO_LOW, f"{value} is below the minimum {var.min} of {var.name}", key=key
            )
        if var.max is not None and value > var.max:
            raise DriveSdoAbort(
                SdoAbort.TOO_HIGH, f"{value} is above the maximum {var.max} of {var.name}", key=key
            )

    def write(self, key: ObjectKey, value: int) -> None:
        """Range check, validate, store, changed (raises DriveSdoAbort; then nothing changed)."""
        self.check_range(key, value)
        validate = self._validators.get(key)
        if validate is not None:
            validate(value)
        self._values[key] = value
        changed = self._changed.get(key)
        if changed is not None:
            changed(value)

    def encode(self, key: ObjectKey, value: int) -> bytes:
        return self._vars[key].encode_raw(value)

    def decode(self, key: ObjectKey, data: bytes) -> int:
        value = self._vars[key].decode_raw(bytes(data))
        assert isinstance(value, int)
        return value

    def bit_length(self, key: ObjectKey) -> int:
        return len(self._vars[key])

    # --- canopen LocalNode callbacks ---------------------------------------------------------
    def _key_for_sdo(self, index: int, subindex: int, od: ODVariable) -> ObjectKey:
        # LocalNode hands a plain variable to any sub-index, and canopen's ODArray makes up
        # members for sub-indices the EDS does not declare: only declared ones exist here.
        if (index, subindex) not in self._vars:
            raise SdoAbortedError(SdoAbort.NO_SUBINDEX)
        return (index, subindex)

    def sdo_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        """LocalNode read callback: the value, or None for the EDS default (strings)."""
        key = self._key_for_sdo(index, subindex, od)
        if key in self._readers or key in self._values:
            return self.read(key)
        return None

    def sdo_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        """LocalNode write callback (the length was checked by LocalNode)."""
        key = self._key_for_sdo(index, subindex, od)
        self.write(key, self.decode(key, data))

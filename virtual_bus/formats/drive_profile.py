"""Drive profiles: what the bridge needs to know about one drive model (``config/drives/``).

A profile is a small TOML file (format in docs/commissioning.md and the shipped examples).
Every key is optional; what a profile leaves out the start-up reads from the drive (1000h,
1018h, 6502h, 608Fh, 6091h, 6092h, 6076h, the PDO objects) or takes from the contract
(docs/canopen_layout.md). ``python -m bridge probe --out`` writes one from a connected drive.

:func:`load_profile` validates the file; a bad one raises :class:`DriveProfileError` (exit 2 in
the CLI) with one line naming the key, the value and what is allowed.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields
from enum import Enum
from pathlib import Path

from virtual_bus.contract import COMMUNICATION_AREA

from .errors import DriveProfileError

ObjectKey = tuple[int, int]


class ModeChoice(Enum):
    """Velocity mode to run the drive in (6060h)."""

    AUTO = "auto"  # cyclic synchronous velocity when 6502h lists it, else profile velocity
    CSV = "csv"  # 6060h = 9
    PV = "pv"  # 6060h = 3, ramps 6083h/6084h opened


class LoadSource(Enum):
    """Where the load position (the paper's direct measuring system) comes from."""

    AUTO = "auto"  # 60E4h:01, else 60E4h:00 (a plain variable), else motor
    ADDITIONAL_SUB1 = "60E4h:01"  # CiA 402 additional position actual value, first entry
    ADDITIONAL_VAR = "60E4h:00"  # a drive that has 60E4h as a plain variable
    VENDOR = "vendor"  # a manufacturer object (load_object)
    ENCODER = "encoder"  # a CiA 406 encoder node on the bus (6004h in its TPDO1, on SYNC)
    MOTOR = "motor"  # no load measuring system: position feedback = motor encoder


#: data types a mapped object may have: name -> (bits, signed)
OBJECT_TYPES = {
    "i8": (8, True),
    "u8": (8, False),
    "i16": (16, True),
    "u16": (16, False),
    "i32": (32, True),
    "u32": (32, False),
}


def parse_key(text: object, where: str = "object") -> ObjectKey:
    """``"60E4h:01"`` / ``"60E4:1"`` / ``"0x60E4:01"`` -> (0x60E4, 1)."""
    if not isinstance(text, str):
        raise ValueError(f'{where} = {text!r}: write an object as "IIIIh:SS" (hex)')
    body = text.strip().lower().removeprefix("0x")
    index, _, sub = body.partition(":")
    index = index.removesuffix("h")
    sub = sub.removesuffix("h") or "0"
    try:
        key = (int(index, 16), int(sub, 16))
    except ValueError:
        raise ValueError(f'{where} = {text!r}: write an object as "IIIIh:SS" (hex)') from None
    if not (COMMUNICATION_AREA.start <= key[0] <= 0xFFFF and 0 <= key[1] <= 0xFE):
        raise ValueError(f"{where} = {text!r}: index 1000h..FFFFh, sub-index 00h..FEh")
    return key


def format_key(key: ObjectKey) -> str:
    return f"{key[0]:04X}h:{key[1]:02X}"


@dataclass(frozen=True)
class DriveProfile:
    """One drive model; ``None`` means "read it from the drive" (or the contract's default).

    name: free text. vendor_id / product_code: 1018h:01 / :02 the drive must report (None:
    not checked). mode: :class:`ModeChoice`. ramp: 6083h/6084h value written in profile
    velocity mode (drive units; None: 4294967295, the UNSIGNED32 maximum).
    tpdos: drive TPDO numbers (1..512) the bridge may use, in order; rpdo: the RPDO number.
    tpdo_cob_ids / rpdo_cob_id: COB-IDs (None: CiA 301 pre-defined connection set).
    max_entries: mapping entries per PDO (1..64); transmission_type: of the TPDOs (1..240,
    every n-th SYNC -- the bridge needs 1). mappable: objects the drive can map (from its
    EDS or ``probe``), None: unknown, the start-up tries and re-plans on 0604 0041.
    load_source / load_object / load_object_type / encoder_id: :class:`LoadSource`.
    load_increments_per_unit: load-position increments per m (linear) or rad (rotary); None:
    the contract's nm / µrad. position_increments_per_rev: 6064h units per motor revolution
    (None: 608Fh/6091h/6092h of the drive). velocity_units_per_rev_s: 606Ch/60FFh units per
    motor revolution per second (None: position units per s). rated_torque_mnm: 6076h in
    mN·m (None: read 6076h; 0: torque shown in per mille of the rated torque).

    How the drive supervises the bridge (``bridge.supervision``; CiA 301 1016h, CiA 402
    6007h): heartbeat_consumer_entries: the number of 1016h entries (None: read 1016h:00; 0:
    the drive has no heartbeat consumer). abort_connection_option: the 6007h value written
    (None: 3, quick stop, where the drive has 6007h). setpoint_timeout_object /
    setpoint_timeout / setpoint_timeout_type: a manufacturer set-point watchdog and the
    value written to it (None: none; the contract's drive has 2102h, SYNCs without an RPDO).
    """

    name: str = "adaptive"
    vendor_id: int | None = None
    product_code: int | None = None
    mode: ModeChoice = ModeChoice.AUTO
    ramp: int | None = None
    tpdos: tuple[int, ...] = (1, 2, 3, 4)
    rpdo: int = 1
    tpdo_cob_ids: tuple[int, ...] | None = None
    rpdo_cob_id: int | None = None
    max_entries: int = 8
    transmission_type: int = 1
    mappable: frozenset[ObjectKey] | None = None
    load_source: LoadSource = LoadSource.AUTO
    load_object: ObjectKey | None = None
    load_object_type: str = "i32"
    encoder_id: int | None = None
    load_increments_per_unit: float | None = None
    position_increments_per_rev: float | None = None
    velocity_units_per_rev_s: float | None = None
    rated_torque_mnm: int | None = None
    heartbeat_consumer_entries: int | None = None
    abort_connection_option: int | None = None
    setpoint_timeout_object: ObjectKey | None = None
    setpoint_timeout: int = 3
    setpoint_timeout_type: str = "u8"

    def __post_init__(self) -> None:
        def bad(key: str, allowed: str) -> DriveProfileError:
            return DriveProfileError(f"{key} = {getattr(self, key)!r}: {allowed}", key=key)

        def is_int(v: object) -> bool:
            return isinstance(v, int) and not isinstance(v, bool)

        if not isinstance(self.name, str) or not self.name:
            raise bad("name", "a non-empty string")
        for key in ("vendor_id", "product_code"):
            v = getattr(self, key)
            if v is not None and not (is_int(v) and 0 <= v <= 0xFFFF_FFFF):
                raise bad(key, "an UNSIGNED32 (0..0xFFFFFFFF)")
        if not isinstance(self.mode, ModeChoice):
            raise bad("mode", f"one of {[m.value for m in ModeChoice]}")
        if self.ramp is not None and not (is_int(self.ramp) and 1 <= self.ramp <= 0xFFFF_FFFF):
            raise bad("ramp", "an integer 1..4294967295 (6083h/6084h, drive units)")
        if not (
            isinstance(self.tpdos, tuple)
            and self.tpdos
            and all(is_int(n) and 1 <= n <= 512 for n in self.tpdos)
            and len(set(self.tpdos)) == len(self.tpdos)
        ):
            raise bad("tpdos", "a list of distinct TPDO numbers 1..512")
        if not (is_int(self.rpdo) and 1 <= self.rpdo <= 512):
            raise bad("rpdo", "an RPDO number 1..512")
        if self.tpdo_cob_ids is not None and not (
            isinstance(self.tpdo_cob_ids, tuple)
            and len(self.tpdo_cob_ids) == len(self.tpdos)
            and all(is_int(c) and 0x181 <= c <= 0x57F for c in self.tpdo_cob_ids)
        ):
            raise bad("tpdo_cob_ids", "one 11-bit COB-ID 0x181..0x57F per entry of tpdos")
        if self.rpdo_cob_id is not None and not (
            is_int(self.rpdo_cob_id) and 0x181 <= self.rpdo_cob_id <= 0x57F
        ):
            raise bad("rpdo_cob_id", "an 11-bit COB-ID 0x181..0x57F")
        if not (is_int(self.max_entries) and 1 <= self.max_entries <= 64):
            raise bad("max_entries", "an integer 1..64")
        if not (is_int(self.transmission_type) and 1 <= self.transmission_type <= 240):
            raise bad("transmission_type", "1..240 (synchronous; the bridge needs every SYNC: 1)")
        if not isinstance(self.load_source, LoadSource):
            raise bad("load_source", f"one of {[s.value for s in LoadSource]}")
        if (self.load_source is LoadSource.VENDOR) != (self.load_object is not None):
            raise bad("load_object", 'required with load_source = "vendor" and only then')
        if not isinstance(self.load_object_type, str) or self.load_object_type not in OBJECT_TYPES:
            raise bad("load_object_type", f"one of {sorted(OBJECT_TYPES)}")
        enc = self.encoder_id
        if (self.load_source is LoadSource.ENCODER) != (enc is not None):
            raise bad("encoder_id", 'required with load_source = "encoder" and only then')
        if enc is not None and not (is_int(enc) and 1 <= enc <= 127):
            raise bad("encoder_id", "a CANopen node-ID 1..127")
        for key in (
            "load_increments_per_unit",
            "position_increments_per_rev",
            "velocity_units_per_rev_s",
        ):
            v = getattr(self, key)
            if v is not None and not (
                isinstance(v, int | float)
                and not isinstance(v, bool)
                and math.isfinite(v)
                and v > 0
            ):
                raise bad(key, "a finite number > 0")
        r = self.rated_torque_mnm
        if r is not None and not (is_int(r) and 0 <= r <= 0xFFFF_FFFF):
            raise bad("rated_torque_mnm", "an UNSIGNED32 in mN·m (0: torque in per mille)")
        n = self.heartbeat_consumer_entries
        if n is not None and not (is_int(n) and 0 <= n <= 127):
            raise bad("heartbeat_consumer_entries", "1016h entries 0..127 (0: no consumer)")
        a = self.abort_connection_option
        if a is not None and not (is_int(a) and -32768 <= a <= 32767):
            raise bad(
                "abort_connection_option",
                "a 6007h value, INTEGER16 (0 none, 1 fault, 2 disable voltage, 3 quick stop; "
                "negative: the manufacturer's)",
            )
        if (
            not isinstance(self.setpoint_timeout_type, str)
            or self.setpoint_timeout_type not in OBJECT_TYPES
        ):
            raise bad("setpoint_timeout_type", f"one of {sorted(OBJECT_TYPES)}")
        bits, signed = OBJECT_TYPES[self.setpoint_timeout_type]
        top = (1 << (bits - 1 if signed else bits)) - 1
        t = self.setpoint_timeout
        if not (is_int(t) and 0 <= t <= top):
            raise bad("setpoint_timeout", f"an integer 0..{top} ({self.setpoint_timeout_type})")

    def may_map(self, key: ObjectKey) -> bool:
        """The profile does not rule out mapping ``key``."""
        return self.mappable is None or key in self.mappable


# --- TOML ---------------------------------------------------------------------------------------
#: TOML table.key -> field name (the file groups the fields; docs/commissioning.md).
_LAYOUT: dict[str, tuple[str, ...]] = {
    "drive": ("name", "vendor_id", "product_code"),
    "mode": ("mode", "ramp"),
    "pdo": (
        "tpdos",
        "rpdo",
        "tpdo_cob_ids",
        "rpdo_cob_id",
        "max_entries",
        "transmission_type",
        "mappable",
    ),
    "load": (
        "load_source",
        "load_object",
        "load_object_type",
        "encoder_id",
        "load_increments_per_unit",
    ),
    "scaling": ("position_increments_per_rev", "velocity_units_per_rev_s", "rated_torque_mnm"),
    "supervision": (
        "heartbeat_consumer_entries",
        "abort_connection_option",
        "setpoint_timeout_object",
        "setpoint_timeout",
        "setpoint_timeout_type",
    ),
}
_TOML_NAME = {"load_source": "source", "load_object": "object", "load_object_type": "object_type"}
_TOML_NAME |= {"load_increments_per_unit": "increments_per_unit"}


def _convert(name: str, value: object, where: str) -> object:
    """A TOML value to the field's type (ValueError with the message on failure)."""
    if name == "mode":
        try:
            return ModeChoice(value)
        except ValueError:
            raise ValueError(
                f"{where} = {value!r}: allowed {[m.value for m in ModeChoice]}"
            ) from None
    if name == "load_source":
        try:
            return LoadSource(value)
        except ValueError:
            raise ValueError(
                f"{where} = {value!r}: allowed {[s.value for s in LoadSource]}"
            ) from None
    if name in ("load_object", "setpoint_timeout_object"):
        return parse_key(value, where)
    if name == "mappable":
        if not isinstance(value, list):
            raise ValueError(f'{where} = {value!r}: a list of objects "IIIIh:SS"')
        return frozenset(parse_key(v, where) for v in value)
    if name in ("tpdos", "tpdo_cob_ids"):
        if not isinstance(value, list):
            raise ValueError(f"{where} = {value!r}: a list of integers")
        return tuple(value)
    return value


def load_profile(path: str | Path) -> DriveProfile:
    """Read and validate a drive profile (:class:`DriveProfileError`, one line, on any fault)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark is no key
    except OSError as exc:
        raise DriveProfileError(f"{path}: cannot read ({exc.strerror})", path=str(path)) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DriveProfileError(f"{path}: not valid TOML ({exc})", path=str(path)) from None
    values: dict[str, object] = {}
    for table, body in data.items():
        names = _LAYOUT.get(table)
        if names is None or not isinstance(body, dict):
            raise DriveProfileError(
                f"{path}: [{table}]: unknown table; allowed {sorted(_LAYOUT)}",
                path=str(path),
                key=table,
            )
        by_toml = {_TOML_NAME.get(n, n): n for n in names}
        for key, value in body.items():
            where = f"{table}.{key}"
            name = by_toml.get(key)
            if name is None:
                raise DriveProfileError(
                    f"{path}: {where}: unknown key; allowed {sorted(by_toml)}",
                    path=str(path),
                    key=where,
                )
            try:
                values[name] = _convert(name, value, where)
            except ValueError as exc:
                raise DriveProfileError(f"{path}: {exc}", path=str(path), key=where) from None
    try:
        return DriveProfile(**values)  # type: ignore[arg-type]
    except DriveProfileError as exc:
        table = next(t for t, names in _LAYOUT.items() if exc.key in names)
        key = f"{table}.{_TOML_NAME.get(exc.key, exc.key)}"
        raise DriveProfileError(f"{path}: {key}: {exc}", path=str(path), key=key) from None


def _toml_value(name: str, value: object) -> str:
    if isinstance(value, Enum):
        return f'"{value.value}"'
    if name in ("load_object", "setpoint_timeout_object"):
        return f'"{format_key(value)}"'  # type: ignore[arg-type]
    if name == "mappable":
        keys = [f'"{format_key(k)}"' for k in sorted(value)]  # type: ignore[call-overload]
        rows = [", ".join(keys[i : i + 6]) for i in range(0, len(keys), 6)]
        return "[\n" + "".join(f"    {row},\n" for row in rows) + "]"
    if name in ("vendor_id", "product_code", "rpdo_cob_id"):
        return f"0x{value:08X}" if name != "rpdo_cob_id" else f"0x{value:03X}"
    if name == "tpdo_cob_ids":
        return "[" + ", ".join(f"0x{c:03X}" for c in value) + "]"  # type: ignore[attr-defined]
    if isinstance(value, tuple):
        return "[" + ", ".join(str(v) for v in value) + "]"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return repr(value)


def render_profile(profile: DriveProfile, comments: tuple[str, ...] = ()) -> str:
    """The TOML text of ``profile`` (keys left at None are omitted); :func:`load_profile`
    reads it back to an equal profile."""
    lines = [f"# {c}" if c else "#" for c in comments]
    defaults = DriveProfile()
    given = {f.name: getattr(profile, f.name) for f in fields(profile)}
    for table, names in _LAYOUT.items():
        body = [
            f"{_TOML_NAME.get(n, n)} = {_toml_value(n, given[n])}"
            for n in names
            if given[n] is not None and (n == "name" or given[n] != getattr(defaults, n))
        ]
        if body:
            lines += ["", f"[{table}]", *body]
    return "\n".join(lines).lstrip("\n") + "\n"

"""Objects of a node's EDS by name or index, their values as text, and SDO access to them.

Object references (:func:`resolve`): ``2001h``, ``0x2001``, ``2001:0``, ``0x2001:00``,
``2001sub0``, ``1016h:01``, or the ParameterName of the EDS (``"Regulator enable"``, a
sub-object's own name such as ``"Max position limit"`` when it is unique, ``"Group name:1"``
or python-canopen's ``"Group name.Member name"``), case-insensitive. An ARRAY or RECORD
without a sub-index means all of its sub-objects (``get``) -- a write needs one.

Values (:func:`parse_value`, :func:`format_value`) follow the CiA 301 data type of the EDS:
integers in decimal or 0x-hex, checked against the type's range and the EDS
LowLimit/HighLimit; BOOLEAN ``0/1/true/false/on/off``; REAL32/REAL64 finite decimals (REAL32
within +-3.4e38, shown with the shortest text that reads back to the same 32 bits);
VISIBLE_STRING as text; OCTET_STRING/DOMAIN as hex. UNSIGNED32 also takes the CiA 301
signatures ``save`` / ``load`` (for 1010h / 1011h). The EDS ``Unit`` is shown with values.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Iterator
from dataclasses import dataclass

import canopen
import numpy as np
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.objectdictionary import datatypes as dt
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ..errors import CommissionInputError, NodeAccessError

_REF = re.compile(
    r"^(?:0x)?([0-9a-f]{1,4})h?(?:(?::|sub)(?:0x)?([0-9a-f]{1,2})h?)?$", re.IGNORECASE
)
_NAME_SUB = re.compile(r"^(.*\S)\s*:\s*(?:0x)?([0-9a-f]{1,2})h?$", re.IGNORECASE)

TYPE_NAMES = {
    dt.BOOLEAN: "BOOLEAN",
    dt.INTEGER8: "INTEGER8",
    dt.INTEGER16: "INTEGER16",
    dt.INTEGER32: "INTEGER32",
    dt.INTEGER64: "INTEGER64",
    dt.UNSIGNED8: "UNSIGNED8",
    dt.UNSIGNED16: "UNSIGNED16",
    dt.UNSIGNED32: "UNSIGNED32",
    dt.UNSIGNED64: "UNSIGNED64",
    dt.REAL32: "REAL32",
    dt.REAL64: "REAL64",
    dt.VISIBLE_STRING: "VISIBLE_STRING",
    dt.OCTET_STRING: "OCTET_STRING",
    dt.DOMAIN: "DOMAIN",
}
_INT_BITS = {
    dt.INTEGER8: 8,
    dt.INTEGER16: 16,
    dt.INTEGER24: 24,
    dt.INTEGER32: 32,
    dt.INTEGER64: 64,
    dt.UNSIGNED8: 8,
    dt.UNSIGNED16: 16,
    dt.UNSIGNED24: 24,
    dt.UNSIGNED32: 32,
    dt.UNSIGNED64: 64,
}
#: CiA 301 signatures written to 1010h ("save") and 1011h ("load"), ISO 8859, LSB first.
SIGNATURES = {"save": 0x6576_6173, "load": 0x6461_6F6C}
REAL32_MAX = 3.4028234663852886e38

Value = int | float | bool | str | bytes


def key_text(var: ODVariable) -> str:
    return f"{var.index:04X}h:{var.subindex:02X}"


def type_name(var: ODVariable) -> str:
    return TYPE_NAMES.get(var.data_type, f"type 0x{var.data_type:04X}")


def variables(od: canopen.ObjectDictionary) -> Iterator[ODVariable]:
    """Every variable of ``od`` (sub-objects of arrays and records too), by index."""
    for index in sorted(od.indices):
        obj = od[index]
        if isinstance(obj, ODVariable):
            yield obj
        else:
            for sub in sorted(obj.subindices):
                yield obj[sub]


def _members(obj: ODArray | ODRecord) -> list[ODVariable]:
    return [obj[sub] for sub in sorted(obj.subindices)]


def _sub_of(obj: ODArray | ODRecord, subindex: int, text: str) -> ODVariable:
    if subindex not in obj.subindices:
        subs = ", ".join(f"{s:02X}" for s in sorted(obj.subindices))
        raise CommissionInputError(
            f"object {text!r}: {obj.index:04X}h ({obj.name}) has no sub-index "
            f"{subindex:02X}; it has {subs}"
        )
    return obj[subindex]


def resolve(od: canopen.ObjectDictionary, text: str) -> list[ODVariable]:
    """The variable(s) ``text`` names (module docstring); CommissionInputError if none."""
    wanted = text.strip().casefold()
    by_name = [v for v in variables(od) if v.name.casefold() == wanted]
    groups = [od[i] for i in od.indices if od[i].name.casefold() == wanted]
    if groups:
        obj = groups[0]
        return _members(obj) if not isinstance(obj, ODVariable) else [obj]
    if len(by_name) == 1:
        return by_name
    if len(by_name) > 1:
        where = ", ".join(key_text(v) for v in by_name)
        raise CommissionInputError(f"object {text!r} is ambiguous ({where}); give the index")
    group_name, dot, sub_name = text.strip().partition(".")
    if dot:  # python-canopen's "Group.Member" form
        for index in od.indices:
            obj = od[index]
            if obj.name.casefold() == group_name.strip().casefold() and not isinstance(
                obj, ODVariable
            ):
                for member in _members(obj):
                    if member.name.casefold() == sub_name.strip().casefold():
                        return [member]
    named_sub = _NAME_SUB.match(text.strip())
    if named_sub is not None:
        name = named_sub[1].casefold()
        for index in od.indices:
            obj = od[index]
            if obj.name.casefold() == name and not isinstance(obj, ODVariable):
                return [_sub_of(obj, int(named_sub[2], 16), text)]
    match = _REF.match(text.strip())
    if match is None:
        raise CommissionInputError(
            f"object {text!r}: not a name of this EDS nor an index like 2001h, 0x2001:00, 2001sub0"
        )
    index = int(match[1], 16)
    if index not in od.indices:
        raise CommissionInputError(f"object {text!r}: {index:04X}h is not in this node's EDS")
    obj = od[index]
    if match[2] is None:
        return [obj] if isinstance(obj, ODVariable) else _members(obj)
    subindex = int(match[2], 16)
    if isinstance(obj, ODVariable):
        if subindex:
            raise CommissionInputError(
                f"object {text!r}: {index:04X}h ({obj.name}) is a VAR, only sub-index 00"
            )
        return [obj]
    return [_sub_of(obj, subindex, text)]


def resolve_one(od: canopen.ObjectDictionary, text: str) -> ODVariable:
    """One variable (for writes): an ARRAY/RECORD needs its sub-index."""
    found = resolve(od, text)
    if len(found) != 1:
        obj = od[found[0].index]
        subs = ", ".join(f"{v.subindex:02X} {v.name}" for v in found)
        raise CommissionInputError(
            f"object {text!r}: {obj.index:04X}h ({obj.name}) has sub-indices ({subs}); "
            f"give one, e.g. {obj.index:04X}h:{found[-1].subindex:02X}"
        )
    return found[0]


# --- values ---------------------------------------------------------------------------------
def _int_range(var: ODVariable) -> tuple[int, int]:
    bits = _INT_BITS[var.data_type]
    if var.data_type in dt.SIGNED_TYPES:
        low, high = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    else:
        low, high = 0, (1 << bits) - 1
    if var.min is not None:
        low = max(low, var.min)
    if var.max is not None:
        high = min(high, var.max)
    return low, high


def _unit(var: ODVariable) -> str:
    return f" {var.unit}" if getattr(var, "unit", "") else ""


def parse_value(var: ODVariable, text: str, node_id: int | None = None) -> Value:
    """``text`` as a value of ``var``'s data type (module docstring); CommissionInputError
    naming the object, the text and what is allowed. ``$NODEID+x`` needs ``node_id``."""
    where = f"{key_text(var)} {var.name} ({type_name(var)})"
    raw = text.strip()
    t = var.data_type
    if t == dt.BOOLEAN:
        word = raw.casefold()
        if word in ("1", "true", "on", "yes"):
            return True
        if word in ("0", "false", "off", "no"):
            return False
        raise CommissionInputError(f"{where}: {text!r} is not a boolean; allowed 0/1/true/false")
    if t in _INT_BITS:
        compact = raw.replace(" ", "")
        if t == dt.UNSIGNED32 and compact.casefold() in SIGNATURES:
            return SIGNATURES[compact.casefold()]
        offset = 0
        if "$NODEID" in compact.upper():
            if node_id is None:
                raise CommissionInputError(f"{where}: {text!r} needs a node-ID")
            offset = node_id
            compact = re.sub(r"\+?\$NODEID\+?", "", compact, flags=re.IGNORECASE) or "0"
        try:
            value = int(compact, 0) + offset
        except ValueError:
            raise CommissionInputError(
                f"{where}: {text!r} is not an integer (decimal or 0x-hex)"
            ) from None
        low, high = _int_range(var)
        if not low <= value <= high:
            raise CommissionInputError(
                f"{where}: {value} is out of range; allowed {low}..{high}{_unit(var)}"
            )
        return value
    if t in dt.FLOAT_TYPES:
        try:
            value_f = float(raw)
        except ValueError:
            raise CommissionInputError(f"{where}: {text!r} is not a number") from None
        if not math.isfinite(value_f):
            raise CommissionInputError(f"{where}: {text!r}: must be a finite number")
        if t == dt.REAL32 and abs(value_f) > REAL32_MAX:
            raise CommissionInputError(
                f"{where}: {text!r} does not fit a REAL32 (|x| <= {REAL32_MAX:.7g})"
            )
        return value_f
    if t in (dt.VISIBLE_STRING, dt.UNICODE_STRING):
        if t == dt.VISIBLE_STRING and not raw.isascii():
            raise CommissionInputError(f"{where}: {text!r}: VISIBLE_STRING is ASCII only")
        return text
    if t in (dt.OCTET_STRING, dt.DOMAIN):
        try:
            return bytes.fromhex(raw)
        except ValueError:
            raise CommissionInputError(f"{where}: {text!r} is not hex bytes") from None
    raise CommissionInputError(f"{where}: data type 0x{t:04X} is not supported")


def encode(var: ODVariable, value: Value) -> bytes:
    """The SDO bytes of ``value`` (already parsed for ``var``)."""
    if var.data_type == dt.BOOLEAN:
        return b"\x01" if value else b"\x00"
    if var.data_type == dt.REAL32:
        return struct.pack("<f", value)
    return var.encode_raw(value)


def decode(var: ODVariable, data: bytes) -> Value:
    """The value of SDO bytes ``data`` of ``var`` (CommissionInputError if the length is
    wrong for the data type)."""
    try:
        if var.data_type == dt.BOOLEAN:
            if len(data) != 1:
                raise ValueError(f"{len(data)} bytes")
            return bool(data[0])
        return var.decode_raw(bytes(data))
    except (ValueError, struct.error) as exc:
        raise CommissionInputError(
            f"{key_text(var)} {var.name}: {bytes(data).hex()} is not a {type_name(var)} ({exc})"
        ) from None


def value_text(var: ODVariable, value: Value) -> str:
    """``value`` as it is written in a DCF and read back by :func:`parse_value`."""
    t = var.data_type
    if t == dt.BOOLEAN:
        return "1" if value else "0"
    if t == dt.REAL32:
        return str(np.float32(value))  # shortest text with the same 32 bits
    if t in dt.FLOAT_TYPES:
        return repr(float(value))
    if t in dt.UNSIGNED_TYPES:
        return f"0x{int(value):0{_INT_BITS.get(t, 32) // 4}X}"
    if isinstance(value, bytes):
        return value.hex()
    return str(value)


def _shown(var: ODVariable, value: Value) -> str:
    text = value_text(var, value)
    if var.data_type in dt.UNSIGNED_TYPES:
        text = f"{int(value)} ({text})"
    elif var.data_type in (dt.VISIBLE_STRING, dt.UNICODE_STRING):
        text = repr(value)
    return f"{text}{_unit(var)}"


def display(var: ODVariable, value: Value) -> str:
    """One line: ``2000h:00 Position gain kv = 25 1/s``; unsigned integers also in decimal."""
    return f"{key_text(var)} {var.name} = {_shown(var, value)}"


def display_change(var: ODVariable, before: Value, after: Value) -> str:
    """:func:`display` of ``after`` and what it replaced, both with the unit:
    ``2014h:02 Max position limit = 0.35 load unit (was 2.0 load unit)``."""
    return f"{display(var, after)} (was {_shown(var, before)})"


# --- SDO --------------------------------------------------------------------------------------
ABORT_TEXT = {code: text for code, text in SdoAbortedError.CODES.items()}


def abort_text(code: int) -> str:
    return f"SDO abort 0x{code:08X} ({ABORT_TEXT.get(code, 'unknown code').lower()})"


@dataclass
class SdoAccess:
    """Reads and writes of ``node`` (a canopen RemoteNode with the node's EDS), as values;
    refusals and silence become :class:`NodeAccessError`."""

    node: canopen.RemoteNode

    def _fail(self, var: ODVariable, verb: str, exc: Exception) -> NodeAccessError:
        where = f"node {self.node.id} {key_text(var)} {var.name}"
        if isinstance(exc, SdoAbortedError):
            return NodeAccessError(
                f"{where}: {verb} refused, {abort_text(exc.code)}",
                index=var.index,
                subindex=var.subindex,
                abort_code=exc.code,
            )
        timeout = self.node.sdo.RESPONSE_TIMEOUT
        return NodeAccessError(
            f"{where}: no SDO answer to the {verb} within {timeout:g} s (node silent?)",
            index=var.index,
            subindex=var.subindex,
        )

    def read_raw(self, var: ODVariable) -> bytes:
        try:
            return self.node.sdo.upload(var.index, var.subindex)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise self._fail(var, "read", exc) from None

    def read(self, var: ODVariable) -> Value:
        return decode(var, self.read_raw(var))

    def write(self, var: ODVariable, value: Value) -> None:
        try:
            self.node.sdo.download(var.index, var.subindex, encode(var, value))
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise self._fail(var, "write", exc) from None

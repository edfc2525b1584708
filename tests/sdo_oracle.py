"""What CiA 301 says an SDO server must answer, derived from an EDS file alone.

Written independently of the servers (virtual_bus.sdo_server, bridge.objects,
plant_sim.drive.od): the EDS is read with :mod:`configparser` (not canopen), the data type
sizes come from CiA 301 table 44 written out here, and the order of the checks is the one of
CiA 301 7.2.4 / CANopenNode: object, sub-index, access, length, value against the EDS limits
(REAL32 too, NaN outside every range), then the application. :func:`expected` returns the
abort code a write must get, or :data:`APPLICATION` when only the device's own rules decide
(success or a value/state code); ``tests/peers/eds_predict.py`` decides those from the rules
the EDS Descriptions state.
"""

from __future__ import annotations

import configparser
import math
import re
import struct
from dataclasses import dataclass
from pathlib import Path

NO_OBJECT = 0x0602_0000
NO_SUBINDEX = 0x0609_0011
READ_ONLY = 0x0601_0002
WRITE_ONLY = 0x0601_0001
LENGTH_TOO_HIGH = 0x0607_0012
LENGTH_TOO_LOW = 0x0607_0013
VALUE_RANGE = 0x0609_0030
TOO_HIGH = 0x0609_0031
TOO_LOW = 0x0609_0032
NOT_MAPPABLE = 0x0604_0041
PDO_LENGTH = 0x0604_0042
DEVICE_STATE = 0x0800_0022
#: Codes the device's own rules may answer a well-formed write in range with.
APPLICATION_CODES = frozenset(
    {VALUE_RANGE, TOO_HIGH, TOO_LOW, DEVICE_STATE, NOT_MAPPABLE, PDO_LENGTH, NO_OBJECT}
    # 1010h/1011h: a wrong signature, or no store (CiA 301: "data cannot be transferred or
    # stored"), and a store file that cannot be written ("hardware error")
    | {0x0800_0020, 0x0606_0000}
)
#: Marker: success or one of APPLICATION_CODES.
APPLICATION = -1

# CiA 301 table 44: data type -> (bytes, struct format; lower case: signed)
TYPES: dict[int, tuple[int, str]] = {
    0x01: (1, "B"),  # BOOLEAN
    0x02: (1, "b"),  # INTEGER8
    0x03: (2, "h"),  # INTEGER16
    0x04: (4, "i"),  # INTEGER32
    0x05: (1, "B"),  # UNSIGNED8
    0x06: (2, "H"),  # UNSIGNED16
    0x07: (4, "I"),  # UNSIGNED32
    0x08: (4, "f"),  # REAL32
    0x11: (8, "d"),  # REAL64
    0x15: (8, "q"),  # INTEGER64
    0x1B: (8, "Q"),  # UNSIGNED64
}
BOOLEAN, REAL32, VISIBLE_STRING, REAL64 = 0x01, 0x08, 0x09, 0x11
WRITABLE = frozenset({"rw", "wo", "rww", "rwr"})
READABLE = frozenset({"ro", "rw", "const", "rww", "rwr"})

_SECTION = re.compile(r"([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]{1,2}))?")


@dataclass(frozen=True)
class Declared:
    """One sub-object as the EDS declares it."""

    index: int
    sub: int
    data_type: int
    access: str
    low: int | float | None
    high: int | float | None
    pdo_mapping: bool
    description: str

    @property
    def size(self) -> int | None:
        entry = TYPES.get(self.data_type)
        return None if entry is None else entry[0]

    def decode(self, data: bytes) -> int | float:
        return struct.unpack("<" + TYPES[self.data_type][1], data)[0]

    def encode(self, value: int | float) -> bytes:
        return struct.pack("<" + TYPES[self.data_type][1], value)


def _number(text: str, data_type: int, node_id: int) -> int | float:
    text = text.strip()
    if data_type in (REAL32, REAL64):
        return float(text)
    total = 0
    for term in text.upper().replace("$NODEID", str(node_id)).split("+"):
        term = term.strip()
        total += int(term, 16) if term.startswith("0X") else int(term)
    size = TYPES[data_type][0] * 8
    signed = TYPES[data_type][1].islower() and data_type != BOOLEAN
    if signed and total >= 1 << (size - 1):  # a signed limit written as hex
        total -= 1 << size
    return total


def read_eds(path: Path, node_id: int) -> dict[tuple[int, int], Declared]:
    """Every VAR and sub-object of an EDS, keyed (index, sub-index)."""
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read(path, encoding="utf-8")
    out: dict[tuple[int, int], Declared] = {}
    for section in parser.sections():
        m = _SECTION.fullmatch(section)
        if not m:
            continue
        s = parser[section]
        if int(s.get("ObjectType", "0x7"), 0) != 7:
            continue
        index, sub = int(m.group(1), 16), int(m.group(2) or "0", 16)
        data_type = int(s["DataType"], 0)
        low, high = s.get("LowLimit", ""), s.get("HighLimit", "")
        out[(index, sub)] = Declared(
            index,
            sub,
            data_type,
            s["AccessType"].strip().lower(),
            _number(low, data_type, node_id) if low.strip() else None,
            _number(high, data_type, node_id) if high.strip() else None,
            s.get("PDOMapping", "0").strip() not in ("", "0"),
            s.get("Description", ""),
        )
    return out


def expected(od: dict[tuple[int, int], Declared], index: int, sub: int, data: bytes) -> int:
    """The abort code a download of ``data`` to index:sub must get, or APPLICATION."""
    if not any(i == index for i, _ in od):
        return NO_OBJECT
    obj = od.get((index, sub))
    if obj is None:
        return NO_SUBINDEX
    if obj.access not in WRITABLE:
        return READ_ONLY
    size = obj.size
    if size is None:  # strings, domains: any length
        return APPLICATION
    if len(data) > size:
        return LENGTH_TOO_HIGH
    if len(data) < size:
        return LENGTH_TOO_LOW
    value = obj.decode(data)
    if obj.data_type == BOOLEAN and value not in (0, 1):
        return VALUE_RANGE
    if isinstance(value, float) and math.isnan(value):
        if obj.low is not None or obj.high is not None:
            return VALUE_RANGE  # NaN is in no range
    else:
        if obj.low is not None and value < obj.low:
            return TOO_LOW
        if obj.high is not None and value > obj.high:
            return TOO_HIGH
    return APPLICATION


def expected_read(od: dict[tuple[int, int], Declared], index: int, sub: int) -> int | None:
    """The abort code an upload must get, or None (data)."""
    if not any(i == index for i, _ in od):
        return NO_OBJECT
    obj = od.get((index, sub))
    if obj is None:
        return NO_SUBINDEX
    return WRITE_ONLY if obj.access == "wo" else None


def _fix_canopen_writable_stream() -> None:
    """Work around a python-canopen 2.4 client bug this project's CiA 301 server exposes.

    ``WritableStream.__init__`` sets ``_done = False`` and ``_exp_header = None`` before it
    initiates a segmented download; when the server refuses the initiate (0601 0002, 0607
    0012, ... -- CiA 301 allows and CANopenNode does this), ``__init__`` raises and the
    half-built stream's finalizer (``IOBase.__del__`` -> ``close()``) later sends a stray
    "last segment" request. Run by the garbage collector inside another ``send_message``, it
    deadlocks on the network's send lock; otherwise its answer is taken for the answer to the
    next request. canopen's own server accepted every initiate, so this never showed. Fix:
    a stream whose initiate failed counts as done."""
    from canopen.sdo import client

    original = client.WritableStream.__init__
    if getattr(original, "_fixed", False):
        return

    def init(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        try:
            original(self, *args, **kwargs)
        except BaseException:
            self._done = True
            raise

    init._fixed = True  # type: ignore[attr-defined]
    client.WritableStream.__init__ = init  # type: ignore[method-assign]


_fix_canopen_writable_stream()

"""Rendering of the bridge's object table (:data:`bridge.od.OBJECTS`) as a CiA 306 EDS.

``python -m bridge eds`` writes ``config/bridge.eds`` with :func:`render_eds`; the output is
deterministic (fixed dates, see FILE_REVISION) so that a test can compare the committed file
with it. Writable objects carry ``StorageLocation`` (a key python-canopen reads into
``storage_location``, as CANopenNode's EDS files do): ``PERSIST`` for the parameters 1010h
stores, ``RAM`` otherwise.
"""

from __future__ import annotations

from canopen.objectdictionary import datatypes as dt

from virtual_bus.contract import MANUFACTURER_AREA

from .od import (
    BOOL,
    CONST,
    DEVICE_TYPE,
    ERROR_REGISTER,
    I32,
    IDENTITY,
    OBJECTS,
    SMALLEST_REAL32,
    STORED,
    U8,
    U16,
    U32,
    VS,
    Access,
    Entry,
    Group,
    R,
)

_MANDATORY = (DEVICE_TYPE, ERROR_REGISTER, IDENTITY)
#: Bump with every change of the object table; the dates are fixed so that the rendering
#: stays deterministic (CiA 306 formats: hh:mm(AM|PM), mm-dd-yyyy).
FILE_REVISION = 2
MODIFIED = ("11:00PM", "11-23-2026")


def _fmt_value(data_type: int, value: int | float | str) -> str:
    if data_type == VS:
        return str(value)
    if data_type in dt.FLOAT_TYPES:
        return repr(float(value))
    if data_type in dt.SIGNED_TYPES:
        return str(int(value))
    return f"0x{int(value):0{2 * max(1, _size(data_type))}X}"


def _size(data_type: int) -> int:
    return {BOOL: 1, U8: 1, U16: 2, U32: 4, I32: 4, R: 4}.get(data_type, 1)


def _entry_lines(section: str, e: Entry) -> list[str]:
    lines = [
        f"[{section}]",
        f"ParameterName={e.name}",
        "ObjectType=0x7",
        f"DataType=0x{e.data_type:04X}",
        f"AccessType={e.access.value}",
        f"DefaultValue={_fmt_value(e.data_type, e.default)}",
        "PDOMapping=0",
    ]
    if e.low is not None:
        lines.append(f"LowLimit={_fmt_value(e.data_type, e.low)}")
    if e.high is not None:
        lines.append(f"HighLimit={_fmt_value(e.data_type, e.high)}")
    if e.access in (Access.RW, Access.WO):
        stored = (e.index, e.subindex) in STORED
        lines.append(f"StorageLocation={'PERSIST' if stored else 'RAM'}")
    if e.unit:
        lines.append(f"Unit={e.unit}")
    description = " ".join(part for part in (e.description, *e.rules) if part)
    if description:
        lines.append(f"Description={description}")
    return [*lines, ""]


def _object_lines(obj: Entry | Group) -> list[str]:
    if isinstance(obj, Entry):
        return _entry_lines(f"{obj.index:04X}", obj)
    lines = [
        f"[{obj.index:04X}]",
        f"ParameterName={obj.name}",
        f"ObjectType=0x{obj.kind.value:X}",
        f"SubNumber={len(obj.members) + 1}",
        "",
    ]
    sub0 = Entry(obj.index, 0, "Highest sub-index supported", U8, CONST, len(obj.members))
    lines += _entry_lines(f"{obj.index:04X}sub0", sub0)
    for member in obj.members:
        lines += _entry_lines(f"{obj.index:04X}sub{member.subindex:X}", member)
    return lines


def _index_list(title: str, indices: list[int]) -> list[str]:
    lines = [f"[{title}]", f"SupportedObjects={len(indices)}"]
    lines += [f"{i}=0x{index:04X}" for i, index in enumerate(indices, start=1)]
    return [*lines, ""]


COMMENTS = (
    "backlash-bridge: CANopen master-side node running the backlash regulator of",
    "Mohammadiasl, Vibration Detection and Backlash Suppression in Machine Tools (eq. 7, 15).",
    "Rendered by bridge.eds.render_eds(); do not edit by hand (python -m bridge eds).",
    "Units: speeds rad/s at the motor, positions in load units (m linear, rad rotary),",
    "move targets/feeds in load-scale increments (nm or urad) like the drive's 60E4h:01.",
    "Invalid writes: 0609 0030/31/32; locked while enabled: 0800 0022; read-only: 0601 0002.",
    "LowLimit/HighLimit hold for REAL32 too (NaN: 0609 0030); a REAL32 LowLimit of",
    f"{SMALLEST_REAL32!r} (the smallest positive REAL32) means a range open at 0.",
    "Rules in a Description: [requires EXPR else CODE]: after the CiA 301 checks and the",
    "limits, a write is refused with abort CODE when EXPR is false. EXPR is a Python",
    "expression of value (the value written), present (the object's present value) and",
    "XXXXh / XXXXh:SS (the present value of another object); rules apply in their order.",
    "2010h-2012h rules assume a linear axis (1e9 nm per m; rotary: 1e6 urad per rad).",
    "StorageLocation=PERSIST: saved by 1010h ('save') and loaded at start-up; RAM: not stored.",
    "Refused frames are counted in 2110h (docs/canopen_layout.md).",
)


def render_eds() -> str:
    """The EDS text of :data:`OBJECTS` (deterministic: fixed dates)."""
    indices = [obj.index for obj in OBJECTS]
    mandatory = [i for i in indices if i in _MANDATORY]
    optional = [i for i in indices if i < 0x2000 and i not in _MANDATORY]
    manufacturer = [i for i in indices if i in MANUFACTURER_AREA]
    lines = [
        "[FileInfo]",
        "FileName=bridge.eds",
        "FileVersion=1",
        f"FileRevision={FILE_REVISION}",
        "EDSVersion=4.0",
        "Description=Backlash regulator bridge (CANopen master side, CiA 402 CSV drive)",
        "CreationTime=12:00PM",
        "CreationDate=01-01-2025",
        "CreatedBy=backlash-bridge",
        f"ModificationTime={MODIFIED[0]}",
        f"ModificationDate={MODIFIED[1]}",
        "ModifiedBy=backlash-bridge",
        "",
        "[DeviceInfo]",
        "VendorName=backlash-bridge project",
        "VendorNumber=0x00000000",
        "ProductName=backlash-bridge",
        "ProductNumber=0x00000000",
        "RevisionNumber=0x00010000",
        "OrderCode=",
        *(f"BaudRate_{rate}=1" for rate in (10, 20, 50, 125, 250, 500, 800, 1000)),
        "SimpleBootUpMaster=1",
        "SimpleBootUpSlave=0",
        "Granularity=0",
        "DynamicChannelsSupported=0",
        "GroupMessaging=0",
        "NrOfRXPDO=0",
        "NrOfTXPDO=0",
        "LSS_Supported=0",
        "",
        "[DummyUsage]",
        *(f"Dummy000{i}=0" for i in range(1, 8)),
        "",
        "[Comments]",
        f"Lines={len(COMMENTS)}",
        *(f"Line{i}={text}" for i, text in enumerate(COMMENTS, start=1)),
        "",
        *_index_list("MandatoryObjects", mandatory),
        *_index_list("OptionalObjects", optional),
        *_index_list("ManufacturerObjects", manufacturer),
    ]
    for obj in OBJECTS:
        lines += _object_lines(obj)
    return "\n".join(lines).rstrip("\n") + "\n"

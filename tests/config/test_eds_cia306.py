"""config/bridge.eds and config/drive.eds pass a CiA 306 (EDS v4.0) check written here from
the standard, and load with canopen's import_od as an independent parser.

Checked: [FileInfo] and [DeviceInfo] keys; the object lists name exactly the object
sections; ObjectType, DataType, AccessType valid; sub-objects complete (SubNumber,
sub-index 0 at most the highest sub-index); every DefaultValue of its data type and within
LowLimit..HighLimit; 1005h rw (CiA 301 7.5.2.5); the mandatory objects 1000h, 1001h, 1018h present.
"""

from __future__ import annotations

import configparser
import re
from pathlib import Path

import canopen
import pytest

from tests.paths import ROOT

REPO = ROOT
EDS_FILES = [REPO / "config" / "bridge.eds", REPO / "config" / "drive.eds"]

FILE_INFO = (
    "FileName",
    "FileVersion",
    "FileRevision",
    "EDSVersion",
    "Description",
    "CreationTime",
    "CreationDate",
    "CreatedBy",
    "ModificationTime",
    "ModificationDate",
    "ModifiedBy",
)
DEVICE_INFO = (
    "VendorName",
    "VendorNumber",
    "ProductName",
    "ProductNumber",
    "RevisionNumber",
    "OrderCode",
    *(f"BaudRate_{r}" for r in (10, 20, 50, 125, 250, 500, 800, 1000)),
    "SimpleBootUpMaster",
    "SimpleBootUpSlave",
    "Granularity",
    "DynamicChannelsSupported",
    "GroupMessaging",
    "NrOfRXPDO",
    "NrOfTXPDO",
    "LSS_Supported",
)
ACCESS = {"ro", "wo", "rw", "rwr", "rww", "const"}
# CiA 306 / CiA 301 table 44: range of the integer types
RANGES = {
    0x0001: (0, 1),
    0x0002: (-(2**7), 2**7 - 1),
    0x0003: (-(2**15), 2**15 - 1),
    0x0004: (-(2**31), 2**31 - 1),
    0x0005: (0, 2**8 - 1),
    0x0006: (0, 2**16 - 1),
    0x0007: (0, 2**32 - 1),
}
REAL32, VISIBLE_STRING = 0x0008, 0x0009


def parse(path: Path) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=True, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read(path, encoding="ascii")
    return parser


def number(text: str) -> int:
    text = text.strip().upper().replace("$NODEID", "0")
    return sum(int(t, 16) if t.strip().startswith("0X") else int(t) for t in text.split("+"))


def problems(path: Path) -> list[str]:
    """Everything in the file that CiA 306 does not allow (empty: the file passes)."""
    eds = parse(path)
    out: list[str] = []
    for section, keys in (("FileInfo", FILE_INFO), ("DeviceInfo", DEVICE_INFO)):
        if section not in eds:
            out.append(f"[{section}] missing")
            continue
        out += [f"[{section}] lacks {key}" for key in keys if key not in eds[section]]
    info = dict(eds.items("FileInfo")) if eds.has_section("FileInfo") else {}
    if info.get("FileName") != path.name:
        out.append(f"FileName {info.get('FileName')!r} is not {path.name!r}")
    if info.get("EDSVersion") != "4.0":
        out.append("EDSVersion must be 4.0")
    for key in ("CreationTime", "ModificationTime"):
        if key in info and not re.fullmatch(r"(0\d|1[0-2]):[0-5]\d(AM|PM)", info[key]):
            out.append(f"{key} {info[key]!r}: hh:mm(AM|PM)")
    for key in ("CreationDate", "ModificationDate"):
        if key in info and not re.fullmatch(
            r"(0[1-9]|1[0-2])-(0[1-9]|[12]\d|3[01])-\d{4}", info[key]
        ):
            out.append(f"{key} {info[key]!r}: mm-dd-yyyy")
    objects = {s for s in eds.sections() if re.fullmatch(r"[0-9A-F]{4}", s)}
    listed: set[str] = set()
    for title in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        lst = eds[title]
        n = int(lst["SupportedObjects"], 0)
        entries = [f"{int(lst[str(i)], 0):04X}" for i in range(1, n + 1)]
        if len(lst) != n + 1:
            out.append(f"[{title}] SupportedObjects={n} but {len(lst) - 1} entries")
        listed.update(entries)
    if listed != objects:
        out.append(f"object lists and sections differ: {sorted(listed ^ objects)}")
    for mandatory in ("1000", "1001", "1018"):
        if mandatory not in objects:
            out.append(f"mandatory object {mandatory}h missing")
    for name in sorted(objects):
        sec = eds[name]
        kind = int(sec.get("ObjectType", "0x7"), 0)
        if kind == 0x7:
            out += check_var(eds, name)
        elif kind in (0x8, 0x9):
            subs = sorted(s for s in eds.sections() if re.fullmatch(name + r"sub[0-9A-F]{1,2}", s))
            if int(sec["SubNumber"], 0) != len(subs):
                out.append(f"{name}: SubNumber {sec['SubNumber']} but {len(subs)} sub-objects")
            highest = max(int(s.split("sub")[1], 16) for s in subs)
            # sub-index 0: highest sub-index supported (or, in PDO mapping objects, the
            # number of mapped entries: at most the highest sub-index)
            if f"{name}sub0" not in subs or number(eds[f"{name}sub0"]["DefaultValue"]) > highest:
                out.append(f"{name}sub0 must be at most the highest sub-index {highest}")
            for sub in subs:
                out += check_var(eds, sub)
        else:
            out.append(f"{name}: ObjectType 0x{kind:X} not a VAR, ARRAY or RECORD")
    if "1005" in objects and eds["1005"]["AccessType"] != "rw":
        out.append("1005h COB-ID SYNC must be rw (CiA 301)")
    return out


def check_var(eds: configparser.ConfigParser, name: str) -> list[str]:
    sec = eds[name]
    out: list[str] = []
    for key in ("ParameterName", "DataType", "AccessType"):
        if key not in sec:
            out.append(f"{name}: no {key}")
    if out:
        return out
    access = sec["AccessType"].lower()
    if access not in ACCESS:
        out.append(f"{name}: AccessType {access!r} not one of {sorted(ACCESS)}")
    data_type = int(sec["DataType"], 0)
    default = sec.get("DefaultValue")
    if default is None:
        return out
    if data_type == VISIBLE_STRING:
        if not default.isascii():
            out.append(f"{name}: DefaultValue not ASCII")
        return out
    if data_type == REAL32:
        float(default)
        return out
    if data_type not in RANGES:
        return [*out, f"{name}: DataType 0x{data_type:04X} not checked here"]
    value = number(default)
    low, high = RANGES[data_type]
    for key, bound in (("LowLimit", 0), ("HighLimit", 1)):
        if sec.get(key, "") != "":
            limit = number(sec[key])
            if not low <= limit <= high:
                out.append(f"{name}: {key} {limit} outside the data type {low}..{high}")
            if bound == 0:
                low = max(low, limit)
            else:
                high = min(high, limit)
    if not low <= value <= high:
        out.append(f"{name}: DefaultValue {value} outside {low}..{high}")
    return out


@pytest.mark.parametrize("path", EDS_FILES, ids=lambda p: p.name)
def test_eds_passes_the_cia306_check(path: Path) -> None:
    assert problems(path) == []


@pytest.mark.parametrize("path", EDS_FILES, ids=lambda p: p.name)
def test_eds_loads_with_canopen(path: Path) -> None:
    od = canopen.import_od(str(path), 1)
    assert 0x1000 in od and 0x1018 in od
    assert od[0x1005].access_type == "rw"


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda t: t.replace("ModifiedBy=backlash-bridge\n", ""), "lacks ModifiedBy"),
        (
            lambda t: t.replace("LowLimit=0x00\nHighLimit=0x03", "LowLimit=0x01\nHighLimit=0x03"),
            "outside",
        ),
        (
            lambda t: t.replace(
                "AccessType=rw\nDefaultValue=0x40000080",
                "AccessType=const\nDefaultValue=0x40000080",
            ),
            "1005h",
        ),
        (lambda t: t.replace("AccessType=ro", "AccessType=readonly", 1), "AccessType"),
    ],
    ids=["file info", "default outside limits", "1005h const", "access type"],
)
def test_the_check_finds_what_cia306_forbids(tmp_path: Path, edit: object, problem: str) -> None:
    text = EDS_FILES[0].read_text(encoding="ascii")
    changed = edit(text)  # type: ignore[operator]
    assert changed != text
    path = tmp_path / "bridge.eds"
    path.write_text(changed, encoding="ascii")
    assert any(problem in p for p in problems(path)), problems(path)

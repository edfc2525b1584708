"""CiA 306 device configuration files (DCF): an EDS with the values of one node.

A DCF is the node's EDS with, per CiA 306, a ``ParameterValue`` key in each object section
that has a value, a ``[DeviceComissioning]`` section (sic, CiA 306's spelling, which
python-canopen reads too) with ``NodeID``, ``NodeName``, ``Baudrate`` (kbit/s),
``NetNumber``, ``NetworkName``, ``CANopenManager`` and ``LSS_SerialNumber``, and in
``[FileInfo]`` the DCF's ``FileName`` and the EDS it was made from (``LastEDS``).

:func:`render_dcf` writes it from the EDS text line by line, so everything the EDS holds
(comments, Unit/Description, StorageLocation) stays as it was. :func:`read_dcf` reads one
back strictly: every ParameterValue must name an object of the node's EDS with the same data
type and be a valid value of it, and the numbers of ``[DeviceComissioning]`` must be what
CiA 306 allows (python-canopen's ``import_od`` skips malformed values silently, so it is used
to cross-check the files, not to load them). A UTF-8 byte-order mark is allowed.
"""

from __future__ import annotations

import configparser
import re
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen.objectdictionary import ODVariable

from ..errors import CommissionInputError
from .access import Value, parse_value

_SECTION = re.compile(r"^\s*\[([^\]]+)\]\s*$")
_OBJECT = re.compile(r"^([0-9A-F]{4})(?:SUB([0-9A-F]{1,2}))?$", re.IGNORECASE)
COMMISSIONING = "DeviceComissioning"

SectionKey = tuple[int, int | None]


@dataclass(frozen=True)
class Commissioning:
    """The ``[DeviceComissioning]`` section. baudrate_kbit: kbit/s; lss_serial: 1018h:04."""

    node_id: int
    node_name: str
    baudrate_kbit: int
    canopen_manager: bool = False
    net_number: int = 0
    network_name: str = ""
    lss_serial: int | None = None

    def lines(self) -> list[str]:
        lines = [
            f"[{COMMISSIONING}]",
            f"NodeID={self.node_id}",
            f"NodeName={self.node_name}",
            f"Baudrate={self.baudrate_kbit}",
            f"NetNumber={self.net_number}",
            f"NetworkName={self.network_name}",
            f"CANopenManager={int(self.canopen_manager)}",
        ]
        if self.lss_serial is not None:
            lines.append(f"LSS_SerialNumber=0x{self.lss_serial:08X}")
        return [*lines, ""]


def section_key(name: str) -> SectionKey | None:
    """(index, sub-index) of an object section (``2000`` -> (0x2000, None))."""
    match = _OBJECT.match(name.strip())
    if match is None:
        return None
    return int(match[1], 16), None if match[2] is None else int(match[2], 16)


def key_of(var: ODVariable, od: canopen.ObjectDictionary) -> SectionKey:
    """The section of ``var``: ``XXXX`` for a VAR, ``XXXXsubY`` for a member."""
    return (var.index, None) if isinstance(od[var.index], ODVariable) else (var.index, var.subindex)


def render_dcf(
    eds_text: str,
    *,
    eds_name: str,
    dcf_name: str,
    values: dict[SectionKey, str],
    commissioning: Commissioning,
) -> str:
    """The DCF text: ``eds_text`` with ``ParameterValue`` lines for ``values`` (value text
    per section key, :func:`bridge.commission.access.value_text`), the commissioning section
    and FileName/LastEDS (ParameterValues or a commissioning section already in the input
    are replaced)."""
    sections: list[tuple[str | None, list[str]]] = [(None, [])]
    for line in eds_text.splitlines():
        match = _SECTION.match(line)
        if match is not None:
            sections.append((match[1].strip(), [line]))
        else:
            sections[-1][1].append(line)
    out: list[str] = []
    for name, lines in sections:
        if name is not None and name.casefold() == COMMISSIONING.casefold():
            continue
        body = [ln for ln in lines if not ln.strip().startswith("ParameterValue=")]
        if name == "FileInfo":
            body = [ln for ln in body if not ln.strip().startswith("LastEDS=")]
            named = [i for i, ln in enumerate(body) if ln.strip().startswith("FileName=")]
            for i in named:
                body[i] = f"FileName={dcf_name}"
            _insert_after_keys(body, [] if named else [f"FileName={dcf_name}"])
            _insert_after_keys(body, [f"LastEDS={eds_name}"])
        key = section_key(name) if name is not None else None
        if key is not None and key in values:
            _insert_after_keys(body, [f"ParameterValue={values[key]}"])
        out += body
        if name == "DeviceInfo":
            if out and out[-1].strip():
                out.append("")
            out += commissioning.lines()
    return "\n".join(out).rstrip("\n") + "\n"


def _insert_after_keys(body: list[str], new: list[str]) -> None:
    """Insert ``new`` after the last ``key=value`` line of a section (before the blank
    lines and comments that precede the next section)."""
    last = 0
    for i, line in enumerate(body):
        text = line.strip()
        if text and not text.startswith(";") and "=" in text:
            last = i
    body[last + 1 : last + 1] = new


@dataclass(frozen=True)
class DcfValues:
    """What :func:`read_dcf` found: the values by variable (in file order) and the node-ID
    of ``[DeviceComissioning]`` (None when absent)."""

    values: list[tuple[ODVariable, Value]]
    node_id: int | None


def read_dcf(path: Path, od: canopen.ObjectDictionary, node_id: int) -> DcfValues:
    """Read the ParameterValues of the DCF at ``path`` against the node's ``od`` (module
    docstring); CommissionInputError naming the file, section and what is wrong."""
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark is not a section
    except (OSError, UnicodeDecodeError) as exc:
        raise CommissionInputError(f"{path}: cannot read the DCF ({exc})") from None
    parser = configparser.RawConfigParser(inline_comment_prefixes=(";",), strict=True)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    try:
        parser.read_string(text, source=str(path))
    except configparser.Error as exc:
        first = str(exc).splitlines()[0]
        raise CommissionInputError(f"{path}: not a readable DCF ({first})") from None
    dcf_node = _commissioning(parser, path).get("NodeID")
    values: list[tuple[ODVariable, Value]] = []
    problems: list[str] = []
    for name in parser.sections():
        if not parser.has_option(name, "ParameterValue"):
            continue
        where = f"{path}: [{name}] ParameterValue={parser.get(name, 'ParameterValue')}"
        key = section_key(name)
        try:
            var = _variable(od, key, name)
            declared = parser.get(name, "DataType", fallback=None)
            if declared is not None and int(declared, 0) != var.data_type:
                raise CommissionInputError(
                    f"DataType {declared} differs from the node's EDS (0x{var.data_type:04X})"
                )
            values.append((var, parse_value(var, parser.get(name, "ParameterValue"), node_id)))
        except (CommissionInputError, ValueError) as exc:
            problems.append(f"{where}: {exc}")
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise CommissionInputError(problems[0] + more)
    if not values:
        raise CommissionInputError(f"{path}: no ParameterValue keys: not a DCF with values")
    return DcfValues(values, dcf_node)


#: ``[DeviceComissioning]`` keys that are numbers (CiA 306): name -> allowed values
_COMMISSIONING_NUMBERS: dict[str, tuple[range | tuple[int, ...], str]] = {
    "NodeID": (range(1, 128), "a node-ID 1..127"),
    "Baudrate": (
        (10, 20, 50, 125, 250, 500, 800, 1000),
        "kbit/s: 10, 20, 50, 125, 250, 500, 800 or 1000",
    ),
    "NetNumber": (range(0, 1 << 32), "an UNSIGNED32"),
    "CANopenManager": ((0, 1), "0 or 1"),
    "LSS_SerialNumber": (range(0, 1 << 32), "an UNSIGNED32"),
}


def _commissioning(parser: configparser.RawConfigParser, path: Path) -> dict[str, int]:
    """The numbers of ``[DeviceComissioning]`` that are given (none when it is absent);
    CommissionInputError naming the key, the value and what CiA 306 allows."""
    found: dict[str, int] = {}
    if not parser.has_section(COMMISSIONING):
        return found
    for key, (allowed, text) in _COMMISSIONING_NUMBERS.items():
        if not parser.has_option(COMMISSIONING, key):
            continue
        raw = parser.get(COMMISSIONING, key)
        try:
            value = int(raw, 0)
        except ValueError:
            value = None
        if value is None or value not in allowed:
            raise CommissionInputError(f"{path}: [{COMMISSIONING}] {key}={raw!r}: allowed {text}")
        found[key] = value
    return found


def _variable(od: canopen.ObjectDictionary, key: SectionKey | None, name: str) -> ODVariable:
    if key is None:
        raise CommissionInputError("not an object section")
    index, sub = key
    if index not in od.indices:
        raise CommissionInputError(f"{index:04X}h is not in the node's EDS")
    obj = od[index]
    if isinstance(obj, ODVariable):
        if sub is not None:
            raise CommissionInputError(f"{index:04X}h is a VAR in the node's EDS")
        return obj
    if sub is None or sub not in obj.subindices:
        raise CommissionInputError(f"{name} is not a sub-object of the node's EDS")
    return obj[sub]

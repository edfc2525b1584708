"""Mutations of CiA 306 device configuration files (DCF): the file, its sections, and the
ParameterValue/DataType of a seeded choice of objects."""

from __future__ import annotations

import random
import re
from collections.abc import Sequence

from .core import EITHER, INVALID, VALID, Mutant, Mutants, garbage

_SECTION = re.compile(r"^\[([^\]]+)\]\s*$", re.MULTILINE)


def dcf_sections(text: str) -> list[tuple[str, str]]:
    """(name, whole text of the section including its header line) in file order; the text
    before the first section has the name ''."""
    starts = [(m.start(), m[1]) for m in _SECTION.finditer(text)]
    out = [("", text[: starts[0][0]] if starts else text)]
    for i, (pos, name) in enumerate(starts):
        end = starts[i + 1][0] if i + 1 < len(starts) else len(text)
        out.append((name, text[pos:end]))
    return out


def _join(sections: Sequence[tuple[str, str]]) -> str:
    return "".join(body for _, body in sections)


def _key(body: str, key: str) -> str | None:
    match = re.search(rf"^{key}=(.*)$", body, re.MULTILINE | re.IGNORECASE)
    return None if match is None else match[1].strip()


def _set_key(body: str, key: str, value: str) -> str:
    return re.sub(rf"^{key}=.*$", f"{key}={value}", body, count=1, flags=re.MULTILINE | re.I)


#: CiA 301 data types (DataType= of an EDS/DCF section) with their integer range.
INT_RANGES = {
    0x0002: (-(1 << 7), (1 << 7) - 1),
    0x0003: (-(1 << 15), (1 << 15) - 1),
    0x0004: (-(1 << 31), (1 << 31) - 1),
    0x0005: (0, (1 << 8) - 1),
    0x0006: (0, (1 << 16) - 1),
    0x0007: (0, (1 << 32) - 1),
}
BOOLEAN, REAL32, REAL64, VISIBLE_STRING = 0x0001, 0x0008, 0x0011, 0x0009


def dcf_mutants(seed: str, text: str, rng_seed: int, objects: int = 12) -> list[Mutant]:
    """Mutations of the DCF ``seed``: the file as a whole, its sections, and the
    ParameterValue/DataType of ``objects`` object sections chosen by the seeded generator
    (every data type the file has among them)."""
    rng = random.Random(rng_seed)
    sections = dcf_sections(text)
    out = Mutants(seed)
    add = out.add

    def replaced(i: int, body: str) -> str:
        return _join([*sections[:i], (sections[i][0], body), *sections[i + 1 :]])

    add("empty file", b"", INVALID)
    add("binary garbage", garbage(rng), INVALID)
    add("byte-order mark", b"\xef\xbb\xbf" + text.encode(), VALID)
    add("CRLF line ends", text.replace("\n", "\r\n"), VALID)
    add("latin-1 byte in a comment", b";\xe9\n" + text.encode(), INVALID)
    for fraction in (0.2, 0.5, 0.8):
        add(f"truncated at {fraction:.0%}", text[: int(len(text) * fraction)], EITHER)
    names = [name for name, _ in sections]
    for name in ("FileInfo", "DeviceInfo", "DeviceComissioning", "MandatoryObjects"):
        if name in names:
            i = names.index(name)
            add(f"delete [{name}]", _join(sections[:i] + sections[i + 1 :]), EITHER, name)
    add("duplicated section", text + "\n" + sections[1][1], INVALID)
    add("key outside a section", "ParameterValue=1\n" + text, INVALID)
    add("unknown object section", text + "\n[2FFE]\nParameterValue=1\n", INVALID, "2FFE")
    add("garbled section name", text + "\n[ZZZZsubQ]\nParameterValue=1\n", INVALID, "ZZZZsubQ")
    with_values = [
        i
        for i, (name, body) in enumerate(sections)
        if _key(body, "ParameterValue") is not None and _key(body, "DataType") is not None
    ]
    add(
        "no ParameterValue at all",
        _join([(n, re.sub(r"^ParameterValue=.*\n", "", b, flags=re.M)) for n, b in sections]),
        INVALID,
    )
    comm = names.index("DeviceComissioning") if "DeviceComissioning" in names else None
    if comm is not None:
        body = sections[comm][1]
        for key, value, verdict in (
            ("NodeID", "abc", INVALID),
            ("NodeID", "0", INVALID),
            ("NodeID", "128", INVALID),
            ("NodeID", "-1", INVALID),
            ("NodeID", "", INVALID),
            ("Baudrate", "abc", INVALID),
            ("Baudrate", "123", INVALID),
            ("Baudrate", "-500", INVALID),
            ("CANopenManager", "2", INVALID),
            ("NetNumber", "x", INVALID),
        ):
            if _key(body, key) is not None:
                add(
                    f"[DeviceComissioning] {key}={value}",
                    replaced(comm, _set_key(body, key, value)),
                    verdict,
                    key,
                )
    by_type: dict[int, list[int]] = {}
    for i in with_values:
        by_type.setdefault(int(_key(sections[i][1], "DataType") or "0", 0), []).append(i)
    chosen = {rng.choice(idx) for idx in by_type.values()}
    rest = [i for i in with_values if i not in chosen]
    chosen |= set(rng.sample(rest, min(len(rest), max(0, objects - len(chosen)))))
    for i in sorted(chosen):
        name, body = sections[i]
        data_type = int(_key(body, "DataType") or "0", 0)
        value = _key(body, "ParameterValue") or ""
        where = f"[{name}]"

        def pv(new: str) -> str:
            return replaced(i, _set_key(body, "ParameterValue", new))  # noqa: B023

        add(f"delete {where}", _join(sections[:i] + sections[i + 1 :]), VALID)
        add(
            f"{where} without ParameterValue",
            replaced(i, re.sub(r"^ParameterValue=.*\n", "", body, flags=re.M)),
            VALID,
        )
        add(
            f"{where} ParameterValue twice",
            replaced(i, body.rstrip("\n") + f"\nParameterValue={value}\n\n"),
            INVALID,
            name,
        )
        add(
            f"{where} DataType=0x0000",
            replaced(i, _set_key(body, "DataType", "0x0000")),
            INVALID,
            name,
        )
        other = 0x0007 if data_type != 0x0007 else 0x0004
        add(
            f"{where} DataType=0x{other:04X}",
            replaced(i, _set_key(body, "DataType", f"0x{other:04X}")),
            INVALID,
            name,
        )
        add(
            f"{where} DataType=0xZZ", replaced(i, _set_key(body, "DataType", "0xZZ")), INVALID, name
        )
        for what, text in (("bad hex", "0xZZ"), ("text", "abc"), ("empty", ""), ("nan", "nan")):
            verdict = EITHER if data_type == VISIBLE_STRING else INVALID
            add(f"{where} ParameterValue {what}", pv(text), verdict, name)
        if data_type in INT_RANGES:
            low, high = INT_RANGES[data_type]
            add(f"{where} ParameterValue max+1", pv(str(high + 1)), INVALID, name)
            add(f"{where} ParameterValue min-1", pv(str(low - 1)), INVALID, name)
            add(f"{where} ParameterValue 2**64", pv(str(1 << 64)), INVALID, name)
            add(f"{where} ParameterValue 1.5", pv("1.5"), INVALID, name)
            add(f"{where} ParameterValue $NODEID+0x1", pv("$NODEID+0x1"), EITHER, name)
        elif data_type in (REAL32, REAL64):
            add(f"{where} ParameterValue inf", pv("inf"), INVALID, name)
            add(
                f"{where} ParameterValue 1e39",
                pv("1e39"),
                INVALID if data_type == REAL32 else EITHER,
                name,
            )
            add(f"{where} ParameterValue 1e400", pv("1e400"), INVALID, name)
            add(f"{where} ParameterValue -0.0", pv("-0.0"), EITHER, name)
        elif data_type == BOOLEAN:
            add(f"{where} ParameterValue 2", pv("2"), INVALID, name)
        elif data_type == VISIBLE_STRING:
            add(f"{where} ParameterValue non-ASCII", pv("é"), INVALID, name)
    return out

"""Mutations of TOML files (axis files, docs/axis-file.md; drive profiles,
docs/commissioning.md) and the shipped files they start from."""

from __future__ import annotations

import math
import random
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from tests.paths import CONFIG

from .core import EITHER, INVALID, VALID, Mutant, Mutants, Verdict, garbage, mutants_of


def toml_value(value: object) -> str:
    """TOML text of a parsed value (strings, booleans, numbers incl. nan/inf, arrays, inline
    tables)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"no TOML for {value!r}")


def toml_text(doc: Mapping[str, Mapping[str, Any]], extra_lines: Mapping[str, str] = {}) -> str:
    """A document of ``[table]`` sections; ``extra_lines[table]`` is appended to a table as
    raw text (a duplicated key)."""
    out: list[str] = []
    for table, body in doc.items():
        out.append(f"[{table}]")
        out += [f"{key} = {toml_value(value)}" for key, value in body.items()]
        if table in extra_lines:
            out.append(extra_lines[table])
        out.append("")
    return "\n".join(out)


class Kind(Enum):
    """The type a TOML key has in its format."""

    FLOAT = "a number"
    INT = "an integer"
    ENUM = "one of a set of strings"
    TEXT = "free text"
    INT_LIST = "a list of integers"
    OBJECT = 'an object "IIIIh:SS"'
    OBJECT_LIST = 'a list of objects "IIIIh:SS"'


@dataclass(frozen=True)
class TomlSchema:
    """What the documentation of a TOML format says about its keys: ``kinds`` by dotted key
    (keys not listed are :attr:`Kind.FLOAT`), ``required`` dotted keys, ``signed`` keys where
    a negative number can be valid."""

    kinds: Mapping[str, Kind]
    required: frozenset[str]
    signed: frozenset[str] = frozenset()

    def kind(self, dotted: str) -> Kind:
        return self.kinds.get(dotted, Kind.FLOAT)


#: docs/axis-file.md
AXIS_SCHEMA = TomlSchema(
    kinds={"axis.kind": Kind.ENUM, "control.position_feedback": Kind.ENUM},
    required=frozenset(
        {
            "axis.kind",
            "axis.transmission_ratio",
            "mechanics.motor_inertia",
            "mechanics.load_mass",
            "mechanics.load_inertia",
            "control.kv",
            "control.ksp",
        }
    ),
    signed=frozenset(
        {"disturbance.constant_torque", "disturbance.periodic_phase", "control.sensor_time_offset"}
    ),
)

#: docs/commissioning.md, "The drive profile"
PROFILE_SCHEMA = TomlSchema(
    kinds={
        "drive.name": Kind.TEXT,
        "drive.vendor_id": Kind.INT,
        "drive.product_code": Kind.INT,
        "mode.mode": Kind.ENUM,
        "mode.ramp": Kind.INT,
        "pdo.tpdos": Kind.INT_LIST,
        "pdo.rpdo": Kind.INT,
        "pdo.tpdo_cob_ids": Kind.INT_LIST,
        "pdo.rpdo_cob_id": Kind.INT,
        "pdo.max_entries": Kind.INT,
        "pdo.transmission_type": Kind.INT,
        "pdo.mappable": Kind.OBJECT_LIST,
        "load.source": Kind.ENUM,
        "load.object": Kind.OBJECT,
        "load.object_type": Kind.ENUM,
        "load.encoder_id": Kind.INT,
        "scaling.rated_torque_mnm": Kind.INT,
        "supervision.heartbeat_consumer_entries": Kind.INT,
        "supervision.abort_connection_option": Kind.INT,
        "supervision.setpoint_timeout_object": Kind.OBJECT,
        "supervision.setpoint_timeout": Kind.INT,
        "supervision.setpoint_timeout_type": Kind.ENUM,
    },
    required=frozenset(),
    # 6007h is INTEGER16: its negative values are the manufacturer's reactions
    signed=frozenset({"supervision.abort_connection_option"}),
)

#: Replacements of a value: (name, value, verdict for a number key); for the other kinds the
#: verdict is decided in :func:`_replacements`.
HUGE, TINY = 1e300, 1e-300


def _replacements(
    dotted: str, value: object, schema: TomlSchema
) -> Iterator[tuple[str, object, Verdict]]:
    kind = schema.kind(dotted)
    number = kind in (Kind.FLOAT, Kind.INT)
    yield "text", "abc", VALID if kind is Kind.TEXT else INVALID
    yield "empty text", "", INVALID
    yield "bool", True, INVALID
    yield "table", {"a": 1}, INVALID
    if kind in (Kind.INT_LIST, Kind.OBJECT_LIST):
        yield "empty array", [], INVALID if kind is Kind.INT_LIST else EITHER
        yield "array of text", ["x"], INVALID
        yield "array of float", [1.5], INVALID
        yield "nested array", [[1]], INVALID
        yield "number", 1, INVALID
        return
    yield "array", [1.0, 2.0], INVALID
    if not number:
        yield "number", 1.0, INVALID
        return
    if kind is Kind.FLOAT and isinstance(value, float) and value.is_integer():
        yield "int where float", int(value), VALID
    elif kind is Kind.FLOAT and isinstance(value, float):
        yield "int where float", max(1, round(value)), EITHER
    if kind is Kind.INT and isinstance(value, int):
        yield "float where int", float(value), INVALID
        yield "fraction", value + 0.5, INVALID
    base = value if isinstance(value, int | float) and value else 1.0
    yield "negative", -abs(base), EITHER if dotted in schema.signed else INVALID
    yield "zero", 0 if kind is Kind.INT else 0.0, EITHER
    yield "nan", math.nan, INVALID
    yield "inf", math.inf, INVALID
    yield "-inf", -math.inf, INVALID
    if kind is Kind.INT:
        yield "huge int", 1 << 70, INVALID  # beyond every integer field (UNSIGNED32 at most)
        yield "huge", 1e300, INVALID
        return
    yield "huge", HUGE, EITHER
    yield "-huge", -HUGE, EITHER
    yield "tiny", TINY, EITHER
    yield "huge int", 10**30, EITHER


def toml_mutants(
    seed: str, text: str, doc: Mapping[str, Mapping[str, Any]], schema: TomlSchema, rng_seed: int
) -> list[Mutant]:
    """Mutations of the TOML file ``seed`` (its ``text``, parsed as ``doc``)."""
    rng = random.Random(rng_seed)
    out = Mutants(seed)
    add = out.add

    # the file as a whole
    add("empty file", b"", INVALID if schema.required else VALID)
    add("blank lines only", "\n\n  \n", INVALID if schema.required else VALID)
    add("binary garbage", garbage(rng), INVALID)
    add("byte-order mark", b"\xef\xbb\xbf" + text.encode(), VALID)
    add("CRLF line ends", text.replace("\n", "\r\n"), VALID)
    add("latin-1 byte in a comment", b"# \xe9\n" + text.encode(), INVALID)
    add("NUL byte", text.encode() + b"\x00", INVALID)
    add("not TOML", "this is not = = toml\n" + text, INVALID)
    for fraction in (0.1, 0.35, 0.6, 0.85):
        cut = int(len(text) * fraction)
        add(f"truncated at {fraction:.0%}", text[:cut], EITHER)
    add("unknown table", toml_text({**doc, "extra": {"a": 1}}), INVALID, "extra")
    add("duplicated table", text + "\n" + toml_text({next(iter(doc)): {}}), INVALID)
    add("top-level key", "stray = 1\n" + toml_text(doc), INVALID, "stray")
    add("array of tables", toml_text(doc) + f"\n[[{next(iter(doc))}]]\n", INVALID)
    for table in doc:
        rest = {t: b for t, b in doc.items() if t != table}
        required = [k for k in doc[table] if f"{table}.{k}" in schema.required]
        add(f"delete [{table}]", toml_text(rest), INVALID if required else EITHER, table)
        add(f"[{table}] as a key", toml_text(rest) + f"\n{table} = 1\n", INVALID, table)
        add(
            f"unknown key {table}.zzz",
            toml_text({**doc, table: {**doc[table], "zzz": 1.0}}),
            INVALID,
            f"{table}.zzz",
        )
        for key, value in doc[table].items():
            dotted = f"{table}.{key}"
            body = {k: v for k, v in doc[table].items() if k != key}
            add(
                f"delete {dotted}",
                toml_text({**doc, table: body}),
                INVALID if dotted in schema.required else EITHER,
                dotted,
            )
            add(
                f"duplicate {dotted}",
                toml_text(doc, {table: f"{key} = {toml_value(value)}"}),
                INVALID,
            )
            for name, new, verdict in _replacements(dotted, value, schema):
                add(
                    f"{dotted} = {name}",
                    toml_text({**doc, table: {**doc[table], key: new}}),
                    verdict,
                    dotted,
                )
    return out


def axis_seeds() -> list[Path]:
    """The shipped axis files."""
    return sorted(CONFIG.glob("*.toml"))


def profile_seeds() -> list[Path]:
    """The shipped drive profiles."""
    return sorted((CONFIG / "drives").glob("*.toml"))


def axis_mutants() -> list[Mutant]:
    return mutants_of(
        axis_seeds(),
        lambda name, text, s: toml_mutants(name, text, tomllib.loads(text), AXIS_SCHEMA, s),
    )


def profile_mutants() -> list[Mutant]:
    return mutants_of(
        profile_seeds(),
        lambda name, text, s: toml_mutants(name, text, tomllib.loads(text), PROFILE_SCHEMA, s),
        100,
    )

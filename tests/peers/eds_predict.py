"""Predict every SDO download answer of a node from its EDS file alone.

Written apart from the project's servers: the EDS, the data type sizes and CiA 301's own
checks (object, sub-index, access, length, value against LowLimit/HighLimit) are those of
``tests/sdo_oracle.py``; what a node enforces beyond that is read from the
``[requires EXPR else CODE]`` / ``[abort EXPR]`` rules its Descriptions state (the notation is
in ``docs/peers.md``). EXPR is evaluated by a small interpreter over Python's ``ast`` that
allows arithmetic, comparisons, ``and``/``or``/``not``, ``x if c else y``, ``value``, ``present``,
object references ``XXXXh`` / ``XXXXh:SS`` (read from the node when the rule needs them) and
three CiA 301 functions: ``restricted(can_id)`` (CiA 301 table 7.3 restricted COB-IDs),
``mapping_error(entry, 'rx'|'tx')`` and ``mapping_count_error(map_index, n, 'rx'|'tx')``
(CiA 301 7.5.2.36/38: 0602 0000 for an object the EDS does not declare, 0604 0041 for one it
does not mark PDOMapping=1 or not readable/writable as the direction needs or mapped with
another length, 0604 0042 beyond 64 bits).

:func:`predict` returns None (the download succeeds) or the abort code.
"""

from __future__ import annotations

import ast
import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from tests.sdo_oracle import (
    APPLICATION,
    NO_OBJECT,
    NOT_MAPPABLE,
    PDO_LENGTH,
    READABLE,
    REAL32,
    REAL64,
    TYPES,
    WRITABLE,
    Declared,
    expected,
    read_eds,
)

_RULE = re.compile(r"\[(requires|abort) ([^\]]*?)(?: else ([0-9A-Fa-f]{4}) ([0-9A-Fa-f]{4}))?\]")
_REF = re.compile(r"\b([0-9A-Fa-f]{4})h(?::([0-9A-Fa-f]{2}))?\b")


@dataclass(frozen=True)
class Rule:
    kind: str  # "requires" or "abort"
    expr: ast.Expression
    code: int | None  # requires: the abort when false
    text: str


@dataclass(frozen=True)
class Obj(Declared):
    """A sub-object as the EDS declares it, with the rules its Description states."""

    rules: tuple[Rule, ...] = ()


def _rules(description: str, where: str) -> tuple[Rule, ...]:
    rules = []
    for m in _RULE.finditer(description):
        kind, text = m.group(1), m.group(2)
        if (kind == "requires") != (m.group(3) is not None):
            raise ValueError(f"{where}: rule [{kind} {text}] malformed")
        source = _REF.sub(lambda r: f"_ref(0x{r.group(1)}, 0x{r.group(2) or '00'})", text.strip())
        expr = ast.parse(source, mode="eval")
        _check_ast(expr, where)
        code = int(m.group(3) + m.group(4), 16) if m.group(3) else None
        rules.append(Rule(kind, expr, code, text.strip()))
    return tuple(rules)


_ALLOWED_NODES = (
    ast.Expression, ast.BoolOp, ast.And, ast.Or, ast.BinOp, ast.Add, ast.Sub, ast.Mult,
    ast.Div, ast.Mod, ast.BitAnd, ast.BitOr, ast.LShift, ast.RShift, ast.UnaryOp, ast.Not,
    ast.USub, ast.Compare, ast.Eq, ast.NotEq, ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.In,
    ast.NotIn, ast.Tuple, ast.Constant, ast.Name, ast.Load, ast.Call, ast.IfExp,
)  # fmt: skip
_NAMES = frozenset(
    {"value", "present", "_ref", "restricted", "mapping_error", "mapping_count_error"}
)


def _check_ast(tree: ast.AST, where: str) -> None:
    for node in ast.walk(tree):
        if not isinstance(node, _ALLOWED_NODES):
            raise ValueError(f"{where}: {type(node).__name__} not allowed in a rule")
        if isinstance(node, ast.Name) and node.id not in _NAMES:
            raise ValueError(f"{where}: unknown name {node.id!r} in a rule")


class Eds:
    """The objects an EDS declares (VARs and sub-indices), keyed (index, sub-index)."""

    def __init__(self, path: Path, node_id: int) -> None:
        self.path = path
        self.objects: dict[tuple[int, int], Obj] = {
            key: Obj(**vars(d), rules=_rules(d.description, f"{d.index:04X}sub{d.sub:X} of {path}"))
            for key, d in read_eds(path, node_id).items()
        }
        self.indices = frozenset(i for i, _ in self.objects)

    @property
    def writable(self) -> list[Obj]:
        return [o for _, o in sorted(self.objects.items()) if o.access in WRITABLE]


Reader = Callable[[int, int], bytes]


def restricted(can_id: int) -> bool:
    """CiA 301 table 7.3: COB-IDs no PDO may use."""
    return (
        can_id <= 0x07F
        or 0x101 <= can_id <= 0x180
        or 0x581 <= can_id <= 0x5FF
        or 0x601 <= can_id <= 0x67F
        or 0x6E0 <= can_id <= 0x6FF
        or can_id >= 0x701
    )


class _Context:
    def __init__(self, eds: Eds, read: Reader, obj: Obj, value: int | float) -> None:
        self.eds, self.read, self.obj, self.value = eds, read, obj, value
        self.cache: dict[tuple[int, int], int | float] = {}

    def ref(self, index: int, sub: int) -> int | float:
        key = (index, sub)
        if key not in self.cache:
            self.cache[key] = self.eds.objects[key].decode(self.read(index, sub))
        return self.cache[key]

    def mapping_error(self, entry: int, kind: str) -> int:
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        obj = self.eds.objects.get((index, sub))
        if obj is None:
            return NO_OBJECT
        usable = obj.access in (WRITABLE if kind == "rx" else READABLE)
        if not obj.pdo_mapping or not usable or obj.size is None or bits != 8 * obj.size:
            return NOT_MAPPABLE
        return 0

    def mapping_count_error(self, map_index: int, count: int, kind: str) -> int:
        total = 0
        for sub in range(1, count + 1):
            entry = int(self.ref(map_index, sub))
            if entry == 0:
                return NOT_MAPPABLE
            error = self.mapping_error(entry, kind)
            if error:
                return error
            total += entry & 0xFF
        return PDO_LENGTH if total > 64 else 0

    def evaluate(self, rule: Rule) -> object:
        namespace = {
            "value": self.value,
            "_ref": self.ref,
            "restricted": restricted,
            "mapping_error": self.mapping_error,
            "mapping_count_error": self.mapping_count_error,
        }
        if "present" in ast.dump(rule.expr):
            namespace["present"] = self.ref(self.obj.index, self.obj.sub)
        code = compile(rule.expr, f"<rule {rule.text}>", "eval")
        return eval(code, {"__builtins__": {}}, namespace)  # the AST was checked (_check_ast)


def predict(eds: Eds, index: int, sub: int, data: bytes, read: Reader) -> int | None:
    """The abort code a download of ``data`` to ``index``:``sub`` gets, or None (success).
    ``read(index, sub)`` uploads an object's present value (rules that need one)."""
    code = expected(eds.objects, index, sub, data)
    if code != APPLICATION:
        return code
    obj = eds.objects[(index, sub)]
    if obj.size is None:  # strings, domains: any length, no value rules here
        return None
    context = _Context(eds, read, obj, obj.decode(data))
    for rule in obj.rules:
        result = context.evaluate(rule)
        if rule.kind == "requires" and not result:
            return rule.code
        if rule.kind == "abort" and result:
            return int(result)  # type: ignore[call-overload]
    return None


# --- random writes ---------------------------------------------------------------------------
@dataclass
class Tally:
    """What a run of random writes found: writes made, answers by code (None: success),
    objects written successfully, and every answer that differed from the prediction."""

    writes: int = 0
    answers: dict[int | None, int] = field(default_factory=dict)
    written: set[tuple[int, int]] = field(default_factory=set)
    unpredicted: list[str] = field(default_factory=list)


#: Heartbeat producer times the random writes use: 0 (off) or at least this many ms, so that a
#: node on a one-CPU guest is not made to flood the bus.
MIN_HEARTBEAT_MS = 100


def _constants(obj: Obj) -> list[int | float]:
    out: list[int | float] = []
    for rule in obj.rules:
        for node in ast.walk(rule.expr):
            constant = isinstance(node, ast.Constant) and isinstance(node.value, int | float)
            if constant and not isinstance(node.value, bool):
                out.append(node.value)
    return out


def _present(obj: Obj, read: Reader) -> bytes | None:
    """The object's present value, None where it has none to read (write-only, or a node
    that answers 0800 0024 "no data available")."""
    if obj.access not in READABLE:
        return None
    try:
        return read(obj.index, obj.sub)
    except Exception:  # the client's abort: no present value to start from
        return None


def _type_range(obj: Obj) -> tuple[int, int]:
    size = 8 * (obj.size or 4)
    if TYPES[obj.data_type][1].islower():
        return -(1 << (size - 1)), (1 << (size - 1)) - 1
    return 0, (1 << size) - 1


def _candidate(eds: Eds, obj: Obj, rng: object, read: Reader) -> bytes:
    """A value for ``obj``: the present one, one in or just outside its limits, a rule's
    constant, a mapping entry of a declared object, a toggled COB-ID bit, NaN/inf."""
    import random

    assert isinstance(rng, random.Random)
    if obj.data_type in (REAL32, REAL64):
        low = obj.low if obj.low is not None else -1e6
        high = obj.high if obj.high is not None else 1e6
        choice = rng.randrange(8)
        if choice == 0:
            return _present(obj, read) or bytes(obj.size or 4)
        if choice == 1:
            value = rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0])
        elif choice == 2:
            value = rng.choice(
                [low, high, math.nextafter(low, -math.inf), math.nextafter(high, math.inf)]
            )
        elif choice == 3:
            value = rng.choice(_constants(obj) or [0.0]) * rng.choice([1.0, 0.5, 2.0])
        elif choice in (4, 5):
            value = rng.uniform(max(low, -1e4), min(high, 1e4))
        elif choice == 6:
            value = math.copysign(10 ** rng.uniform(-6, 6), rng.choice([-1.0, 1.0]))
        else:
            return rng.randbytes(obj.size or 4)
        return struct.pack("<f" if obj.data_type == REAL32 else "<d", value)
    lo, hi = _type_range(obj)
    low = obj.low if obj.low is not None else lo
    high = obj.high if obj.high is not None else hi
    raw = _present(obj, read)
    present = obj.decode(raw) if raw is not None and len(raw) == obj.size else 0
    choice = rng.randrange(9)
    if choice == 0:
        value = present
    elif choice == 1:
        value = rng.choice([low, high, low - 1, high + 1])
    elif choice == 2:
        value = rng.choice(_constants(obj) or [0])
    elif choice == 3 and obj.index >> 8 in (0x16, 0x17, 0x1A, 0x1B) and obj.sub:
        target = rng.choice(list(eds.objects.values()))
        bits = 8 * (target.size or 1) if rng.random() < 0.8 else rng.choice([1, 8, 16, 32, 64])
        value = target.index << 16 | target.sub << 8 | bits
    elif choice == 4 and obj.size == 4:
        value = present ^ rng.choice([0x8000_0000, 0x4000_0000, rng.randrange(1, 0x800)])
    elif choice == 5:
        value = rng.randint(int(low), int(high)) if high >= low else low
    elif choice == 6 and obj.size == 1:
        value = rng.randrange(0, 10)
    else:
        value = rng.randint(lo, hi)
    value = min(max(int(value), lo), hi)
    if (obj.index, obj.sub) == (0x1017, 0) and 0 < value < MIN_HEARTBEAT_MS:
        value = 0
    return obj.encode(value)


def random_writes(
    eds: Eds,
    write: Callable[[int, int, bytes], int | None],
    read: Reader,
    count: int,
    seed: int,
    *,
    lengths: range = range(0, 9),
    skip: Callable[[int, int], bool] = lambda index, sub: False,
) -> Tally:
    """``count`` seeded random downloads through ``write`` (returns the abort code or None),
    each predicted first with :func:`predict` (``read`` uploads what a rule needs); every
    answer that differs from the prediction is listed in ``Tally.unpredicted``. ``lengths``:
    the data lengths the client can send (a client that cannot send 0 bytes says so);
    ``skip(index, sub)``: objects the run leaves alone."""
    import random

    rng = random.Random(seed)
    tally = Tally()
    declared = [o for _, o in sorted(eds.objects.items()) if not skip(o.index, o.sub)]
    writable = [o for o in declared if o.access in WRITABLE]
    indices = sorted(eds.indices)
    absent_index = [i for i in (0x0FFF, 0x1FFF, 0x2FFF, 0x5FFF, 0x9000) if i not in eds.indices]
    while tally.writes < count:
        r = rng.random()
        if r < 0.05:
            index, sub, data = rng.choice(absent_index), rng.randrange(256), rng.randbytes(4)
        elif r < 0.10:
            index = rng.choice(indices)
            sub = rng.randrange(256)
            data = rng.randbytes(rng.choice(list(lengths)))
        else:
            obj = rng.choice(writable if r < 0.85 else declared)
            index, sub = obj.index, obj.sub
            if rng.random() < 0.2 or obj.size is None or obj.data_type not in TYPES:
                data = rng.randbytes(rng.choice(list(lengths)))
            else:
                data = _candidate(eds, obj, rng, read)
        if len(data) not in lengths or skip(index, sub):
            continue
        if (index, sub) == (0x1017, 0) and len(data) == 2:
            ms = int.from_bytes(data, "little")
            data = data if ms == 0 or ms >= MIN_HEARTBEAT_MS else bytes(2)
        want = predict(eds, index, sub, data, read)
        got = write(index, sub, data)
        tally.writes += 1
        tally.answers[got] = tally.answers.get(got, 0) + 1
        if got is None:
            tally.written.add((index, sub))
        if got != want:
            tally.unpredicted.append(
                f"{index:04X}h:{sub:02X} = {data.hex() or '(0 bytes)'}: predicted "
                f"{'success' if want is None else f'0x{want:08X}'}, answered "
                f"{'success' if got is None else f'0x{got:08X}'}"
            )
    return tally

"""The benchmark registry of ``python3 dev.py bench``: ``tools/benches.toml`` read into
:class:`Bench` and :class:`Figure` objects, every entry checked when it is read.

Placeholders: ``{realtime_s}`` (``--realtime-seconds``), ``{rate_hz}`` and ``{rate_k}`` (each
of an entry's ``rates``, and the rate in kHz) are filled when the registry is read, in names,
arguments, setup commands, result files and labels; ``{out}`` (a fresh directory) and
``{shared}`` (the third-party folder) when a command runs (arguments and setup commands).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from tools.checkout import ROOT
from tools.errors import RegistryError

#: the registry
BENCHES = Path(__file__).with_name("benches.toml")
#: filled when the registry is read
READ_PLACEHOLDERS = ("realtime_s", "rate_hz", "rate_k")
#: filled when a command runs
RUN_PLACEHOLDERS = ("out", "shared")
_PLACEHOLDER = re.compile(r"\{([^{}]*)\}")
_BENCH_KEYS = {"name", "args", "result", "figures", "setup", "needs", "rates"}
_FIGURE_KEYS = {"label", "keys", "unit", "scale"}


@dataclass(frozen=True)
class Figure:
    """One figure of a benchmark: where it is in the command's JSON (dotted keys; "wall_s" is
    the command's wall time), its unit and the factor from the JSON's SI value to that unit."""

    label: str
    keys: str
    unit: str
    scale: float = 1.0


@dataclass(frozen=True)
class Bench:
    """A command of the project (``python -m ...`` args; ``{out}`` is a fresh directory) and
    the JSON file it writes there (``result``) holding its figures; ``setup``: commands run
    before it, untimed (a setup that fails, e.g. data not present, leaves the figures out);
    ``needs``: a program it runs (not installed: the figures are left out, saying so)."""

    name: str
    args: tuple[str, ...]
    result: str
    figures: tuple[Figure, ...]
    setup: tuple[tuple[str, ...], ...] = ()
    needs: str = ""


def filled(args: Sequence[str], out: str) -> list[str]:
    """A bench's arguments with ``{out}`` and ``{shared}`` (the third-party folder) filled."""
    shared = os.environ.get("BACKLASH_SHARED") or str(ROOT.parent / "shared")
    return [a.replace("{out}", out).replace("{shared}", shared) for a in args]


def shown(args: Sequence[str]) -> str:
    """A bench's arguments as the README's table shows them."""
    return " ".join(a.replace("{out}", "DIR").replace("{shared}", "../shared") for a in args)


def load(realtime_s: float, path: Path = BENCHES) -> tuple[Bench, ...]:
    """Every benchmark of the registry at ``path``, in its order (an entry with ``rates``: one
    benchmark per rate), for real-time runs of ``realtime_s`` seconds."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RegistryError(f"{path}: cannot read it: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise RegistryError(f"{path}: not a TOML file: {exc}") from None
    extra = sorted(set(doc) - {"bench"})
    if extra:
        raise RegistryError(f"{path}: unknown top-level keys {extra}; allowed: ['bench']")
    entries = doc.get("bench")
    if not isinstance(entries, list) or not entries:
        raise RegistryError(f"{path}: needs at least one [[bench]] table")
    benches: list[Bench] = []
    for i, entry in enumerate(entries, 1):
        benches += _entry(entry, realtime_s, f"{path}: [[bench]] {i}")
    names = [b.name for b in benches]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise RegistryError(f"{path}: benchmark names must be unique; twice: {twice}")
    return tuple(benches)


def _entry(entry: object, realtime_s: float, where: str) -> list[Bench]:
    if not isinstance(entry, dict):
        raise RegistryError(f"{where}: must be a table")
    if isinstance(entry.get("name"), str):
        where += f" ({entry['name']!r})"
    extra = sorted(set(entry) - _BENCH_KEYS)
    if extra:
        raise RegistryError(f"{where}: unknown keys {extra}; allowed: {sorted(_BENCH_KEYS)}")
    name = _text(entry, "name", where)
    args = _texts(entry, "args", where)
    result = _text(entry, "result", where)
    needs = _text(entry, "needs", where, required=False)
    setup = entry.get("setup", [])
    if not isinstance(setup, list):
        raise RegistryError(f"{where}: 'setup' must be a list of commands (lists of strings)")
    setups = [_texts({"setup": s}, "setup", where) for s in setup]
    figures = entry.get("figures")
    if not isinstance(figures, list) or not figures:
        raise RegistryError(f"{where}: 'figures' must be a non-empty list of tables")
    rates = entry.get("rates")
    if rates is not None and (
        not isinstance(rates, list)
        or not rates
        or not all(isinstance(r, int) and not isinstance(r, bool) and r > 0 for r in rates)
    ):
        raise RegistryError(f"{where}: 'rates' must be a non-empty list of positive integers (Hz)")
    benches = []
    for rate_hz in rates or [None]:
        values = {"realtime_s": f"{realtime_s:g}"}
        if rate_hz is not None:
            values |= {"rate_hz": str(rate_hz), "rate_k": f"{rate_hz / 1000:g}"}
        bench = Bench(
            name=_fill(name, values, False, where),
            args=tuple(_fill(a, values, True, where) for a in args),
            result=_fill(result, values, False, where),
            figures=tuple(_figure(f, j, values, where) for j, f in enumerate(figures, 1)),
            setup=tuple(tuple(_fill(a, values, True, where) for a in s) for s in setups),
            needs=needs,
        )
        labels = [f.label for f in bench.figures]
        twice = sorted({lb for lb in labels if labels.count(lb) > 1})
        if twice:
            raise RegistryError(f"{where}: figure labels must be unique; twice: {twice}")
        benches.append(bench)
    return benches


def _figure(fig: object, j: int, values: dict[str, str], where: str) -> Figure:
    where = f"{where}: figure {j}"
    if not isinstance(fig, dict):
        raise RegistryError(f"{where}: must be a table {{label, keys, unit, scale}}")
    extra = sorted(set(fig) - _FIGURE_KEYS)
    if extra:
        raise RegistryError(f"{where}: unknown keys {extra}; allowed: {sorted(_FIGURE_KEYS)}")
    scale = fig.get("scale", 1.0)
    if (
        not isinstance(scale, int | float)
        or isinstance(scale, bool)
        or not math.isfinite(scale)
        or scale == 0
    ):
        raise RegistryError(f"{where}: 'scale' must be a finite non-zero number, not {scale!r}")
    return Figure(
        label=_fill(_text(fig, "label", where), values, False, where),
        keys=_text(fig, "keys", where),
        unit=_text(fig, "unit", where),
        scale=float(scale),
    )


def _text(table: Mapping[str, object], key: str, where: str, required: bool = True) -> str:
    value = table.get(key, None if required else "")
    if not isinstance(value, str) or (required and not value.strip()):
        raise RegistryError(f"{where}: {key!r} must be a non-empty string, not {value!r}")
    return value


def _texts(table: Mapping[str, object], key: str, where: str) -> tuple[str, ...]:
    value = table.get(key)
    if not isinstance(value, list) or not value or not all(isinstance(a, str) and a for a in value):
        raise RegistryError(f"{where}: {key!r} must be a non-empty list of non-empty strings")
    return tuple(value)


def _fill(text: str, values: dict[str, str], run_too: bool, where: str) -> str:
    def one(match: re.Match[str]) -> str:
        key = match.group(1)
        if key in values:
            return values[key]
        if run_too and key in RUN_PLACEHOLDERS:
            return match.group(0)
        allowed = [*values, *(RUN_PLACEHOLDERS if run_too else ())]
        raise RegistryError(
            f"{where}: unknown placeholder {{{key}}} in {text!r}; allowed here: "
            + ", ".join(f"{{{k}}}" for k in allowed)
            + ("" if "rate_hz" in values else " ({rate_hz}, {rate_k}: with 'rates')")
        )

    return _PLACEHOLDER.sub(one, text)

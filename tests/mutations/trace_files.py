"""Mutations of servo trace files (CSV, docs/trace-file.md) and the good traces they start
from."""

from __future__ import annotations

import random
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from virtual_bus.formats.trace import COLUMN_UNITS, REQUIRED_COLUMNS

from .core import EITHER, INVALID, VALID, Mutant, Mutants, garbage


def _csv(header: Sequence[str], rows: Sequence[Sequence[str]], sep: str = ",") -> str:
    return "\n".join([sep.join(header), *(sep.join(r) for r in rows)]) + "\n"


def trace_mutants(seed: str, text: str, rng_seed: int) -> list[Mutant]:
    """Mutations of the trace file ``seed`` (CSV ``text``, at least 120 data rows)."""
    rng = random.Random(rng_seed)
    lines = text.splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:]]
    n = len(rows)
    out = Mutants(seed)
    add = out.add

    def cell(col: int, value: str, row: int | None = None) -> str:
        r = rng.randrange(n) if row is None else row
        new = [list(x) for x in rows]
        new[r][col] = value
        return _csv(header, new)

    # the file as a whole
    add("empty file", b"", INVALID)
    add("header only", _csv(header, []), INVALID)
    add("binary garbage", garbage(rng), INVALID)
    add("byte-order mark", b"\xef\xbb\xbf" + text.encode(), VALID)
    add("CRLF line ends", text.replace("\n", "\r\n"), VALID)
    latin = [list(r) for r in rows]
    latin[n // 2][-1] += "\xe9"
    add("latin-1 byte in a cell", _csv(header, latin).encode("latin-1"), INVALID)
    nul = [list(r) for r in rows]
    nul[n // 3][0] = "\x00" + nul[n // 3][0]
    add("NUL byte in a cell", _csv(header, nul), INVALID, header[0])
    add("semicolon delimiter", _csv(header, rows, ";"), INVALID)
    add("tab delimiter", _csv(header, rows, "\t"), INVALID)
    add("99 rows", _csv(header, rows[:99]), INVALID)
    add("100 rows", _csv(header, rows[:100]), VALID)
    add("1 row", _csv(header, rows[:1]), INVALID)
    add(
        "blank line in the middle",
        _csv(header, rows[: n // 2]) + "\n" + _csv([], rows[n // 2 :])[1:],
        EITHER,
    )
    add("truncated mid-row", text[: len(text) - len(lines[-1]) // 2 - 1], EITHER)
    add("truncated mid-file", text[: len(text) // 2], EITHER)
    add("spaces around names", _csv([f" {h} " for h in header], rows), VALID)
    add("upper-case names", _csv([h.upper() for h in header], rows), INVALID, "time")
    add("quoted cells", _csv(header, [[f'"{c}"' for c in r] for r in rows]), VALID)
    add("extra unknown column", _csv([*header, "zzz"], [[*r, "1.0"] for r in rows]), VALID)
    add(
        "text in an unknown column",
        _csv([*header, "note"], [[*r, "ok"] for r in rows]),
        INVALID,
        "note",
    )
    order = list(range(len(header)))
    rng.shuffle(order)
    add(
        "columns reordered",
        _csv([header[i] for i in order], [[r[i] for i in order] for r in rows]),
        VALID,
    )
    add("rows reversed", _csv(header, rows[::-1]), INVALID, "time")
    add("empty header name", _csv([*header, ""], [[*r, "1"] for r in rows]), EITHER)
    ti = header.index("time")
    in_ms = [[repr(float(c) * 1000.0) if i == ti else c for i, c in enumerate(r)] for r in rows]
    add("time in ms", _csv(header, in_ms), EITHER, "time")
    in_ns = [[repr(float(c) * 1e9) if i == ti else c for i, c in enumerate(r)] for r in rows]
    add("time in ns", _csv(header, in_ns), EITHER, "time")
    k = rng.randrange(1, n)
    dup_t = [list(r) for r in rows]
    dup_t[k][ti] = rows[k - 1][ti]
    add("repeated time", _csv(header, dup_t), INVALID, "time")
    back = [list(r) for r in rows]
    back[k][ti] = repr(float(rows[k - 1][ti]) - 1e-3)
    add("time going back", _csv(header, back), INVALID, "time")
    short = [list(r) for r in rows]
    short[k] = short[k][:-1]
    add("short row", _csv(header, short), INVALID)
    long_ = [list(r) for r in rows]
    long_[k] = [*long_[k], "1.0"]
    add("long row", _csv(header, long_), INVALID)
    add("row of one cell", _csv(header, [*rows[:k], ["1.0"], *rows[k:]]), INVALID)
    for j, name in enumerate(header):
        spec = name in COLUMN_UNITS
        required = name in REQUIRED_COLUMNS
        keep = [i for i in range(len(header)) if i != j]
        add(
            f"without column {name}",
            _csv([header[i] for i in keep], [[r[i] for i in keep] for r in rows]),
            INVALID if required else VALID,
            name,
        )
        add(
            f"duplicate column {name}",
            _csv([*header, name], [[*r, r[j]] for r in rows]),
            INVALID,
            name,
        )
        for what, value in (
            ("text", "abc"),
            ("empty", ""),
            ("nan", "nan"),
            ("inf", "inf"),
            ("-inf", "-inf"),
            ("1e200", "1e200"),
            ("hex", "0x10"),
            ("comma decimal", '"1,5"'),
        ):
            verdict = INVALID if spec else EITHER
            add(f"{what} cell in {name}", cell(j, value), verdict, name)
        add(
            f"{name} cell in the last row empty",
            cell(j, "", n - 1),
            INVALID if spec else EITHER,
            name,
        )
        add(f"{name} cell 1e100", cell(j, "1e100"), EITHER, name)
    return out


def trace_seeds(folder: Path) -> list[Path]:
    """Good trace files written into ``folder`` by the project's writer: a 0.3 s move of the
    paper axis (motor position k_r times the reference, every column of the format) and,
    where ``shared/`` has them, 0.4 s of the EMPS and 0.3 s of a BAM XL330 recording."""
    from virtual_bus.formats.axis import load_axis
    from virtual_bus.formats.trace import Trace
    from virtual_bus.shipped import PAPER_AXIS, SHARED_DIR

    kr = load_axis(PAPER_AXIS).transmission_ratio
    t = np.arange(300) * 0.001
    ref = 0.01 * np.sin(2.0 * np.pi * 2.0 * t)
    speed = 0.01 * 2.0 * np.pi * 2.0 * np.cos(2.0 * np.pi * 2.0 * t) * kr
    columns = {
        "time": t,
        "position_reference": ref,
        "speed_setpoint": speed,
        "motor_position": ref * kr,
        "motor_speed": speed,
        "load_position": ref,
        "motor_torque": 3.0 * np.cos(t),
        "disturbance": 0.0 * t,
        "beta": 0.0 * t,
        "lambda": 1.0 + 0.0 * t,
    }
    paths = [folder / "sine.csv"]
    Trace(columns).to_csv(paths[0])
    emps = SHARED_DIR / "data" / "emps" / "DATA_EMPS.mat"
    if emps.is_file():
        from plant_sim.datasets.emps import emps_trace, read_emps_mat

        paths.append(folder / "emps.csv")
        _head(emps_trace(read_emps_mat(emps)), 400).to_csv(paths[-1])
    xl330 = sorted((SHARED_DIR / "data" / "bam_xl330").glob("*.json"))
    if xl330:
        from plant_sim.datasets.xl330 import read_xl330_log, xl330_trace

        paths.append(folder / "xl330.csv")
        _head(xl330_trace(read_xl330_log(xl330[0])), 300).to_csv(paths[-1])
    return paths


def _head(trace: Any, rows: int) -> Any:
    from virtual_bus.formats.trace import Trace

    return Trace({name: values[:rows] for name, values in trace.columns.items()})

"""A recording as a stream of chunks: bounded memory whatever the recording's length.

Two formats:

* **trace files** (CSV, the project's trace spec), parsed block by block with Arrow's
  streaming CSV reader (``pyarrow.csv.open_csv``); the spec's rules are checked across blocks
  (required columns, numbers only, finite values, strictly increasing time, >= 100 rows,
  plausible time unit);
* **candump logs** (``candump -l`` format, ``(EPOCH) IFACE ID#DATA``) of a bus with the PDO
  layout of ``docs/canopen_layout.md``: one sample per SYNC, from the drive's TPDO1 (6064h
  motor position, 60E4h:01 load position) and TPDO2 (6077h torque, 606Ch speed) and the
  bridge's RPDO1 (60FFh speed set point). The scaling is :class:`CandumpLayout`'s; the motor
  rated torque is taken from the start-up's SDO upload of 6076h when the log holds it,
  otherwise torque stays in per mille of the rated torque (``torque_unit``).

Every chunk carries arrays of one length, SI units at the motor (rad, rad/s, N·m) and load
units (m or rad) for the load position.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import RecordingError
from .sources import RecordingKind

if TYPE_CHECKING:
    from .candump import CandumpLayout

#: Rows (trace) or SYNC cycles (log) per chunk.
CHUNK_ROWS = 16384
#: Arrow's parse block, bytes (~ 10,000 rows of a 7-column trace).
CSV_BLOCK_BYTES = 1 << 20
#: A trace must have at least this many rows (trace spec).
MIN_ROWS = 100
#: Plausible sampling interval of a servo trace, s: outside, the time column is not in seconds.
DT_RANGE_S = (1e-6, 1.0)

REQUIRED = ("time", "motor_position", "motor_torque")
OPTIONAL = ("position_reference", "speed_setpoint", "motor_speed", "load_position")


@dataclass
class Chunk:
    """Consecutive samples of one recording (all arrays of one length).

    time_s: s. motor_position_rad, motor_speed_rad_s, speed_setpoint_rad_s: motor side.
    load_position, position_reference: load units (m or rad). motor_torque: N·m, or ‰ of the
    rated torque where the log gives no 6076h (``torque_unit``). Absent signals
    are None for the whole recording.
    """

    time_s: np.ndarray
    motor_position_rad: np.ndarray
    motor_torque: np.ndarray
    load_position: np.ndarray | None = None
    position_reference: np.ndarray | None = None
    speed_setpoint_rad_s: np.ndarray | None = None
    motor_speed_rad_s: np.ndarray | None = None
    torque_unit: str = "N·m"

    def __len__(self) -> int:
        return int(self.time_s.size)


def _check_time(t: np.ndarray, last_t: float, rows_before: int, path: Path) -> None:
    if not np.all(np.isfinite(t)):
        bad = int(np.argmin(np.isfinite(t)))
        raise RecordingError(
            f"{path}: column 'time' row {rows_before + bad + 2}: not a finite number",
            path=str(path),
        )
    steps = np.diff(np.concatenate(([last_t], t))) if math.isfinite(last_t) else np.diff(t)
    if steps.size and not np.all(steps > 0):
        bad = int(np.argmin(steps > 0)) + (1 if not math.isfinite(last_t) else 0)
        raise RecordingError(
            f"{path}: column 'time' row {rows_before + bad + 2}: time must increase strictly",
            path=str(path),
        )


def _check_dt(t: np.ndarray, path: Path) -> None:
    if t.size < 2:
        return
    dt_s = float(np.median(np.diff(t)))
    lo, hi = DT_RANGE_S
    if not lo <= dt_s <= hi:
        raise RecordingError(
            f"{path}: median time step {dt_s:.6g} s lies outside {lo:g}..{hi:g} s: "
            "the time column must be in seconds",
            path=str(path),
        )


def read_trace_chunks(path: Path) -> Iterator[Chunk]:
    """Chunks of a trace file; raises :class:`RecordingError` (one line) where a rule breaks.

    Memory is bounded by :data:`CSV_BLOCK_BYTES` and :data:`CHUNK_ROWS`, not by the file.
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    try:
        reader = pacsv.open_csv(
            path,
            read_options=pacsv.ReadOptions(block_size=CSV_BLOCK_BYTES),
            convert_options=pacsv.ConvertOptions(strings_can_be_null=False),
        )
    except (pa.ArrowInvalid, OSError, UnicodeDecodeError) as exc:
        raise RecordingError(
            f"{path}: not a trace file ({first_line(exc)})", path=str(path)
        ) from None
    names = [n.strip().lstrip("\ufeff") for n in reader.schema.names]
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
        raise RecordingError(
            f"{path}: not a trace file: missing required column(s) {', '.join(missing)} "
            f"(header: {shown})",
            path=str(path),
        )
    index = {n: i for i, n in enumerate(names)}
    rows, last_t, first = 0, -math.inf, True
    try:
        for batch in reader:
            cols: dict[str, np.ndarray] = {}
            for name in (*REQUIRED, *OPTIONAL):
                if name not in index:
                    continue
                column = batch.column(index[name])
                if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
                    raise RecordingError(
                        f"{path}: column '{name}' holds text, not numbers (type {column.type})",
                        path=str(path),
                    )
                values = column.to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
                if name in REQUIRED and not np.all(np.isfinite(values)):
                    bad = int(np.argmin(np.isfinite(values)))
                    raise RecordingError(
                        f"{path}: column '{name}' row {rows + bad + 2}: empty, NaN or inf",
                        path=str(path),
                    )
                cols[name] = values
            t = cols["time"]
            _check_time(t, last_t if not first else math.nan, rows, path)
            if first:
                _check_dt(t, path)
                first = False
            if t.size:
                last_t = float(t[-1])
            rows += t.size
            for start in range(0, t.size, CHUNK_ROWS):
                sl = slice(start, start + CHUNK_ROWS)
                yield Chunk(
                    time_s=t[sl],
                    motor_position_rad=cols["motor_position"][sl],
                    motor_torque=cols["motor_torque"][sl],
                    load_position=_opt(cols, "load_position", sl),
                    position_reference=_opt(cols, "position_reference", sl),
                    speed_setpoint_rad_s=_opt(cols, "speed_setpoint", sl),
                    motor_speed_rad_s=_opt(cols, "motor_speed", sl),
                )
    except pa.ArrowInvalid as exc:
        raise RecordingError(
            f"{path}: not a trace file after row {rows + 1} ({first_line(exc)})", path=str(path)
        ) from None
    if rows < MIN_ROWS:
        raise RecordingError(
            f"{path}: {rows} rows; a trace needs at least {MIN_ROWS}", path=str(path)
        )


def _opt(cols: dict[str, np.ndarray], name: str, sl: slice) -> np.ndarray | None:
    """An optional column's slice; an empty cell, NaN or ±inf there is a sample without that
    measurement (nan), never a number (a required column refuses them instead)."""
    values = cols.get(name)
    if values is None:
        return None
    part = values[sl]
    return np.where(np.isfinite(part), part, np.nan)


def backward_difference(x: np.ndarray, previous: float, dt_s: float) -> np.ndarray:
    """``(x[k] − x[k−1]) / dt_s`` of a chunk whose predecessor ended at ``previous`` (nan at
    the start of a recording: the first value then repeats the second)."""
    start = math.isfinite(previous)
    v = np.diff(np.concatenate(([previous if start else x[0]], x))) / dt_s
    if not start and v.size > 1:
        v[0] = v[1]
    return v


def first_line(exc: BaseException) -> str:
    """First line of an error, without Arrow's parse-block row count (it depends on threads)."""
    text = str(exc).strip()
    return re.sub(r"Row #\d+: ", "", text.splitlines()[0]) if text else type(exc).__name__


def checked(chunk: Chunk, path: Path) -> Chunk:
    """``chunk`` if its time stamps increase, else RecordingError (a log's SYNC times)."""
    if not np.all(np.diff(chunk.time_s) > 0):
        raise RecordingError(f"{path}: SYNC time stamps do not increase", path=str(path))
    return chunk


def open_chunks(
    path: Path, kind: RecordingKind, layout: CandumpLayout | None = None
) -> Iterator[Chunk]:
    """The chunk stream of a recording of either kind (``layout``: how a log is scaled)."""
    if kind is RecordingKind.TRACE:
        return read_trace_chunks(path)
    from .candump import CandumpLayout as _Layout
    from .candump import read_candump_chunks

    return read_candump_chunks(path, layout or _Layout())

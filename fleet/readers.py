"""A recording as a stream of chunks: bounded memory whatever the recording's length.

Two formats:

* **trace files** (CSV, the project's trace spec), parsed block by block with Arrow's
  streaming CSV reader (``pyarrow.csv.open_csv``); the format's rules are checked across
  blocks by the format's own functions (:mod:`virtual_bus.formats.trace`: required columns,
  finite values, strictly increasing time, >= 100 rows, a time step that can be seconds);
  an empty, NaN or infinite cell of an optional column is a sample without that measurement
  (a finite value beyond the format's magnitude limit is refused), a blank line is a row
  without values (refused in the required columns, as by ``read_trace``); a last row without
  its line end (a recorder killed mid-write) is dropped with one warning, as by ``read_trace``;
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
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from virtual_bus.formats import trace as trace_format
from virtual_bus.formats.errors import TraceFileError
from virtual_bus.formats.records import file_whole_lines_end, torn_tail

from .candump import CandumpLayout, read_candump_chunks
from .chunks import CHUNK_ROWS, Chunk, first_line
from .errors import RecordingError
from .sources import RecordingKind

#: Arrow's parse block, bytes (~ 10,000 rows of a 7-column trace).
CSV_BLOCK_BYTES = 1 << 20
#: The optional columns of the trace format the monitor reads (others are ignored).
OPTIONAL = ("position_reference", "speed_setpoint", "motor_speed", "load_position")


def read_trace_chunks(path: Path) -> Iterator[Chunk]:
    """Chunks of a trace file; raises :class:`RecordingError` (one line) where a rule breaks.

    Memory is bounded by :data:`CSV_BLOCK_BYTES` and :data:`CHUNK_ROWS`, not by the file.
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    try:
        end, size = file_whole_lines_end(path)
        torn_tail(str(path), end, size, "row")
        whole = path if end == size else pa.BufferReader(_head(path, end))
        reader = pacsv.open_csv(
            whole,
            read_options=pacsv.ReadOptions(block_size=CSV_BLOCK_BYTES),
            # a blank line is a row without values, refused in a required column as by
            # read_trace (Arrow would skip it and shift every line number after it)
            parse_options=pacsv.ParseOptions(ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(strings_can_be_null=False),
        )
        names = [n.strip().lstrip("\ufeff") for n in reader.schema.names]  # decodes UTF-8
    except (pa.ArrowInvalid, OSError, UnicodeDecodeError) as exc:
        raise RecordingError(
            f"{path}: not a trace file ({first_line(exc)})", path=str(path)
        ) from None
    source = str(path)
    index = {n: i for i, n in enumerate(names)}
    rows, last_t = 0, -math.inf
    try:
        trace_format.check_header(names, trace_format.REQUIRED_COLUMNS, source)
        for batch in reader:
            cols: dict[str, np.ndarray] = {}
            for name in (*trace_format.REQUIRED_COLUMNS, *OPTIONAL):
                if name not in index:
                    continue
                column = batch.column(index[name])
                if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
                    raise RecordingError(
                        f"{path}: column '{name}' holds text, not numbers (type {column.type})",
                        path=source,
                    )
                values = column.to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
                missing = name not in trace_format.REQUIRED_COLUMNS
                trace_format.check_values(name, values, rows + 2, source, missing=missing)
                cols[name] = values
            t = cols["time"]
            trace_format.check_time(t, last_t, rows + 2, source)
            if rows == 0 and (problem := trace_format.sample_time_problem(t, source)):
                raise RecordingError(problem, path=source)
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
        trace_format.check_rows(rows, source)
    except pa.ArrowInvalid as exc:
        raise RecordingError(
            f"{path}: not a trace file after row {rows + 1} ({first_line(exc)})", path=source
        ) from None
    except TraceFileError as exc:
        raise RecordingError(str(exc), path=source) from None


def _head(path: Path, nbytes: int) -> object:
    """The first ``nbytes`` of the file, mapped (not read into memory)."""
    import pyarrow as pa

    return pa.memory_map(str(path)).read_buffer(nbytes) if nbytes else pa.py_buffer(b"")


def _opt(cols: dict[str, np.ndarray], name: str, sl: slice) -> np.ndarray | None:
    """An optional column's slice; an empty cell, NaN or ±inf there is a sample without that
    measurement (nan), never a number (a required column refuses them instead)."""
    values = cols.get(name)
    if values is None:
        return None
    part = values[sl]
    return np.where(np.isfinite(part), part, np.nan)


def open_chunks(
    path: Path, kind: RecordingKind, layout: CandumpLayout | None = None
) -> Iterator[Chunk]:
    """The chunk stream of a recording of either kind (``layout``: how a log is scaled)."""
    if kind is RecordingKind.TRACE:
        return read_trace_chunks(path)
    return read_candump_chunks(path, layout or CandumpLayout())

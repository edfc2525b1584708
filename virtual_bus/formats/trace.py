"""Servo traces (``docs/trace-file.md``): one CSV, one header row, one row per sample.

:class:`Trace` holds named float64 columns of equal length. :func:`read_trace` enforces the
spec's rules (required columns, numeric cells, finite values, strictly increasing time, at
least 100 rows) and warns on implausible units without rescaling; it reads a file up to its
last line end and drops a torn last row with one warning (:mod:`.records`). :class:`TraceWriter`
writes row by row in blocks (:class:`~.records.RecordFile`), so a recorder killed at any moment
leaves whole rows and at most one torn last row; :meth:`Trace.to_csv` replaces a file whole
(:func:`virtual_bus.atomic.replacing`).
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import replacing
from ..closing import Closing
from .errors import TraceFileError, TraceWarning, decode_text, read_bytes
from .records import RecordFile, torn_tail, whole_lines_end

REQUIRED_COLUMNS = ("time", "motor_position", "motor_torque")
MIN_ROWS = 100
#: Largest magnitude of a value in a spec column: beyond it squares and sums over a recording
#: overflow float64 (1e150² · 10⁷ rows < 1.8e308), so such a file is refused, not computed on.
MAX_MAGNITUDE = 1e150
#: Plausible sampling interval of a servo trace, s: outside, the time column is not in seconds.
SAMPLE_TIME_RANGE_S = (1e-6, 1.0)
#: Most sample times per position cycle a replay accepts (beyond: time is not in seconds).
MAX_CYCLES_PER_SAMPLE = 1000
#: Most position cycles a replay of one trace may simulate (10⁸: 28 h at 1 ms).
MAX_REPLAY_CYCLES = 100_000_000

#: Columns of the spec with their units (extra columns are allowed and kept).
COLUMN_UNITS = {
    "time": "s",
    "position_reference": "load unit",
    "speed_setpoint": "rad/s (motor)",
    "motor_position": "rad (motor)",
    "motor_speed": "rad/s (motor)",
    "load_position": "load unit",
    "motor_torque": "N m (motor)",
    "disturbance": "N m (motor)",
    # written by this project's simulator and bridge in addition
    "beta": "rad/s (motor), vibration level",
    "lambda": "1, switching factor of eq. 15",
}

#: Conventional column order for writing (others follow in their own order).
COLUMN_ORDER = tuple(COLUMN_UNITS)
#: The spec's measured columns, in that order: what a recorder on a real axis writes.
RECORDED_COLUMNS = COLUMN_ORDER[:7]
#: What a recording of the motion holds without the drive's internals: the time, the
#: reference, both measuring systems, the motor speed and torque.
MOTION_COLUMNS = (
    "time",
    "position_reference",
    "motor_position",
    "load_position",
    "motor_speed",
    "motor_torque",
)


@dataclass(frozen=True)
class Trace:
    """Named columns of one recording; every column is a float64 array of the same length."""

    columns: Mapping[str, np.ndarray]

    def __post_init__(self) -> None:
        cols = {name: np.asarray(values, dtype=float) for name, values in self.columns.items()}
        lengths = {name: len(v) for name, v in cols.items()}
        if len(set(lengths.values())) > 1:
            raise TraceFileError(f"columns differ in length: {lengths}")
        if "time" not in cols:
            raise TraceFileError("a trace needs a 'time' column", column="time")
        object.__setattr__(self, "columns", cols)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise TraceFileError(
                f"trace has no column {name!r}; it has {', '.join(self.columns)}", column=name
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    def __len__(self) -> int:
        return len(self.columns["time"])

    @property
    def time(self) -> np.ndarray:
        return self.columns["time"]

    @property
    def names(self) -> list[str]:
        ordered = [c for c in COLUMN_ORDER if c in self.columns]
        return ordered + [c for c in self.columns if c not in COLUMN_UNITS]

    def with_columns(self, extra: Mapping[str, np.ndarray]) -> Trace:
        return Trace({**self.columns, **extra})

    def window(self, t_start: float, t_end: float) -> Trace:
        """Rows with t_start <= time < t_end."""
        keep = (self.time >= t_start) & (self.time < t_end)
        return Trace({k: v[keep] for k, v in self.columns.items()})

    def to_csv(self, path: str | Path) -> None:
        """Write the trace to ``path``, replacing the file whole: a kill leaves the file that
        was there (or none) or the complete new one, never a part."""
        with replacing(Path(path)) as tmp, TraceWriter(tmp, self.names) as writer:
            writer.write_rows(np.column_stack([self.columns[c] for c in self.names]))


class TraceWriter(Closing):
    """Row-wise CSV writer: rows are collected and every ``flush_every`` rows (and on close)
    appended as one block (:class:`~.records.RecordFile`: short writes finished, a failed
    write undone). A recorder killed at any moment leaves the header and whole rows, and at
    most one last row cut short without its line end, which the readers drop."""

    def __init__(self, path: str | Path, columns: Sequence[str], flush_every: int = 100) -> None:
        if "time" not in columns:
            raise TraceFileError("a trace needs a 'time' column", column="time")
        self.columns = list(columns)
        self._file = RecordFile(path, pad=False)
        self._file.write((",".join(self.columns) + "\n").encode())
        self._fmt = ",".join(["%r"] * len(self.columns)) + "\n"
        self._flush_every = max(1, flush_every)
        self._lines: list[str] = []

    def write_row(self, values: Sequence[float]) -> None:
        if len(values) != len(self.columns):
            raise TraceFileError(
                f"row has {len(values)} values, the trace {len(self.columns)} columns"
            )
        self._lines.append(self._fmt % tuple(map(float, values)))
        if len(self._lines) >= self._flush_every:
            self.flush()

    def write_rows(self, rows: Iterable[Sequence[float]]) -> None:
        for row in rows:
            self.write_row(row)

    def flush(self) -> None:
        if self._lines:
            self._file.write_lines(self._lines)
            self._lines.clear()

    def close(self) -> None:
        if not self._file.closed:
            self.flush()
            self._file.close()


def _plausibility(trace: Trace, path: Path) -> None:
    """Warn on a column whose range does not fit its unit (spec: warn, never rescale)."""
    limits = {
        "position_reference": 100.0,  # load units: 100 m or 100 rad
        "load_position": 100.0,
        "motor_speed": 2e4,  # rad/s: ~190,000 rpm
        "speed_setpoint": 2e4,
        "motor_torque": 1e6,  # N m (or N for a load-side trace)
    }
    for name, limit in limits.items():
        if name in trace:
            peak = float(np.max(np.abs(trace[name])))
            if peak > limit:
                warnings.warn(
                    f"{path}: column {name!r} reaches {peak:g}, implausible for "
                    f"{COLUMN_UNITS[name]} (limit {limit:g}); wrong unit (mm? deg? rpm?)",
                    TraceWarning,
                    stacklevel=3,
                )
    problem = sample_time_problem(trace.time, str(path))
    if problem is not None:
        warnings.warn(problem, TraceWarning, stacklevel=3)


def first_non_increasing(values: np.ndarray) -> int | None:
    """Index of the first sample that is not greater than its predecessor, None if the
    sequence strictly increases (shared by the trace reader and the recording importers)."""
    steps = np.diff(values)
    return int(np.argmax(steps <= 0)) + 1 if (steps <= 0).any() else None


# --- the rules, shared by read_trace and the fleet monitor's streaming reader ------------------
def check_header(header: Sequence[str], required: Sequence[str], source: str) -> None:
    """Refuse duplicate column names and missing required columns."""
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if list(header).count(h) > 1})
        raise TraceFileError(f"{source}: duplicate column(s) {dup}", column=dup[0])
    for name in required:
        if name not in header:
            shown = ", ".join(header[:8]) + (", ..." if len(header) > 8 else "")
            raise TraceFileError(
                f"{source}: missing required column {name!r} (header: {shown})", column=name
            )


def check_values(
    name: str, values: np.ndarray, first_line: int, source: str, *, missing: bool = False
) -> None:
    """Refuse NaN/inf and magnitudes beyond :data:`MAX_MAGNITUDE` in column ``name``;
    ``first_line`` is the file line of ``values[0]`` (the header is line 1). ``missing``:
    NaN/inf are samples without that measurement (the fleet monitor's optional columns,
    docs/trace-file.md), only the magnitude of the others is checked."""
    finite = np.isfinite(values)
    if not missing and not finite.all():
        line = first_line + int(np.argmax(~finite))
        raise TraceFileError(
            f"{source}: line {line}, column {name!r}: {float(values[line - first_line])} "
            "(empty, NaN or inf not allowed)",
            column=name,
            row=line,
        )
    huge = finite & (np.abs(values) > MAX_MAGNITUDE)
    if huge.any():
        line = first_line + int(np.argmax(huge))
        raise TraceFileError(
            f"{source}: line {line}, column {name!r}: {float(values[line - first_line]):.6g} "
            f"is beyond ±{MAX_MAGNITUDE:g} (computations on it overflow)",
            column=name,
            row=line,
        )


def check_time(time: np.ndarray, previous: float, first_line: int, source: str) -> None:
    """Refuse a time column that does not increase strictly; ``previous`` is the time of the
    line before ``time[0]`` (-inf at the start of a file)."""
    bad = first_non_increasing(np.concatenate(([previous], time)))
    if bad is not None:
        line = first_line + bad - 1
        before = float(previous) if bad == 1 else float(time[bad - 2])
        raise TraceFileError(
            f"{source}: line {line}, column 'time': {float(time[bad - 1])!r} does not "
            f"increase (previous {before!r}); time must be strictly increasing",
            column="time",
            row=line,
        )


def check_rows(rows: int, source: str) -> None:
    """Refuse a trace with fewer than :data:`MIN_ROWS` data rows."""
    if rows < MIN_ROWS:
        raise TraceFileError(f"{source}: {rows} data rows, at least {MIN_ROWS} needed")


def sample_time_problem(time: np.ndarray, source: str) -> str | None:
    """Why the median step of ``time`` cannot be seconds (outside
    :data:`SAMPLE_TIME_RANGE_S`), or None. :func:`read_trace` warns with it (a trace may be
    a slow log); a reader that must compute on the time base refuses with it."""
    if time.size < 2:
        return None
    dt = float(np.median(np.diff(time)))
    lo, hi = SAMPLE_TIME_RANGE_S
    if lo <= dt <= hi:
        return None
    return (
        f"{source}: median time step {dt:.6g} s lies outside {lo:g}..{hi:g} s: the time "
        "column must be in seconds (is it in ms, µs or ns?)"
    )


def read_trace(path: str | Path, required: Sequence[str] = REQUIRED_COLUMNS) -> Trace:
    """Read and check a trace file; raises TraceFileError naming the column or row. A last
    row without its line end (a recorder stopped mid-write) is dropped with one
    :class:`~.errors.TornTailWarning`; every row before it is read."""
    path = Path(path)
    data = read_bytes(path, "trace file", TraceFileError)
    end = whole_lines_end(data)
    torn_tail(str(path), end, len(data), "row")
    text = decode_text(data[:end], path, "trace file", TraceFileError)
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:
        raise TraceFileError(f"{path}: not a CSV file ({exc})") from None
    if not rows:
        raise TraceFileError(f"{path}: empty file, expected a header row")
    header = [h.strip() for h in rows[0]]
    check_header(header, required, str(path))
    body = rows[1:]
    check_rows(len(body), str(path))
    data = np.empty((len(body), len(header)))
    for i, row in enumerate(body):
        line = i + 2  # 1-based, header is line 1
        if len(row) != len(header):
            raise TraceFileError(
                f"{path}: line {line} has {len(row)} cells, header has {len(header)}", row=line
            )
        for j, cell in enumerate(row):
            try:
                data[i, j] = float(cell)
            except ValueError:
                raise TraceFileError(
                    f"{path}: line {line}, column {header[j]!r}: {cell!r} is not a number",
                    column=header[j],
                    row=line,
                ) from None
    for j, name in enumerate(header):
        if name in required or name in COLUMN_UNITS:
            check_values(name, data[:, j], 2, str(path))
    check_time(data[:, header.index("time")], -math.inf, 2, str(path))
    trace = Trace({name: data[:, j].copy() for j, name in enumerate(header)})
    _plausibility(trace, path)
    return trace


def uniform_step(trace: Trace, rel_tol: float = 1e-3) -> float | None:
    """The sample time if ``time`` is uniform within rel_tol, else None."""
    dt = np.diff(trace.time)
    step = float(np.median(dt))
    return step if np.all(np.abs(dt - step) <= rel_tol * step) and math.isfinite(step) else None


def check_time_base(trace: Trace, cycle_s: float, source: str = "trace") -> None:
    """Refuse a trace whose time column cannot be seconds for an axis of position cycle
    ``cycle_s`` before anything is simulated on its time base (shared by identify,
    force_error, simulate and diagnose): more than :data:`MAX_CYCLES_PER_SAMPLE` position
    cycles per sample, or more than :data:`MAX_REPLAY_CYCLES` cycles in all (a time in ms or
    ns would otherwise ask for a replay of years)."""
    dt = float(np.median(np.diff(trace.time)))
    span = float(trace.time[-1] - trace.time[0])
    hint = "time must be in s (is it in ms, µs or ns?)"
    if dt > MAX_CYCLES_PER_SAMPLE * cycle_s:
        raise TraceFileError(
            f"{source}: median sample time {dt:.6g} s is {dt / cycle_s:.3g} position cycles of "
            f"{cycle_s:g} s, allowed at most {MAX_CYCLES_PER_SAMPLE}; {hint}",
            column="time",
        )
    if span / cycle_s > MAX_REPLAY_CYCLES:
        raise TraceFileError(
            f"{source}: time spans {span:.6g} s = {span / cycle_s:.3g} position cycles of "
            f"{cycle_s:g} s, allowed at most {MAX_REPLAY_CYCLES:g}; {hint}",
            column="time",
        )

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

import numpy as np

from ..errors import RecordingError
from .sources import RecordingKind

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


@dataclass(frozen=True)
class CandumpLayout:
    """How the bus log encodes the signals (defaults: docs/canopen_layout.md).

    motor_increments_per_rev: 6064h/606Ch/60FFh increments per motor revolution.
    load_increments_per_unit: 60E4h:01 increments per load unit (nm: 1e9 per m; µrad: 1e6).
    drive_id: the drive's node-ID, 0 = the node whose TPDO1 is seen most often.
    """

    motor_increments_per_rev: int = 1 << 20
    load_increments_per_unit: float = 1e9
    drive_id: int = 0

    @property
    def rad_per_increment(self) -> float:
        return 2.0 * math.pi / self.motor_increments_per_rev


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
            f"{path}: not a trace file ({_first_line(exc)})", path=str(path)
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
            f"{path}: not a trace file after row {rows + 1} ({_first_line(exc)})", path=str(path)
        ) from None
    if rows < MIN_ROWS:
        raise RecordingError(
            f"{path}: {rows} rows; a trace needs at least {MIN_ROWS}", path=str(path)
        )


def _opt(cols: dict[str, np.ndarray], name: str, sl: slice) -> np.ndarray | None:
    values = cols.get(name)
    if values is None:
        return None
    return np.nan_to_num(values[sl], nan=np.nan)


def _first_line(exc: BaseException) -> str:
    """First line of an error, without Arrow's parse-block row count (it depends on threads)."""
    text = str(exc).strip()
    return re.sub(r"Row #\d+: ", "", text.splitlines()[0]) if text else type(exc).__name__


# --- candump logs ---------------------------------------------------------------------------
SYNC = 0x080


def _parse_line(line: str) -> tuple[float, int, bytes] | None:
    """(epoch s, CAN-ID, data) of one ``candump -l`` line; None for a blank line."""
    line = line.strip()
    if not line:
        return None
    stamp, _iface, frame = line.split(" ", 2)
    if not (stamp.startswith("(") and stamp.endswith(")")):
        raise ValueError("no (timestamp)")
    can_id, sep, data = frame.strip().partition("#")
    if not sep:
        raise ValueError("no ID#DATA")
    if data.startswith("R"):
        return float(stamp[1:-1]), int(can_id, 16), b""
    return float(stamp[1:-1]), int(can_id, 16), bytes.fromhex(data)


def _drive_id(path: Path, head: list[tuple[float, int, bytes]]) -> int:
    counts: dict[int, int] = {}
    for _, cid, _ in head:
        if 0x181 <= cid <= 0x1FF:
            counts[cid - 0x180] = counts.get(cid - 0x180, 0) + 1
    if not counts:
        raise RecordingError(
            f"{path}: candump log without the drive's TPDO1 (0x181..0x1FF, 6064h + 60E4h:01): "
            "not a log of the bridge's bus",
            path=str(path),
        )
    return max(counts, key=lambda k: counts[k])


class _CandumpDecoder:
    """Turns frames into one sample per SYNC (the values the drive sampled at that SYNC)."""

    def __init__(self, path: Path, layout: CandumpLayout, drive_id: int) -> None:
        self.path = path
        self.layout = layout
        self.tpdo1, self.tpdo2, self.rpdo1 = 0x180 + drive_id, 0x280 + drive_id, 0x200 + drive_id
        self.sdo_tx = 0x580 + drive_id
        self.rated_torque_nm: float | None = None
        self.rows: list[tuple[float, float, float, float, float, float]] = []
        self._sync_t = math.nan
        self._p1: tuple[int, int] | None = None
        self._p2: tuple[int, int] | None = None
        self._setpoint = math.nan
        self.syncs = 0

    def feed(self, t: float, cid: int, data: bytes) -> None:
        if cid == SYNC:
            self._close_cycle()
            self._sync_t = t
            self.syncs += 1
        elif cid == self.tpdo1 and len(data) >= 8:
            self._p1 = (
                int.from_bytes(data[0:4], "little", signed=True),
                int.from_bytes(data[4:8], "little", signed=True),
            )
        elif cid == self.tpdo2 and len(data) >= 8:
            self._p2 = (
                int.from_bytes(data[2:4], "little", signed=True),
                int.from_bytes(data[4:8], "little", signed=True),
            )
        elif cid == self.rpdo1 and len(data) >= 6:
            self._setpoint = int.from_bytes(data[2:6], "little", signed=True)
        elif (
            cid == self.sdo_tx
            and len(data) == 8
            and data[0] & 0xE2 == 0x42  # expedited upload response (CiA 301)
            and data[1:4] == b"\x76\x60\x00"  # 6076h:00 motor rated torque, mN·m
        ):
            self.rated_torque_nm = int.from_bytes(data[4:8], "little") / 1000.0

    def _close_cycle(self) -> None:
        if self._p1 is not None and self._p2 is not None and math.isfinite(self._sync_t):
            rad = self.layout.rad_per_increment
            self.rows.append(
                (
                    self._sync_t,
                    self._p1[0] * rad,
                    self._p1[1] / self.layout.load_increments_per_unit,
                    float(self._p2[0]),
                    self._p2[1] * rad,
                    self._setpoint * rad,
                )
            )
        self._p1 = self._p2 = None

    def take(self, final: bool = False) -> Chunk | None:
        if final:
            self._close_cycle()
        if not self.rows:
            return None
        a = np.asarray(self.rows, dtype=np.float64)
        self.rows.clear()
        torque = a[:, 3] * (self.rated_torque_nm / 1000.0) if self.rated_torque_nm else a[:, 3]
        return Chunk(
            time_s=a[:, 0],
            motor_position_rad=a[:, 1],
            motor_torque=torque,
            load_position=a[:, 2],
            speed_setpoint_rad_s=a[:, 5],
            motor_speed_rad_s=a[:, 4],
            torque_unit="N·m" if self.rated_torque_nm else "‰",
        )


def read_candump_chunks(path: Path, layout: CandumpLayout = CandumpLayout()) -> Iterator[Chunk]:
    """Chunks of a candump log of the bridge's bus (see the module docstring)."""
    try:
        handle = path.open("r", encoding="ascii", errors="strict")
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read it ({exc.strerror})", path=str(path)) from None
    with handle:
        head: list[tuple[float, int, bytes]] = []
        lineno = 0
        try:
            for line in handle:
                lineno += 1
                parsed = _parse_line(line)
                if parsed is not None:
                    head.append(parsed)
                if len(head) >= 2000:
                    break
            drive = layout.drive_id or _drive_id(path, head)
            decoder = _CandumpDecoder(path, layout, drive)
            for frame in head:
                decoder.feed(*frame)
            for line in handle:
                lineno += 1
                parsed = _parse_line(line)
                if parsed is None:
                    continue
                decoder.feed(*parsed)
                if len(decoder.rows) >= CHUNK_ROWS:
                    chunk = decoder.take()
                    if chunk is not None:
                        yield _checked(chunk, path)
        except (ValueError, UnicodeDecodeError) as exc:
            # a decode error happens while the line is read, before it is counted
            lineno += isinstance(exc, UnicodeDecodeError)
            raise RecordingError(
                f"{path}: line {lineno}: not a candump -l log line ({_first_line(exc)})",
                path=str(path),
            ) from None
        chunk = decoder.take(final=True)
        if decoder.syncs == 0:
            raise RecordingError(f"{path}: candump log without SYNC frames (0x080)", path=str(path))
        if chunk is not None:
            yield _checked(chunk, path)


def _checked(chunk: Chunk, path: Path) -> Chunk:
    if not np.all(np.diff(chunk.time_s) > 0):
        raise RecordingError(f"{path}: SYNC time stamps do not increase", path=str(path))
    return chunk


def open_chunks(path: Path, kind: RecordingKind) -> Iterator[Chunk]:
    """The chunk stream of a recording of either kind."""
    if kind is RecordingKind.TRACE:
        return read_trace_chunks(path)
    return read_candump_chunks(path)

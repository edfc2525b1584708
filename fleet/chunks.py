"""One chunk of a recording: consecutive samples of every signal in SI units, whatever the
recording's format (a trace file, a candump log), and what every reader of chunks shares."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import RecordingError

#: Rows (trace) or SYNC cycles (log) per chunk.
CHUNK_ROWS = 16384


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

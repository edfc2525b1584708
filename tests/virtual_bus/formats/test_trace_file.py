"""Trace files (docs/trace-file.md): round trip, refusals naming column/row, warnings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from virtual_bus.formats.errors import TraceFileError, TraceWarning
from virtual_bus.formats.trace import Trace, TraceWriter, read_trace


def _trace(n: int = 200) -> Trace:
    t = np.arange(n) * 0.001
    return Trace(
        {
            "time": t,
            "motor_position": np.sin(t),
            "motor_torque": np.cos(t),
            "load_position": 1e-3 * t,
            "extra_column": t * 2,
        }
    )


def test_round_trip_keeps_every_column_exactly(tmp_path: Path) -> None:
    trace = _trace()
    trace.to_csv(tmp_path / "t.csv")
    back = read_trace(tmp_path / "t.csv")
    assert set(back.names) == set(trace.names)
    for name in trace.names:
        assert np.array_equal(back[name], trace[name])  # repr() of floats is exact


def test_writer_flushes_so_a_killed_recorder_leaves_a_readable_file(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    writer = TraceWriter(path, ["time", "motor_position", "motor_torque"], flush_every=50)
    for i in range(120):
        writer.write_row([i * 0.001, 0.0, 0.0])
    # not closed (as if killed): the first 100 rows are on disk
    assert len(read_trace(path)) == 100
    writer.close()
    assert len(read_trace(path)) == 120


def _write(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


ROWS = [f"{i * 0.001},{i},{i}" for i in range(150)]


@pytest.mark.parametrize(
    ("header", "rows", "message", "column", "row"),
    [
        (
            "time,motor_position",
            [r.rsplit(",", 1)[0] for r in ROWS],
            "missing required column 'motor_torque'",
            "motor_torque",
            None,
        ),
        ("time,motor_position,motor_torque", ROWS[:50], "50 data rows, at least 100", None, None),
        (
            "time,motor_position,motor_torque",
            [*ROWS[:10], "0.010,abc,1", *ROWS[11:]],
            "line 12, column 'motor_position': 'abc'",
            "motor_position",
            12,
        ),
        (
            "time,motor_position,motor_torque",
            [*ROWS[:20], "0.020,nan,1", *ROWS[21:]],
            "line 22, column 'motor_position'",
            "motor_position",
            22,
        ),
        (
            "time,motor_position,motor_torque",
            [*ROWS[:30], "0.0,1,1", *ROWS[31:]],
            "line 32, column 'time'",
            "time",
            32,
        ),
        (
            "time,motor_position,motor_torque",
            [*ROWS[:5], "0.005,1", *ROWS[6:]],
            "line 7 has 2 cells",
            None,
            7,
        ),
        ("time,time,motor_torque", ROWS, "duplicate column", "time", None),
    ],
)
def test_bad_traces_are_refused_naming_column_and_row(
    tmp_path: Path, header: str, rows: list[str], message: str, column: str | None, row: int | None
) -> None:
    path = _write(tmp_path / "bad.csv", header, rows)
    with pytest.raises(TraceFileError) as info:
        read_trace(path)
    assert message in str(info.value)
    assert info.value.column == column
    assert info.value.row == row


def test_millimetres_in_a_metre_column_give_a_warning_not_a_rescale(tmp_path: Path) -> None:
    trace = _trace()
    mm = trace.with_columns({"load_position": trace["load_position"] * 1e6})
    mm.to_csv(tmp_path / "mm.csv")
    with pytest.warns(TraceWarning, match="load_position"):
        back = read_trace(tmp_path / "mm.csv")
    assert np.array_equal(back["load_position"], mm["load_position"])

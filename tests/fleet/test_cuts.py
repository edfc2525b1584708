"""The fleet monitor's readers on what a kill or a power loss leaves (docs/monitor.md): a
recorder's trace and a bridge's bus log cut at every 4096-byte boundary inside their last
writes and at random byte offsets. The readers return exactly the whole rows and SYNC
cycles before the cut -- checked against the values the writers were given -- and drop a
torn tail with one warning naming the file, the byte and the length; analyse() passes it
on in the result's ``warning``."""

from __future__ import annotations

import math
import random
import warnings
from pathlib import Path

import numpy as np
import pytest

from fleet.analyse import analyse
from fleet.candump import read_candump_chunks
from fleet.errors import RecordingError
from fleet.readers import read_trace_chunks
from fleet.sources import RecordingKind, Source
from tests.bridge.test_recorder import log_run, page_cuts
from tests.virtual_bus.formats.test_trace_cuts import (
    COLUMNS,
    check_warning,
    cuts,
    expected_cut,
    recorded,
)
from virtual_bus.formats.errors import TornTailWarning
from virtual_bus.formats.records import PAGE_BYTES
from virtual_bus.formats.trace import MIN_ROWS
from virtual_bus.shipped import PAPER_AXIS

INC_RAD = 2 * math.pi / (1 << 20)  # the contract's scaling (docs/canopen_layout.md)


def _chunks(reader, path: Path) -> tuple[object, list[warnings.WarningMessage]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return list(reader(path)), caught
        except RecordingError as exc:
            return exc, caught


def test_cut_trace_streams_back_to_its_last_whole_row(tmp_path: Path) -> None:
    source = tmp_path / "recording.csv"
    rows, before, after = recorded(source, seed=2)
    data = source.read_bytes()
    for cut in cuts(before, after, len(data), 60, seed=3):
        path = tmp_path / f"cut_{cut}.csv"
        path.write_bytes(data[:cut])
        n, end = expected_cut(data, cut)
        got, caught = _chunks(read_trace_chunks, path)
        if n < MIN_ROWS:
            assert isinstance(got, RecordingError)
            assert f": {n} data rows, at least" in str(got) or "not a trace file" in str(got)
        else:
            assert not isinstance(got, RecordingError), got
            time = np.concatenate([c.time_s for c in got])
            motor = np.concatenate([c.motor_position_rad for c in got])
            torque = np.concatenate([c.motor_torque for c in got])
            assert np.array_equal(time, rows[:n, COLUMNS.index("time")])
            assert np.array_equal(motor, rows[:n, COLUMNS.index("motor_position")])
            assert np.array_equal(torque, rows[:n, COLUMNS.index("motor_torque")])
        check_warning(caught, path, end, cut)
        path.unlink()


def _cycle_lines(data: bytes) -> tuple[list[int], list[int]]:
    """Byte offsets of the SYNC lines and the ends of the RPDO lines (a cycle's last frame)."""
    syncs, ends, offset = [], [], 0
    for line in data.splitlines(keepends=True):
        if b" 080#" in line:
            syncs.append(offset)
        if b" 202#" in line:
            ends.append(offset + len(line))
        offset += len(line)
    return syncs, ends


@pytest.mark.parametrize("page", [True, False], ids=["page boundaries", "random bytes"])
def test_cut_bus_log_decodes_to_its_last_whole_cycle(tmp_path: Path, page: bool) -> None:
    source = tmp_path / "bus.log"
    run = log_run(source, 1099, seed=5)
    data = source.read_bytes()
    syncs, ends = _cycle_lines(data)
    if page:
        cut_at = [c for w in run.writes[-2:] for c in page_cuts(w)]
    else:
        rng = random.Random(6)
        cut_at = [rng.randrange(0, len(data) + 1) for _ in range(80)]
    v = run.cycles
    for cut in cut_at:
        path = tmp_path / f"cut_{cut}.log"
        path.write_bytes(data[:cut])
        n = sum(e <= cut for e in ends)  # whole cycles: their RPDO line is in
        got, caught = _chunks(read_candump_chunks, path)
        if n == 0:
            assert isinstance(got, RecordingError) or sum(len(c) for c in got) == 0
            path.unlink()
            continue
        assert not isinstance(got, RecordingError), got
        motor = np.concatenate([c.motor_position_rad for c in got])
        assert motor.size == n
        np.testing.assert_array_equal(motor, v[:n, 0] * INC_RAD)
        np.testing.assert_array_equal(
            np.concatenate([c.load_position for c in got]), v[:n, 1] / 1e9
        )
        np.testing.assert_array_equal(np.concatenate([c.motor_torque for c in got]), v[:n, 3])
        np.testing.assert_array_equal(
            np.concatenate([c.speed_setpoint_rad_s for c in got]), v[:n, 5] * INC_RAD
        )
        # dropped: from the SYNC line of a cycle cut short, else a torn last line
        whole = data.rfind(b"\n", 0, cut) + 1
        start = syncs[n] if n < len(syncs) and syncs[n] < whole else None
        start = whole if start is None and whole < cut else start
        torn = [str(w.message) for w in caught if issubclass(w.category, TornTailWarning)]
        if start is None:
            assert not torn, torn
        else:
            assert len(torn) == 1, torn
            assert torn[0].startswith(f"{path}: the last {cut - start} bytes (from byte {start})")
        if page:  # a kill's cut is the end of a line (padding): only a cut cycle is dropped
            assert data[cut - 1] == 0x0A
        path.unlink()


def test_analyse_names_the_dropped_tail_and_goes_on(tmp_path: Path) -> None:
    source = tmp_path / "recording.csv"
    recorded(source, seed=7)
    data = source.read_bytes()
    cut = 30 * PAGE_BYTES + 17
    source.write_bytes(data[:cut])
    result = analyse(Source(source, RecordingKind.TRACE, "M", "X", None, PAPER_AXIS))
    assert result.ok, result.error
    end = data.rfind(b"\n", 0, cut) + 1
    assert result.warning.startswith(f"{source}: the last {cut - end} bytes (from byte {end})")
    assert result.samples == data.count(b"\n", 0, end) - 1

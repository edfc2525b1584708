"""Recorder: the trace file (trace-file.md, read back by plant_sim's reader) and the candump
log (read back by python-can's reader), both flushed while the recording runs."""

from __future__ import annotations

import copy
from pathlib import Path

import can
import numpy as np
import pytest

from bridge.cycle import BridgeState
from bridge.interpolator import Move
from bridge.recorder import BASE_COLUMNS, EXTRA_COLUMNS, BusLog, TraceRecorder
from tests.bridge_helpers import AXIS, PayloadDrive, controller  # tests/ helper module
from virtual_bus.formats.trace import read_trace


def _record(rec: TraceRecorder, cycles: int) -> list[float]:
    c = controller()
    drive = PayloadDrive(AXIS)
    c.queue_move(Move(0.01, 0.05))
    loads = []
    for k in range(cycles):
        drive.advance(bytes(c.step(k * 0.001, *drive.tpdos())), 0.0)
        rec.record(c)
        loads.append(c.load_position)
    return loads


def test_trace_file_has_the_spec_columns_and_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "trace.csv"
    rec = TraceRecorder(path, disturbance=np.full(300, 0.5))
    loads = _record(rec, 300)
    rec.close()
    trace = read_trace(path)
    assert set(BASE_COLUMNS) | {"disturbance"} | set(EXTRA_COLUMNS) == set(trace.names)
    assert len(trace) == 300
    np.testing.assert_allclose(trace["time"], np.arange(300) * 0.001, atol=1e-15)
    np.testing.assert_array_equal(trace["load_position"], loads)  # repr round-trips
    assert np.all(trace["disturbance"] == 0.5)
    assert np.all(trace["state"] == BridgeState.RUNNING.value)
    # the in-memory copy is the same
    mem = rec.trace()
    for name in trace.names:
        np.testing.assert_array_equal(mem[name], trace[name])


def test_trace_file_is_readable_while_recording(tmp_path: Path) -> None:
    """A recorder killed mid-run leaves a file that reads back up to its last flush."""
    path = tmp_path / "trace.csv"
    rec = TraceRecorder(path, keep=False, flush_rows=100)
    _record(rec, 250)  # not closed: rows 201..250 wait for the next block
    assert len(read_trace(path)) == 200
    rec.close()
    assert len(read_trace(path)) == 250


def test_memory_only_recorder_refuses_trace_without_keep() -> None:
    rec = TraceRecorder(None, keep=False)
    with pytest.raises(RuntimeError, match="keep"):
        rec.trace()


def test_bus_log_is_candump_format_and_flushed(tmp_path: Path) -> None:
    path = tmp_path / "bus.log"
    now = [0.0]
    log = BusLog(path, lambda: now[0], channel="vcan0", flush_every=10)
    sent = []
    for k in range(25):
        now[0] = k * 0.001
        msg = can.Message(arbitration_id=0x180 + k % 3, data=bytes([k, 1, 2]), is_extended_id=False)
        log.log(msg, received=bool(k % 2))
        sent.append((k * 0.001, msg.arbitration_id, bytes([k, 1, 2]), bool(k % 2)))
    assert len(path.read_text().splitlines()) == 20  # two flushes of 10 so far
    log.close()
    lines = path.read_text().splitlines()
    assert lines[0] == "(0.000000) vcan0 180#000102 T"
    frames = list(can.CanutilsLogReader(str(path)))
    assert [(f.timestamp, f.arbitration_id, bytes(f.data), f.is_rx) for f in frames] == [
        (pytest.approx(t), i, d, rx) for t, i, d, rx in sent
    ]


@pytest.mark.parametrize("channel", ["vcan0", "sim-0123456789a", "7"])
def test_bus_log_file_is_python_cans_byte_for_byte(tmp_path: Path, channel: str) -> None:
    """BusLog writes the common frame itself (a shorter path); the file must be the one
    python-can's CanutilsLogWriter writes for the same frames and timestamps: standard,
    extended, remote, error and FD frames, a clock that steps back, both directions."""
    frames = [
        can.Message(arbitration_id=0x80, data=b"", is_extended_id=False),
        can.Message(arbitration_id=0x182, data=bytes(range(8)), is_extended_id=False),
        can.Message(arbitration_id=0x1ABCDEF0, data=b"\xaa\x0b", is_extended_id=True),
        can.Message(arbitration_id=0x602, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(is_error_frame=True, arbitration_id=0x20000004, data=bytes(8)),
        can.Message(arbitration_id=0x123, data=bytes(range(12)), is_fd=True, bitrate_switch=True),
        can.Message(arbitration_id=0x7FF, data=b"\xff\x00", is_extended_id=False),
        can.Message(arbitration_id=0x202, data=b"\x0f\x00\x10\x27\x00\x00", is_extended_id=False),
    ]
    # the first frame's instant; one step back (written as the first instant); on
    clock = [1700000000.25, 1700000000.5, 1700000000.125, 1700000001.0000005, 12.0]
    times = [clock[k % len(clock)] for k in range(3 * len(frames))]
    ours = tmp_path / "ours.log"
    reference = tmp_path / "python-can.log"
    it = iter(times)
    log = BusLog(ours, lambda: next(it), channel=channel, flush_every=4)
    writer = can.CanutilsLogWriter(str(reference), channel=channel)
    for k in range(3 * len(frames)):
        msg, received = frames[k % len(frames)], bool(k % 2)
        log.log(msg, received=received)
        expected = copy.copy(msg)
        expected.is_rx, expected.timestamp, expected.channel = received, times[k], channel
        writer.on_message_received(expected)
    log.close()
    writer.stop()
    assert ours.read_bytes() == reference.read_bytes()

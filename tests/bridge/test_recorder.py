"""Recorder: the trace file (trace-file.md, read back by plant_sim's reader) and the candump
log (read back by python-can's reader), both flushed while the recording runs."""

from __future__ import annotations

import copy
import itertools
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
import pytest

from bridge.cycle import BridgeState
from bridge.interpolator import Move
from bridge.recorder import BASE_COLUMNS, EXTRA_COLUMNS, BusLog, TraceRecorder
from tests.bridge_helpers import AXIS, PayloadDrive, controller  # tests/ helper module
from tests.paths import checkout_env
from virtual_bus.formats.records import PAGE_BYTES
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


def test_bus_log_is_candump_format_and_written_in_sync_blocks(tmp_path: Path) -> None:
    """Blocks end before every flush_syncs-th SYNC (the first too: the start-up's frames),
    so the file holds whole cycles between kills; close writes the rest."""
    path = tmp_path / "bus.log"
    now = [0.0]
    log = BusLog(path, lambda: now[0], channel="vcan0", flush_syncs=3)
    sent = []
    lines_on_disk = []
    for k in range(25):
        now[0] = k * 0.001
        cob = 0x080 if k % 4 == 1 else 0x180 + k % 3  # a SYNC every 4 frames from frame 1
        msg = can.Message(arbitration_id=cob, data=bytes([k, 1, 2]), is_extended_id=False)
        log.log(msg, received=bool(k % 2))
        sent.append((k * 0.001, msg.arbitration_id, bytes([k, 1, 2]), bool(k % 2)))
        lines_on_disk.append(len(path.read_text().splitlines()))
    # SYNCs are frames 1, 5, 9, ...: written before SYNCs 0, 3, 6 (frames 1, 13)
    assert lines_on_disk[:13] == [0] * 1 + [1] * 12
    assert lines_on_disk[13:] == [13] * 12
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
    extended, remote, error and FD frames, a clock that steps back, both directions; a
    remote frame's DLC as candump writes it (tests/peers checks against candump itself)."""
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
    log = BusLog(ours, lambda: next(it), channel=channel, flush_syncs=2)
    writer = can.CanutilsLogWriter(str(reference), channel=channel)
    for k in range(3 * len(frames)):
        msg, received = frames[k % len(frames)], bool(k % 2)
        log.log(msg, received=received)
        expected = copy.copy(msg)
        expected.is_rx, expected.timestamp, expected.channel = received, times[k], channel
        writer.on_message_received(expected)
    log.close()
    writer.stop()
    # but a remote frame's DLC, which candump writes after the R and python-can's writer
    # leaves out (its reader takes it)
    expected = reference.read_text().replace(" 602#R ", " 602#R8 ")
    assert ours.read_text() == expected
    remote = [m for m in can.LogReader(str(ours)) if m.is_remote_frame]
    assert remote and all(m.dlc == 8 and m.arbitration_id == 0x602 for m in remote)


# --- what a kill leaves of the bus log ------------------------------------------------------
@dataclass(frozen=True)
class LoggedRun:
    """A bus log as :func:`log_run` wrote it: the frames in file order (COB-ID, data, received),
    the values each cycle carried, and the file's size before and after each write."""

    frames: list[tuple[int, bytes, bool]]
    cycles: np.ndarray  # per cycle: motor inc, load nm, statusword, torque, speed, set point
    writes: list[tuple[int, int]]


def log_run(path: Path, cycles: int, seed: int = 0, channel: str = "vcan0") -> LoggedRun:
    """The traffic of a bridge's run through :class:`BusLog`: an SDO start-up, then per cycle
    SYNC (sent), TPDO1 (6064h, 60E4h:01) and TPDO2 (6041h, 6077h, 606Ch) received, RPDO1
    (6040h, 60FFh) sent, the drive's heartbeat every 100 cycles; random values."""
    rng = np.random.default_rng(seed)
    t = [1_700_000_000.0]

    def clock() -> float:
        t[0] += 1.7e-5
        return t[0]

    log = BusLog(path, clock, channel=channel)
    frames: list[tuple[int, bytes, bool]] = []
    sizes = [0]

    def send(cob: int, data: bytes, received: bool) -> None:
        log.log(can.Message(arbitration_id=cob, data=data, is_extended_id=False), received)
        frames.append((cob, data, received))
        size = path.stat().st_size
        if size != sizes[-1]:
            sizes.append(size)

    for _ in range(20):  # the start-up: SDO uploads of 1000h and their answers
        send(0x602, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]), False)
        send(0x582, bytes([0x43, 0x00, 0x10, 0, 0x92, 0x01, 0x02, 0x00]), True)
    values = np.column_stack(
        [
            rng.integers(-(2**31), 2**31, cycles),
            rng.integers(-(2**31), 2**31, cycles),
            rng.integers(0, 2**16, cycles),
            rng.integers(-(2**15), 2**15, cycles),
            rng.integers(-(2**31), 2**31, cycles),
            rng.integers(-(2**31), 2**31, cycles),
        ]
    )
    for k, (pos, load, status, torque, speed, setpoint) in enumerate(values.tolist()):
        send(0x080, b"", False)
        le = int.to_bytes
        send(0x182, le(pos, 4, "little", signed=True) + le(load, 4, "little", signed=True), True)
        tpdo2 = le(status, 2, "little") + le(torque, 2, "little", signed=True)
        send(0x282, tpdo2 + le(speed, 4, "little", signed=True), True)
        send(0x202, b"\x0f\x00" + le(setpoint, 4, "little", signed=True), False)
        if k % 100 == 99:
            send(0x702, b"\x05", True)
    log.close()
    sizes.append(path.stat().st_size)
    writes = [(a, b) for a, b in itertools.pairwise(sizes) if b > a]
    return LoggedRun(frames, values, writes)


def page_cuts(write: tuple[int, int]) -> list[int]:
    """The 4096-byte boundaries inside a write: where a SIGKILL can stop it."""
    before, after = write
    return list(range((before // PAGE_BYTES + 1) * PAGE_BYTES, after, PAGE_BYTES))


def test_clean_bus_log_is_python_cans_lines_and_padding(tmp_path: Path) -> None:
    """Over many pages: the frame lines are python-can's writer's, byte for byte and in its
    order; between them only padding lines (spaces, a line end) that end on a 4096-byte
    boundary, so no frame line crosses one."""
    path = tmp_path / "bus.log"
    run = log_run(path, 2000)
    reference = tmp_path / "python-can.log"
    writer = can.CanutilsLogWriter(str(reference), channel="vcan0")
    for msg in can.LogReader(str(path)):
        writer.on_message_received(msg)
    writer.stop()
    data = path.read_bytes()
    lines = data.splitlines(keepends=True)
    assert b"".join(line for line in lines if line.strip()) == reference.read_bytes()
    offset = 0
    for line in lines:
        if not line.strip():
            assert set(line[:-1]) <= {0x20} and (offset + len(line)) % PAGE_BYTES == 0
        else:
            assert offset // PAGE_BYTES == (offset + len(line) - 1) // PAGE_BYTES
        offset += len(line)
    padding = sum(len(line) for line in lines if not line.strip())
    assert 0 < padding < 0.02 * len(data)  # ~ half a line a page
    assert len(run.writes) == 2000 // 100 + 1  # the start-up, 19 blocks of 100 cycles, close


def test_every_page_cut_of_a_bus_log_reads_with_python_can_and_log2asc(tmp_path: Path) -> None:
    """Cut where a SIGKILL can stop a write (every page boundary inside the last two writes:
    a block at a SYNC and the close): python-can's LogReader reads every cut without an error
    and returns exactly the frames before it; can-utils' log2asc converts each of them."""
    source = tmp_path / "bus.log"
    run = log_run(source, 1099)
    data = source.read_bytes()
    log2asc = shutil.which("log2asc")
    cut_at = [c for w in run.writes[-2:] for c in page_cuts(w)]
    assert len(cut_at) >= 6
    for cut in cut_at:
        path = tmp_path / f"cut_{cut}.log"
        path.write_bytes(data[:cut])
        n = sum(1 for line in data[:cut].splitlines() if line.strip())
        frames = [(m.arbitration_id, bytes(m.data), m.is_rx) for m in can.LogReader(str(path))]
        assert frames == run.frames[:n]
        if log2asc is not None:
            done = subprocess.run(
                [log2asc, "-I", str(path), "vcan0"], capture_output=True, text=True, timeout=60
            )
            assert done.returncode == 0 and not done.stderr, done.stderr
            rows = [ln for ln in done.stdout.splitlines() if re.match(r"\s*\d+\.\d+ 1 ", ln)]
            assert len(rows) == n
        path.unlink()
    if log2asc is None:
        pytest.skip("can-utils' log2asc is not installed (apt-get install can-utils)")


FULL_DISK = """
import os, resource, signal, sys
import can
from bridge.recorder import BusLog
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of a signal, as a full disk
resource.setrlimit(resource.RLIMIT_FSIZE, (30000, resource.RLIM_INFINITY))
log = BusLog(sys.argv[1], channel="vcan0")
for k in range(2000):  # ~90 kB: the disk is full after ~30 kB
    log.log(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False), False)
    log.log(can.Message(arbitration_id=0x182, data=bytes(8), is_extended_id=False), True)
log.close()
print(log.failed.errno if log.failed else "none")
"""


def test_a_bus_log_on_a_full_disk_stops_at_its_last_whole_block(tmp_path: Path) -> None:
    """RLIMIT_FSIZE as a full disk: logging never raises into the loop; the file keeps the
    blocks written before, whole (python-can reads it), and the log says why it stopped."""
    path = tmp_path / "bus.log"
    done = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(path)],
        capture_output=True,
        text=True,
        env=checkout_env(),
        timeout=120,
        check=True,
    )
    assert done.stdout.split() == ["27"]  # EFBIG
    assert "bus log" in done.stderr and "logging stops" in done.stderr
    data = path.read_bytes()
    assert 0 < len(data) <= 30000 and data.endswith(b"\n")
    frames = list(can.LogReader(str(path)))
    assert sum(f.arbitration_id == 0x080 for f in frames) % 100 == 0  # whole blocks

"""``python -m bridge``: help, one-line errors with exit 2, busload, eds and run."""

from __future__ import annotations

import json
import struct
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from bridge.__main__ import main
from plant_sim.drive import DriveConfig, SimulatedDrive, State402
from tests.command_line import refused_in_one_line
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import read_trace

AXIS_FILE = "config/paper_axis.toml"


@pytest.mark.parametrize(
    "command",
    [
        [],
        ["run"],
        ["busload"],
        ["probe"],
        ["host-latency"],
        ["eds"],
        ["config"],
        ["config", "load"],
    ],
)
def test_help(command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main([*command, "--help"])
    assert info.value.code == 0
    assert "usage: python -m bridge" in capsys.readouterr().out


def run_on(channel: str, *rest: str) -> list[str]:
    """``run`` of the paper axis on virtual bus ``channel`` with the options ``rest``."""
    return ["run", "--interface", "virtual", "--channel", channel, "--axis", AXIS_FILE, *rest]


RUN = run_on("nobody-here")


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        ([], "required: COMMAND"),
        (["fly"], "invalid choice"),
        (["run", "--channel", "x", "--axis", AXIS_FILE], "--interface"),
        ([*RUN, "--node-id", "200", "--seconds", "1"], "node-ID is 1..127"),
        ([*RUN, "--move", "0.3,0.05"], "key=value"),
        ([*RUN, "--move", "target=1,feed=-1"], "feed"),
        ([*RUN], "give --move, --move-file or --seconds"),
        ([*RUN, "--seconds", "-1"], "must be a finite number > 0"),
        ([*RUN[:-1], "missing.toml", "--seconds", "1"], "no such axis file"),
        ([*RUN, "--move-file", "missing.toml"], "no such move file"),
        (
            [
                "run",
                "--interface",
                "udp_multicast",
                "--channel",
                "x",
                "--axis",
                AXIS_FILE,
                "--seconds",
                "1",
            ],
            "not allowed",
        ),
        ([*RUN, "--bitrate", "100000", "--seconds", "1"], "not a CiA 301 bit rate"),
        (
            [
                "run",
                "--interface",
                "kvaser",
                "--channel",
                "0",
                "--axis",
                AXIS_FILE,
                "--seconds",
                "1",
            ],
            "cannot open interface 'kvaser'",
        ),
        ([*RUN, "--node-id", "2", "--drive-id", "2", "--seconds", "1"], "different node-IDs"),
        (["busload", "--bitrate", "100000"], "not a CiA 301 bit rate"),
        (["busload", "--axes", "0"], "must be >= 1"),
        (["busload", "--cycle-us", "abc"], "not a number"),
        (
            ["run", "--channel", "x", "--interface", "virtual", "--axis", AXIS_FILE, "--hold", "0"],
            "> 0",
        ),
        (["config", "get", "--interface", "virtual", "--channel", "x", "2000h"], "--node-id"),
        (["config", "fly"], "invalid choice"),
        ([*RUN, "--seconds", "1", "--store", "/nonexistent-dir/s.json"], "nonexistent"),
        ([*RUN, "--seconds", "1", "--lockstep-wait", "0"], "allowed 0.001..60"),
        ([*RUN, "--seconds", "1", "--lockstep-wait", "61"], "allowed 0.001..60"),
        (
            [*RUN, "--seconds", "1", "--clock", "realtime", "--lockstep-wait", "2"],
            "--lockstep-wait applies to --clock lockstep only",
        ),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert fragment in refused_in_one_line(main, argv, capsys)


def test_busload_of_one_axis(capsys: pytest.CaptureFixture[str]) -> None:
    # Davis et al. worst case: SYNC 55 bits, 8-byte TPDOs 135, 6-byte RPDO 115 = 440 bits
    assert main(["busload", "--bitrate", "500000"]) == 0
    out = capsys.readouterr().out
    assert "total 440 bits = 880.0 us per cycle" in out
    assert "bus load 88.0 % (fits)" in out
    assert main(["busload"]) == 0  # the default is 1 Mbit/s
    assert "bus load 44.0 % (fits)" in capsys.readouterr().out
    assert main(["busload", "--bitrate", "1000000", "--axes", "3"]) == 0
    out = capsys.readouterr().out
    assert "total 1210 bits" in out and "does NOT fit" in out


def test_eds_prints_to_stdout_and_leaves_the_tracked_file_alone(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from bridge.od import DEFAULT_EDS_PATH

    before = DEFAULT_EDS_PATH.stat().st_mtime_ns
    assert main(["eds"]) == 0
    out = capsys.readouterr().out
    assert out == DEFAULT_EDS_PATH.read_text(encoding="utf-8")  # the tracked file is current
    assert "[FileInfo]" in out
    assert DEFAULT_EDS_PATH.stat().st_mtime_ns == before


def test_eds_check(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["eds", "--check"]) == 0
    assert "up to date" in capsys.readouterr().out
    stale = tmp_path / "bridge.eds"
    stale.write_text("[FileInfo]\n")
    assert main(["eds", "--check", "--out", str(stale)]) == 1
    assert main(["eds", "--out", str(stale)]) == 0
    assert main(["eds", "--check", "--out", str(stale)]) == 0


@pytest.fixture
def drive_on_virtual_bus() -> Iterator[tuple[str, SimulatedDrive]]:
    channel = f"cli-{uuid.uuid4().hex[:10]}"
    bus = open_bus(BusConfig(interface=Interface.VIRTUAL, channel=channel))
    drive = SimulatedDrive(bus, 2, load_axis(AXIS_FILE), DriveConfig())
    drive.start()
    try:
        yield channel, drive
    finally:
        drive.stop()
        bus.shutdown()


def test_run_against_the_simulated_drive(
    drive_on_virtual_bus: tuple[str, SimulatedDrive], tmp_path: Path
) -> None:
    channel, drive = drive_on_virtual_bus
    trace_path, log_path = tmp_path / "trace.csv", tmp_path / "bus.log"
    argv = run_on(channel, "--move", "target=0.005,feed=0.05", "--hold", "0.3", "--clock")
    argv += ["lockstep", "--trace", str(trace_path), "--bus-log", str(log_path)]
    assert main(argv) == 0
    assert drive.plant.load_position == pytest.approx(0.005, abs=2e-5)
    assert drive.state is State402.SWITCHED_ON  # disabled at the end, latched by a SYNC
    trace = read_trace(trace_path)
    assert len(trace) == drive.sync_count
    assert trace["position_reference"][-1] == pytest.approx(0.005)
    frames = list(can.CanutilsLogReader(str(log_path)))
    ids = [f.arbitration_id for f in frames]
    assert ids.count(0x080) == drive.sync_count
    assert 0x602 in ids and 0x582 in ids  # the SDO start-up is in the log
    rpdos = [f for f in frames if f.arbitration_id == 0x202]
    assert bytes(rpdos[-1].data[:2]) == b"\x07\x00"  # switch on: at rest after the move
    # the end: the drive's watch of the bridge given back as it was (1016h:01 = 0) over SDO
    last_sync = len(ids) - 1 - ids[::-1].index(0x080)
    writes = [bytes(f.data[:4]) for f in frames[last_sync:] if f.arbitration_id == 0x602]
    assert b"\x23\x16\x10\x01" in writes  # 1016h:01 downloaded (4 bytes, expedited)
    assert drive.read_object(0x1016, 1) == 0


def test_run_exits_1_when_a_fault_stops_the_axis(
    drive_on_virtual_bus: tuple[str, SimulatedDrive], capsys: pytest.CaptureFixture[str]
) -> None:
    channel, _ = drive_on_virtual_bus
    # 0.3 m/s needs 12 mm of following error (eq. 1), above the 5 mm limit
    assert main(run_on(channel, "--move", "target=0.5,feed=0.3", "--clock", "lockstep")) == 1
    out = capsys.readouterr().out
    assert "state STOPPED" in out and "following error" in out


def _store(path: Path, objects: dict[str, str]) -> Path:
    doc = {"format": "backlash-bridge parameter store", "version": 1, "objects": objects}
    path.write_text(json.dumps(doc))
    return path


def test_run_applies_the_parameter_store(
    drive_on_virtual_bus: tuple[str, SimulatedDrive],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A store with a 0.1 mm following-error limit (2008h): the 50 mm/s move (2 mm of
    following error, eq. 1) is stopped -- the stored value, not the axis file's 5 mm."""
    channel, _ = drive_on_virtual_bus
    store = _store(tmp_path / "s.json", {"2008h:00": struct.pack("<f", 1e-4).hex()})
    argv = run_on(channel, "--move", "target=0.01,feed=0.05", "--clock", "lockstep")
    assert main([*argv, "--store", str(store)]) == 1
    assert "2008h = 0.0001 load units" in capsys.readouterr().out


def test_run_refuses_a_store_it_would_refuse(tmp_path: Path, capsys) -> None:
    store = _store(tmp_path / "s.json", {"2000h:00": struct.pack("<f", 5000.0).hex()})
    argv = [*RUN, "--seconds", "1", "--store", str(store)]
    assert "kv_per_s = 5000.0: too high" in refused_in_one_line(main, argv, capsys)

"""``bridge run`` against the drive served on its own (``plant_sim.drive.process.serve``): as
two processes over ``udp_multicast`` in a private network namespace the test creates and
removes, and in one process on ``virtual`` / vcan0. In both, python canopen's own master
reads the drive's objects afterwards, and the bridge's candump log is read back by
python-can's ``can.LogReader`` and, where installed, converted by can-utils' ``log2asc`` and
``asc2log``."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from bridge.__main__ import main as bridge_main
from plant_sim.drive.process import DriveProcessConfig
from tests.command_line import next_line
from tests.paths import ROOT
from tests.serving import drive_in_thread
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import load_axis
from virtual_bus.netns import UDP_GROUP, NetworkNamespace

AXIS_FILE = ROOT / "config" / "paper_axis.toml"
EDS = ROOT / "config" / "drive.eds"
TARGET_M = 0.005
#: Backstop of the wait for the boot-up (a drive that dies ends it at once: end of its output).
#: A drive compiles before its boot-up: on an empty numba cache and a loaded 2-core machine,
#: or in a one-CPU guest, that takes minutes, so the bound is far beyond it.
BOOT_TIMEOUT_S = 900.0


def _bridge_argv(interface: str, channel: str, log: Path, trace: Path) -> list[str]:
    return [
        "run",
        "--interface",
        interface,
        "--channel",
        channel,
        "--axis",
        str(AXIS_FILE),
        "--move",
        f"target={TARGET_M},feed=0.05",
        "--hold",
        "0.3",
        "--clock",
        "lockstep",
        # the exchange is checked here, not how fast a busy host answers (tests/peers/live_bus)
        "--lockstep-wait",
        "30",
        "--bus-log",
        str(log),
        "--trace",
        str(trace),
    ]


def read_drive(bus: can.BusABC) -> dict[str, int]:
    """python canopen's master: SDO uploads of what the bridge left behind (10 s for an
    answer: a busy host may hold one longer than canopen's 0.3 s default)."""
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        node = network.add_node(2, str(EDS))
        node.sdo.RESPONSE_TIMEOUT = 10.0
        return {
            "load_nm": node.sdo[0x60E4][1].raw,
            "statusword": node.sdo[0x6041].raw,
            "syncs": node.sdo[0x2103].raw,
        }
    finally:
        network.disconnect()


def check_bus_log(log: Path, channel: str, syncs: int, started_s: float) -> list[can.Message]:
    """The log by python-can's generic reader: every frame on ``channel``, epoch times from
    the first frame on (the SDO start-up too), as many SYNCs as the drive counted."""
    frames = list(can.LogReader(str(log)))
    assert {f.channel for f in frames} == {channel}
    times = [f.timestamp for f in frames]
    assert started_s - 1.0 <= times[0] <= time.time() and times == sorted(times)
    first_sync = next(i for i, f in enumerate(frames) if f.arbitration_id == 0x080)
    startup = times[: first_sync + 1]
    assert first_sync > 10 and len(set(startup)) > len(startup) // 2  # not all at one instant
    assert sum(f.arbitration_id == 0x080 for f in frames) == syncs
    return frames


# --- one process: virtual (and vcan0) --------------------------------------------------------
@pytest.fixture
def served(bus_mode: Interface) -> Iterator[BusConfig]:
    """The drive served (serve()) in a thread on the bus ``bus_mode``; yields the config of
    that bus for the bridge; stops the drive at the end."""
    if bus_mode is Interface.SOCKETCAN:
        config = BusConfig(interface=Interface.SOCKETCAN, channel="vcan0")
    else:
        config = BusConfig(interface=Interface.VIRTUAL, channel=f"two-{uuid.uuid4().hex[:10]}")
    bus = open_bus(config)
    with drive_in_thread(DriveProcessConfig(load_axis(AXIS_FILE)), bus, BOOT_TIMEOUT_S):
        yield config


def test_bridge_run_against_the_served_drive_in_process(served: BusConfig, tmp_path: Path) -> None:
    log, trace = tmp_path / "bus.log", tmp_path / "trace.csv"
    channel = served.channel or ""
    started = time.time()
    assert bridge_main(_bridge_argv(str(served.interface.value), channel, log, trace)) == 0
    master = open_bus(served)
    try:
        got = read_drive(master)
    finally:
        master.shutdown()
    assert got["load_nm"] == pytest.approx(TARGET_M * 1e9, abs=2e4)
    assert got["statusword"] & 0x6F == 0x23  # switched on: disabled at the end
    check_bus_log(log, channel, got["syncs"], started)


# --- can-utils on the log --------------------------------------------------------------------
def test_bus_log_converts_with_can_utils(served: BusConfig, tmp_path: Path) -> None:
    if not (shutil.which("log2asc") and shutil.which("asc2log")):
        pytest.skip("can-utils' log2asc/asc2log are not installed (apt-get install can-utils)")
    log, trace = tmp_path / "bus.log", tmp_path / "trace.csv"
    channel = served.channel or ""
    assert bridge_main(_bridge_argv(str(served.interface.value), channel, log, trace)) == 0
    frames = list(can.LogReader(str(log)))
    asc, back = tmp_path / "bus.asc", tmp_path / "back.log"
    # log2asc names the interfaces to convert; frames on any other are dropped
    subprocess.run(["log2asc", "-I", str(log), "-O", str(asc), channel], check=True, timeout=60)
    subprocess.run(["asc2log", "-I", str(asc), "-O", str(back)], check=True, timeout=60)
    converted = list(can.LogReader(str(back)))
    assert len(converted) == len(frames)
    assert [(f.arbitration_id, bytes(f.data), f.is_rx) for f in converted] == [
        (f.arbitration_id, bytes(f.data), f.is_rx) for f in frames
    ]
    # asc keeps times relative to the first frame (µs): the offsets survive
    t0, c0 = frames[0].timestamp, converted[0].timestamp
    for original, copy in zip(frames, converted, strict=True):
        assert copy.timestamp - c0 == pytest.approx(original.timestamp - t0, abs=2e-6)


# --- two processes: udp_multicast in a private network namespace -----------------------------
READER = """
import json, sys
from tests.hil.test_two_processes import read_drive
from virtual_bus import BusConfig, open_bus
bus = open_bus(BusConfig(interface="udp_multicast"))
try:
    print(json.dumps(read_drive(bus)))
finally:
    bus.shutdown()
"""


def test_drive_and_bridge_as_two_processes_over_udp(
    private_netns: NetworkNamespace, tmp_path: Path, subprocess_env: dict[str, str]
) -> None:
    """Drive process, ``bridge run`` process, then a python canopen master process; SIGTERM
    ends the drive with exit 0 and one line."""
    log, trace = tmp_path / "bus.log", tmp_path / "trace.csv"
    drive = private_netns.popen(
        [
            sys.executable,
            "-m",
            "plant_sim",
            "drive",
            "--interface",
            "udp_multicast",
            "--axis",
            str(AXIS_FILE),
            # its heartbeat on SYNC time, as the lockstep bridge supervises it: on the wall
            # clock a loop faster than real time (or a starved drive) misses 250 ms of it
            "--clock",
            "lockstep",
        ],
        env=subprocess_env,
    )
    try:
        line = next_line(drive, BOOT_TIMEOUT_S)
        assert line.startswith("drive 2: boot-up sent on udp_multicast group"), line
        started = time.time()
        argv = _bridge_argv("udp_multicast", UDP_GROUP, log, trace)
        run = private_netns.run(
            [sys.executable, "-m", "bridge", *argv], timeout_s=300, env=subprocess_env
        )
        assert run.returncode == 0, run.stderr
        assert "state DISABLED; missed TPDOs 0" in run.stdout
        script = tmp_path / "reader.py"
        script.write_text(READER)
        reader = private_netns.run(
            [sys.executable, str(script), str(EDS)], timeout_s=60, env=subprocess_env
        )
        assert reader.returncode == 0, reader.stderr
        import json

        got = json.loads(reader.stdout)
    finally:
        drive.send_signal(signal.SIGTERM)
        out, err = drive.communicate(timeout=30)
    assert drive.returncode == 0, err
    last = out.strip().splitlines()[-1]
    assert last == (
        f"drive 2: stopped on SIGTERM, bus closed; {got['syncs']} SYNCs served; CiA 402 "
        "switched on, NMT operational, active errors none; refused frames (2105h) none"
    )
    assert got["load_nm"] == pytest.approx(TARGET_M * 1e9, abs=2e4)
    check_bus_log(log, UDP_GROUP, got["syncs"], started)

"""The simulated drive with an FMU as its plant, as its own process on vcan0 (the kernel's
SocketCAN, in the guest where the host has none): probed by ``bridge probe``, run by
``bridge run`` (a separate process), read by CANopenNode (an industrial C stack, written by
others) through its CiA 309-3 gateway. The plant is the shared feed-axis family's seed 0
with a large free play (``shared/plants``, written apart from this project)."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest

from tests.peers import canopennode as cn
from tests.peers.live_bus import Program, bridge_argv, drive_process, env
from tests.peers.peers_common import DRIVE_ID, GATEWAY_ID
from tests.plant_sim.fmu.fmus import family_fmu

pytestmark = pytest.mark.vcan


def fmu_options(family: int = 1) -> list[str]:
    return ["--fmu", str(family_fmu()), "--fmu-param", f"seed=0,family={family}"]


def data_sheet_axis(tmp: Path, options: list[str]) -> Path:
    """The axis file a user writes from the FMU's data sheet (``plant_sim fmu-axis``)."""
    axis = tmp / "axis.toml"
    argv = [sys.executable, "-m", "plant_sim", "fmu-axis", *options, "--out", str(axis)]
    subprocess.run(argv, env=env(), check=True, capture_output=True, timeout=cn.BOUND_S)
    return axis


def test_bridge_probe_reads_the_fmu_drive(tmp_path: Path) -> None:
    drive = drive_process(None, "realtime", extra=fmu_options())
    try:
        assert any("plant: FMU axis_family.fmu (seed=0,family=1)" in x for x in drive.lines)
        profile = tmp_path / "drive.toml"
        argv = [sys.executable, "-m", "bridge", "probe", "--interface", "socketcan"]
        argv += ["--channel", "vcan0", "--drive-id", str(DRIVE_ID), "--out", str(profile)]
        done = subprocess.run(
            argv, env=env(), capture_output=True, text=True, timeout=cn.BOUND_S, check=False
        )
    finally:
        drive.stop()
    assert done.returncode == 0, done.stdout + done.stderr
    assert "start-up would stop" not in done.stdout
    assert "cyclic synchronous velocity" in done.stdout.lower() or "csv" in done.stdout.lower()
    assert profile.is_file()


def test_bridge_run_drives_the_fmu_axis(tmp_path: Path) -> None:
    """The clean axis of seed 0 (family 0): to the target within a micrometre."""
    axis = data_sheet_axis(tmp_path, fmu_options(family=0))
    drive = drive_process(None, "lockstep", extra=fmu_options(family=0))
    try:
        argv = bridge_argv(axis, "lockstep", tmp_path, "--move", "target=0.01,feed=0.02")
        bridge = Program([*argv, "--hold", "0.5", "--trace", str(tmp_path / "t.csv")], "bridge")
        code = bridge.finish()
    finally:
        drive.stop()
    out = "\n".join(bridge.lines)
    assert code == 0, bridge.stderr
    assert "missed TPDOs 0" in out
    from virtual_bus.formats.trace import read_trace

    trace = read_trace(tmp_path / "t.csv")
    # the FMU axis went where it was told (its 50 nm scale, the loop's standstill error)
    assert abs(trace["load_position"][-1] - 0.01) < 1e-6


def test_canopennode_reads_the_fmu_drive(canopennode: cn.Binaries) -> None:
    drive = drive_process(None, "realtime", extra=fmu_options())
    try:
        with cn.gateway(canopennode, GATEWAY_ID) as gw:
            device_type = gw.read(DRIVE_ID, 0x1000, 0)
            position = gw.read(DRIVE_ID, 0x6064, 0)
            load = gw.read(DRIVE_ID, 0x60E4, 1)
            statusword = gw.read(DRIVE_ID, 0x6041, 0)
    finally:
        drive.stop()
    assert device_type.ok and struct.unpack("<I", device_type.data)[0] & 0xFFFF == 402
    # at rest at its start: motor encoder and load scale at 0
    assert position.ok and struct.unpack("<i", position.data)[0] == 0
    assert load.ok and struct.unpack("<i", load.data)[0] == 0
    assert statusword.ok and struct.unpack("<H", statusword.data)[0] & 0x4F == 0x40

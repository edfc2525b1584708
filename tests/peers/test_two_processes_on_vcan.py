"""``bridge run --clock lockstep`` started before the drive it drives (issue 21, point 5).

A simulated drive compiles its physics before its boot-up message; on an empty numba cache
and a busy machine that takes longer than any SDO timeout. In lockstep the bridge's start-up
waits on the drive itself, not on the clock: started first, it says it is waiting, and runs
once the drive (a second process, started only after that line) has booted.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.peers.live_bus import ROOT, Program, bridge_argv, drive_process

pytestmark = pytest.mark.vcan

AXIS_FILE = ROOT / "config" / "paper_axis.toml"


def test_a_lockstep_bridge_started_first_waits_for_the_drives_boot_up(tmp_path: Path) -> None:
    argv = bridge_argv(AXIS_FILE, "lockstep", tmp_path, "--move", "target=0.002,feed=0.05")
    bridge = Program(argv, "bridge run")
    drive = None
    try:
        # its first SDO request went unanswered (3 tries of 0.3 s): now it waits
        bridge.wait_for(lambda _: "waiting for its boot-up" in bridge.stderr, "its wait")
        assert bridge.proc.poll() is None
        drive = drive_process(AXIS_FILE, "lockstep")
        code = bridge.finish()
    finally:
        bridge.stop()
        if drive is not None:
            drive.stop()
    out = "\n".join(bridge.lines)
    assert code == 0 and "state DISABLED; missed TPDOs 0, late 0" in out, bridge.stderr

"""What the kill test (tests/hil/test_kill.py) runs in each forked child (tests/forking.py):
``python -m hil demo`` and ``python -m bridge run`` against the simulated drive, each by its
command's own ``main``."""

from __future__ import annotations

import threading
import uuid
from pathlib import Path

from bridge.__main__ import main as bridge_main
from hil.__main__ import main as hil_main
from plant_sim.drive.config import DriveConfig, TimeMode
from plant_sim.drive.process import DriveProcessConfig, serve
from tests.paths import ROOT
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import load_axis

AXIS_FILE = ROOT / "config" / "paper_axis.toml"
#: Backstop of the wait for the drive's boot-up (it compiles first on an empty numba cache).
BOOT_BACKSTOP_S = 900.0
LOCKSTEP = DriveConfig(time_mode=TimeMode.LOCKSTEP)


def demo(out: str) -> int:
    """``python -m hil demo --out OUT --quiet``."""
    return hil_main(["demo", "--out", out, "--quiet"])


def bridge_run(out: str) -> int:
    """``python -m bridge run`` in lockstep with a move and its trace and bus log, against
    the simulated drive served on the same python-can virtual bus (as
    tests/hil/test_two_processes.py does), its heartbeat on SYNC time as the lockstep bridge
    supervises it (``plant_sim drive --clock lockstep``)."""
    channel = f"kill-{uuid.uuid4().hex[:10]}"
    bus = open_bus(BusConfig(interface=Interface.VIRTUAL, channel=channel))
    stop, booted = threading.Event(), threading.Event()
    thread = threading.Thread(
        target=serve,
        args=(DriveProcessConfig(load_axis(AXIS_FILE), drive=LOCKSTEP), bus, stop),
        kwargs={"ready": lambda _: booted.set()},
        name="drive",
    )
    thread.start()
    try:
        if not booted.wait(BOOT_BACKSTOP_S):
            return 3
        return bridge_main(
            [
                "run",
                "--interface",
                "virtual",
                "--channel",
                channel,
                "--axis",
                str(AXIS_FILE),
                "--move",
                "target=0.005,feed=0.05",
                "--hold",
                "0.3",
                "--clock",
                "lockstep",
                "--bus-log",
                str(Path(out) / "bus.log"),
                "--trace",
                str(Path(out) / "trace.csv"),
                "--quiet",
            ]
        )
    finally:
        stop.set()
        thread.join(60.0)
        bus.shutdown()


def references() -> None:
    """Both trials once, complete, into ``$KILL_REFERENCES/demo`` and ``.../bridge_run``: the
    runs every killed one is compared with, made by the forker itself before it forks, so
    that what they compile and load is in its memory for every child (the threads they start
    end with them)."""
    import os

    folder = Path(os.environ["KILL_REFERENCES"])
    for trial in (demo, bridge_run):
        out = folder / trial.__name__
        out.mkdir(parents=True)
        if trial(str(out)) != 0:
            raise RuntimeError(f"the reference {trial.__name__} failed")

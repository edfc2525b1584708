"""Fail-safe over udp_multicast (issue 28): the simulated drive and ``bridge run`` as two
processes with the real-time clock in a private network namespace, python-can's own
udp_multicast reader beside them (``tests/udp_dump.py``), and at the end a fresh process
reading the drive over SDO (``tests/read_drive.py``). The scenarios are ``tests/fail_safe.py``'s;
their twins on vcan0 (in the guest) are ``tests/peers/test_fail_safe_on_vcan.py``.

* every stop reason of the bridge -- following error, PDO loss (a tool switches the drive's
  TPDO1 off), overrun (the bridge held by SIGSTOP), SIGINT, SIGTERM -- leaves the drive out
  of Operation Enabled with the motor at rest when ``bridge run`` has exited, and the bridge
  says how the stop reached the drive (SYNC, SDO or NMT);
* ``kill -9`` of the bridge mid-move: the drive's heartbeat consumer finds it lost within
  the consumer time and a cycle of the drive's clock, its EMCY 8130h names the cause, the
  quick stop (6007h = 3) brings the motor to rest, within the travel that time allows;
* with no foreign traffic neither node refuses a frame (2105h, 2110h all 0), with the
  real-time and the lockstep clock.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests import fail_safe as fs
from tests.peers.live_bus import Program
from virtual_bus.netns import UDP_GROUP, NetworkNamespace


@pytest.fixture(scope="module")
def udp(netns_skip_reason: str | None) -> Iterator[fs.Wire]:
    if netns_skip_reason is not None:
        pytest.skip(netns_skip_reason)
    with NetworkNamespace.create() as ns:
        yield fs.Wire("udp_multicast", UDP_GROUP, tuple(ns.command([])))


@pytest.fixture(scope="module")
def axis(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fs.axis_file(tmp_path_factory.mktemp("axis"))


@pytest.fixture(scope="module")
def running_drive(udp: fs.Wire, axis: Path) -> Iterator[tuple[Program, Program]]:
    """The observer, then the drive (real-time clock), for the scenarios of this module."""
    observer = udp.observer()
    drive = None
    try:
        drive = udp.drive(axis)
        yield drive, observer
    finally:
        fs.stop(drive)
        fs.stop(observer)


@pytest.mark.parametrize("stop_reason", list(fs.STOPS))
def test_every_stop_of_the_bridge_leaves_the_drive_at_rest(
    udp: fs.Wire,
    axis: Path,
    running_drive: tuple[Program, Program],
    stop_reason: str,
    tmp_path: Path,
) -> None:
    fs.check_stop(udp, axis, tmp_path, running_drive[1], stop_reason)


def test_kill_9_mid_move_the_drive_stops_by_itself(
    udp: fs.Wire, axis: Path, running_drive: tuple[Program, Program], tmp_path: Path
) -> None:
    drive, observer = running_drive
    wall_s = fs.check_kill(udp, axis, tmp_path, observer, drive)
    print(f"EMCY 8130h {wall_s * 1e3:.1f} ms after the bridge's last heartbeat (observer)")


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_no_foreign_traffic_no_refused_frame(
    private_netns: NetworkNamespace, axis: Path, clock: str, tmp_path: Path
) -> None:
    """A bus of its own (the scenarios' drive is node 2 too)."""
    wire = fs.Wire("udp_multicast", UDP_GROUP, tuple(private_netns.command([])))
    fs.check_no_refused_frames(wire, axis, tmp_path, clock)

"""Fail-safe on SocketCAN vcan0 (issue 28), in the User-mode Linux guest where the host has no
SocketCAN: the scenarios of ``tests/fail_safe.py`` with ``candump -L vcan0`` as the observer
(their twins over udp_multicast are ``tests/hil/test_fail_safe.py``), and CANopenNode's
``canopend`` as a node that watches the bridge's heartbeat:

* every stop reason of the bridge leaves the drive out of Operation Enabled at rest when
  ``bridge run`` has exited (a fresh process reads it over SDO), and the bridge says how the
  stop reached the drive;
* ``kill -9`` of the bridge mid-move: the drive stops by itself within the consumer time and
  two cycles (EMCY 8130h, quick stop to rest); with canopend watching the bridge's heartbeat
  (1016h) canopend reports the loss too.

Own frames and refused-frame counters on vcan0: ``tests/peers/test_own_frames_on_vcan.py``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests import fail_safe as fs
from tests.peers import canopennode as cn
from tests.peers.live_bus import Program, need_programs
from tests.peers.peers_common import BRIDGE_ID, GATEWAY_ID
from tests.peers.test_canopennode_master import consume, heartbeat_seen

pytestmark = pytest.mark.vcan

VCAN = fs.Wire("socketcan", "vcan0")


@pytest.fixture(scope="module")
def axis(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fs.axis_file(tmp_path_factory.mktemp("axis"))


@pytest.fixture(scope="module")
def running_drive(axis: Path) -> Iterator[tuple[Program, Program]]:
    """candump, then the drive (real-time clock), for the scenarios of this module."""
    need_programs("candump")
    observer = VCAN.observer()
    drive = None
    try:
        drive = VCAN.drive(axis)
        yield drive, observer
    finally:
        fs.stop(drive)
        fs.stop(observer, 2)


@pytest.mark.parametrize("stop_reason", list(fs.STOPS))
def test_every_stop_of_the_bridge_leaves_the_drive_at_rest(
    axis: Path, running_drive: tuple[Program, Program], stop_reason: str, tmp_path: Path
) -> None:
    fs.check_stop(VCAN, axis, tmp_path, running_drive[1], stop_reason)


def test_kill_9_mid_move_the_drive_stops_by_itself_and_canopend_reports_the_loss(
    axis: Path,
    running_drive: tuple[Program, Program],
    canopennode: cn.Binaries,
    tmp_path: Path,
) -> None:
    """canopend (node 5) watches the bridge's heartbeat with its own consumer (1016h, 500
    ms): it sees the bridge operational, and after ``kill -9`` logs its NMT state as
    unknown (CANopenNode's heartbeat consumer timeout), beside the drive's own reaction."""
    drive, observer = running_drive
    with cn.gateway(canopennode, GATEWAY_ID) as gw:
        consume(gw, 1, BRIDGE_ID)
        start = len(gw.log)
        wall_s = fs.check_kill(VCAN, axis, tmp_path, observer, drive)
        heartbeat_seen(gw, BRIDGE_ID, "operational", start)
        heartbeat_seen(gw, BRIDGE_ID, "unknown", start)
    print(f"EMCY 8130h {wall_s * 1e3:.1f} ms after the bridge's last heartbeat (candump)")

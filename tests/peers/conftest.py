"""Fixtures of the tests against third-party programs (``tests/peers``).

* ``canopennode`` (session): canopend and cocomm built from ``shared/peers`` (cached by the
  source's hash, :mod:`canopennode`); skips with the reason where there is no source or no
  compiler;
* ``drive_process``: the simulated drive as its own process (``python -m plant_sim drive``)
  on vcan0, node 2, wall-clock heartbeat; stopped with SIGTERM at teardown;
* ``bridge_on_vcan``: the bridge node (node 1, axis disabled, its object dictionary served
  over SDO by the service thread, a parameter store in a temporary folder) on vcan0.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.node import Bridge
from tests.bridge_helpers import idle_bridge
from tests.peers import canopennode as cn
from tests.peers.peers_common import AXIS_FILE, DRIVE_ID
from virtual_bus import BusConfig, Interface, open_bus


@pytest.fixture(scope="session")
def canopennode() -> cn.Binaries:
    try:
        return cn.build()
    except cn.PeerUnavailable as exc:
        pytest.skip(str(exc))


@pytest.fixture
def drive_process(subprocess_env: dict[str, str], tmp_path: Path) -> Iterator[subprocess.Popen]:
    """The drive process on vcan0; the caller waits for its boot-up (e.g. by heartbeat)."""
    log = (tmp_path / "drive.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "plant_sim", "drive", "--interface", "socketcan", "--channel",
         "vcan0", "--node-id", str(DRIVE_ID), "--axis", str(AXIS_FILE), "--quiet"],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=subprocess_env,
    )  # fmt: skip
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(cn.BOUND_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()


@pytest.fixture
def bridge_on_vcan(tmp_path: Path) -> Iterator[Bridge]:
    """The paper axis's bridge (node 1), disabled, serving SDO on vcan0."""
    bus = open_bus(BusConfig(interface=Interface.SOCKETCAN, channel="vcan0"))
    try:
        with idle_bridge(bus, tmp_path / "bridge-store.json") as bridge:
            yield bridge
    finally:
        bus.shutdown()

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
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.cycle import Command
from bridge.node import Bridge, BridgeConfig
from bridge.params import BridgeParams
from bridge.timing import LockstepPacer
from tests.peers import canopennode as cn
from tests.peers.peers_common import AXIS_FILE, BRIDGE_ID, DRIVE_ID
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import load_axis


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
    axis = load_axis(AXIS_FILE)
    bus = open_bus(BusConfig(interface=Interface.SOCKETCAN, channel="vcan0"))
    bridge = Bridge(
        bus,
        BridgeParams.for_axis(axis),
        axis.kind,
        LockstepPacer(axis.control.position_cycle),
        config=BridgeConfig(node_id=BRIDGE_ID, store_path=tmp_path / "bridge-store.json"),
    )
    try:
        bridge.start(configure_drive=False)
        bridge.controller.command(Command.DISABLE)
        with bridge.serving():
            yield bridge
    finally:
        bridge.close()
        bus.shutdown()


def service_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "bridge-service"]

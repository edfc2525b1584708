"""Fixtures of the bridge's tests that talk to the simulated drive served in a thread."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator

import can
import canopen
import pytest

from plant_sim.drive import DriveConfig, TimeMode
from plant_sim.drive.process import DriveProcessConfig
from tests.bridge_helpers import AXIS
from tests.paths import ROOT
from tests.serving import drive_in_thread

SIM_EDS = ROOT / "config" / "drive.eds"
#: Backstop of the waits of these fixtures (a thread that hangs; never reached when all is well).
BOUND_S = 120.0


@pytest.fixture
def served() -> Iterator[tuple[str, threading.Event, list]]:
    """The simulated drive served with the real-time clock in a thread (its own clock runs
    when SYNC stops) on a fresh virtual channel; yields the channel, the stop flag and the
    drive (once booted)."""
    channel = f"halt-{uuid.uuid4().hex[:10]}"
    bus = can.Bus(interface="virtual", channel=channel)
    config = DriveProcessConfig(AXIS, drive=DriveConfig(time_mode=TimeMode.REAL_TIME))
    with drive_in_thread(config, bus, BOUND_S) as (stop, drives):
        yield channel, stop, drives


@pytest.fixture
def tool(served: tuple[str, threading.Event, list]) -> Iterator[canopen.RemoteNode]:
    """A CANopen tool beside the bridge: python canopen's master of drive 2."""
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.02
    network.connect(interface="virtual", channel=served[0])
    try:
        node = network.add_node(2, str(SIM_EDS))
        node.sdo.RESPONSE_TIMEOUT = BOUND_S
        yield node
    finally:
        network.disconnect()

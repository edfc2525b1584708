"""Fixtures of the bridge's tests that talk to the simulated drive served in a thread."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator

import can
import canopen
import pytest

from plant_sim.drive import DriveConfig, TimeMode
from plant_sim.drive.process import DriveProcessConfig, serve
from tests.bridge_helpers import AXIS
from tests.paths import ROOT

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
    stop, booted = threading.Event(), threading.Event()
    drives: list = []
    errors: list[BaseException] = []

    def body() -> None:
        config = DriveProcessConfig(AXIS, drive=DriveConfig(time_mode=TimeMode.REAL_TIME))
        try:
            serve(config, bus, stop, ready=lambda d: (drives.append(d), booted.set()))
        except BaseException as exc:
            errors.append(exc)
            booted.set()

    thread = threading.Thread(target=body, name="drive")
    thread.start()
    try:
        assert booted.wait(BOUND_S) and not errors, errors
        yield channel, stop, drives
    finally:
        stop.set()
        thread.join(BOUND_S)
        bus.shutdown()
    assert not errors, errors


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

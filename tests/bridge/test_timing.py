"""Pacers (injected clocks) and the start-up's errors against devices that are not the drive."""

from __future__ import annotations

from collections.abc import Iterator

import can
import canopen
import pytest

from bridge.errors import BridgeConfigError, DriveSetupError, DriveTimeoutError
from bridge.master import DriveSetup
from bridge.node import Bridge, BridgeConfig
from bridge.timing import LockstepPacer, RealTimePacer, TimeMode
from tests.bridge_helpers import paper_bridge
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")


class FakeWall:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_lockstep_time_is_cycles_times_the_period() -> None:
    wall = FakeWall()
    pacer = LockstepPacer(0.001, wait_s=0.02, wall=wall)
    assert pacer.mode is TimeMode.LOCKSTEP
    assert pacer.begin_cycle(0) is None and pacer.now() == 0.0
    assert pacer.begin_cycle(2500) is None and pacer.now() == 2.5
    assert pacer.window_end(wall()) == pytest.approx(100.02)
    wall.t += 10.0  # wall time does not move the control time
    assert pacer.now() == 2.5


def test_real_time_schedule_window_and_skips() -> None:
    wall = FakeWall()
    pacer = RealTimePacer(0.001, deadline_fraction=0.5, wall=wall)
    assert pacer.mode is TimeMode.REAL_TIME
    assert pacer.begin_cycle(0) == 100.0  # t0 is the first call
    assert pacer.begin_cycle(3) == pytest.approx(100.003)
    assert pacer.window_end(100.003) == pytest.approx(100.0035)
    wall.t = 100.0031
    assert pacer.now() == pytest.approx(0.0031)
    assert pacer.cycles_behind(3) == 0
    wall.t = 100.0062  # 3.2 cycles past SYNC 3's instant
    assert pacer.cycles_behind(3) == 3


@pytest.mark.parametrize(
    "make",
    [
        lambda: LockstepPacer(0.0),
        lambda: LockstepPacer(0.001, wait_s=-1.0),
        lambda: RealTimePacer(0.001, deadline_fraction=1.5),
        lambda: RealTimePacer(0.001, spin_s=0.01),
    ],
)
def test_pacer_arguments_are_checked(make: object) -> None:
    with pytest.raises(BridgeConfigError):
        make()  # type: ignore[operator]


def test_bridge_config_checks_node_ids() -> None:
    with pytest.raises(BridgeConfigError, match=r"1\.\.127"):
        BridgeConfig(node_id=0)
    with pytest.raises(BridgeConfigError, match="different"):
        BridgeConfig(node_id=3, drive_id=3)


@pytest.fixture
def other_device(bus_pair: tuple[can.BusABC, can.BusABC]) -> Iterator[canopen.LocalNode]:
    """A CANopen device with node-ID 2 whose dictionary has no PDO objects."""
    network = canopen.Network(bus_pair[1])
    notifier = can.Notifier(bus_pair[1], network.listeners, 0.02)
    network.notifier = notifier
    od = canopen.ObjectDictionary()
    var = canopen.objectdictionary.ODVariable("Device type", 0x1000)
    var.data_type = canopen.objectdictionary.UNSIGNED32
    var.default = 0
    od.add_object(var)
    node = network.create_node(2, od)
    try:
        yield node
    finally:
        notifier.stop(2.0)


def _bridge(bus: can.BusABC, drive_id: int = 2) -> Bridge:
    setup = DriveSetup(sdo_timeout_s=0.05, sdo_retries=1)
    config = BridgeConfig(drive_id=drive_id, drive_setup=setup)
    return paper_bridge(bus, config)


def test_start_up_names_the_object_the_device_refuses(
    bus_pair: tuple[can.BusABC, can.BusABC], other_device: canopen.LocalNode
) -> None:
    bridge = _bridge(bus_pair[0])
    with pytest.raises(DriveSetupError) as info:
        bridge.start()
    # the start-up reads before it writes: the first missing CiA 402 object is named
    assert (info.value.index, info.value.subindex) == (0x6040, 0)
    assert "6040h:00 missing: not a CiA 402 drive" in str(info.value)
    assert other_device.data_store == {}  # nothing written
    bridge.close()


def test_start_up_without_a_drive_times_out(bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
    bridge = _bridge(bus_pair[0], drive_id=9)
    with pytest.raises(DriveTimeoutError) as info:
        bridge.start()
    assert info.value.index == 0x1000 and info.value.abort_code is None
    assert isinstance(info.value, TimeoutError)
    bridge.close()

"""The set point timeout under python canopen's own master, which sends RPDO1 only when the
set point changes (``PdoMap.transmit`` after setting the values): off by default, so the
axis holds its speed; configured over SDO (2102h = 3), it acts within 3 SYNCs and its EMCY,
read by canopen's own EMCY consumer, names the cause."""

from __future__ import annotations

import math
import threading

import canopen
import pytest

from plant_sim.drive.cia402 import State402, state_from_statusword
from plant_sim.drive.rig import Rig, virtual_rig
from virtual_bus.formats.axis import AxisConfig, load_axis

AXIS_FILE = "config/paper_axis.toml"
INC_PER_RAD = 2**20 / (2 * math.pi)


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(AXIS_FILE)


class OnChangeMaster:
    """canopen's RemoteNode as a generic master: RPDO1 (controlword, target velocity) sent
    only when a value changes, SYNC from canopen's producer, TPDO2 through canopen's PDO
    callbacks."""

    def __init__(self, rig: Rig) -> None:
        self.node: canopen.RemoteNode = rig.sdo
        self.network = self.node.network
        self.node.rpdo.read(from_od=True)
        self.node.tpdo.read(from_od=True)
        self._tpdo2 = threading.Event()
        self.node.tpdo[2].add_callback(lambda _map: self._tpdo2.set())
        self.sent = 0

    def set_point(self, controlword: int, speed_rad_s: float) -> None:
        rpdo = self.node.rpdo[1]
        new = (controlword, round(speed_rad_s * INC_PER_RAD))
        if new != (rpdo["Controlword"].raw, rpdo["Target velocity"].raw):
            rpdo["Controlword"].raw, rpdo["Target velocity"].raw = new
            rpdo.transmit()
            self.sent += 1

    def sync(self) -> State402:
        """One SYNC; the state from the TPDO2 it brings."""
        self._tpdo2.clear()
        self.network.sync.transmit()
        assert self._tpdo2.wait(5.0), "no TPDO2 after SYNC"
        return state_from_statusword(self.node.tpdo[2]["Statusword"].raw)


def _enable(master: OnChangeMaster, speed_rad_s: float) -> None:
    master.node.nmt.state = "OPERATIONAL"
    master.set_point(0x06, 0.0)
    master.sync()
    master.set_point(0x0F, speed_rad_s)
    assert master.sync() is State402.OPERATION_ENABLED


def test_default_no_timeout_a_master_sending_on_change_keeps_the_axis(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        master = OnChangeMaster(rig)
        _enable(master, 10.0)
        states = [master.sync() for _ in range(200)]  # the set point does not change
        assert master.sent == 2
        assert set(states) == {State402.OPERATION_ENABLED}
        assert rig.drive.plant.motor_speed_rad_s == pytest.approx(10.0, rel=0.02)
        assert not master.node.emcy.log


def test_configured_timeout_acts_within_3_syncs_and_names_the_cause(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        master = OnChangeMaster(rig)
        master.node.sdo[0x2102].raw = 3  # ask for the timeout: 3 SYNCs without RPDO
        _enable(master, 10.0)
        states = [master.sync() for _ in range(3)]
        assert states == [State402.OPERATION_ENABLED] * 2 + [State402.QUICK_STOP_ACTIVE]
        # the EMCY goes out before the TPDO of that SYNC: canopen's consumer has logged it
        (error,) = [e for e in master.node.emcy.log if e.code == 0x8250]
        assert error.register == 0x11 and master.node.emcy.active == [error]
        # manufacturer bytes: object 2102h (LE), 3 SYNCs, 6007h option 3 (quick stop), 0
        assert bytes(error.data) == bytes([0x02, 0x21, 3, 3, 0])

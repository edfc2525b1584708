"""Helpers of the bridge tests: the stepped loop without a bus, the bridge on a bus.

:class:`PayloadDrive` is plant_sim's AxisPlant behind the contract's PDO scaling with the
one-cycle set point delay; :func:`run_loop` closes the loop with a CycleController.
:func:`paper_bridge` is the bridge of the paper's axis on a bus, :func:`idle_bridge` the same
started without a drive and answering SDO, :func:`sdo_tool` python-canopen's master of it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from canopen.sdo import SdoAbortedError

from bridge import od as objdict
from bridge.cycle import Command, CycleController
from bridge.layout import RPDO1_STRUCT, TPDO1_STRUCT, TPDO2_STRUCT
from bridge.node import Bridge, BridgeConfig
from bridge.params import BridgeParams
from bridge.scaling import MOTOR_INCREMENTS_PER_RAD, Scaling
from bridge.timing import LockstepPacer
from plant_sim.physics.model import AxisPlant, KernelOptions
from plant_sim.physics.simulate import References
from regulator import RegulatorConfig
from virtual_bus.formats.axis import AxisConfig, load_axis

AXIS = load_axis("config/paper_axis.toml")
#: The paper's axis with the guideway friction that shows section X's limit cycle
#: (plant_sim.paper.outputs.LIMIT_CYCLE_VISCOUS).
LIMIT_CYCLE_AXIS = AXIS.with_values({"friction.viscous": 5.0})

RATED_TORQUE_NM = 100.0
OPERATION_ENABLED = 0x0027
FAULT = 0x0008


class PayloadDrive:
    """AxisPlant behind the contract's PDO scaling; the set point of SYNC k acts at k+1."""

    def __init__(self, axis: AxisConfig) -> None:
        self.plant = AxisPlant(axis, KernelOptions())
        self.statusword = OPERATION_ENABLED
        self.setpoint = 0.0
        self.load_offset = 0.0

    def tpdos(self) -> tuple[bytes, bytes]:
        p = self.plant
        tpdo1 = TPDO1_STRUCT.pack(
            round(p.motor_position_rad * MOTOR_INCREMENTS_PER_RAD),
            round((p.load_position + self.load_offset) * 1e9),
        )
        tpdo2 = TPDO2_STRUCT.pack(
            self.statusword,
            round(p.motor_torque_nm * 1000.0 / RATED_TORQUE_NM),
            round(p.motor_speed_rad_s * MOTOR_INCREMENTS_PER_RAD),
        )
        return tpdo1, tpdo2

    def advance(self, rpdo: bytes, disturbance_nm: float) -> int:
        self.plant.advance(self.setpoint, disturbance_nm)
        controlword, increments = RPDO1_STRUCT.unpack(rpdo)
        self.setpoint = increments / MOTOR_INCREMENTS_PER_RAD
        return controlword


def disturbance_in_mnm(refs: References) -> References:
    """``refs`` with the disturbance the simulated drive can hold: 2100h is whole mN·m."""
    return dataclasses.replace(refs, disturbance_nm=np.round(refs.disturbance_nm * 1000) / 1000)


def controller(axis: AxisConfig = AXIS, enabled: bool = True, **changes: object) -> CycleController:
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle, enabled=enabled)
    params = dataclasses.replace(BridgeParams.for_axis(axis, reg), **changes)
    return CycleController(params, Scaling.for_kind(axis.kind, RATED_TORQUE_NM))


def run_loop(c: CycleController, drive: PayloadDrive, refs: References) -> dict[str, np.ndarray]:
    n = refs.position.size
    out = {k: np.empty(n) for k in ("fe", "beta", "lambda", "omega_r")}
    for k in range(n):
        rpdo = c.step(k * c.params.cycle_s, *drive.tpdos())
        out["fe"][k] = c.following_error
        out["beta"][k] = c.vibration_level
        out["lambda"][k] = c.switching_factor
        out["omega_r"][k] = c.omega_r
        drive.advance(bytes(rpdo), refs.disturbance_nm[k])
    return out


def paper_bridge(
    bus: can.BusABC,
    config: BridgeConfig | None = None,
    wall: Callable[[], float] = time.monotonic,
) -> Bridge:
    """The bridge of the paper's axis (its defaults) on ``bus``, paced in lockstep at 1 ms;
    ``wall``: the clock of its service thread (heartbeats between runs)."""
    params = BridgeParams.for_axis(AXIS)
    config = config or BridgeConfig()
    return Bridge(bus, params, AXIS.kind, LockstepPacer(0.001), config=config, wall=wall)


@contextlib.contextmanager
def idle_bridge(
    bus: can.BusABC, store: Path | None = None, wall: Callable[[], float] = time.monotonic
) -> Iterator[Bridge]:
    """:func:`paper_bridge` started without a drive (no drive answers on ``bus``), disabled,
    serving SDO, with its parameter store at ``store``; closed at the end (a "restart" is a
    second block on the same bus and store file)."""
    bridge = paper_bridge(bus, BridgeConfig(store_path=store), wall)
    try:
        bridge.start(configure_drive=False)
        bridge.controller.command(Command.DISABLE)
        with bridge.serving():
            yield bridge
    finally:
        bridge.close()


@contextlib.contextmanager
def sdo_tool(bus: can.BusABC, timeout_s: float = 2.0) -> Iterator[canopen.RemoteNode]:
    """A CANopen tool on ``bus``: python-canopen's RemoteNode of the bridge with its EDS,
    fed by a python-can Notifier; ``timeout_s``: its SDO response timeout."""
    network = canopen.Network(bus)
    notifier = can.Notifier(bus, network.listeners, 0.02)
    network.notifier = notifier
    node = canopen.RemoteNode(objdict.DEFAULT_NODE_ID, objdict.load_od())
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = timeout_s
    try:
        yield node
    finally:
        notifier.stop(2.0)


def abort_code(call: Callable[[], object]) -> int:
    """The SDO abort code ``call`` fails with."""
    with pytest.raises(SdoAbortedError) as info:
        call()
    return info.value.code

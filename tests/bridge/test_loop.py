"""The bridge's loop over the bus with the simulated drive (plant_sim.drive), lockstep.

Same code on vcan0 where the host has it and on python-can's virtual bus otherwise
(``bus_mode``). Independent references: the stepped loop of test_bridge_cycle (AxisPlant
behind the contract scaling, no bus) and ``simulate(..., setpoint_delay_cycles=1)``; the
drive's own state (its CiA 402 state, its plant) for the stops.
"""

from __future__ import annotations

import contextlib
import dataclasses
import struct
import threading
from collections.abc import Iterator
from typing import Any

import can
import numpy as np
import pytest

from bridge.cycle import BridgeState, Command, StopReason
from bridge.interpolator import Move, Table
from bridge.layout import TPDO1_STRUCT
from bridge.params import BridgeParams
from hil.harness import SimulatedAxis, play_references, simulated_axis
from plant_sim.drive import State402
from plant_sim.paper.scenarios import SectionX
from plant_sim.physics.simulate import References
from regulator import RegulatorConfig
from tests.bridge_helpers import (  # tests/ helper module
    AXIS,
    LIMIT_CYCLE_AXIS,
    PayloadDrive,
    controller,
    disturbance_in_mnm,
    run_loop,
)
from virtual_bus import BusConfig, Direction, FaultConfig, FaultKind, Interface, open_bus

#: Section X compressed (limit cycle after 1.0 s without the regulator); 1.6 s.
SHORT_X = SectionX(disturbance_start_s=0.5, disturbance_end_s=1.0, stop_s=1.5, end_s=1.6)
DRIVE_ID = 2
TPDO_IDS = (0x180 + DRIVE_ID, 0x280 + DRIVE_ID)


def params(axis=AXIS, enabled: bool = True, **changes: object) -> BridgeParams:
    reg = RegulatorConfig(kv=25.0, cycle_s=0.001, enabled=enabled)
    return dataclasses.replace(BridgeParams.for_axis(axis, reg), **changes)


@contextlib.contextmanager
def limit_cycle_over_bus(
    enabled: bool, bus_mode: Interface, **options: Any
) -> Iterator[tuple[References, SimulatedAxis]]:
    """:data:`SHORT_X` on the limit-cycle axis over the bus with the simulated drive: its
    references (the disturbance in the whole mN·m the drive holds in 2100h) and the axis."""
    refs = disturbance_in_mnm(SHORT_X.references(LIMIT_CYCLE_AXIS))
    config = params(LIMIT_CYCLE_AXIS, enabled)
    with simulated_axis(
        LIMIT_CYCLE_AXIS, config, interface=bus_mode, disturbance=refs.disturbance_nm, **options
    ) as sim:
        yield refs, sim


class TamperBus(can.BusABC):
    """Test wrapper on the bridge's end: drops received frames with ids in ``drop`` and adds
    ``load_offset_nm`` to 60E4h:01 in received TPDO1 frames (a slipping load scale)."""

    def __init__(self, inner: can.BusABC) -> None:
        self._inner = inner
        self.drop: set[int] = set()
        self.load_offset_nm = 0
        self.dropped = 0
        self.channel_info = f"tamper {inner.channel_info}"
        super().__init__(channel=None)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg = self._inner.recv(timeout)
        if msg is None:
            return None, False
        if msg.arbitration_id in self.drop:
            self.dropped += 1
            return None, False
        if msg.arbitration_id == TPDO_IDS[0] and self.load_offset_nm and len(msg.data) == 8:
            pos, load = TPDO1_STRUCT.unpack(msg.data)
            msg.data = bytearray(TPDO1_STRUCT.pack(pos, load + self.load_offset_nm))
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._inner.send(msg, timeout)

    def shutdown(self) -> None:
        super().shutdown()


@pytest.fixture
def tamper() -> Iterator[list[TamperBus]]:
    made: list[TamperBus] = []
    yield made


def wrap(made: list[TamperBus]):
    def wrapper(bus: can.BusABC) -> can.BusABC:
        made.append(TamperBus(bus))
        return made[-1]

    return wrapper


# --- reproduction ---------------------------------------------------------------------------------
@pytest.mark.parametrize("enabled", [False, True], ids=["ordinary", "regulated"])
def test_loop_over_the_bus_equals_the_stepped_loop(bus_mode: Interface, enabled: bool) -> None:
    """Over the bus (SDO start-up, SYNC, TPDOs, RPDO, the drive's CiA 402 machine, 2100h
    disturbance) the loop is the stepped loop of test_bridge_cycle, value for value: the
    bus adds nothing but the PDO scaling that the stepped loop has too."""
    with limit_cycle_over_bus(enabled, bus_mode) as (refs, sim):
        run = play_references(sim, refs)
        assert sim.drive.sync_count == refs.position.size
    assert run.state is BridgeState.RUNNING and run.counters.missed == 0
    c = controller(LIMIT_CYCLE_AXIS, enabled)
    c.queue_move(Table.from_references(refs))
    stepped = run_loop(c, PayloadDrive(LIMIT_CYCLE_AXIS), refs)
    fe = run.trace["following_error"]
    np.testing.assert_allclose(fe, stepped["fe"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.trace["beta"], stepped["beta"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.trace["lambda"], stepped["lambda"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.trace["speed_setpoint"], stepped["omega_r"], atol=1e-9)


# --- stops -----------------------------------------------------------------------------------
def _moving(sim, cycles: int = 300) -> None:
    sim.bridge.controller.queue_move(Move(0.2, 0.05))
    sim.bridge.run(cycles=cycles)
    assert sim.bridge.controller.state is BridgeState.RUNNING
    assert abs(sim.drive.plant.motor_speed_rad_s) > 10.0  # 0.05 m/s = 15.7 rad/s


def _no_setpoints_after(sim, cycles: int) -> None:
    """After the stop: only quick stop with 0 set point; the drive brings the axis to rest."""
    rec = sim.bridge.recorder
    start = rec.rows
    sim.bridge.run(cycles=cycles)
    after = rec.trace()["speed_setpoint"][start:]
    assert np.all(after == 0.0)
    assert sim.bridge.controller.controlword == 0x0002
    assert abs(sim.drive.plant.motor_speed_rad_s) < 0.05
    assert sim.drive.state in (
        State402.QUICK_STOP_ACTIVE,
        State402.SWITCH_ON_DISABLED,
        State402.FAULT,
    )


def test_heartbeat_loss_stops_the_axis(bus_mode: Interface) -> None:
    with simulated_axis(AXIS, params(), interface=bus_mode) as sim:
        _moving(sim)
        c = sim.bridge.controller
        last_beat = c.drive_watch.heartbeat_at
        assert last_beat is not None  # the drive's 100 ms heartbeat is monitored
        sim.drive.write_object(0x1017, 0, 0)  # the drive's heartbeat producer stops
        sim.bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED)
        assert c.stop_reason is StopReason.HEARTBEAT_LOST
        # detected in the first cycle beyond the 250 ms consumer time of 1016h
        assert 0.250 < c.now_s - c.drive_watch.heartbeat_at <= 0.251 + 1e-9
        assert "1016h" in c.stop_message
        _no_setpoints_after(sim, 400)


def test_drive_fault_during_motion_stops_the_axis_and_reset_recovers(bus_mode: Interface) -> None:
    with simulated_axis(AXIS, params(), interface=bus_mode) as sim:
        _moving(sim)
        # the drive's own encoder monitor (2101h) trips: fault 0x7300, EMCY, Fault state
        sim.drive.write_object(0x2101, 0, 1)
        sim.bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED)
        c = sim.bridge.controller
        assert c.stop_reason in (StopReason.DRIVE_EMCY, StopReason.DRIVE_FAULT)
        assert "0x7300" in c.stop_message
        assert c.drive_error_code == 0x7300
        _no_setpoints_after(sim, 400)
        assert sim.drive.state is State402.FAULT
        # cause removed; reset + enable: fault reset and CiA 402 sequence through the RPDO
        sim.drive.write_object(0x2101, 0, 500_000)
        c.command(Command.RESET)
        c.command(Command.ENABLE)
        sim.bridge.run(until=lambda b: b.controller.state is not BridgeState.ENABLING)
        assert c.state is BridgeState.RUNNING
        assert sim.drive.state is State402.OPERATION_ENABLED
        target = c.load_position + 0.005
        c.queue_move(Move(target, 0.05))
        sim.bridge.run(cycles=600)  # 0.1 s of motion, then the position loop settles
        assert c.state is BridgeState.RUNNING
        assert sim.drive.plant.load_position == pytest.approx(target, abs=2e-5)


def test_encoder_discrepancy_stops_the_axis(bus_mode: Interface, tamper: list) -> None:
    with simulated_axis(AXIS, params(), interface=bus_mode, wrap_bridge_bus=wrap(tamper)) as sim:
        _moving(sim)
        tamper[0].load_offset_nm = 400_000  # 0.4 mm: within 2009h = 0.5 mm
        sim.bridge.run(cycles=50)
        assert sim.bridge.controller.state is BridgeState.RUNNING
        tamper[0].load_offset_nm = 700_000  # the scale slips by 0.7 mm
        sim.bridge.run(cycles=1)
        c = sim.bridge.controller
        assert c.stop_reason is StopReason.ENCODER_DISCREPANCY
        # the slip plus the true motor-load difference (free play, deflection; 2104h = x_l - θ/k_r)
        true_difference = -sim.drive.read_object(0x2104) * 1e-9
        assert c.motor_load_difference == pytest.approx(-0.0007 + true_difference, abs=2e-6)
        _no_setpoints_after(sim, 400)
        assert sim.drive.active_errors == ()  # only the bridge saw it (the frames were bent)


def test_persistent_pdo_loss_stops_the_axis(bus_mode: Interface, tamper: list) -> None:
    with simulated_axis(
        AXIS, params(pdo_loss_tolerance=4), interface=bus_mode, wrap_bridge_bus=wrap(tamper)
    ) as sim:
        _moving(sim)  # the default lockstep wait: the drive's TPDOs come however busy the host
        c = sim.bridge.controller
        assert c.consecutive_missed == 0
        missed = sim.bridge.counters.missed
        tamper[0].drop = set(TPDO_IDS)
        # from now on no TPDO reaches the loop: how long it waits for them changes no count,
        # only how long this test takes
        sim.bridge.pacer.wait_s = 0.005
        k0 = sim.bridge.cycle_index
        sim.bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED)
        assert c.stop_reason is StopReason.PDO_LOSS
        assert sim.bridge.cycle_index - k0 == 5  # tolerance 4: the 5th lost cycle stops
        assert sim.bridge.counters.missed - missed == 10
        tamper[0].drop = set()
        _no_setpoints_after(sim, 400)


# --- random loss and delay -----------------------------------------------------------------------
def test_random_loss_and_delay_keep_the_loop_stable_and_are_all_counted(
    bus_mode: Interface,
) -> None:
    """1 % of the received frames dropped and 1 % delayed by 2.5 cycles (seeded): the loop
    runs on (PDO loss tolerance 5 consecutive cycles), nothing crashes, and the counters
    account for every TPDO frame: missed - late = dropped + still held."""
    fault = FaultConfig(
        seed=7, direction=Direction.RECEIVE, drop_p=0.01, delay_p=0.01, delay_s=0.0025
    )
    refs = SectionX(end_s=1.5, stop_s=1.0).references(AXIS)
    with simulated_axis(
        AXIS,
        params(),
        interface=bus_mode,
        fault=fault,
        lockstep_wait_s=0.02,
        disturbance=refs.disturbance_nm,
    ) as sim:
        run = play_references(sim, refs)
        bridge = sim.bridge
        bridge.pacer.begin_cycle(bridge.cycle_index + 10)  # let held frames come due
        bridge.drain()
        counts = sim.bridge_bus.counters  # type: ignore[attr-defined]
    assert run.state is BridgeState.RUNNING, run.stop_message
    k = bridge.counters
    dropped = sum(
        counts.count(FaultKind.DROP, direction=Direction.RECEIVE, can_id=i) for i in TPDO_IDS
    )
    delayed = sum(
        counts.count(FaultKind.DELAY, direction=Direction.RECEIVE, can_id=i) for i in TPDO_IDS
    )
    assert dropped > 0 and delayed > 0
    assert counts.pending[Direction.RECEIVE] == 0
    assert k.missed - k.late == dropped  # a TPDO that came late was counted missed first
    # every delayed TPDO (2.5 cycles) arrived after its cycle; on a busy host a TPDO that was
    # not delayed may also miss the 20 ms wall-clock window: it is then late, never lost
    assert k.late >= delayed
    assert k.missed_cycles <= k.missed
    # stable: the following error stays where the undisturbed loop has it (eq. 1: 2 mm)
    fe = run.trace["following_error"]
    assert np.max(np.abs(fe)) < 2.2e-3
    assert np.max(run.trace["beta"]) < 0.2  # no vibration was provoked


def test_sdo_configuration_while_the_loop_runs(bus_mode: Interface) -> None:
    """A CANopen tool changes a limit over SDO while the loop runs (served between frames)."""
    import canopen

    from bridge import od as objdict

    with simulated_axis(AXIS, params(), interface=bus_mode) as sim:
        bus = open_bus(BusConfig(interface=bus_mode, channel=sim.channel))
        network = canopen.Network(bus)
        notifier = can.Notifier(bus, network.listeners, 0.02)
        node = canopen.RemoteNode(1, objdict.load_od())
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 5.0
        stop = threading.Event()
        loop = threading.Thread(
            target=lambda: sim.bridge.run(until=lambda b: stop.is_set()), name="bridge-loop"
        )
        try:
            loop.start()
            # the loop enables the axis in its first cycles: wait for RUNNING, bounded by
            # the loop's own progress (its cycles), not by the clock
            state = node.sdo.upload(objdict.STATE, 0)[0]
            while state != BridgeState.RUNNING.value and sim.bridge.cycle_index < 1000:
                assert loop.is_alive()
                state = node.sdo.upload(objdict.STATE, 0)[0]
            node.sdo.download(objdict.FE_LIMIT, 0, struct.pack("<f", 0.003))
            state = node.sdo.upload(objdict.STATE, 0)[0]
            code = None
            try:
                node.sdo.download(objdict.KV, 0, struct.pack("<f", 30.0))
            except canopen.SdoAbortedError as exc:
                code = exc.code
        finally:
            stop.set()
            loop.join()
            notifier.stop(2.0)
            bus.shutdown()
    assert sim.bridge.controller.params.following_error_limit == pytest.approx(0.003)
    assert state == BridgeState.RUNNING.value
    assert code == 0x0800_0022

"""Software position limits 2014h (like CiA 402 607Dh): a move whose path leaves them is
refused with the side it leaves on (0609 0031 / 0609 0032) and changes nothing; an axis
outside them while running is stopped with its reason (StopReason.POSITION_LIMIT) unless a
move heads back inside; limits must keep min < max.

Closed-loop cases run the bridge against the simulated drive over the bus (its CiA 402
machine and physics), the rest the stepped controller with the contract's PDO payloads.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from bridge import od as objdict
from bridge.cycle import BridgeState, Command, StopReason
from bridge.errors import ParameterError, SdoAbort
from bridge.interpolator import Move, Table
from bridge.layout import TPDO1_STRUCT, TPDO2_STRUCT
from bridge.scaling import MOTOR_INCREMENTS_PER_RAD
from hil.harness import simulated_axis
from tests.bridge_helpers import AXIS, OPERATION_ENABLED, controller  # tests/ helper module
from virtual_bus import Interface

KR = AXIS.transmission_ratio


def payloads(x_l: float) -> tuple[bytes, bytes]:
    """TPDOs of an axis at rest at x_l (m), motor and load scale agreeing."""
    motor = round(x_l * KR * MOTOR_INCREMENTS_PER_RAD)
    return TPDO1_STRUCT.pack(motor, round(x_l * 1e9)), TPDO2_STRUCT.pack(OPERATION_ENABLED, 0, 0)


def running(x_l: float = 0.0, low: float = -0.01, high: float = 0.01):
    c = controller(position_limit_min=low, position_limit_max=high)
    c.step(0.0, *payloads(x_l))  # ENABLING -> RUNNING (drive already enabled)
    return c


@pytest.mark.parametrize(
    ("target", "code"), [(0.0101, SdoAbort.TOO_HIGH), (-0.02, SdoAbort.TOO_LOW)]
)
def test_move_beyond_a_limit_is_refused_and_changes_nothing(target: float, code: int) -> None:
    c = running()
    with pytest.raises(ParameterError, match=r"2014h \[-0.01, 0.01\]") as info:
        c.start_move(Move(target, 0.05))
    assert info.value.abort_code == code
    assert not c.interpolator.busy
    with pytest.raises(ParameterError):
        c.queue_move(Move(target, 0.05))
    assert not c.moving
    c.start_move(Move(0.01, 0.05))  # on the limit: allowed
    assert c.interpolator.busy


def test_table_leaving_the_limits_is_refused() -> None:
    c = running()
    x = np.linspace(0.0, 0.02, 50)
    with pytest.raises(ParameterError, match=r"table positions 0\.\.0\.02"):
        c.queue_move(Table(x, np.gradient(x)))


def test_axis_outside_the_limits_is_stopped_with_its_reason() -> None:
    c = running(0.005)
    c.step(0.001, *payloads(0.005))
    assert c.state is BridgeState.RUNNING
    c.set_params(c.params.with_value("position_limit_max", 0.004))  # limits may change live
    rpdo = c.step(0.002, *payloads(0.005))
    assert c.state is BridgeState.STOPPED
    assert c.stop_reason is StopReason.POSITION_LIMIT
    assert "0.005 load units outside the software position limits 2014h" in c.stop_message
    assert bytes(rpdo) == struct.pack("<Hi", 0x0002, 0)  # quick stop, set point 0


def test_a_move_back_inside_is_allowed_from_outside() -> None:
    c = running(0.005)
    c.set_params(c.params.with_value("position_limit_max", 0.004))
    c.step(0.001, *payloads(0.005))
    assert c.stop_reason is StopReason.POSITION_LIMIT
    c.command(Command.RESET)
    c.queue_move(Move(0.003, 0.05))  # target inside: accepted while disabled
    c.command(Command.ENABLE)
    x = 0.005
    for k in range(2, 60):  # the axis follows the reference back inside
        c.step(k * 0.001, *payloads(x))
        assert c.state is BridgeState.RUNNING, c.stop_message
        x = max(0.003, x - 0.05 * 0.001)
    assert not c.interpolator.busy and x == 0.003


@pytest.mark.parametrize(
    ("field", "value", "code"),
    [
        ("position_limit_min", 0.02, SdoAbort.TOO_HIGH),  # above max
        ("position_limit_max", -0.02, SdoAbort.TOO_LOW),  # below min
        ("position_limit_max", 2000.0, SdoAbort.TOO_HIGH),
        ("position_limit_min", float("nan"), SdoAbort.VALUE_RANGE),
    ],
)
def test_limits_keep_min_below_max(field: str, value: float, code: int) -> None:
    c = running()
    with pytest.raises(ParameterError) as info:
        c.params.with_value(field, value)
    assert info.value.abort_code == code


def test_eds_defaults_lie_within_the_limits() -> None:
    """Every default of the table that is a position (targets, references) is inside the
    default 2014h, and the default limits are the ones BridgeParams.for_axis gives."""
    defaults = {(e.index, e.subindex): e.default for e in objdict.entries()}
    low, high = defaults[(objdict.POSITION_LIMITS, 1)], defaults[(objdict.POSITION_LIMITS, 2)]
    assert low < 0.0 < high
    assert low <= defaults[(objdict.TARGET, 0)] * 1e-9 <= high
    assert low <= defaults[(objdict.POSITION_REFERENCE, 0)] <= high
    p = controller().params
    assert (p.position_limit_min, p.position_limit_max) == (low, high)


def test_over_the_bus_a_target_beyond_the_limit_is_refused_and_a_crossing_stops(
    bus_mode: Interface,
) -> None:
    """The bridge against the simulated drive: 2010h beyond 2014h:02 answers 0609 0031 and
    the axis stays put; after lowering 2014h:02 below the axis, the next cycle stops it."""
    params = controller(position_limit_max=0.004).params
    with simulated_axis(AXIS, params, interface=bus_mode) as sim:
        objects, c = sim.bridge.objects, sim.bridge.controller
        sim.bridge.run(cycles=5)
        assert c.state is BridgeState.RUNNING
        with pytest.raises(ParameterError) as info:
            objects.write(objdict.TARGET, 0, struct.pack("<i", 5_000_000))  # 5 mm
        assert info.value.abort_code == SdoAbort.TOO_HIGH
        objects.write(objdict.TARGET, 0, struct.pack("<i", 3_000_000))  # 3 mm: inside
        sim.bridge.run(until=lambda b: not b.controller.moving)
        sim.bridge.run(cycles=300)
        assert sim.drive.plant.load_position == pytest.approx(0.003, abs=2e-5)
        objects.write(objdict.POSITION_LIMITS, 2, struct.pack("<f", 0.002))
        sim.bridge.run(cycles=1)
        assert c.stop_reason is StopReason.POSITION_LIMIT
        sim.bridge.run(cycles=300)
        assert abs(sim.drive.plant.motor_speed_rad_s) < 0.05

"""The cycle's arithmetic (bridge.cyclecore) run as Python and compiled by numba: the same bits.

Both controllers get the same TPDO payloads, cycle by cycle, from a plant (plant_sim's
AxisPlant behind the contract's scaling) that the Python one drives; every output of the
compiled one must equal the Python one's to the bit -- set points, measurements, beta,
lambda, errors -- through section X (feed, disturbance, stop) ordinary and regulated, and
through every way the core hands a cycle back to the controller (a stop with its message,
an error). The loop over the bus runs the compiled core against the Python controller of
tests/hil/test_lockstep_identity.py as well.
"""

from __future__ import annotations

import math
import struct
import subprocess
import sys

import pytest

from bridge.cycle import BridgeState, CycleController, StopReason
from bridge.cyclecore import load
from bridge.interpolator import Move, Table
from bridge.layout import TPDO1_STRUCT, TPDO2_STRUCT
from bridge.scaling import Scaling
from plant_sim.paper.scenarios import SectionX
from regulator.errors import RegulatorInputError
from tests.bridge_helpers import OPERATION_ENABLED, PayloadDrive, controller
from tests.paths import ROOT
from virtual_bus.formats.axis import load_axis

pytest.importorskip("numba")

AXIS = load_axis("config/paper_axis.toml")
LIMIT_CYCLE_AXIS = AXIS.with_values({"friction.viscous": 5.0})
SHORT_X = SectionX(disturbance_start_s=0.5, disturbance_end_s=1.0, stop_s=2.5, end_s=2.6)
OUTPUTS = (
    "omega_r",
    "omega_s",
    "omega_c",
    "position_reference",
    "following_error",
    "motor_load_difference",
    "motor_position_rad",
    "load_position",
    "motor_speed_rad_s",
    "motor_torque_nm",
    "vibration_level",
    "switching_factor",
    "statusword",
    "consecutive_missed",
    "missed_cycles",
    "controlword",
)


def _twins(enabled: bool = True, **changes: object) -> tuple[CycleController, CycleController]:
    python = controller(LIMIT_CYCLE_AXIS, enabled, **changes)
    compiled = CycleController(python.params, python.scaling, compiled=True)
    assert not python.core.compiled and compiled.core.compiled
    return python, compiled


def _same(a: CycleController, b: CycleController, k: int) -> None:
    for name in OUTPUTS:
        x, y = getattr(a, name), getattr(b, name)
        assert type(x) is type(y) and (x == y or (x != x and y != y)), (k, name, x, y)
        if isinstance(x, float):
            assert struct.pack("<d", x) == struct.pack("<d", y), (k, name)
    assert (a.state, a.stop_reason, a.stop_message) == (b.state, b.stop_reason, b.stop_message)


@pytest.mark.parametrize("enabled", [False, True], ids=["ordinary", "regulated"])
def test_compiled_and_python_cores_give_the_same_bits_through_section_x(enabled: bool) -> None:
    refs = SHORT_X.references(LIMIT_CYCLE_AXIS)
    python, compiled = _twins(enabled)
    for c in (python, compiled):
        c.queue_move(Table.from_references(refs))
    drive = PayloadDrive(LIMIT_CYCLE_AXIS)
    lost = {700, 701, 1500}  # TPDO2 missing: extrapolation and the PDO-loss counters
    for k in range(refs.position.size):
        tpdo1, tpdo2 = drive.tpdos()
        frames = (tpdo1, None if k in lost else tpdo2)
        rpdo = bytes(python.step(k * 0.001, *frames))
        assert bytes(compiled.step(k * 0.001, *frames)) == rpdo, k
        _same(python, compiled, k)
        drive.advance(rpdo, float(refs.disturbance_nm[k]))
    assert python.state is BridgeState.RUNNING and python.missed_cycles == 3


def _running(c: CycleController, x_l: float = 0.0) -> None:
    c.step(0.0, TPDO1_STRUCT.pack(0, round(x_l * 1e9)), TPDO2_STRUCT.pack(OPERATION_ENABLED, 0, 0))
    assert c.state is BridgeState.RUNNING


@pytest.mark.parametrize(
    ("reason", "change", "x_l"),
    [
        (StopReason.FOLLOWING_ERROR, {"following_error_limit": 0.001}, 0.002),
        (
            StopReason.POSITION_LIMIT,
            {"position_limit_max": 0.001, "following_error_limit": 0.01, "discrepancy_limit": 0.01},
            0.002,
        ),
        (
            StopReason.ENCODER_DISCREPANCY,
            {"discrepancy_limit": 0.001, "following_error_limit": 0.01},
            0.002,
        ),
    ],
)
def test_a_stop_the_core_finds_is_the_controllers_own(
    reason: StopReason, change: dict[str, float], x_l: float
) -> None:
    python, compiled = _twins(**change)
    for c in (python, compiled):
        _running(c)
        # the load jumps 2 mm: one measured cycle, the core hands the stop back with its code
        c.step(0.001, TPDO1_STRUCT.pack(0, round(x_l * 1e9)), TPDO2_STRUCT.pack(0x27, 0, 0))
        assert c.stop_reason is reason, c.stop_message
    _same(python, compiled, 1)


def test_pdo_loss_and_a_drive_that_left_operation_enabled_stop_alike() -> None:
    for statusword, reason in (
        (0x0008, StopReason.DRIVE_FAULT),
        (0x0040, StopReason.DRIVE_DISABLED),
    ):
        python, compiled = _twins()
        for c in (python, compiled):
            _running(c)
            c.step(0.001, TPDO1_STRUCT.pack(0, 0), TPDO2_STRUCT.pack(statusword, 0, 0))
            assert c.stop_reason is reason
        _same(python, compiled, 1)
    python, compiled = _twins(pdo_loss_tolerance=2)
    for c in (python, compiled):
        _running(c)
        for k in range(1, 4):
            c.step(k * 0.001, None, None)
        assert c.stop_reason is StopReason.PDO_LOSS and "3 consecutive" in c.stop_message
    _same(python, compiled, 3)


def test_a_non_finite_reference_raises_the_regulators_error_in_both() -> None:
    for c in _twins():
        _running(c)
        c.interpolator.queue(Move(0.001, 0.01))
        c.interpolator.step()
        c.interpolator.position = math.nan  # as a broken move would leave it
        c.interpolator.step = lambda: None  # type: ignore[method-assign]
        with pytest.raises(RegulatorInputError, match="x_ref"):
            c.step(0.001, TPDO1_STRUCT.pack(0, 0), TPDO2_STRUCT.pack(OPERATION_ENABLED, 0, 0))


def test_a_set_point_beyond_60ffh_raises_in_both() -> None:
    """A drive whose velocity unit is fine enough that 2007h's largest speed limit does not
    fit INTEGER32 (a real drive's scaling, docs/commissioning.md): the pack raises."""
    python, compiled = _twins(speed_limit_rad_s=12000.0, following_error_limit=10.0)
    for c in (python, compiled):
        c.set_scaling(Scaling(1e9, velocity_units_per_rev_s=2.0**30))
        _running(c)
        c.interpolator.position = 5.0  # a following error of 5 m: the clamp, 12000 rad/s
        c.interpolator.step = lambda: None  # type: ignore[method-assign]
        with pytest.raises(struct.error):
            c.step(0.001, TPDO1_STRUCT.pack(0, 0), TPDO2_STRUCT.pack(OPERATION_ENABLED, 0, 0))
        assert c.omega_r == 12000.0


def test_without_numba_the_bridge_runs_the_same_code_as_python() -> None:
    """A bridge installed without numba (the import refused): load() gives Python's core."""
    code = (
        "import sys; sys.modules['numba'] = None\n"
        "from bridge.cyclecore import load, numba_available\n"
        "print(numba_available(), load().compiled, load(None).compiled)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "False", "False"]
    assert load(True).compiled and not load(False).compiled

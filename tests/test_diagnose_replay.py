"""Closed-loop replay of an axis file like a recording (plant_sim/diagnose/replay.py)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from plant_sim.axis import AxisConfig, AxisKind, Control, Friction, Mechanics, PositionFeedback
from plant_sim.diagnose.errors import DiagnosisInputError
from plant_sim.diagnose.metrics import fit_percent
from plant_sim.diagnose.replay import prepare_replay, replay, simulate_like
from plant_sim.errors import TraceWarning
from plant_sim.model import KernelOptions
from plant_sim.simulate import References, simulate
from plant_sim.trace import Trace


def small_axis(feedback: PositionFeedback = PositionFeedback.MOTOR) -> AxisConfig:
    return AxisConfig(
        kind=AxisKind.LINEAR,
        transmission_ratio=2 * math.pi / 0.01,
        mechanics=Mechanics(motor_inertia=1.2e-4, screw_inertia=0.8e-4, load_mass=25.0),
        friction=Friction(coulomb=0.08, viscous=0.4),
        control=Control(
            kv=30.0, ksp=0.1, tsi=0.008, current_lag=0.0002, position_feedback=feedback
        ),
    )


def move(n: int, cycle: float) -> np.ndarray:
    """A smooth back-and-forth move (load units), one value per position cycle."""
    t = np.arange(n) * cycle
    return 0.05 * (1 - np.cos(2 * np.pi * t / 2.0)) * np.sin(2 * np.pi * t / 3.0)


def recorded(axis: AxisConfig, n: int = 3000, every: int = 1) -> Trace:
    """A noise-free 'recording': the simulator's own trace, every ``every``-th cycle."""
    refs = References.from_position(
        move(n, axis.control.position_cycle), axis.control.position_cycle
    )
    sim = simulate(axis, refs, options=KernelOptions(substeps=2))
    cols = (
        "time",
        "position_reference",
        "motor_position",
        "load_position",
        "motor_speed",
        "motor_torque",
    )
    return Trace({c: sim[c][::every] for c in cols})


def test_replay_reproduces_the_simulator_on_its_own_time_base() -> None:
    """Same axis, same cycle grid: replay is the simulator (independent path: simulate())."""
    axis = small_axis()
    rec = recorded(axis)
    sim = replay(axis, prepare_replay(rec, axis), KernelOptions(substeps=2))
    for col in ("motor_position", "motor_speed", "motor_torque", "load_position"):
        np.testing.assert_allclose(sim[col], rec[col], rtol=0, atol=1e-9 * np.ptp(rec[col]) + 1e-12)


@pytest.mark.parametrize("every", [2, 5])
def test_replay_resamples_a_coarser_recording(every: int) -> None:
    """A recording every 2 or 5 position cycles: the reference is resampled onto the cycle
    grid (cubic spline) and the outputs back; the torque fit stays above 99.9 %."""
    axis = small_axis()
    rec = recorded(axis, n=4000, every=every)
    sim = replay(axis, prepare_replay(rec, axis), KernelOptions(substeps=2))
    assert len(sim) == len(rec)
    np.testing.assert_array_equal(sim.time, rec.time)
    assert fit_percent(rec["motor_torque"], sim["motor_torque"]) > 99.9
    fe_rec = rec["position_reference"] - rec["motor_position"] / axis.transmission_ratio
    fe_sim = rec["position_reference"] - sim["motor_position"] / axis.transmission_ratio
    assert fit_percent(fe_rec, fe_sim) > 99.9


def test_non_feedback_position_zero_is_aligned() -> None:
    """A linear scale with another zero than the motor encoder: the simulated one is shifted."""
    axis = small_axis()
    rec = recorded(axis)
    shifted = rec.with_columns({"load_position": rec["load_position"] + 0.123})
    sim = replay(axis, prepare_replay(shifted, axis), KernelOptions(substeps=2))
    np.testing.assert_allclose(sim["load_position"], shifted["load_position"], atol=1e-9)


def test_simulate_like_keeps_the_recordings_columns() -> None:
    axis = small_axis()
    rec = recorded(axis).with_columns({"operator_note": np.arange(3000.0)})
    sim = simulate_like(axis, rec)
    assert set(sim.names) == set(rec.names)
    np.testing.assert_array_equal(sim["operator_note"], rec["operator_note"])
    np.testing.assert_array_equal(sim["position_reference"], rec["position_reference"])


def test_disturbance_column_drives_the_replay() -> None:
    """A known disturbance in the recording is applied: a run with it differs from one
    without it by the expected holding torque at standstill (PI integral: exact)."""
    axis = small_axis()
    n = 2000
    cycle = axis.control.position_cycle
    dist = np.where(np.arange(n) * cycle > 1.0, 0.2, 0.0)  # N m, at rest
    refs = References(np.zeros(n), np.zeros(n), dist)
    sim = simulate(axis, refs)
    rec = Trace(
        {
            c: sim[c]
            for c in ("time", "position_reference", "motor_position", "motor_torque", "disturbance")
        }
    )
    out = replay(axis, prepare_replay(rec, axis))
    # the motor holds the load against the push: -0.2 N m minus the friction it leans on
    assert out["motor_torque"][-1] == pytest.approx(sim["motor_torque"][-1], abs=1e-9)
    assert out["motor_torque"][-1] < -0.2 + 0.08 + 1e-6


def test_missing_reference_is_refused() -> None:
    axis = small_axis()
    rec = recorded(axis)
    cols = {k: v for k, v in rec.columns.items() if k != "position_reference"}
    with pytest.raises(DiagnosisInputError, match="position_reference") as err:
        prepare_replay(Trace(cols), axis)
    assert err.value.column == "position_reference"


def test_load_feedback_without_load_position_is_refused() -> None:
    axis = small_axis(PositionFeedback.LOAD)
    rec = recorded(small_axis())
    cols = {k: v for k, v in rec.columns.items() if k != "load_position"}
    with pytest.raises(DiagnosisInputError, match='position_feedback = "load"') as err:
        prepare_replay(Trace(cols), axis)
    assert err.value.column == "load_position"


def test_transmission_ratio_contradicting_the_recording_is_refused() -> None:
    axis = small_axis()
    rec = recorded(axis)
    wrong = axis.with_values({"axis.transmission_ratio": 2.0 * axis.transmission_ratio})
    with pytest.raises(DiagnosisInputError, match="transmission_ratio") as err:
        prepare_replay(rec, wrong)
    assert err.value.key == "axis.transmission_ratio"


def test_load_position_in_millimetres_is_refused() -> None:
    axis = small_axis()
    rec = recorded(axis)
    mm = rec.with_columns({"load_position": 1000.0 * rec["load_position"]})
    with pytest.raises(DiagnosisInputError, match="load_position"):
        prepare_replay(mm, axis)


def test_speed_in_rpm_warns() -> None:
    axis = small_axis()
    rec = recorded(axis)
    rpm = rec.with_columns({"motor_speed": rec["motor_speed"] * 60 / (2 * math.pi)})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        prepare_replay(rpm, axis)
    msgs = [str(w.message) for w in caught if issubclass(w.category, TraceWarning)]
    assert any("rpm" in m for m in msgs)

"""Closed-loop replay of an axis file like a recording (diagnosis/replay.py)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from diagnosis.errors import DiagnosisInputError
from diagnosis.metrics import fit_percent
from diagnosis.replay import prepare_replay, replay, simulate_like
from plant_sim.physics.model import KernelOptions
from plant_sim.physics.simulate import References, simulate
from virtual_bus.formats.axis import (
    AxisConfig,
    AxisKind,
    Control,
    Disturbance,
    Friction,
    Mechanics,
    PositionFeedback,
)
from virtual_bus.formats.errors import TraceWarning
from virtual_bus.formats.trace import MOTION_COLUMNS, Trace


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
    return Trace({c: sim[c][::every] for c in MOTION_COLUMNS})


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


# --- a soft loop that lags its reference by design (a hobby servo lifting a pendulum) ----------
def pendulum_axis(kv: float = 40.0, gravity_nm: float | None = 0.5) -> AxisConfig:
    """A P/P servo at transmission ratio 1 whose position loop (kv*ksp = 0.8 N m/rad) is
    barely stiffer than the gravity on its pendulum (0.5 N m/rad near the bottom): it travels
    0.66 rad per rad of its reference."""
    return AxisConfig(
        kind=AxisKind.ROTARY,
        transmission_ratio=1.0,
        mechanics=Mechanics(motor_inertia=0.0016, load_mass=0.005),
        friction=Friction(viscous=0.01),
        disturbance=Disturbance(
            periodic_amplitude=gravity_nm,
            periodic_period=None if gravity_nm is None else 2 * math.pi,
        ),
        control=Control(
            kv=kv,
            ksp=0.02,
            position_feedback=PositionFeedback.MOTOR,
            position_cycle=0.001,
            speed_cycle=0.001,
        ),
    )


def pendulum_recording(axis: AxisConfig) -> Trace:
    n = 4000
    t = np.arange(n) * axis.control.position_cycle
    refs = References.from_position(np.sin(2 * np.pi * 0.5 * t), axis.control.position_cycle)
    sim = simulate(axis, refs)
    cols = ("time", "position_reference", "motor_position", "motor_speed", "motor_torque")
    return Trace({c: sim[c] for c in cols})


def test_a_soft_loop_lagging_like_its_axis_file_is_accepted() -> None:
    """The recording travels far less than k_r (gravity wins over the loop); an axis file whose
    own replay lags as well, even with a gravity 30 % off, is accepted and replayed."""
    rec = pendulum_recording(pendulum_axis())
    slope = np.polyfit(rec["position_reference"], rec["motor_position"], 1)[0]
    assert slope < 0.8  # the premise: outside the stiff-loop tolerance
    off = pendulum_axis(gravity_nm=0.65)
    out = replay(off, prepare_replay(rec, off))
    assert np.all(np.isfinite(out["motor_position"]))


def test_a_stiff_axis_file_does_not_excuse_a_lagging_recording() -> None:
    """The same recording against an axis file that follows its reference (no gravity, a
    stiff loop) is refused: the model does not lag, so the lag must be units or k_r."""
    rec = pendulum_recording(pendulum_axis())
    stiff = pendulum_axis(kv=400.0, gravity_nm=None)
    with pytest.raises(DiagnosisInputError, match="replayed travels"):
        prepare_replay(rec, stiff)


def test_a_soft_loop_recorded_in_degrees_is_refused() -> None:
    axis = pendulum_axis()
    rec = pendulum_recording(axis)
    degrees = rec.with_columns({"motor_position": np.degrees(rec["motor_position"])})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TraceWarning)  # motor_speed no longer matches: expected
        with pytest.raises(DiagnosisInputError, match="motor_position"):
            prepare_replay(degrees, axis)

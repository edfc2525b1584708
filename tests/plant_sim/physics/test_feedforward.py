"""Feed-forward and sensor time offset (axis file ``control.velocity_feedforward``,
``control.acceleration_feedforward``, ``control.sensor_time_offset``) against analytic
results of the sampled cascade."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from diagnosis.synthetic import slide_axis
from plant_sim.physics.simulate import References, simulate
from tests.plant_sim.physics.axis_docs import small_axis
from virtual_bus.formats.axis import AxisConfig, PositionFeedback, axis_from_mapping
from virtual_bus.formats.errors import AxisFileError

CYCLE_S = 0.001


def _ideal_slide(**values: float | None) -> AxisConfig:
    """The small rigid slide without friction or current lag (so that the analytic
    steady states hold exactly)."""
    base: dict[str, float | None] = {
        "friction.coulomb": None,
        "friction.viscous": None,
        "control.current_lag": None,
    }
    base.update({k.replace("__", "."): v for k, v in values.items()})
    return slide_axis().with_values(base)


def _ramp(speed: float, n: int, start: int = 200) -> np.ndarray:
    t = np.arange(n) * CYCLE_S
    return speed * np.clip(t - start * CYCLE_S, 0.0, None)


@pytest.mark.parametrize("gain", [0.0, 0.5, 1.0])
def test_velocity_feedforward_ramp_following_error(gain: float) -> None:
    """P position loop, PI speed loop: on a steady ramp the following error is (1 − k_vff)·v/k_v
    (the speed loop delivers ω_set exactly; ω_set = k_vff·ω_s + k_r·k_v·e)."""
    axis = _ideal_slide(control__velocity_feedforward=gain or None)
    speed = 0.05
    x_ref = _ramp(speed, 1500)
    tr = simulate(axis, References.from_position(x_ref, CYCLE_S))
    e = tr["position_reference"] - tr["motor_position"] / axis.transmission_ratio
    steady = float(np.mean(e[-200:]))
    expected = (1.0 - gain) * speed / axis.control.kv
    assert steady == pytest.approx(expected, abs=0.005 * speed / axis.control.kv)


@pytest.mark.parametrize("fraction", [0.0, 1.0])
def test_acceleration_feedforward_removes_acceleration_lag(fraction: float) -> None:
    """P-only speed loop, full velocity feed-forward, constant acceleration a: the speed
    loop lags by J·k_r·a/k_sp, so the position loop holds e = J·k_r·a/(k_sp·k_v·k_r);
    J_ff = J (the exact total inertia) removes it."""
    probe = _ideal_slide(control__tsi=None, control__velocity_feedforward=1.0)
    inertia = probe.total_inertia
    axis = probe.with_values({"control.acceleration_feedforward": fraction * inertia or None})
    accel = 0.5  # m/s^2
    n = 1500
    t = np.clip(np.arange(n) * CYCLE_S - 0.2, 0.0, None)
    tr = simulate(axis, References.from_position(0.5 * accel * t**2, CYCLE_S))
    kr, c = axis.transmission_ratio, axis.control
    e = tr["position_reference"] - tr["motor_position"] / kr
    lag = inertia * kr * accel / c.ksp / (c.kv * kr)
    # sampling: the speed is measured over the last speed cycle (T_sc/2 old) and the torque
    # is held over the next (T_sc/2 late), so the loop leads by a·T_sc/k_v
    sampling = accel * c.speed_cycle / c.kv
    steady = float(np.mean(e[-300:]))
    assert steady == pytest.approx((1.0 - fraction) * lag - sampling, abs=1e-3 * lag)


def _cross_correlation_lag_s(a: np.ndarray, b: np.ndarray, dt: float, max_lag: int) -> float:
    """Delay of b behind a (s): the lag that maximises the normalised cross-correlation of
    the increments, first on whole samples, then refined over continuous lags (b read at
    t + lag by linear interpolation)."""
    t = np.arange(len(a)) * dt
    inner = slice(max_lag + 2, len(a) - max_lag - 2)

    def corr(lag_s: float) -> float:
        da = np.diff(a[inner])
        db = np.diff(np.interp(t[inner] + lag_s, t, b))
        return float(np.dot(da, db) / math.sqrt(np.dot(da, da) * np.dot(db, db)))

    whole = max(range(-max_lag, max_lag + 1), key=lambda k: corr(k * dt))
    best = minimize_scalar(
        lambda lag: -corr(lag),
        bounds=((whole - 1) * dt, (whole + 1) * dt),
        method="bounded",
        options={"xatol": 1e-7},
    )
    return float(best.x)


def _random_moves(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    speed = np.repeat(rng.uniform(-0.1, 0.1, n // 100 + 1), 100)[:n]
    kernel = np.ones(25) / 25.0
    speed = np.convolve(speed, kernel, mode="same")
    return np.cumsum(speed) * CYCLE_S


@pytest.mark.parametrize("offset_s", [0.0123, -0.0071])
def test_sensor_time_offset_shifts_the_reading(offset_s: float) -> None:
    """Positive offset: the load reading is x(t − offset); negative: the motor reading is
    θ(t − |offset|). The position loop closes on the other measuring system, so the motion
    itself is unchanged; the cross-correlation finds the shift and interpolation matches."""
    feedback = PositionFeedback.MOTOR if offset_s > 0 else PositionFeedback.LOAD
    base = _ideal_slide(mechanics__antiresonance=2000.0, mechanics__damping_ratio=0.2)
    base = base.with_values({"control.position_feedback": feedback})  # type: ignore[dict-item]
    shifted = base.with_values({"control.sensor_time_offset": offset_s})
    refs = References.from_position(_random_moves(4000, 7), CYCLE_S)
    a, b = simulate(base, refs), simulate(shifted, refs)
    column = "load_position" if offset_s > 0 else "motor_position"
    other = "motor_position" if offset_s > 0 else "load_position"
    np.testing.assert_array_equal(a[other], b[other])  # the motion is the same
    lag = _cross_correlation_lag_s(a[column], b[column], CYCLE_S, 30)
    assert lag == pytest.approx(abs(offset_s), abs=0.01 * CYCLE_S)
    t = a["time"]
    expected = np.interp(t - abs(offset_s), t, a[column])
    valid = t > 0.1
    spread = float(np.ptp(a[column]))
    assert np.max(np.abs(b[column][valid] - expected[valid])) < 1e-4 * spread


@pytest.mark.parametrize(
    ("key", "value", "allowed"),
    [
        ("velocity_feedforward", 1.6, "[0, 1.5]"),
        ("velocity_feedforward", -0.1, "[0, 1.5]"),
        ("acceleration_feedforward", -1e-4, "[0, 1e+06]"),
        ("sensor_time_offset", 0.06, "[-0.05, 0.05]"),
        ("sensor_time_offset", -0.051, "[-0.05, 0.05]"),
    ],
)
def test_new_control_keys_refused_out_of_range(key: str, value: float, allowed: str) -> None:
    with pytest.raises(AxisFileError) as info:
        axis_from_mapping(small_axis(**{key: value}))
    msg = str(info.value)
    assert f"control.{key}" in msg and repr(value) in msg and allowed in msg


def test_new_control_keys_read() -> None:
    axis = axis_from_mapping(
        small_axis(
            velocity_feedforward=1.0, acceleration_feedforward=2e-4, sensor_time_offset=-0.002
        )
    )
    c = axis.control
    assert (c.velocity_feedforward, c.acceleration_feedforward, c.sensor_time_offset) == (
        1.0,
        2e-4,
        -0.002,
    )


def test_lumped_rigid_model_without_motor_inertia() -> None:
    """motor_inertia = 0 is a lumped rigid model (all inertia in the load); it simulates like
    the same total inertia split between motor and load."""
    doc = small_axis()
    doc["mechanics"] = {"motor_inertia": 0.0, "load_mass": 25.0}
    lumped = axis_from_mapping(doc)
    kr = lumped.transmission_ratio
    split = lumped.with_values(
        {"mechanics.motor_inertia": 2e-5, "mechanics.load_mass": 25.0 - 2e-5 * kr**2}
    )
    refs = References.from_position(_random_moves(1000, 3), CYCLE_S)
    a, b = simulate(lumped, refs), simulate(split, refs)
    np.testing.assert_allclose(a["motor_torque"], b["motor_torque"], atol=1e-9, rtol=1e-6)
    assert math.isinf(lumped.inertia_ratio)


def test_elastic_axis_needs_motor_side_inertia() -> None:
    doc = small_axis()
    doc["mechanics"] = {"motor_inertia": 0.0, "load_mass": 25.0, "antiresonance": 500.0}
    with pytest.raises(AxisFileError, match=r"mechanics\.motor_inertia = 0\.0"):
        axis_from_mapping(doc)

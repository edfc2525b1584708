"""Late readings and the load scale's periodic error (axis file
``control.measurement_delay``, ``control.scale_error_*``) against what they are: a reading
d late is the undelayed run's value at t − d (linear interpolation between speed-cycle
samples) while the drive's own speed loop, and so the motion, is untouched when the position
loop is open; closed on the late reading, a steady ramp puts the load v·d ahead of where an
undelayed loop holds it; the scale reads x + A·sin(2πx/P + φ) at the true position x, and a
loop closed on it holds the reading, not the position, at the reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from diagnosis.synthetic import slide_axis
from plant_sim.physics import kernel as K
from plant_sim.physics.model import AxisPlant, build_params, initial_state
from plant_sim.physics.simulate import References
from regulator.core import detector_state_size
from tests.plant_sim.physics.axis_docs import small_axis
from virtual_bus.formats.axis import AxisConfig, PositionFeedback, axis_from_mapping, dump_axis
from virtual_bus.formats.errors import AxisFileError

SPEED_CYCLE = 125e-6
PER = 8  # speed cycles per 1 ms position cycle


def _slide(**values: object) -> AxisConfig:
    axis = slide_axis().with_values(
        {"mechanics.antiresonance": 900.0, "mechanics.damping_ratio": 0.05}
    )
    return axis.with_values({k.replace("__", "."): v for k, v in values.items()})  # type: ignore[misc]


def _set_points(n: int) -> np.ndarray:
    rng = np.random.default_rng(11)
    return np.repeat(rng.uniform(-50.0, 50.0, n // 9 + 1), 9)[:n]


def _readings(axis: AxisConfig, set_points: np.ndarray, every: int) -> np.ndarray:
    """(motor encoder, load scale, speed actual value, true motor angle) after each
    ``every``-th step of a plant stepped once per set point (position loop open)."""
    plant = AxisPlant(axis)
    rows = []
    for k, w in enumerate(set_points):
        plant.advance(float(w))
        if (k + 1) % every == 0:
            rows.append(
                (
                    plant.motor_position_rad,
                    plant.load_position,
                    plant.motor_speed_rad_s,
                    float(plant._st[K.S_TH]),
                )
            )
    return np.array(rows)


def _late(fine: np.ndarray, delay_s: float) -> np.ndarray:
    """Per position cycle the speed-cycle samples ``fine`` (one row per speed cycle, the
    state at its end) read ``delay_s`` back, linearly interpolated; before the run: at
    rest (the first sample's position, zero speed)."""
    cycles = delay_s / SPEED_CYCLE
    m = math.floor(cycles)
    f = cycles - m
    out = []
    for k in range(len(fine) // PER):
        j = (k + 1) * PER - 1  # the latest speed-cycle sample at the end of position cycle k

        def at(i: int) -> np.ndarray:
            return fine[i] if i >= 0 else np.array([0.0, 0.0, 0.0, 0.0])

        a, b = at(j - m), at(j - m - 1)
        out.append(a + (b - a) * f)
    return np.array(out)


@pytest.mark.parametrize(
    ("delay", "offset"),
    [(3 * SPEED_CYCLE, None), (1.6e-3, None), (4.3e-4, 2.5e-4), (4.3e-4, -3.1e-4)],
)
def test_late_readings_are_the_values_of_t_minus_d(delay: float, offset: float | None) -> None:
    """Position loop open (set points fed directly): the drive moves exactly as without the
    delay (its speed loop reads the encoder at once); each reading is the undelayed value of
    t − d, the load's d + a positive sensor offset, the motor's d + a negative one's |o|."""
    n = 240
    s = _set_points(n)
    base = _readings(_slide(), s, 1)
    late = _readings(
        _slide(control__measurement_delay=delay, control__sensor_time_offset=offset), s, 1
    )
    np.testing.assert_array_equal(late[:, 3], base[:, 3])  # the motion is the same
    fine = _readings(_slide(control__position_cycle=SPEED_CYCLE), np.repeat(s, PER), 1)
    o = offset or 0.0
    load_late = _late(fine, delay + max(o, 0.0))
    motor_late = _late(fine, delay + max(-o, 0.0))
    np.testing.assert_allclose(late[:, 0], motor_late[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(late[:, 1], load_late[:, 1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(late[:, 2], motor_late[:, 2], rtol=0, atol=1e-9)


def test_a_loop_on_a_late_scale_runs_ahead_on_a_ramp() -> None:
    """Rigid slide, no friction or current lag, loop on the load scale read d late: on a
    steady ramp of speed v the scale reads x_ref − v/k_v (as without the delay), so the load
    itself is at x_ref − v/k_v + v·d."""
    delay, v = 2.4e-3, 0.04
    axis = slide_axis().with_values(
        {
            "friction.coulomb": None,
            "friction.viscous": None,
            "control.current_lag": None,
            "control.position_feedback": PositionFeedback.LOAD,  # type: ignore[dict-item]
            "control.measurement_delay": delay,
        }
    )
    n = 3000
    t = np.arange(n) * 1e-3
    x_ref = v * np.clip(t - 0.2, 0.0, None)
    refs = References.from_position(x_ref, 1e-3)
    p = build_params(axis)
    st = initial_state(axis)
    reg = np.zeros(detector_state_size(int(p[K.P_REG_N])))
    out = np.empty((n, K.N_OUT))
    K.run_closed_loop(
        p, st, reg, K.cycle_block(p), refs.position, refs.speed, refs.disturbance_nm, out
    )
    kv = axis.control.kv
    reading_error = out[-1, K.O_XREF] - out[-1, K.O_X]
    assert reading_error == pytest.approx(v / kv, rel=1e-4)
    # the true load position after the last cycle, against the reference of that instant
    x_ref_end = x_ref[-1] + v * 1e-3
    assert x_ref_end - st[K.S_X] == pytest.approx(v / kv - v * delay, rel=1e-3)


def test_the_scale_reads_its_periodic_error_at_the_true_position() -> None:
    amp, period, phase = 4e-6, 0.012, 0.7
    axis = _slide(
        control__scale_error_amplitude=amp,
        control__scale_error_period=period,
        control__scale_error_phase=phase,
    )
    plant = AxisPlant(axis)
    for w in np.full(300, 40.0):  # 40 rad/s: 64 mm/s, several periods
        plant.advance(float(w))
        x = float(plant._st[K.S_X])
        assert plant.load_position == pytest.approx(
            x + amp * math.sin(2.0 * math.pi * x / period + phase), abs=1e-15
        )


def test_a_loop_on_the_scale_holds_the_reading_at_the_reference() -> None:
    """No friction: at rest the loop holds the scale's reading at the reference exactly, so
    the load stands at the root of x + A·sin(2πx/P + φ) = x_ref."""
    amp, period, phase = 8e-6, 0.01, 0.3
    axis = slide_axis().with_values(
        {
            "friction.coulomb": None,
            "friction.viscous": 0.05,
            "control.position_feedback": PositionFeedback.LOAD,  # type: ignore[dict-item]
            "control.scale_error_amplitude": amp,
            "control.scale_error_period": period,
            "control.scale_error_phase": phase,
        }
    )
    target = 0.0123
    n = 4000
    x_ref = np.minimum(np.arange(n) * 1e-3 * 0.02, target)
    refs = References.from_position(x_ref, 1e-3)
    p = build_params(axis)
    st = initial_state(axis)
    out = np.empty((n, K.N_OUT))
    K.run_closed_loop(
        p,
        st,
        np.zeros(detector_state_size(int(p[K.P_REG_N]))),
        K.cycle_block(p),
        refs.position,
        refs.speed,
        refs.disturbance_nm,
        out,
    )
    assert out[-1, K.O_X] == pytest.approx(target, abs=1e-10)
    true = brentq(
        lambda x: x + amp * math.sin(2 * math.pi * x / period + phase) - target, 0.0, 0.03
    )
    assert st[K.S_X] == pytest.approx(true, abs=1e-10)
    assert abs(true - target) > 1e-6  # the error is there to find


@pytest.mark.parametrize(
    ("control", "message"),
    [
        ({"measurement_delay": 0.06}, "control.measurement_delay = 0.06: allowed range [0, 0.05]"),
        ({"measurement_delay": -1e-4}, "allowed range [0, 0.05]"),
        (
            {"scale_error_amplitude": 0.02, "scale_error_period": 0.01},
            "control.scale_error_amplitude = 0.02: allowed range [0, 0.01]",
        ),
        (
            {"scale_error_amplitude": 1e-6, "scale_error_period": 0.0},
            "control.scale_error_period = 0.0: allowed range (0, inf)",
        ),
        ({"scale_error_amplitude": 1e-6}, "go together"),
        ({"scale_error_period": 0.01}, "go together"),
        ({"scale_error_phase": 0.1}, "needs control.scale_error_amplitude"),
    ],
)
def test_bad_keys_are_refused_naming_them(control: dict[str, float], message: str) -> None:
    with pytest.raises(AxisFileError) as info:
        axis_from_mapping(small_axis(**control))
    assert message in str(info.value)


def test_the_keys_survive_a_written_file() -> None:
    import tomllib

    values = {
        "setpoint_delay": 0.0012,
        "setpoint_delay_rate": -2e-4,
        "measurement_delay": 3e-4,
        "scale_error_amplitude": 2e-6,
        "scale_error_period": 0.015,
        "scale_error_phase": -1.1,
    }
    axis = axis_from_mapping(small_axis(**values))
    again = axis_from_mapping(tomllib.loads(dump_axis(axis)))
    assert again == axis
    assert {k: getattr(again.control, k) for k in values} == values

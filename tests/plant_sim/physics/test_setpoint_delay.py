"""The set point applied late (axis file ``control.setpoint_delay``,
``control.setpoint_delay_rate``) against what a dead time is: the drive with the delay
d(t) = clip(d0 + rate·t, 0, 0.1) behaves exactly as the same drive without it fed, speed
cycle by speed cycle, the set point of time t − d(t) (linearly interpolated between
speed-cycle samples, zero before the run); a delay of one position cycle is the one-cycle
PDO delay the kernel had before (``KernelOptions.setpoint_delay_cycles``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis.synthetic import FAMILIES, reference_profile, slide_axis
from plant_sim.errors import ScenarioError
from plant_sim.physics import kernel as K
from plant_sim.physics.model import AxisPlant, KernelOptions, build_params, initial_state
from plant_sim.physics.simulate import References, simulate
from tests.plant_sim.physics.axis_docs import small_axis
from virtual_bus.formats.axis import AxisConfig, axis_from_mapping
from virtual_bus.formats.errors import AxisFileError

SPEED_CYCLE = 125e-6
POSITION_CYCLE = 1e-3
PER = round(POSITION_CYCLE / SPEED_CYCLE)


def _elastic_slide(**values: float | None) -> AxisConfig:
    """The slide with an elastic element, friction and a current lag (dynamics in every
    state), position cycle 1 ms, speed cycle 125 µs."""
    axis = slide_axis().with_values(
        {"mechanics.antiresonance": 900.0, "mechanics.damping_ratio": 0.05}
    )
    return axis.with_values({k.replace("__", "."): v for k, v in values.items()})


def _set_points(n: int, seed: int) -> np.ndarray:
    """Speed set points (rad/s at the motor), one per position cycle: random levels held a
    few cycles, both signs."""
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(-60.0, 60.0, n // 7 + 1), 7)[:n]


def _delayed(samples: np.ndarray, d0: float, rate: float) -> np.ndarray:
    """Per speed cycle j the set point of time t_j − d(t_j): ``samples`` arriving one per
    speed cycle (zero before the run), read at d(t_j)/T_sc cycles back with linear
    interpolation; t_j accumulated as the kernel does."""
    out = np.empty(len(samples))
    t = 0.0
    for j in range(len(samples)):
        d = min(K.MAX_SETPOINT_DELAY_S, max(0.0, d0 + rate * t))
        cycles = d / SPEED_CYCLE
        m = math.floor(cycles + 1e-9)
        f = cycles - m
        f = 0.0 if f < 1e-9 else f
        a = samples[j - m] if j - m >= 0 else 0.0
        b = samples[j - m - 1] if j - m - 1 >= 0 else 0.0
        out[j] = a + (b - a) * f
        t += SPEED_CYCLE
    return out


def _run(axis: AxisConfig, set_points: np.ndarray, every: int) -> np.ndarray:
    """Torque, measured speed and load position after each ``every``-th step of a plant of
    ``axis`` stepped once per set point."""
    plant = AxisPlant(axis)
    rows = []
    for k, w in enumerate(set_points):
        plant.advance(float(w))
        if (k + 1) % every == 0:
            rows.append((plant.motor_torque_nm, plant.motor_speed_rad_s, plant.load_position))
    return np.array(rows)


@pytest.mark.parametrize(
    ("d0", "rate"),
    [
        (4 * SPEED_CYCLE, None),  # whole speed cycles, within a position cycle
        (2.37 * SPEED_CYCLE, None),  # a fraction: interpolated between two samples
        (0.0031, None),  # several position cycles
        (0.0002, 0.004),  # growing: 0.2 ms -> 1.8 ms over the 0.4 s
        (0.0018, -0.006),  # shrinking to 0 and clipped there
    ],
)
def test_a_late_set_point_is_the_set_point_of_t_minus_d(d0: float, rate: float | None) -> None:
    """The drive with the delay, stepped one position cycle per set point, equals the drive
    without it stepped one speed cycle per step with the set point of t − d(t): torque,
    speed actual value and load position at every position cycle."""
    n = 400
    s = _set_points(n, 3)
    late = _run(_elastic_slide(control__setpoint_delay=d0, control__setpoint_delay_rate=rate), s, 1)
    per_speed_cycle = _delayed(np.repeat(s, PER), d0, rate or 0.0)
    fine = _elastic_slide(control__position_cycle=SPEED_CYCLE)
    expected = _run(fine, per_speed_cycle, PER)
    np.testing.assert_allclose(late, expected, rtol=1e-9, atol=1e-12)
    # and it is not the undelayed drive
    assert np.max(np.abs(late[:, 0] - _run(_elastic_slide(), s, 1)[:, 0])) > 1e-3


def test_the_delay_is_clipped_at_its_largest_value() -> None:
    """d0 + rate·t beyond 0.1 s is 0.1 s: from then on the drive is 0.1 s behind."""
    d0, rate = 0.0995, 0.01
    s = _set_points(300, 5)
    late = _run(_elastic_slide(control__setpoint_delay=d0, control__setpoint_delay_rate=rate), s, 1)
    expected = _run(
        _elastic_slide(control__position_cycle=SPEED_CYCLE),
        _delayed(np.repeat(s, PER), d0, rate),
        PER,
    )
    np.testing.assert_allclose(late, expected, rtol=1e-9, atol=1e-12)


def test_one_position_cycle_is_the_pdo_delay() -> None:
    """setpoint_delay = one position cycle in the closed loop is the kernel's one-cycle PDO
    delay (the set point computed at cycle k applied over cycle k+1), bit for bit, also
    with torque feed-forward (delayed with the set point)."""
    fam = FAMILIES["mill"]
    x = reference_profile(fam.excitation, 1.5, POSITION_CYCLE, np.random.default_rng(4))
    refs = References.from_position(x, POSITION_CYCLE)
    axis = fam.truth.with_values({"control.acceleration_feedforward": 0.05})
    pdo = simulate(axis, refs, None, KernelOptions(setpoint_delay_cycles=1))
    late = simulate(axis.with_values({"control.setpoint_delay": POSITION_CYCLE}), refs)
    for name in ("motor_position", "load_position", "motor_speed", "motor_torque"):
        np.testing.assert_array_equal(late[name], pdo[name])


@pytest.mark.parametrize(
    "values",
    [
        {"control.setpoint_delay": 0.0},
        {
            "control.setpoint_delay": 0.0,
            "control.setpoint_delay_rate": 0.0,
        },
    ],
)
def test_zero_is_absent_bit_for_bit(values: dict[str, float]) -> None:
    fam = FAMILIES["slide"]
    x = reference_profile(fam.excitation, 1.0, POSITION_CYCLE, np.random.default_rng(2))
    refs = References.from_position(x, POSITION_CYCLE)
    a = simulate(fam.truth, refs)
    b = simulate(fam.truth.with_values(values), refs)
    for name in ("motor_position", "load_position", "motor_speed", "motor_torque"):
        np.testing.assert_array_equal(a[name], b[name])


def test_a_disabled_drive_takes_zero_set_points_into_its_delay() -> None:
    """Power stage off (advance_torque) for longer than the delay: what the delay line held
    before is gone (a disabled drive's set point is 0), so re-enabled it applies nothing of
    the moves it got before it was disabled."""
    axis = _elastic_slide(control__setpoint_delay=0.003)
    p = build_params(axis)
    st = initial_state(axis)
    for w in _set_points(20, 8):
        K.advance(p, st, float(w), 0.0)
    line = slice(K.S_SPH0, K.S_SPH0 + int(p[K.P_SPH_LEN]))
    assert np.any(st[line] != 0.0)
    for _ in range(4):  # 4 position cycles off: longer than 3 ms
        K.advance_torque(p, st, 0.0, 0.0)
    assert np.all(st[line] == 0.0)
    assert np.all(st[K.S_FFH0 : K.S_FFH0 + int(p[K.P_SPH_LEN])] == 0.0)


@pytest.mark.parametrize(
    ("control", "message"),
    [
        ({"setpoint_delay": 0.2}, "control.setpoint_delay = 0.2: allowed range [0, 0.1]"),
        ({"setpoint_delay": -1e-3}, "control.setpoint_delay = -0.001: allowed range [0, 0.1]"),
        (
            {"setpoint_delay": 1e-3, "setpoint_delay_rate": 0.02},
            "control.setpoint_delay_rate = 0.02: allowed range [-0.01, 0.01]",
        ),
        ({"setpoint_delay_rate": 1e-4}, "needs control.setpoint_delay"),
    ],
)
def test_bad_keys_are_refused_naming_them(control: dict[str, float], message: str) -> None:
    with pytest.raises(AxisFileError) as info:
        axis_from_mapping(small_axis(**control))
    assert message in str(info.value)


def test_a_delay_the_history_cannot_hold_is_refused() -> None:
    """A growing delay may reach 0.1 s: at a speed cycle of 20 µs that is 5,000 samples,
    more than the kernel keeps; refused before anything runs, naming the key."""
    axis = axis_from_mapping(
        small_axis(
            setpoint_delay=1e-3,
            setpoint_delay_rate=1e-3,
            speed_cycle=20e-6,
            position_cycle=1e-3,
        )
    )
    with pytest.raises(ScenarioError, match=r"control\.setpoint_delay"):
        build_params(axis)
    build_params(axis.with_values({"control.setpoint_delay_rate": None}))  # constant: fits

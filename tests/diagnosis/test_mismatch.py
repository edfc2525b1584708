"""Operating conditions, mismatch windows and residual tests (diagnosis/mismatch.py)."""

from __future__ import annotations

import numpy as np

from diagnosis.mismatch import (
    Condition,
    classify,
    find_windows,
    reference_kinematics,
    residual_tests,
    white_noise_sigma,
)

DT = 0.002


def profile() -> tuple[np.ndarray, np.ndarray]:
    """0-1 s rest, 1-3 s move + (trapezoid), 3-4 s rest, 4-6 s move -, 6-8 s rest."""
    t = np.arange(0.0, 8.0, DT)
    v = np.zeros_like(t)
    for start, sign in ((1.0, 1.0), (4.0, -1.0)):
        tau = t - start
        ramp = np.clip(tau / 0.2, 0, 1) * np.clip((2.0 - tau) / 0.2, 0, 1)
        v += sign * 0.1 * ramp * (tau >= 0) * (tau <= 2.0)
    x = np.concatenate([[0.0], np.cumsum(v[:-1]) * DT])
    return t, x


def test_conditions_follow_the_reference() -> None:
    t, x = profile()
    kin = reference_kinematics(t, x, x)
    labels = classify(kin, kv=25.0)
    at = {time: labels[round(time / DT)] for time in (0.5, 1.1, 2.0, 2.9, 3.5, 4.05, 5.0, 7.5)}
    assert at[0.5] is Condition.STANDSTILL
    assert at[1.1] is Condition.ACCELERATION
    assert at[2.0] is Condition.CONSTANT_SPEED
    assert at[2.9] is Condition.DECELERATION
    # the dwell before the opposite move and its start are the reversal
    assert at[3.5] is Condition.REVERSAL and at[4.05] is Condition.REVERSAL
    assert at[5.0] is Condition.CONSTANT_SPEED
    assert at[7.5] is Condition.STANDSTILL


def test_white_noise_sigma_ignores_slow_parts() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(0, 10, DT)
    r = 0.3 * rng.standard_normal(len(t)) + 5.0 * np.sin(t)
    assert abs(white_noise_sigma(r) - 0.3) < 0.02


def test_window_found_where_the_residual_departs() -> None:
    rng = np.random.default_rng(2)
    t, x = profile()
    kin = reference_kinematics(t, x, x)
    labels = classify(kin, kv=25.0)
    r = 0.1 * rng.standard_normal(len(t))
    bump = (t >= 4.0) & (t < 4.3)  # at the reversal
    r[bump] += 0.2
    windows = find_windows({"motor_torque": r}, kin, labels)
    # the bump is found where it is, split by condition: the reversal (start of the move up
    # to the end of its acceleration at 4.2 s), then constant speed
    assert [w.condition for w in windows] == ["reversal", "constant speed"]
    assert 3.9 < windows[0].t_start < 4.05 and 4.25 < windows[-1].t_end < 4.4
    assert all(w.signal == "motor_torque" and w.peak_residual > 0 for w in windows)


def test_no_window_in_white_noise() -> None:
    rng = np.random.default_rng(3)
    t, x = profile()
    kin = reference_kinematics(t, x, x)
    assert (
        find_windows({"motor_torque": rng.standard_normal(len(t))}, kin, classify(kin, 25.0)) == []
    )


def test_pervasive_offset_is_located_with_the_final_model() -> None:
    """A load torque acting whenever the axis moves is not an outlier of its own residual,
    but the final model removes it: flagged while moving, marked explained."""
    rng = np.random.default_rng(4)
    t, x = profile()
    kin = reference_kinematics(t, x, x)
    labels = classify(kin, 25.0)
    noise = 0.05 * rng.standard_normal(len(t))
    moving = np.abs(kin.speed) > 1e-3
    refit = noise + 0.1 * moving
    assert find_windows({"motor_torque": refit}, kin, labels) == []
    windows = find_windows({"motor_torque": refit}, kin, labels, {"motor_torque": noise})
    assert windows and all(w.explained for w in windows)
    covered = sum(w.t_end - w.t_start for w in windows)
    assert 3.0 < covered < 4.5  # the two 2 s moves


def test_residual_tests_see_speed_sign_and_whiteness() -> None:
    rng = np.random.default_rng(5)
    t, x = profile()
    kin = reference_kinematics(t, x, x)
    white = rng.standard_normal(len(t))
    friction_like = 0.5 * np.sign(kin.speed) + white
    tests = {r.signal: r for r in residual_tests({"white": white, "friction": friction_like}, kin)}
    assert tests["white"].white
    assert not tests["white"].cross_correlation["speed_sign"].significant
    assert tests["friction"].cross_correlation["speed_sign"].significant
    assert not tests["friction"].white

"""Torque clipping found in the recorded torque (diagnosis/clipping.py): against signals whose
clipping is known by construction (np.clip of a smooth torque plus white noise), and on the
FMU family (a plant written apart from this project) with and without its lower limit."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis.clipping import clipping_test, torque_noise

DT = 0.001


def _torque(rng: np.random.Generator, noise: float = 0.02) -> np.ndarray:
    """Smooth accelerations of both signs (sums of sines, 10 s at 1 kHz) plus white noise
    added after any clipping (the reading's noise)."""
    t = np.arange(0.0, 10.0, DT)
    smooth = 3.0 * np.sin(2 * np.pi * 0.7 * t) + 1.5 * np.sin(2 * np.pi * 2.3 * t + 1.0)
    return smooth, noise * rng.standard_normal(len(t))


def test_the_third_difference_noise_is_the_white_noise() -> None:
    rng = np.random.default_rng(1)
    smooth, noise = _torque(rng, 0.05)
    assert torque_noise(smooth + noise) == pytest.approx(0.05, rel=0.05)


def test_a_torque_clipped_on_both_signs_is_found_at_its_limit() -> None:
    rng = np.random.default_rng(2)
    smooth, noise = _torque(rng)
    c = clipping_test(np.clip(smooth, -3.0, 3.0) + noise, DT)
    assert c.clipped, c.describe()
    # the plateau's median: the limit within a few noise σ / √n (not the noise's maximum)
    assert abs(c.level - 3.0) < 0.01, c.level
    assert abs(c.level_positive - c.level_negative) < 0.01


def test_an_unclipped_torque_is_not() -> None:
    rng = np.random.default_rng(3)
    smooth, noise = _torque(rng)
    assert not clipping_test(smooth + noise, DT).clipped


def test_a_plateau_on_one_sign_only_is_not_a_limit() -> None:
    """A drive's limit clips both signs at one level; a one-sided plateau (a hard stop, a
    saturated sensor) is not this effect."""
    rng = np.random.default_rng(4)
    smooth, noise = _torque(rng)
    assert not clipping_test(np.minimum(smooth, 3.0) + noise, DT).clipped
    # both signs clipped, at levels 30 % apart
    assert not clipping_test(np.clip(smooth, -2.1, 3.0) + noise, DT).clipped


@pytest.mark.parametrize(
    ("seed", "family", "clipped"),
    [(0, 10, True), (22, 10, True), (0, 0, False), (4, 0, False), (6, 9, False)],
)
def test_the_fmu_familys_lower_limit_is_found_and_only_there(
    seed: int, family: int, clipped: bool
) -> None:
    """FMU axes (development seeds, the sweep's 25 s plans: a 10 s plan of axis 22 clips one sign
    only) with the hidden lower torque limit (family 10) and
    without (clean, constant load): found where the FMU clips, at its truth within 1 %."""
    from diagnosis.testsets import fmu

    rng = np.random.default_rng([seed + fmu.SEED_SHIFT, family, 0, 0])
    rec, _, _ = fmu.make_recording(seed, family, 25.0, rng)
    c = clipping_test(rec["motor_torque"], DT)
    assert c.clipped is clipped, c.describe()
    if clipped:
        truth = fmu.truth_values(fmu.spec_for(seed, family).load())["truth_torque_limit"]
        assert c.level == pytest.approx(truth, rel=0.01)

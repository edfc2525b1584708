"""'Unexplained, here' from a residual that stands out in part of the recording (unexplained.py):
checked on residuals whose bins are known by construction."""

from __future__ import annotations

import numpy as np

from diagnosis.unexplained import LOCAL_CONTRAST, LOCAL_RATIO, local_misfit, where


def _where(residual: np.ndarray, speed: np.ndarray) -> list:
    t = np.arange(len(residual)) * 1e-3
    return where({"motor_torque": residual}, t, speed, speed.copy(), [], ("motor_torque",))


def test_white_noise_everywhere_is_not_unexplained() -> None:
    rng = np.random.default_rng(1)
    n = 12_000
    speed = np.linspace(-0.1, 0.1, n)
    assert local_misfit(_where(rng.standard_normal(n), speed)) == []


def test_a_range_far_above_the_noise_and_the_rest_is_named_with_where() -> None:
    """One twelfth of the speeds carries a slow error of 2 x LOCAL_RATIO σ: its RMS stands
    out from the noise and from the residual's own RMS (contrast above LOCAL_CONTRAST)."""
    rng = np.random.default_rng(2)
    n = 12_000
    speed = np.linspace(-0.1, 0.1, n)
    r = rng.standard_normal(n)
    band = slice(0, n // 12)
    r[band] += 2.0 * LOCAL_RATIO * np.sin(np.linspace(0.0, 3.0, n // 12))
    items = _where(r, speed)
    rms = float(np.sqrt(np.mean(r**2)))
    band_rms = float(np.sqrt(np.mean(r[band] ** 2)))
    assert band_rms / rms >= LOCAL_CONTRAST  # the construction does what it claims
    hints = local_misfit(items)
    assert any("speed -0.1" in h for h in hints), hints


def test_a_slow_misfit_spread_over_the_recording_is_not_localised() -> None:
    """A slow residual of 40 σ everywhere (a model-class misfit the whole recording shares)
    is judged by the whole recording's rule, not called local: no bin stands out."""
    rng = np.random.default_rng(3)
    n = 12_000
    speed = np.linspace(-0.1, 0.1, n)
    r = rng.standard_normal(n) + 40.0 * np.sin(np.linspace(0.0, 60.0, n))
    assert local_misfit(_where(r, speed)) == []

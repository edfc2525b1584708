"""Analysis formulas (eqs. 1, 5, 12-14), FFT condition monitoring (section VI) and the
describing-function limit-cycle prediction, each against an independent computation."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from scipy.optimize import brentq

from regulator import AnalysisError
from regulator.analysis import (
    BandVerdict,
    condition_monitoring,
    deadzone_amplitude_for_gain,
    deadzone_df,
    deadzone_first_harmonic,
    dominant_frequency_hz,
    following_error,
    min_decay_time_s,
    predict_limit_cycle,
    restitution_frequency_hz,
    vibration_band_hz,
)

KV = 25.0

# --- eqs. 1, 12, 13, 14 ------------------------------------------------------------------------


def test_following_error_eq1() -> None:
    assert following_error(0.1, KV) == pytest.approx(0.004, rel=1e-15)  # 100 mm/s -> 4 mm
    speeds = np.array([[0.0, -0.05], [0.2, 1.0]])
    np.testing.assert_allclose(following_error(speeds, KV), speeds / KV, rtol=1e-15)
    with pytest.raises(AnalysisError, match="kv_per_s = 0"):
        following_error(0.1, 0)


def _frequency_from_impact_model(kv: float, e: float) -> float:
    """Solve eqs. 10 and 11 for the period T numerically; return 1 / T."""

    def residual(period: float) -> float:
        x_l_dot = 1.0
        x_m_dot = kv * x_l_dot * period / 4.0  # eq. 10
        return (x_l_dot - x_m_dot) / (x_l_dot + x_m_dot) - e  # eq. 11

    return 1.0 / brentq(residual, 1e-9, 4.0 / kv, xtol=1e-15)


@pytest.mark.parametrize("e", [0.0, 0.2, 0.6, 0.9])
def test_restitution_frequency_eq12_solves_eqs10_11(e: float) -> None:
    assert restitution_frequency_hz(KV, e) == pytest.approx(
        _frequency_from_impact_model(KV, e), rel=1e-9
    )


@pytest.mark.parametrize("kv", [10.0, 25.0, 40.0])
def test_band_eq13_is_eq12_between_e0_and_e06(kv: float) -> None:
    low, high = vibration_band_hz(kv)
    assert (low, high) == (kv / 4.0, kv)
    assert restitution_frequency_hz(kv, 0.0) == low
    assert restitution_frequency_hz(kv, 0.6) == pytest.approx(high, rel=1e-14)
    # eq. 14: five periods of the slowest vibration in the band
    assert min_decay_time_s(kv) == pytest.approx(5.0 / low, rel=1e-15)
    assert min_decay_time_s(kv) == pytest.approx(20.0 / kv, rel=1e-15)


@pytest.mark.parametrize("e", [-0.1, 1.0, 1.5, math.nan])
def test_restitution_refuses_e_outside_0_1(e: float) -> None:
    with pytest.raises(AnalysisError, match=r"e = .*must be in \[0, 1\)") as info:
        restitution_frequency_hz(KV, e)
    assert isinstance(info.value, ValueError)


# --- eq. 5: dead-zone describing function ----------------------------------------------------


@pytest.mark.parametrize("delta", [1e-4, 0.5, 3.0])
def test_deadzone_df_matches_numerical_first_harmonic(delta: float) -> None:
    amplitude = delta * np.concatenate(
        (np.linspace(0.0, 1.0, 5), np.geomspace(1.0 + 1e-6, 1e3, 60))
    )
    analytic = deadzone_df(amplitude, delta)
    numeric = deadzone_first_harmonic(amplitude, delta)
    assert isinstance(analytic, np.ndarray) and analytic.shape == amplitude.shape
    np.testing.assert_allclose(analytic, numeric, rtol=0.0, atol=1e-6)
    assert np.all(analytic[amplitude <= delta] == 0.0)  # A <= delta: inside the dead zone
    assert np.all(np.diff(analytic) >= 0.0) and analytic[-1] < 1.0


def test_deadzone_df_shape_scalar_and_asymptote() -> None:
    grid = np.array([[0.5, 2.0], [4.0, 100.0]])
    assert deadzone_df(grid, 1.0).shape == (2, 2)
    assert isinstance(deadzone_df(2.0, 1.0), float)
    assert deadzone_df(2.0, 1.0) == pytest.approx(deadzone_first_harmonic(2.0, 1.0), abs=1e-6)
    # large A: N = 1 - 4 delta / (pi A) + O((delta/A)^3)
    assert deadzone_df(1e4, 1.0) == pytest.approx(1.0 - 4.0 / (math.pi * 1e4), abs=1e-11)


def test_deadzone_df_of_a_backlash_uses_half_the_free_play() -> None:
    """Axis files give the TOTAL free play; a play of 0.1 mm is a dead zone of +-0.05 mm.
    The numerical harmonic of a play whose contact points are at +-backlash/2 agrees."""
    backlash_m = 1e-4
    amplitude = np.array([0.06e-3, 0.1e-3, 0.5e-3])
    np.testing.assert_allclose(
        deadzone_df(amplitude, backlash_m / 2),
        deadzone_first_harmonic(amplitude, backlash_m / 2),
        atol=1e-6,
    )
    assert deadzone_df(0.06e-3, backlash_m) == 0.0  # with the total play it would be 0


@pytest.mark.parametrize("gain", [0.01, 0.5, 0.99])
def test_amplitude_for_gain_inverts_eq5(gain: float) -> None:
    amplitude = deadzone_amplitude_for_gain(gain, 0.2)
    assert deadzone_first_harmonic(amplitude, 0.2) == pytest.approx(gain, abs=1e-6)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf])
def test_deadzone_refuses_bad_delta(bad: float) -> None:
    with pytest.raises(AnalysisError, match=r"delta = .*half-width > 0"):
        deadzone_df(1.0, bad)


def test_deadzone_refuses_negative_amplitude() -> None:
    with pytest.raises(AnalysisError, match="amplitude"):
        deadzone_df(np.array([1.0, -1.0]), 0.5)


# --- section VI: FFT and condition monitoring ------------------------------------------------


def _sinusoid(f_hz: float, seed: int, dt_s: float = 0.001, duration_s: float = 2.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s / dt_s)) * dt_s
    phase = rng.uniform(0.0, 2.0 * math.pi)
    # offset and drift (removed by the detrend) plus white noise of 30 % of the amplitude
    return 0.7 * np.sin(2 * np.pi * f_hz * t + phase) + 3.0 + 0.5 * t + rng.normal(0, 0.2, t.size)


@pytest.mark.parametrize("seed", range(8))
def test_dominant_frequency_within_half_a_percent(seed: int) -> None:
    f_hz = float(np.random.default_rng(100 + seed).uniform(5.0, 45.0))
    estimate = dominant_frequency_hz(_sinusoid(f_hz, seed), 0.001)
    assert estimate == pytest.approx(f_hz, rel=5e-3)
    assert abs(estimate - f_hz) < 0.1 * 0.5  # and well below one bin (0.5 Hz)


def test_dominant_frequency_search_range() -> None:
    t = np.arange(4000) * 0.001
    # a strong 3.3 Hz motion and a weak (-40 dB) 17.2 Hz vibration: the window must keep the
    # strong line's leakage below the weak one at the edge of the search range
    x = 2.0 * np.sin(2 * np.pi * 3.3 * t) + 0.02 * np.sin(2 * np.pi * 17.2 * t)
    assert dominant_frequency_hz(x, 0.001) == pytest.approx(3.3, rel=2e-3)
    assert dominant_frequency_hz(x, 0.001, f_min_hz=6.0, f_max_hz=40.0) == pytest.approx(
        17.2, rel=2e-3
    )


@pytest.mark.parametrize(
    ("f_hz", "in_band"), [(7.0, True), (15.0, True), (24.0, True), (3.0, False), (60.0, False)]
)
def test_condition_monitoring_verdicts(f_hz: float, in_band: bool) -> None:
    verdict = condition_monitoring(_sinusoid(f_hz, 1), 0.001, KV)
    assert isinstance(verdict, BandVerdict)
    assert verdict.band_hz == (6.25, 25.0)
    assert verdict.in_band is in_band
    assert verdict.frequency_hz == pytest.approx(f_hz, rel=5e-3)
    assert verdict.amplitude == pytest.approx(0.7, rel=0.05)


def test_condition_monitoring_of_a_calm_signal() -> None:
    verdict = condition_monitoring(np.linspace(1.0, 2.0, 500), 0.001, KV)
    assert math.isnan(verdict.frequency_hz) and verdict.amplitude == 0.0
    assert verdict.in_band is False
    with pytest.raises(AnalysisError, match="no oscillating component"):
        dominant_frequency_hz(np.full(500, 4.0), 0.001)


@pytest.mark.parametrize(
    ("signal", "dt_s", "kwargs", "pattern"),
    [
        (np.ones(10), 0.001, {}, "at least 16 samples"),
        (np.r_[np.ones(100), np.nan], 0.001, {}, "NaN or inf"),
        (np.ones(100), 0.0, {}, "dt_s = 0.0"),
        (np.ones(100), 0.001, {"f_min_hz": 10.0, "f_max_hz": 5.0}, "frequency range"),
        (np.ones(100), 0.001, {"f_max_hz": 900.0}, "Nyquist = 500 Hz"),
    ],
)
def test_dominant_frequency_refuses_bad_arguments(
    signal: np.ndarray, dt_s: float, kwargs: dict[str, float], pattern: str
) -> None:
    with pytest.raises(AnalysisError, match=pattern):
        dominant_frequency_hz(signal, dt_s, **kwargs)


# --- describing-function limit cycle ---------------------------------------------------------


def _third_order(k: float) -> Callable[[np.ndarray], np.ndarray]:
    def loop(omega: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(omega)
        return k / (s * (s + 1.0) * (s + 2.0))

    return loop


@pytest.mark.parametrize("k", [9.0, 12.0, 60.0])
def test_limit_cycle_of_third_order_loop(k: float) -> None:
    """L = k / (s (s+1) (s+2)): phase -180 deg at omega = sqrt(2), |L| = k / 6 there."""
    cycle = predict_limit_cycle(_third_order(k), delta=0.01)
    assert cycle is not None
    assert cycle.frequency_rad_s == pytest.approx(math.sqrt(2.0), rel=1e-9)
    assert cycle.frequency_hz == pytest.approx(math.sqrt(2.0) / (2 * math.pi), rel=1e-9)
    assert cycle.loop_gain == pytest.approx(k / 6.0, rel=1e-9)
    # harmonic balance N(A) |L| = 1, checked with the numerical first harmonic
    assert deadzone_first_harmonic(cycle.amplitude, 0.01) == pytest.approx(6.0 / k, abs=1e-6)


def test_no_limit_cycle_when_the_linear_loop_has_gain_margin() -> None:
    assert predict_limit_cycle(_third_order(5.0), delta=0.01) is None


def test_limit_cycle_picks_the_strongest_of_several_crossovers() -> None:
    """L = K exp(-s tau) / s crosses -180 deg at omega = (2m + 1/2) pi / tau with |L| = K / omega;
    the first crossover has the largest gain (here three have |L| > 1)."""
    gain, tau = 400.0, 0.05

    def loop(omega: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(omega)
        return gain * np.exp(-s * tau) / s

    cycle = predict_limit_cycle(loop, delta=1.0, omega_max_rad_s=1e3)
    assert cycle is not None
    assert cycle.frequency_rad_s == pytest.approx(math.pi / (2 * tau), rel=1e-9)
    assert cycle.loop_gain == pytest.approx(gain * 2 * tau / math.pi, rel=1e-9)


def test_limit_cycle_strongest_crossover_need_not_be_the_first() -> None:
    """arg L = -pi + 0.5 sin(ln omega) crosses -180 deg at omega = 1, e^pi, e^(2 pi); |L| peaks
    (5) at e^pi and is ~2 at the other two."""

    def loop(omega: np.ndarray) -> np.ndarray:
        log_w = np.log(np.asarray(omega))
        magnitude = 2.0 + 3.0 * np.exp(-((log_w - math.pi) ** 2))
        return magnitude * np.exp(1j * (-math.pi + 0.5 * np.sin(log_w)))

    cycle = predict_limit_cycle(loop, delta=1.0)
    assert cycle is not None
    assert cycle.frequency_rad_s == pytest.approx(math.exp(math.pi), rel=1e-9)
    assert cycle.loop_gain == pytest.approx(5.0, rel=1e-9)


def test_limit_cycle_refuses_bad_range() -> None:
    with pytest.raises(AnalysisError, match="omega range"):
        predict_limit_cycle(
            _third_order(12.0), delta=0.01, omega_min_rad_s=10.0, omega_max_rad_s=1.0
        )

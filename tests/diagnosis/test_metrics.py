"""Scores and statistics of the diagnosis against analytic results."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis.metrics import (
    autocorrelation_time,
    fit_percent,
    improvement_test,
    information_criterion,
    ljung_box,
    newey_west_variance,
    nrmse,
)


def _ar1(a: float, n: int, rng: np.random.Generator) -> np.ndarray:
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0] / math.sqrt(1 - a * a)
    for i in range(1, n):
        x[i] = a * x[i - 1] + e[i]
    return x


def test_nrmse_perfect_mean_and_fit_percent() -> None:
    y = np.sin(np.linspace(0, 10, 500))
    assert nrmse(y, y) == 0.0
    assert nrmse(y, np.full_like(y, y.mean())) == pytest.approx(1.0)
    # a simulation off by a fifth of the signal everywhere: NRMSE 0.2, fit 80 %
    assert fit_percent(y, y + 0.2 * (y - y.mean())) == pytest.approx(80.0)


def test_nrmse_constant_signal() -> None:
    assert nrmse(np.ones(10), np.ones(10)) == 0.0
    assert math.isinf(nrmse(np.ones(10), np.zeros(10)))


@pytest.mark.parametrize("a", [0.0, 0.5, 0.9])
def test_autocorrelation_time_of_ar1(a: float) -> None:
    """τ = (1 + a)/(1 − a) for an AR(1) process."""
    x = _ar1(a, 200_000, np.random.default_rng(1))
    assert autocorrelation_time(x) == pytest.approx((1 + a) / (1 - a), rel=0.1)


def test_newey_west_variance_of_ar1_sum() -> None:
    """Var(Σx) = n·σ²·(1+a)/(1−a) for an AR(1) of unit innovations (σ² = 1/(1−a²))."""
    a, n = 0.8, 100_000
    x = _ar1(a, n, np.random.default_rng(2))
    expected = n / (1 - a * a) * (1 + a) / (1 - a)
    assert newey_west_variance(x, 200) == pytest.approx(expected, rel=0.1)


def test_information_criterion_penalises_parameters() -> None:
    assert information_criterion(1.0, 100.0, 3) - information_criterion(1.0, 100.0, 2) == (
        pytest.approx(math.log(100.0))
    )


def test_ljung_box_white_and_coloured() -> None:
    rng = np.random.default_rng(3)
    _, p_white = ljung_box(rng.standard_normal(5000))
    _, p_ar = ljung_box(_ar1(0.3, 5000, rng))
    assert p_white > 0.01
    assert p_ar < 1e-6


def test_improvement_test_real_effect_and_spurious_one() -> None:
    """A real localized effect (present in the data) is significant; a spurious one
    (fitted to noise elsewhere) is not, however large its share of the recording."""
    rng = np.random.default_rng(4)
    n = 20_000
    noise = _ar1(0.7, n, rng) * 0.5
    bump = np.zeros(n)
    bump[5000:5200] = 0.6  # the effect: acts on 1 % of the samples
    data = bump + noise
    without = data  # residual of the model without the effect
    with_effect = data - bump
    z, p = improvement_test(without, with_effect, 20)
    assert p < 1e-3 and z > 3.1
    spurious = 0.05 * np.sin(np.arange(n) / 50.0)  # a change unrelated to the data
    _, p0 = improvement_test(without, without - spurious, 20)
    assert p0 > 0.01


def test_improvement_test_calibrated_under_null() -> None:
    """Under the null the one-sided p-value is not below 1 % much more often than 1 %."""
    rng = np.random.default_rng(5)
    n, trials, hits = 4000, 300, 0
    for _ in range(trials):
        e = _ar1(0.5, n, rng)
        delta = 0.02 * _ar1(0.9, n, rng)  # what a spurious candidate changes
        _, p = improvement_test(e, e - delta, 12)
        hits += p < 0.01
    assert hits <= 0.03 * trials

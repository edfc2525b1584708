"""omega_a from the two-mass model fitted to the motor admittance (regulator/admittance_fit.py)
against analytic admittances (eq. 2 with known parameters, the readings' first-order filters,
noise of a known size) and against a rigid body, where no antiresonance may be claimed."""

from __future__ import annotations

import numpy as np
import pytest

from regulator.admittance_fit import MODEL_SHARE, fit_two_mass

J1, J2 = 0.004, 0.006  # kg m^2: motor side and load at the motor
WA, XI = 480.0, 0.05  # rad/s, the transmission's antiresonance and damping


def _admittance(
    f: np.ndarray, wa: float | None, lag_speed: float = 0.0, lag_torque: float = 0.0
) -> np.ndarray:
    """omega_m / tau_m of eq. 2 (rigid without ``wa``), the speed read through a first-order
    filter of ``lag_speed`` s and the torque through one of ``lag_torque`` s."""
    s = 2j * np.pi * f
    if wa is None:
        y = 1.0 / ((J1 + J2) * s)
    else:
        k = J2 * wa**2
        c = 2.0 * XI * J2 * wa
        load = J2 * s**2 + c * s + k
        y = load / (s * (J1 * J2 * s**2 + (J1 + J2) * (c * s + k)))
    return y * (1.0 + lag_torque * s) / (1.0 + lag_speed * s)


def _measured(y: np.ndarray, rel: float, realizations: int, seed: int):
    rng = np.random.default_rng(seed)
    shape = (realizations, y.size)
    noise = rel * np.abs(y) * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    draws = y + noise / np.sqrt(2.0)
    mean = draws.mean(axis=0)
    std = np.sqrt((draws.real.var(axis=0, ddof=1) + draws.imag.var(axis=0, ddof=1)) / realizations)
    loo = (draws.sum(axis=0) - draws) / (realizations - 1)
    return mean, std, loo


@pytest.mark.parametrize("lags", [(0.0, 0.0), (4e-4, 0.0), (0.0, 2e-4)])
def test_the_antiresonance_of_eq_2_is_recovered_within_its_uncertainty(lags) -> None:
    f = np.arange(1.0, 450.0, 1.0)
    y = _admittance(f, WA, *lags)
    mean, std, loo = _measured(y, 0.03, 8, 1)
    fit = fit_two_mass(f, mean, std, loo)
    assert fit is not None and fit.resolved, fit
    assert abs(fit.antiresonance_rad_s - WA) <= fit.uncertainty_rad_s
    assert fit.antiresonance_rad_s == pytest.approx(WA, rel=0.01)
    assert fit.damping_ratio == pytest.approx(XI, rel=0.2)
    assert fit.resonance_rad_s == pytest.approx(WA * np.sqrt(1 + J2 / J1), rel=0.02)
    assert fit.inertia_kgm2 == pytest.approx(J1 + J2, rel=0.05)
    # the stated uncertainty holds the model's share at least (about 95 %)
    assert fit.uncertainty_rad_s >= MODEL_SHARE * fit.antiresonance_rad_s


def test_a_rigid_body_is_no_antiresonance() -> None:
    """A load without elastic element (or decoupled): the two-mass model is no better than
    the rigid body, and nothing is claimed -- on ten noise draws."""
    f = np.arange(1.0, 450.0, 1.0)
    for seed in range(10):
        mean, std, loo = _measured(_admittance(f, None), 0.03, 8, seed)
        fit = fit_two_mass(f, mean, std, loo)
        assert fit is not None and not fit.resolved, (seed, fit)


def test_lines_in_the_noise_are_no_fit() -> None:
    f = np.arange(1.0, 450.0, 1.0)
    mean, std, loo = _measured(_admittance(f, WA), 2.0, 8, 3)
    assert fit_two_mass(f, mean, std, loo) is None

"""Scores of a simulation against a recording, and the statistics of the decision rule.

* :func:`nrmse` / :func:`fit_percent`: normalised root-mean-square error of a *simulation*,
  ``||y - ŷ|| / ||y - mean(y)||``, and the fit in per cent ``100·(1 - NRMSE)`` (the "fit" of
  system-identification toolboxes; 100 % is perfect, 0 % is no better than the mean, it can
  be negative).
* :func:`autocorrelation_time`: integrated autocorrelation time τ of a residual; a coloured
  residual of n samples carries n/τ independent samples (``n_eff``); the information
  criterion is computed with n_eff, not n.
* :func:`information_criterion`: BIC with n_eff (reported per held-out score).
* :func:`ljung_box`: portmanteau whiteness test.
* :func:`improvement_test`: the held-out comparison of two closed-loop models
  (:mod:`.closed_loop`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

#: Largest lag (in samples) summed for τ, and the cut-off of the initial positive sequence.
MAX_TAU_LAG = 2000
RHO_CUTOFF = 0.05


def nrmse(measured: np.ndarray, simulated: np.ndarray) -> float:
    """||y - ŷ|| / ||y - mean(y)|| (inf when the measured signal is constant and ŷ differs)."""
    y = np.asarray(measured, dtype=float)
    err = float(np.linalg.norm(y - np.asarray(simulated, dtype=float)))
    spread = float(np.linalg.norm(y - y.mean()))
    if spread == 0.0:
        return 0.0 if err == 0.0 else math.inf
    return err / spread


def fit_percent(measured: np.ndarray, simulated: np.ndarray) -> float:
    """100·(1 − NRMSE), in per cent."""
    return 100.0 * (1.0 - nrmse(measured, simulated))


def autocorrelation(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation ρ_0..ρ_max_lag of x (mean removed), by FFT."""
    x = np.asarray(x, dtype=float) - float(np.mean(x))
    n = len(x)
    max_lag = min(max_lag, n - 1)
    size = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(x, size)
    acf = np.fft.irfft(spec * np.conj(spec), size)[: max_lag + 1]
    if acf[0] <= 0.0:
        out = np.zeros(max_lag + 1)
        out[0] = 1.0
        return out
    return acf / acf[0]


def autocorrelation_time(x: np.ndarray, max_lag: int = MAX_TAU_LAG) -> float:
    """τ = 1 + 2·Σ ρ_k over the initial run of ρ_k > RHO_CUTOFF (Geyer's initial positive
    sequence, truncated): 1 for white noise, ≈ (1+a)/(1−a) for an AR(1) with pole a."""
    if len(x) < 4:
        return 1.0
    rho = autocorrelation(x, max_lag)
    below = np.nonzero(rho[1:] <= RHO_CUTOFF)[0]
    stop = int(below[0]) + 1 if len(below) else len(rho)
    return max(1.0, 1.0 + 2.0 * float(np.sum(rho[1:stop])))


def effective_samples(n: int, tau: float) -> float:
    """n / τ, at least 2."""
    return max(2.0, n / max(tau, 1.0))


def information_criterion(mse: float, n_eff: float, k: int) -> float:
    """Bayesian information criterion n_eff·ln(MSE) + k·ln(n_eff) (lower is better)."""
    return float(n_eff * math.log(max(mse, 1e-300)) + k * math.log(max(n_eff, 2.0)))


def ljung_box(x: np.ndarray, lags: int = 20) -> tuple[float, float]:
    """Ljung-Box Q over lags 1..lags and its p-value (small p: the residual is not white)."""
    n = len(x)
    lags = max(1, min(lags, n - 2))
    rho = autocorrelation(x, lags)[1:]
    q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    return q, float(stats.chi2.sf(q, lags))


def newey_west_variance(d: np.ndarray, lags: int) -> float:
    """Long-run variance of the sum of d (Bartlett kernel, ``lags`` lags): Var(Σ d_t)."""
    d = np.asarray(d, dtype=float) - float(np.mean(d))
    n = len(d)
    lags = max(0, min(lags, n - 1))
    size = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(d, size)
    acov = np.fft.irfft(spec * np.conj(spec), size)[: lags + 1]  # Σ_t d_t d_{t+k}
    weights = 1.0 - np.arange(lags + 1) / (lags + 1.0)
    return float(acov[0] + 2.0 * np.sum(weights[1:] * acov[1:]))


def improvement_test(
    residual_small: np.ndarray, residual_big: np.ndarray, lags: int
) -> tuple[float, float]:
    """One-sided test that the held-out simulation errors ``residual_big`` (rows: signals,
    columns: samples; scaled) of the model with an added effect are smaller than
    ``residual_small`` of the model without it.

    With δ = r_small − r_big (what the effect changes in the simulation), the held-out
    improvement is ΔC = Σ(r_small² − r_big²) = Σδ² + 2·Σ δ·r_big. Were the effect not real,
    δ would be fitted training noise, independent of the held-out noise e, and
    ΔC = 2·Σδ·e − Σδ² (negative on average: unneeded parameters cost on held-out data), with
    standard deviation sd(2·Σδ·e). That is estimated with the Newey-West long-run variance of
    c_t = 2·Σ_signals δ·r_big (lags: the noise's correlation length) and
    z = ΔC / sd, p = Φ(−z). Where the two models simulate the same, δ = 0, so an effect that
    acts only at reversals or at the torque limit is judged against the noise where it acts,
    not against the noise of the whole recording (a Diebold-Mariano test whose variance comes
    from the noise instead of from the loss differences, which a few large events dominate)."""
    rs = np.atleast_2d(np.asarray(residual_small, dtype=float))
    rb = np.atleast_2d(np.asarray(residual_big, dtype=float))
    delta = rs - rb
    gain = float(np.sum(rs**2 - rb**2))
    c = 2.0 * np.sum(delta * rb, axis=0)
    var = newey_west_variance(c, lags)
    if var <= 0.0:
        return (math.inf, 0.0) if gain > 0.0 else (-math.inf if gain < 0 else 0.0, 1.0)
    z = gain / math.sqrt(var)
    return z, float(stats.norm.sf(z))

"""omega_a from the motor admittance: the two-mass model of eq. 2 fitted to a measured
``omega_m / tau_m`` (section IX takes omega_a "through the experimental frequency response").

Seen from the motor, the elastic axis of eq. 2 (motor side J_1, load J_2 = M / k_r^2, spring
and damper between them) turns a torque into an acceleration as

    A(j w) = j w omega_m / tau_m = (1 / J) * N(w) / D(w),
    N = 1 - (w / w_a)^2 + 2 j xi_a w / w_a,    D = 1 - (w / w_r)^2 + 2 j xi_r w / w_r,

J = J_1 + J_2 the whole inertia, w_a the antiresonance (the load's own frequency with the
motor held: the zero of eq. 2), w_r = w_a sqrt(1 + J_2 / J_1) the resonance. Nothing of the
controller enters: the admittance is the plant's, whatever loop measured it (the estimate of
:func:`regulator.frequency_response.estimate` takes torque and speed from the same periods).

:func:`fit_two_mass` fits log |A| over the measured lines, each weighted by its own relative
standard deviation (lines in the noise, relative deviation above ``max_rel_std``, are left
out), five parameters (log J, log w_a, log xi_a, log w_r, log xi_r; ``scipy.optimize.
least_squares`` from the deepest line and the highest line above it), and the rigid body
(1 / J alone) beside it. Its verdict rests on what was measured, not on a fixed notch depth:

* the two-mass model must explain the lines better than the rigid body beyond doubt (an F
  test, p below :data:`MAX_P`): an open backlash gap or a load held by its static friction
  leaves no zero-pole pair to find;
* w_a's spread over the realizations (each left out in turn: the jackknife, Student's t for
  their number; never less than the fit's own standard error, which alone judges fewer than
  :data:`MIN_REALIZATIONS`) plus the model's own error (:data:`MODEL_SHARE` of w_a: the
  sampled data and what eq. 2 leaves out; on development axes 1-7 of the FMU family the fit
  lay within 1.6 % of
  the data sheet) is the stated uncertainty (about 95 %); above ``max_rel_uncertainty`` of
  w_a, or w_a outside the band, it is not resolved;
* a zero damped more than :data:`MAX_DAMPING`, or more than :data:`DAMPING_OVER_SHEET` times
  the axis file's damping where it states one, is not the transmission's alone (a load held
  by static friction at standstill, a backlash gap that opens under the excitation);
* where the two-mass model itself does not fit (reduced chi-square above
  :data:`MAX_REDUCED_CHI2`: a second mode, a gap that opens during the test) the uncertainty
  grows by the square root of the reduced chi-square (Birge's ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import f as f_dist
from scipy.stats import t as student_t

#: A fit damped more than this many times the axis file's damping ratio is not resolved:
#: on the FMU family's development axes 0-9 (clean) the fit's damping was 1.0-1.5 times the
#: data sheet's; with free play (family 1, 0-19, 10 mm/s offset feed) the three values off
#: by 5-20 % were damped 2.8-3.6 times it (a gap that opens under the excitation).
DAMPING_OVER_SHEET = 2.0
#: Parameters fitted: log J, log w_a, log xi_a, log w_r, log xi_r and the first-order lags
#: of the torque and the speed readings (s; a drive's filters, an average over its cycle).
N_PARAMS = 7
#: The two-mass model's own share of w_a in the stated uncertainty (measured: 1.6 % at most).
MODEL_SHARE = 0.02
#: The two-mass model must beat the rigid body with an F test below this p.
MAX_P = 1e-6
#: The fit's band ends this factor above the admittance's highest line above its deepest.
BAND_ABOVE_PEAK = 2.0
#: A line's relative deviation is taken as at least this: the sampled-data model's own
#: accuracy, not the noise's (a noise-free simulation would weigh its lines without bound).
MIN_REL_STD = 0.01
#: Coverage factor of the fit's own standard error (about 95 %).
COVERAGE = 2.0
#: The jackknife judges the noise from this many realizations up (fewer: the fit's error).
MIN_REALIZATIONS = 4
#: Above this reduced chi-square the uncertainty is scaled by its square root.
MAX_REDUCED_CHI2 = 2.0
#: Damping ratios fitted.
XI_RANGE = (1e-4, 0.7)
#: A zero damped more than this is not the elastic transmission's (a screw-nut element: a few
#: per cent, the FMU family's 1-10 %): the load's friction takes part. Measured on development
#: axes 1-3 of the FMU family: with a 10 mm/s offset feed 0.083, 0.110, 0.030 (data sheet
#: 0.080, 0.093, 0.024); at standstill, where the load sticks, 0.187, 0.195, 0.115 (the zero
#: still within its uncertainty of the data sheet's).
MAX_DAMPING = 0.3


@dataclass(frozen=True)
class TwoMassFit:
    """The fitted two-mass admittance: rad/s, damping ratios, kg m^2; ``uncertainty_rad_s``
    of w_a about 95 %; ``reason``: why it is not resolved ('' when it is)."""

    antiresonance_rad_s: float
    damping_ratio: float
    resonance_rad_s: float
    resonance_damping_ratio: float
    inertia_kgm2: float
    uncertainty_rad_s: float
    jackknife_std_rad_s: float
    reduced_chi2: float
    p_rigid: float
    depth_db: float
    lines: int
    reason: str

    @property
    def resolved(self) -> bool:
        return not self.reason


def acceleration_admittance(params: np.ndarray, w: np.ndarray) -> np.ndarray:
    """log |A(j w)| of the module docstring at ``params`` = (log J, log w_a, log xi_a,
    log w_r, log xi_r)."""
    lj, lwa, lxa, lwr, lxr, lag_torque, lag_speed = params
    wa, wr = math.exp(lwa), math.exp(lwr)
    n = np.abs(1.0 - (w / wa) ** 2 + 2j * math.exp(lxa) * w / wa)
    d = np.abs(1.0 - (w / wr) ** 2 + 2j * math.exp(lxr) * w / wr)
    filters = 0.5 * (np.log1p((w * lag_torque) ** 2) - np.log1p((w * lag_speed) ** 2))
    return -lj + np.log(n) - np.log(d) + filters


def _fit(
    w: np.ndarray, log_a: np.ndarray, sigma: np.ndarray, start: np.ndarray
) -> tuple[np.ndarray, float]:
    """The parameters and the standard error of log w_a from the fit's Jacobian (the
    lines' own deviations, scaled by the reduced chi-square where it is above 1)."""
    lo_w, hi_w = math.log(w[0] / 2.0), math.log(w[-1] * 2.0)
    lag = 2.0 / w[0]
    lo = np.array([-np.inf, lo_w, math.log(XI_RANGE[0]), lo_w, math.log(XI_RANGE[0]), 0.0, 0.0])
    hi = np.array([np.inf, hi_w, math.log(XI_RANGE[1]), hi_w, math.log(XI_RANGE[1]), lag, lag])
    start = np.clip(start, lo + 1e-9, hi - 1e-9)
    res = least_squares(
        lambda p: (acceleration_admittance(p, w) - log_a) / sigma, start, bounds=(lo, hi)
    )
    reduced = max(1.0, float(np.sum(res.fun**2)) / max(1, w.size - N_PARAMS))
    try:
        cov = np.linalg.inv(res.jac.T @ res.jac) * reduced
        se = math.sqrt(max(float(cov[1, 1]), 0.0))
    except np.linalg.LinAlgError:
        se = math.inf
    return res.x, se


def _start(w: np.ndarray, log_a: np.ndarray) -> np.ndarray:
    """From the deepest line (w_a) and the highest line above it (w_r)."""
    i = int(np.argmin(log_a))
    j = i + int(np.argmax(log_a[i:]))
    if j == i:
        j = min(i + 1, w.size - 1)
    level = float(np.median(log_a[: max(3, i // 2)]))
    return np.array(
        [-level, math.log(w[i]), math.log(0.05), math.log(w[j]), math.log(0.05), 1e-5, 1e-5]
    )


def fit_two_mass(
    frequency_hz: np.ndarray,
    admittance: np.ndarray,
    std: np.ndarray,
    leave_one_out: np.ndarray,
    max_rel_std: float = 0.3,
    max_rel_uncertainty: float = 0.1,
    sheet_damping: float | None = None,
) -> TwoMassFit | None:
    """The two-mass model fitted to ``admittance`` (omega_m / tau_m, complex, at
    ``frequency_hz``, with its standard deviation ``std`` and the estimates with each
    realization left out, realizations x lines); None where fewer than 12 lines are clear of
    the noise. ``sheet_damping``: the axis file's damping ratio of the transmission; a fit
    damped more than :data:`DAMPING_OVER_SHEET` times it is not resolved."""
    a = np.abs(admittance)
    keep = (std <= max_rel_std * a) & (a > 0.0) & (frequency_hz > 0.0)
    if np.count_nonzero(keep) < 12:
        return None
    w = 2.0 * np.pi * frequency_hz[keep]
    log_a = np.log(a[keep] * w)
    # up to BAND_ABOVE_PEAK times the highest line above the deepest: the readings' filters
    # and the sampled data bend the admittance far above its pole, not the pair itself
    start = _start(w, log_a)
    near = w <= BAND_ABOVE_PEAK * math.exp(start[3])
    if np.count_nonzero(near) >= 12:
        keep[keep] = near
        w, log_a = w[near], log_a[near]
    sigma = np.maximum(std[keep] / a[keep], MIN_REL_STD)
    # the cut keeps every line up to the peak, so the start stands on the lines kept
    p, se_log_wa = _fit(w, log_a, sigma, start)
    resid = (acceleration_admittance(p, w) - log_a) / sigma
    n = w.size
    chi2 = float(np.sum(resid**2))
    rigid = float(np.average(log_a, weights=sigma**-2))
    chi2_rigid = float(np.sum(((log_a - rigid) / sigma) ** 2))
    dof = n - N_PARAMS
    reduced = chi2 / dof
    f_stat = ((chi2_rigid - chi2) / (N_PARAMS - 1)) / max(reduced, 1e-300)
    p_rigid = float(f_dist.sf(f_stat, N_PARAMS - 1, dof)) if f_stat > 0.0 else 1.0
    # the jackknife over the realizations, each fitted from the full fit's parameters
    others = []
    for row in leave_one_out:
        ar = np.abs(row[keep])
        if np.any(ar <= 0.0):
            continue
        others.append(math.exp(_fit(w, np.log(ar * w), sigma, p)[0][1]))
    m = len(others)
    wa = math.exp(p[1])
    jack = (
        math.sqrt((m - 1) / m * float(np.sum((np.array(others) - np.mean(others)) ** 2)))
        if m >= 2
        else math.nan
    )
    # the noise: the jackknife where there are enough realizations to judge it by
    # (MIN_REALIZATIONS), never less than the fit's own standard error (about 95 % each)
    noise = COVERAGE * wa * se_log_wa
    if m >= MIN_REALIZATIONS:
        noise = max(noise, float(student_t.ppf(0.975, m - 1)) * jack)
    birge = math.sqrt(max(1.0, reduced / MAX_REDUCED_CHI2))
    uncertainty = math.hypot(noise, MODEL_SHARE * wa) * birge
    xi_a, wr, xi_r = math.exp(p[2]), math.exp(p[3]), math.exp(p[4])
    depth = acceleration_admittance(p, np.array([wa]))[0] + p[0]
    reason = ""
    if p_rigid > MAX_P:
        reason = (
            f"the two-mass model explains the admittance no better than a rigid body "
            f"(F test p = {p_rigid:.2g}): the load is decoupled (an open gap, a load its "
            "friction holds) or its zero lies outside the band"
        )
    elif not (w[0] < wa < w[-1]) or wr <= wa:
        reason = (
            f"the fitted zero {wa:.1f} rad/s (pole {wr:.1f} rad/s) is not an antiresonance "
            f"inside the measured band {w[0]:.1f}..{w[-1]:.1f} rad/s"
        )
    elif xi_a > MAX_DAMPING:
        reason = (
            f"the fitted zero ({wa:.1f} rad/s) is damped {xi_a:.2f}, more than an elastic "
            "transmission is: the load's friction takes part (at standstill it sticks; an "
            "offset feed, --offset-speed, keeps the load sliding)"
        )
    elif sheet_damping and xi_a > DAMPING_OVER_SHEET * sheet_damping:
        reason = (
            f"the fitted zero ({wa:.1f} rad/s) is damped {xi_a:.3f}, "
            f"{xi_a / sheet_damping:.1f} times the axis file's {sheet_damping:.3f}: something "
            "besides the elastic element takes part (a backlash gap that opens under the "
            "excitation, the load's friction); a load that keeps the gap closed (a preload, a "
            "vertical axis's weight, a larger offset feed) or a smaller --amplitude decides"
        )
    elif uncertainty > max_rel_uncertainty * wa:
        reason = (
            f"its uncertainty {uncertainty:.1f} rad/s is above "
            f"{max_rel_uncertainty:.0%} of {wa:.1f} rad/s"
        )
    return TwoMassFit(
        wa,
        xi_a,
        wr,
        xi_r,
        math.exp(p[0]),
        uncertainty,
        jack,
        reduced,
        p_rigid,
        float(depth * 20.0 / math.log(10.0)),
        n,
        reason,
    )

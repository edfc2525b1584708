"""The torque balance of the axis from its measured motion: the inverse dynamic model (IDIM)
fitted by least squares, as the EMPS authors identify their axis (Janot, Gautier, Brunot 2019:
force = M·q̈ + Fv·q̇ + Fc·sign(q̇) + offset), with the regressors of every effect of the
axis-file table that acts on the torque.

For a two-mass axis (paper section III) — motor side J1 at θ, load M at x, friction and load
torques acting on the load — adding the motor's and the load's equations of motion gives,
exactly and whatever the stiffness between them:

    τ − J1·θ̈ = M·ẍ/k_r + τ_f(ẋ) + τ_load(x)        (τ_f, τ_load reflected to the motor)

With both measuring systems recorded ẍ is the load's; with the motor encoder only it is θ̈/k_r
(and an elastic element shows in the fourth derivative, :data:`COMPLIANCE_KEY`). Every term
is linear in its parameter:

=========================  =========================================  ====================
effect                     regressor(s)                               coefficient
=========================  =========================================  ====================
(mass)                     ẍ/k_r                                       load_mass
coulomb_friction           sign(ẋ)                                     coulomb
viscous_friction           ẋ                                           viscous
asymmetric_friction        −[ẋ<0], ẋ·[ẋ<0]                              Δ coulomb/viscous (−)
stribeck_friction          sign(ẋ)·exp(−(ẋ/v_s)²), scan of v_s          stribeck
constant_load_torque       1                                           constant_torque
periodic_disturbance       sin(2πx/P), cos(2πx/P), P from the         A·cos φ, A·sin φ
                           residual's spectrum over position
compliance (one system)    −x⁗/k_r                                     M/ω_a²
=========================  =========================================  ====================

Rows: the load moving (|ẋ| above :data:`MOVING_FRACTION` of the top speed) and not within a
derivative window of a reversal (sign(ẋ) of a smoothed speed is wrong there, and set-valued
friction is any value at rest).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from virtual_bus.formats.axis import AxisConfig

from .effects import COMPLIANCE_KEY, DELTA_COULOMB_NEG, DELTA_VISCOUS_NEG, Effect
from .fit import PERIODIC_COS, PERIODIC_SIN
from .measured import Measured, window_samples
from .regression import Candidate, Relation

NAME = "torque balance"
#: Slowest speed used, as a fraction of the top reference speed.
MOVING_FRACTION = 0.005
#: Points of the Stribeck-speed scan.
STRIBECK_POINTS = 12


@dataclass(frozen=True)
class Scans:
    """The non-linear parameters scanned, chosen from the recording (so that the recording
    and every replay are tested on the same grid): Stribeck speeds, and the band of periods
    a position-periodic torque is looked for in."""

    speed_max: float
    stribeck_speeds: tuple[float, ...]
    period_band: tuple[float, float] | None


def scans_for(rec: Measured) -> Scans:
    """Stribeck speeds log-spaced from 4x the slowest speed used to 0.3 of the top speed;
    periods from what the sampling resolves (8 samples per period at the median moving speed)
    to half the travel."""
    v_ref = np.gradient(rec.reference, rec.time_s)
    vmax = max(float(np.max(np.abs(v_ref))), 1e-12)
    v_lo = MOVING_FRACTION * vmax
    strb = tuple(np.geomspace(4.0 * v_lo, 0.3 * vmax, STRIBECK_POINTS))
    moving = np.abs(rec.speed) > 0.05 * vmax
    span = float(np.ptp(rec.load_position))
    band = None
    if moving.sum() > 50 and span > 0.0:
        v_typ = float(np.median(np.abs(rec.speed[moving])))
        p_lo = max(8.0 * v_typ * rec.dt, span / 2000.0)
        p_hi = span / 2.0
        if p_hi > 1.5 * p_lo:
            band = (p_lo, p_hi)
    return Scans(vmax, strb, band)


@dataclass(frozen=True)
class PeriodChoice:
    """The period a position-periodic torque is tested at, and the number of independent
    periods the choice was made among (the test's p is multiplied by it: Bonferroni)."""

    period: float
    looked_at: float


def choose_period(
    m: Measured, residual: np.ndarray, rows: np.ndarray, band: tuple[float, float]
) -> PeriodChoice | None:
    """The largest peak in ``band`` of the residual's spectrum over position: the moving rows'
    residual averaged in position bins a quarter of the shortest period wide, the binned
    profile's FFT (zero-padded four times). Independent periods in the band: the unpadded
    FFT's frequencies there, span/p_lo − span/p_hi."""
    x, r = m.load_position[rows], residual[rows]
    if len(x) < 50:
        return None
    r = r - float(np.mean(r))
    p_lo, p_hi = band
    width = p_lo / 4.0
    idx = np.floor((x - float(x.min())) / width).astype(int)
    n_bins = int(idx.max()) + 1
    sums = np.bincount(idx, r, n_bins)
    counts = np.bincount(idx, None, n_bins)
    profile = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    size = 4 * (1 << (n_bins - 1).bit_length())
    power = np.abs(np.fft.rfft(profile, size)) ** 2
    freqs = np.fft.rfftfreq(size, width)
    with np.errstate(divide="ignore"):
        periods = np.where(freqs > 0, 1.0 / freqs, np.inf)
    inside = (periods >= p_lo) & (periods <= p_hi)
    if not inside.any():
        return None
    k = int(np.argmax(np.where(inside, power, -1.0)))
    span = n_bins * width
    return PeriodChoice(float(periods[k]), max(1.0, span / p_lo - span / p_hi))


def moving_rows(m: Measured, speed_max: float) -> np.ndarray:
    """Rows where the torque balance is fitted: moving, away from reversals."""
    v = m.speed
    moving = np.abs(v) > MOVING_FRACTION * speed_max
    sign = np.sign(v) * moving
    change = np.zeros(len(v), dtype=bool)
    change[1:] = sign[1:] != sign[:-1]
    half = window_samples(m.dt, m.n) // 2 + 1
    near = np.convolve(change.astype(float), np.ones(2 * half + 1), mode="same") > 0
    return moving & ~near


def _friction_columns(axis: AxisConfig, v: np.ndarray) -> dict[str, np.ndarray]:
    fr = axis.friction
    pos, neg = (v > 0).astype(float), (v < 0).astype(float)
    cols: dict[str, np.ndarray] = {}
    asym_c = fr.coulomb_negative is not None
    asym_v = fr.viscous_negative is not None
    if fr.coulomb is not None:
        cols["friction.coulomb"] = pos if asym_c else np.sign(v)
    if asym_c:
        cols["friction.coulomb_negative"] = -neg
    if fr.viscous is not None:
        cols["friction.viscous"] = v * pos if asym_v else v
    if asym_v:
        cols["friction.viscous_negative"] = v * neg
    if fr.stribeck is not None and fr.stribeck_speed:
        cols["friction.stribeck"] = np.sign(v) * np.exp(-((v / fr.stribeck_speed) ** 2))
    return cols


def _model_values(axis: AxisConfig, keys: list[str]) -> dict[str, float]:
    out = {}
    d = axis.disturbance
    for k in keys:
        if k in (PERIODIC_COS, PERIODIC_SIN):
            amp, phase = d.periodic_amplitude or 0.0, d.periodic_phase or 0.0
            out[k] = amp * (math.cos(phase) if k == PERIODIC_COS else math.sin(phase))
        else:
            out[k] = float(axis.value(k) or 0.0)
    return out


def torque_relation(m: Measured, axis: AxisConfig, scans: Scans) -> Relation:
    """The torque balance with the columns of the effects ``axis`` has (its base)."""
    kr = axis.transmission_ratio
    v, x = m.speed, m.load_position
    y = m.torque - axis.motor_side_inertia * m.motor_accel
    cols: dict[str, np.ndarray] = {"mechanics.load_mass": m.accel / kr}
    cols.update(_friction_columns(axis, v))
    d = axis.disturbance
    if d.constant_torque is not None and axis.friction.coulomb_negative is not None:
        # while the axis moves, a load torque is direction-dependent Coulomb friction (1 =
        # [v>0] + [v<0]): with both in the model the load torque is not identified on these
        # rows and stays at the model's value (a known term)
        y = y - d.constant_torque
    elif d.constant_torque is not None:
        cols["disturbance.constant_torque"] = np.ones(m.n)
    if d.periodic_amplitude is not None and d.periodic_period:
        ph = 2.0 * math.pi * x / d.periodic_period
        cols[PERIODIC_COS] = np.sin(ph)
        cols[PERIODIC_SIN] = np.cos(ph)
    return Relation(NAME, y, cols, moving_rows(m, scans.speed_max), _model_values(axis, list(cols)))


def torque_candidates(
    m: Measured,
    axis: AxisConfig,
    scans: Scans,
    effects: frozenset[Effect],
    period: PeriodChoice | None = None,
) -> list[Candidate]:
    """The regressors of every effect in ``effects`` that acts on the torque balance (the
    position-periodic torque at ``period``, :func:`choose_period`)."""
    v, x = m.speed, m.load_position
    kr = axis.transmission_ratio
    sign = np.sign(v)
    out: list[Candidate] = []

    def one(effect: Effect, cols: dict[str, np.ndarray]) -> None:
        out.append(Candidate(effect, NAME, [cols], [None]))

    if Effect.COULOMB_FRICTION in effects:
        one(Effect.COULOMB_FRICTION, {"friction.coulomb": sign})
    if Effect.VISCOUS_FRICTION in effects:
        one(Effect.VISCOUS_FRICTION, {"friction.viscous": v})
    if Effect.ASYMMETRIC_FRICTION in effects:
        neg = (v < 0).astype(float)
        one(Effect.ASYMMETRIC_FRICTION, {DELTA_COULOMB_NEG: -neg, DELTA_VISCOUS_NEG: v * neg})
    if Effect.CONSTANT_LOAD_TORQUE in effects:
        one(Effect.CONSTANT_LOAD_TORQUE, {"disturbance.constant_torque": np.ones(m.n)})
    if Effect.STRIBECK_FRICTION in effects and scans.stribeck_speeds:
        scan = [
            {"friction.stribeck": sign * np.exp(-((v / vs) ** 2))} for vs in scans.stribeck_speeds
        ]
        out.append(
            Candidate(
                Effect.STRIBECK_FRICTION,
                NAME,
                scan,
                list(scans.stribeck_speeds),
                "friction.stribeck_speed",
            )
        )
    if Effect.PERIODIC_DISTURBANCE in effects and period is not None:
        ph = 2.0 * math.pi * x / period.period
        out.append(
            Candidate(
                Effect.PERIODIC_DISTURBANCE,
                NAME,
                [{PERIODIC_COS: np.sin(ph), PERIODIC_SIN: np.cos(ph)}],
                [period.period],
                "disturbance.periodic_period",
                look_elsewhere=period.looked_at,
            )
        )
    if Effect.COMPLIANCE in effects and not m.two_systems:
        one(Effect.COMPLIANCE, {COMPLIANCE_KEY: -m.jerk2 / kr})
    return out


def scan_columns(effect: Effect, m: Measured, value: float) -> dict[str, np.ndarray]:
    """The regressors of a scanned effect at one value of its scanned parameter."""
    if effect is Effect.STRIBECK_FRICTION:
        v = m.speed
        return {"friction.stribeck": np.sign(v) * np.exp(-((v / value) ** 2))}
    if effect is Effect.PERIODIC_DISTURBANCE:
        ph = 2.0 * math.pi * m.load_position / value
        return {PERIODIC_COS: np.sin(ph), PERIODIC_SIN: np.cos(ph)}
    raise ValueError(f"{effect.value} has no scanned parameter")

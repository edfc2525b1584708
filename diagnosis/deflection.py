"""What two measuring systems say about the transmission between them: the deflection
θ/k_r − x against the force the transmission carries.

With the motor encoder θ and a load measuring system x recorded, the screw-nut element (paper
section III, eq. 2) carries the force F_s that moves the load, F_s = M·ẍ + F_f(ẋ) − F_load(x)
(the load's equation of motion, :func:`load_side_force`: the calibrated torque balance of
:mod:`.idim` times k_r, so free of the torque's noise — a regressor with noise biases a
least-squares fit — and of the motor side's inertia, which on a light slide is three times
the load's and leaves F_s = k_r·(τ − J1·θ̈) the small difference of two large terms) and
deflects

    θ/k_r − x = c₀ + F_s/k − (c/k)·(θ̇/k_r − ẋ) + (δ/2)·sign(F_s) + o·ẋ

    − A·sin(2πx/P + φ)

c₀ the unrelated zeros of the two systems, k = M·ω_a² the stiffness and c its damping (eq. 2:
c/k = 2ξ/ω_a), δ the free play crossed at every reversal of the force (lost motion between the
two systems), o a sensor time offset (the load read o later: x(t − o) ≈ x − o·ẋ), and a
periodic error of the load scale (it reads x + A·sin(2πx/P + φ): a reading error, so it lives
here and not in the torque balance, which sees it only through ẍ). Linear in 1/k, c/k, δ, o,
A·cos φ and A·sin φ at a period P, chosen like the torque's (:func:`.idim.choose_period` on
this relation's residual over position, the choice paid for in the test's p):

=====================  ==========================  =======================================
effect                 regressor                   coefficient
=====================  ==========================  =======================================
compliance             F_s, −(θ̇/k_r − ẋ)            1/k = 1/(M·ω_a²), c/k = 2ξ/ω_a
backlash               sign(F_s)/2                 δ (mechanics.backlash)
sensor_time_offset     ẋ                           o (control.sensor_time_offset)
scale_error            −sin(2πx/P), −cos(2πx/P)    A·cos φ, A·sin φ (control.scale_error_*)
=====================  ==========================  =======================================

Rows: where |F_s| is clear of zero (the free play is being crossed there, and the contact
side is unknown).
"""

from __future__ import annotations

import numpy as np

from virtual_bus.formats.axis import AxisConfig

from .effects import DAMPING, FLEXIBILITY, SCALE_COS, SCALE_PERIOD, SCALE_SIN, Effect, model_values
from .idim import PeriodChoice
from .measured import Measured
from .regression import Candidate, Relation

NAME = "deflection"
ZERO = "deflection.zero"  # the two systems' zero difference (nuisance)
#: Force below which a row is not used, as a fraction of the 99th percentile of |F_s|.
FORCE_FRACTION = 0.02


def load_side_force(
    columns: dict[str, np.ndarray], coefficients: dict[str, float], transmission_ratio: float
) -> np.ndarray:
    """F_s = k_r·Σ θ_j·x_j over the torque balance's columns (the load side's torque at the
    motor, with the calibrated coefficients), load coordinates (N for a linear axis)."""
    total = np.zeros(len(next(iter(columns.values()))))
    for k, x in columns.items():
        total = total + coefficients.get(k, 0.0) * x
    return transmission_ratio * total


def force_threshold(force: np.ndarray) -> float:
    """|F_s| below which rows are not used, from the recording's force (the same rule for the
    recording and every replay): FORCE_FRACTION of its 99th percentile."""
    return FORCE_FRACTION * float(np.percentile(np.abs(force), 99.0))


def scale_columns(m: Measured, period: float) -> dict[str, np.ndarray]:
    """The scale error's regressors at ``period`` (load units): the deflection θ/k_r − x
    carries −A·sin(2πx/P + φ) = −A·cos φ·sin(2πx/P) − A·sin φ·cos(2πx/P)."""
    ph = 2.0 * np.pi * m.load_position / period
    return {SCALE_COS: -np.sin(ph), SCALE_SIN: -np.cos(ph)}


def deflection_relation(
    m: Measured,
    axis: AxisConfig,
    force: np.ndarray,
    threshold: float,
    rows: np.ndarray,
    contact: bool = False,
) -> Relation | None:
    """The deflection with the columns of what ``axis`` has (None: one measuring system);
    ``force`` from :func:`load_side_force`; ``rows`` where that force is known (the torque
    balance's: moving — at rest friction holds any force up to its static level — away from
    reversals) and |F_s| > ``threshold`` (:func:`force_threshold` of the recording).
    ``contact``: the axis's elastic element is the stiff contact added with free play to a
    rigid model (not fitted): its deflection is a known term, not a free column."""
    if not m.two_systems or m.deflection is None or m.deflection_rate is None:
        return None
    cols: dict[str, np.ndarray] = {ZERO: np.ones(m.n)}
    y = m.deflection
    values = model_values(axis)
    if axis.mechanics.antiresonance is not None and contact:
        y = y - values[FLEXIBILITY] * force + values[DAMPING] * m.deflection_rate
    elif axis.mechanics.antiresonance is not None:
        cols[FLEXIBILITY] = force
        cols[DAMPING] = -m.deflection_rate
    if axis.mechanics.backlash is not None:
        cols["mechanics.backlash"] = 0.5 * np.sign(force)
    if axis.control.sensor_time_offset is not None:
        cols["control.sensor_time_offset"] = m.speed
    if axis.control.scale_error_amplitude is not None and axis.control.scale_error_period:
        cols.update(scale_columns(m, axis.control.scale_error_period))
    values = {k: v for k, v in values.items() if k in cols}
    return Relation(NAME, y, cols, rows & (np.abs(force) > threshold), values)


def deflection_candidates(
    m: Measured,
    force: np.ndarray,
    effects: frozenset[Effect],
    period: PeriodChoice | None = None,
) -> list[Candidate]:
    """Regressors of compliance, backlash, sensor time offset and the scale error at
    ``period`` (those in ``effects``)."""
    if not m.two_systems or m.deflection_rate is None:
        return []
    out = []
    if Effect.COMPLIANCE in effects:
        cols = {FLEXIBILITY: force, DAMPING: -m.deflection_rate}
        out.append(Candidate(Effect.COMPLIANCE, NAME, [cols], [None]))
    if Effect.BACKLASH in effects:
        cols = {"mechanics.backlash": 0.5 * np.sign(force)}
        out.append(Candidate(Effect.BACKLASH, NAME, [cols], [None]))
    if Effect.SENSOR_TIME_OFFSET in effects:
        cols = {"control.sensor_time_offset": m.speed}
        out.append(Candidate(Effect.SENSOR_TIME_OFFSET, NAME, [cols], [None]))
    if Effect.SCALE_ERROR in effects and period is not None:
        out.append(
            Candidate(
                Effect.SCALE_ERROR,
                NAME,
                [scale_columns(m, period.period)],
                [period.period],
                SCALE_PERIOD,
                look_elsewhere=period.looked_at,
            )
        )
    return out

"""The evidence stage's linear relations against things this project did not write: the
inverse dynamic model of the EMPS authors (their published least-squares estimates on their
own recording), and analytic signals built from a known torque law and a known deflection
law (every parameter recovered)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis import deflection as dfl
from diagnosis import idim
from diagnosis.effects import MODELS, SCALE_PERIOD, Effect
from diagnosis.fit import PERIODIC_COS, PERIODIC_SIN
from diagnosis.measured import measured
from diagnosis.regression import evaluate_candidates, fit_relation
from diagnosis.synthetic import slide_axis
from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisConfig, load_axis
from virtual_bus.formats.trace import Trace
from virtual_bus.shipped import SHARED_DIR

EMPS = SHARED_DIR / "data" / "emps"

#: Janot, Gautier, Brunot (2019), EMPS data set README: the reference model's inverse dynamic
#: model identified by least squares on DATA_EMPS.
PUBLISHED = {
    "mechanics.load_mass": 95.1089,
    "friction.viscous": 203.5034,
    "friction.coulomb": 20.3935,
    "disturbance.constant_torque": -3.1648,
}


@pytest.mark.skipif(
    not (EMPS / "DATA_EMPS.mat").exists(), reason=f"EMPS data not in {EMPS} (set EMPS_DATA)"
)
def test_idim_least_squares_reproduces_the_emps_authors_estimates() -> None:
    """The torque balance of :mod:`diagnosis.idim` fitted by ordinary least squares
    on the estimation recording gives the published reference model within 5 % (mass,
    viscous and Coulomb friction) and 10 % (the offset): the authors filtered and decimated
    their signals their own way, the method is theirs."""
    from plant_sim.datasets.emps import emps_trace, read_emps_mat

    trace = emps_trace(read_emps_mat(EMPS / "DATA_EMPS.mat"))
    axis = load_axis(CONFIG / "emps_reference.toml")
    m = measured(trace, axis)
    rel = idim.torque_relation(m, axis, idim.scans_for(m))
    keys = list(rel.columns)
    x = rel.matrix(keys)[rel.mask]
    coef, *_ = np.linalg.lstsq(x, rel.y[rel.mask], rcond=None)
    got = dict(zip(keys, coef, strict=True))
    for key, value in PUBLISHED.items():
        tol = 0.10 if key.startswith("disturbance") else 0.05
        assert got[key] == pytest.approx(value, rel=tol), key


def _kinematics(kr: float, seconds: float = 20.0, dt: float = 0.002) -> tuple[np.ndarray, ...]:
    t = np.arange(0.0, seconds, dt)
    x = 0.15 + 0.1 * np.sin(2 * np.pi * t / 3.1) + 0.02 * np.sin(2 * np.pi * t / 0.7)
    v = np.gradient(x, dt)
    a = np.gradient(v, dt)
    return t, x, v, a


def _recording(axis: AxisConfig, tau_law, seed: int) -> tuple[Trace, np.ndarray]:
    kr, j1 = axis.transmission_ratio, axis.motor_side_inertia
    t, x, v, a = _kinematics(kr)
    tau = j1 * kr * a + tau_law(x, v, a)
    rng = np.random.default_rng(seed)
    trace = Trace(
        {
            "time": t,
            "position_reference": x,
            "motor_position": kr * x,
            "motor_torque": tau + 0.002 * rng.standard_normal(len(t)),
        }
    )
    return trace, v


MASS, C, B = 25.0, 0.08, 0.4


def _rigid(x: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    return MASS * a / slide_axis().transmission_ratio + C * np.sign(v) + B * v


def test_torque_law_with_every_torque_effect_is_recovered() -> None:
    """An analytic recording: the torque of a rigid axis from a known law (mass, Coulomb,
    viscous, direction-dependent friction, a Stribeck peak, a periodic torque) on exact
    kinematics plus white noise. Each effect tested against a base that has the others is
    found, at the law's values."""
    axis = slide_axis()
    dcn, dvn, s, vs = 0.01, 0.05, 0.02, 0.01
    amp, period, phase = 0.006, 0.013, 0.7

    def law(x: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        return (
            _rigid(x, v, a)
            + (v < 0) * (-dcn + dvn * v)
            + s * np.sign(v) * np.exp(-((v / vs) ** 2))
            + amp * np.sin(2 * np.pi * x / period + phase)
        )

    trace, _ = _recording(axis, law, 0)
    m = measured(trace, axis)
    scans = idim.scans_for(m)
    rng = np.random.default_rng(1)
    full = axis.with_values(
        {
            "friction.stribeck": s,
            "friction.stribeck_speed": vs,
            "disturbance.periodic_amplitude": amp,
            "disturbance.periodic_period": period,
            "disturbance.periodic_phase": phase,
        }
    )
    rel_full = idim.torque_relation(m, full, scans)
    cands = idim.torque_candidates(m, full, scans, frozenset({Effect.ASYMMETRIC_FRICTION}))
    res = evaluate_candidates(rel_full, [], fit_relation(rel_full), cands, [], rng)
    asym = res[Effect.ASYMMETRIC_FRICTION]
    assert asym.p < 1e-6
    assert asym.estimate[idim.DELTA_COULOMB_NEG] == pytest.approx(dcn, abs=0.002)
    assert asym.estimate[idim.DELTA_VISCOUS_NEG] == pytest.approx(dvn, abs=0.01)
    # the model with every term of the law: each coefficient is the law's
    complete = full.with_values(
        {"friction.coulomb_negative": C + dcn, "friction.viscous_negative": B + dvn}
    )
    got = fit_relation(idim.torque_relation(m, complete, scans)).recording
    assert got["mechanics.load_mass"] == pytest.approx(MASS, rel=0.02)
    assert got["friction.coulomb"] == pytest.approx(C, rel=0.03)
    assert got["friction.coulomb_negative"] == pytest.approx(C + dcn, rel=0.03)
    assert got["friction.viscous_negative"] == pytest.approx(B + dvn, rel=0.03)
    assert got["friction.stribeck"] == pytest.approx(s, rel=0.05)
    assert math.hypot(got[PERIODIC_COS], got[PERIODIC_SIN]) == pytest.approx(amp, rel=0.05)
    # against the rigid base alone (the residual holds the other terms too, which widen the
    # null), the Stribeck peak is still found near its speed
    rel = idim.torque_relation(m, axis, scans)
    cands0 = idim.torque_candidates(m, axis, scans, frozenset({Effect.STRIBECK_FRICTION}))
    found = evaluate_candidates(rel, [], fit_relation(rel), cands0, [], rng)
    assert found[Effect.STRIBECK_FRICTION].p < 0.01
    assert found[Effect.STRIBECK_FRICTION].estimate["friction.stribeck_speed"] == pytest.approx(
        vs, rel=0.5
    )


def test_a_load_torque_is_recovered_and_no_effect_is_found_in_a_clean_law() -> None:
    axis = slide_axis()
    c0 = 0.012

    def law(x: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        return _rigid(x, v, a) + c0

    effects = frozenset(
        {Effect.CONSTANT_LOAD_TORQUE, Effect.STRIBECK_FRICTION, Effect.PERIODIC_DISTURBANCE}
    )
    trace, _ = _recording(axis, law, 2)
    m = measured(trace, axis)
    scans = idim.scans_for(m)
    rel = idim.torque_relation(m, axis, scans)
    rng = np.random.default_rng(3)
    found = evaluate_candidates(
        rel, [], fit_relation(rel), idim.torque_candidates(m, axis, scans, effects), [], rng
    )
    assert found[Effect.CONSTANT_LOAD_TORQUE].p < 1e-6
    assert found[Effect.CONSTANT_LOAD_TORQUE].estimate[
        "disturbance.constant_torque"
    ] == pytest.approx(c0, abs=5e-4)
    clean, _ = _recording(axis, _rigid, 4)
    m = measured(clean, axis)
    rel = idim.torque_relation(m, axis, scans)
    period = idim.choose_period(
        m,
        rel.y
        - rel.matrix(list(rel.columns))
        @ np.linalg.lstsq(rel.matrix(list(rel.columns))[rel.mask], rel.y[rel.mask], rcond=None)[0],
        rel.mask,
        scans.period_band,
    )
    nothing = evaluate_candidates(
        rel, [], fit_relation(rel), idim.torque_candidates(m, axis, scans, effects, period), [], rng
    )
    assert all(t.p > 0.001 for t in nothing.values()), {e.value: t.p for e, t in nothing.items()}


def test_choose_period_finds_a_position_periodic_torque() -> None:
    axis = slide_axis()
    kr = axis.transmission_ratio
    t, x, _, _ = _kinematics(kr)
    period = 0.013
    r = 0.004 * np.sin(2 * np.pi * x / period) + 0.002 * np.random.default_rng(1).standard_normal(
        len(t)
    )
    trace = Trace({"time": t, "position_reference": x, "motor_position": kr * x, "motor_torque": r})
    m = measured(trace, axis)
    band = idim.scans_for(m).period_band
    assert band is not None
    choice = idim.choose_period(m, r, np.abs(m.speed) > 0.01, band)
    assert choice is not None
    assert choice.period == pytest.approx(period, rel=0.03)
    assert choice.looked_at > 10.0


def _two_mass(axis: AxisConfig) -> AxisConfig:
    return axis.with_values({"mechanics.antiresonance": 800.0, "mechanics.damping_ratio": 0.05})


def test_deflection_law_is_recovered() -> None:
    """Motor and load positions from a known deflection law: F/k + δ/2·sign(F) + o·v (with
    the load-side force known): flexibility, free play and sensor offset recovered."""
    axis = slide_axis()
    kr = axis.transmission_ratio
    t, x, v, a = _kinematics(kr)
    force = 25.0 * a + 50.0 * np.sign(v) + 250.0 * v
    k, delta, offset = 1.6e7, 8e-6, 4e-4
    defl = force / k + 0.5 * delta * np.sign(force) + offset * v
    rng = np.random.default_rng(2)
    trace = Trace(
        {
            "time": t,
            "position_reference": x,
            "motor_position": kr * (x + defl),
            "load_position": x + 2e-8 * rng.standard_normal(len(t)),
            "motor_torque": np.zeros_like(t),
        }
    )
    m = measured(trace, axis)
    rows = np.abs(m.speed) > 0.005
    rel = dfl.deflection_relation(m, axis, force, dfl.force_threshold(force), rows)
    assert rel is not None
    effects = frozenset({Effect.COMPLIANCE, Effect.BACKLASH, Effect.SENSOR_TIME_OFFSET})
    cands = dfl.deflection_candidates(m, force, effects)
    # all three at once: the largest model's fit
    fitted = fit_relation(rel, [], cands)
    keys = list(rel.columns) + [key for c in cands for key in c.scan[0]]
    cols = {**rel.columns, **{key: c.scan[0][key] for c in cands for key in c.scan[0]}}
    x_all = np.column_stack([cols[key] for key in keys])
    w, valid = fitted.whitener, fitted.valid
    coef, *_ = np.linalg.lstsq(w.apply(x_all)[valid], w.apply(rel.y)[valid], rcond=None)
    got = dict(zip(keys, coef, strict=True))
    assert got[dfl.FLEXIBILITY] == pytest.approx(1.0 / k, rel=0.05)
    assert got["mechanics.backlash"] == pytest.approx(delta, rel=0.05)
    assert got["control.sensor_time_offset"] == pytest.approx(offset, rel=0.05)


def test_a_periodic_scale_error_is_found_in_the_deflection_not_in_the_torque() -> None:
    """A load scale that reads x + A·sin(2πx/P + φ) over a stiff transmission: the period
    from the deflection's residual over position, A and φ recovered from the deflection's
    two coefficients (the torque law, a clean one, has nothing to show)."""
    axis = slide_axis()
    kr = axis.transmission_ratio
    t, x, v, a = _kinematics(kr)
    amp, period, phase = 5e-6, 0.0125, 2.1
    force = 25.0 * a + 50.0 * np.sign(v)
    rng = np.random.default_rng(3)
    trace = Trace(
        {
            "time": t,
            "position_reference": x,
            "motor_position": kr * x,
            "load_position": x
            + amp * np.sin(2 * np.pi * x / period + phase)
            + 2e-8 * rng.standard_normal(len(t)),
            "motor_torque": np.zeros_like(t),
        }
    )
    m = measured(trace, axis)
    rows = np.abs(m.speed) > 0.005
    rel = dfl.deflection_relation(m, axis, force, dfl.force_threshold(force), rows)
    assert rel is not None
    band = idim.scans_for(m).period_band
    assert band is not None
    fitted = fit_relation(rel, [])
    base = rel.matrix(list(fitted.keys)) @ np.array([fitted.recording[k] for k in fitted.keys])
    choice = idim.choose_period(m, rel.y - base, rel.mask, band)
    assert choice is not None
    assert choice.period == pytest.approx(period, rel=0.03)
    cands = dfl.deflection_candidates(m, force, frozenset({Effect.SCALE_ERROR}), choice)
    assert [c.effect for c in cands] == [Effect.SCALE_ERROR]
    cols = {**rel.columns, **dfl.scale_columns(m, period)}
    keys = list(cols)
    coef, *_ = np.linalg.lstsq(
        np.column_stack([cols[k] for k in keys])[rel.mask], rel.y[rel.mask], rcond=None
    )
    got = dict(zip(keys, coef, strict=True))
    vals = MODELS[Effect.SCALE_ERROR].values({**got, SCALE_PERIOD: period}, axis)[0]
    assert vals["control.scale_error_amplitude"] == pytest.approx(amp, rel=0.02)
    assert vals["control.scale_error_phase"] == pytest.approx(phase, abs=0.02)
    assert vals[SCALE_PERIOD] == period

"""The diagnosis does not hide an effect behind a re-fit, keeps nominal parameters within
their data sheet unless the evidence says the sheet is wrong (and says so), never aborts on a
legal model, and says where its model class does not explain a recording ("unexplained,
here") instead of that nothing was left out (issue 17 items 2-4)."""

from __future__ import annotations

import math
import re
import tomllib

import numpy as np
import pytest

from diagnosis.adequacy import NOISE_RATIO_MAX, assess
from diagnosis.effects import MODELS, Effect
from diagnosis.engine import DiagnosisOptions, diagnose
from diagnosis.metrics import fit_percent
from diagnosis.mismatch import classify, reference_kinematics
from diagnosis.parameters import UNCERTAINTY, key_unit, uncertainty_box, units
from diagnosis.results import SignalFit
from diagnosis.synthetic import slide_axis
from plant_sim.physics.model import KernelOptions, default_substeps
from plant_sim.physics.simulate import References, simulate
from virtual_bus.formats.axis import AxisKind, axis_from_mapping, dump_axis
from virtual_bus.formats.trace import Trace


def test_units_follow_the_axis() -> None:
    linear = slide_axis()
    assert units(linear) == {"torque": "N·m", "position": "m", "speed": "m/s"}
    assert key_unit("friction.viscous", linear) == "N·m·s/m"
    assert key_unit("mechanics.backlash", linear) == "m"
    ratio_one = linear.with_values({"axis.transmission_ratio": 1.0})  # EMPS: forces in N
    assert key_unit("friction.coulomb", ratio_one) == "N"
    assert key_unit("friction.viscous", ratio_one) == "N·s/m"
    from dataclasses import replace

    rotary = replace(linear, kind=AxisKind.ROTARY)
    assert key_unit("mechanics.backlash", rotary) == "rad"
    assert key_unit("friction.stribeck_speed", rotary) == "rad/s"
    assert key_unit("mechanics.load_mass", rotary) == "kg·m²"


@pytest.mark.parametrize("effect", list(Effect), ids=[e.value for e in Effect])
def test_every_effect_strips_to_a_valid_axis_without_it(effect: Effect) -> None:
    """Each effect object knows its keys: an axis with every effect present loses exactly
    this one (and stays a valid axis file, checked by writing and reading it back)."""
    full = slide_axis().with_values(
        {
            "mechanics.antiresonance": 900.0,
            "mechanics.damping_ratio": 0.05,
            "mechanics.backlash": 1e-5,
            "friction.coulomb_negative": 0.09,
            "friction.viscous_negative": 0.45,
            "friction.stribeck": 0.03,
            "friction.stribeck_speed": 0.005,
            "disturbance.constant_torque": 0.01,
            "disturbance.periodic_amplitude": 0.01,
            "disturbance.periodic_period": 0.01,
            "disturbance.periodic_phase": 0.2,
            "control.torque_limit": 3.0,
            "control.delay": 0.000375,
            "control.sensor_time_offset": 0.001,
            "control.setpoint_delay": 0.002,
            "control.setpoint_delay_rate": 1e-4,
            "control.measurement_delay": 0.0005,
            "control.scale_error_amplitude": 5e-6,
            "control.scale_error_period": 0.0125,
            "control.scale_error_phase": 0.3,
        }
    )
    model = MODELS[effect]
    assert model.present(full)
    stripped = model.strip(full)
    assert not model.present(stripped)
    back = axis_from_mapping(tomllib.loads(dump_axis(stripped)))
    assert back == stripped
    others = {e for e, m in MODELS.items() if m.present(full)} - {effect}
    if effect is Effect.COMPLIANCE:
        others.discard(Effect.BACKLASH)  # the contact goes with the elastic element
    assert all(MODELS[e].present(stripped) for e in others)
    assert model.describe(full)


def _recording(axis, seconds: float, seed: int, load_nm=None) -> Trace:
    """Back-and-forth moves at two speeds, both positions recorded, noise; ``load_nm``: an
    unmodelled load torque as a function of the reference position (N·m)."""
    cycle = axis.control.position_cycle
    t = np.arange(round(seconds / cycle)) * cycle
    x = 0.1 + 0.06 * np.sin(2 * np.pi * t / 2.3) + 0.01 * np.sin(2 * np.pi * t / 0.37 + seed)
    dist = np.zeros(len(x)) if load_nm is None else -load_nm(x)
    refs = References.from_position(x, cycle, dist)
    sim = simulate(axis, refs, None, KernelOptions(substeps=2 * default_substeps(axis)))
    rng = np.random.default_rng(seed)
    cols = {c: sim[c][::2] for c in ("time", "position_reference", "motor_position")}
    n = len(cols["time"])
    cols["load_position"] = sim["load_position"][::2] + 5e-7 * rng.standard_normal(n)
    cols["motor_speed"] = sim["motor_speed"][::2] + 0.05 * rng.standard_normal(n)
    cols["motor_torque"] = sim["motor_torque"][::2] + 0.005 * rng.standard_normal(n)
    return Trace(cols)


@pytest.mark.slow
def test_rigid_nominal_with_zero_backlash_never_aborts() -> None:
    """A compliant truth, a rigid nominal with backlash = 0 present: compliance is named
    from the deflection between the two measuring systems, at the truth's stiffness, and
    every model built is a valid axis file whose numbers the explanation prints."""
    truth = slide_axis().with_values(
        {"mechanics.antiresonance": 800.0, "mechanics.damping_ratio": 0.05}
    )
    nominal = slide_axis().with_values({"mechanics.backlash": 0.0})
    rec = _recording(truth, 8.0, 1)
    d = diagnose(rec, nominal, options=DiagnosisOptions(effects=(Effect.COMPLIANCE,)))
    assert d.left_out == [Effect.COMPLIANCE]
    assert d.fitted.mechanics.antiresonance == pytest.approx(800.0, rel=0.1)
    text = dump_axis(d.fitted)
    assert axis_from_mapping(tomllib.loads(text)) == d.fitted
    wa = d.fitted.mechanics.antiresonance
    assert f"antiresonance = {wa!r}" in text
    assert f"mechanics.antiresonance = {wa!r} rad/s" in d.explanation


@pytest.mark.slow
def test_a_data_sheet_that_is_wrong_is_said_to_be_and_fitted_around_the_evidence() -> None:
    """The nominal's mass is 40 % high (its uncertainty is 15 %): the evidence's estimate
    lies beyond the box by many standard errors, the report says the data sheet is wrong,
    and the closed-loop fit takes the mass near the truth, outside the sheet's box. A mass
    only 8 % off stays within its box."""
    truth = slide_axis()
    rec = _recording(truth, 8.0, 2)
    wrong = truth.with_values({"mechanics.load_mass": 35.0})
    d = diagnose(rec, wrong, options=DiagnosisOptions(effects=()))
    verdict = next(x for x in d.datasheet if x.key == "mechanics.load_mass")
    assert verdict.datasheet_wrong
    assert verdict.evidence == pytest.approx(25.0, rel=0.05)
    assert d.fitted.mechanics.load_mass == pytest.approx(25.0, rel=0.05)
    assert "data sheet is wrong for mechanics.load_mass" in d.explanation
    near = truth.with_values({"mechanics.load_mass": 27.0})
    d2 = diagnose(rec, near, options=DiagnosisOptions(effects=()))
    box = uncertainty_box("mechanics.load_mass", near)
    assert box == pytest.approx((27.0 * (1 - UNCERTAINTY["mechanics.load_mass"]), 27.0 * 1.15))
    assert not any(x.datasheet_wrong for x in d2.datasheet)
    assert box[0] <= d2.fitted.mechanics.load_mass <= box[1]


@pytest.mark.slow
def test_physics_outside_the_table_is_unexplained_here_with_where() -> None:
    """A friction patch the table cannot state (0.15 N·m more in 0.11-0.13 m of travel):
    no effect of the table explains it; the report says the model class does not explain
    the recording and locates it in position, never that nothing is left out. (A patch of
    0.05 N·m is 8 σ of the noise in its range: below the local bar of 15 σ that clean axes
    of the FMU family need, docs/diagnosis.md, "Unexplained, here".)"""
    truth = slide_axis()

    def patch(x: np.ndarray) -> np.ndarray:
        return 0.15 * ((x > 0.11) & (x < 0.13))

    rec = _recording(truth, 10.0, 3, patch)
    d = diagnose(rec, truth)
    assert not d.adequacy.adequate
    assert "Unexplained, here" in d.explanation
    assert "nothing of the table is needed" not in d.explanation
    torque = next(w for w in d.unexplained if w.signal == "motor_torque")
    hit = [r for r in torque.position_ranges if r.low < 0.13 and r.high > 0.11]
    assert hit, torque.position_ranges


def test_adequacy_white_residual_is_explained_and_a_resonance_is_not() -> None:
    """Analytic residuals: white noise around a good fit is adequate; a 7 Hz oscillation 30
    times the noise is not, and its frequency is found."""
    dt = 0.002
    t = np.arange(0.0, 20.0, dt)
    x = 0.05 * np.sin(2 * np.pi * t / 4.0)
    kin = reference_kinematics(t, x, x)
    labels = classify(kin, 30.0)
    rng = np.random.default_rng(0)
    signal = 2.0 * np.sin(2 * np.pi * t / 4.0)
    noise = 0.01 * rng.standard_normal(len(t))

    def fits(r: np.ndarray) -> dict[str, SignalFit]:
        return {"motor_torque": SignalFit(0.0, fit_percent(signal, signal - r), "")}

    good = assess({"motor_torque": noise}, kin, labels, [], fits(noise))
    assert good.adequate
    assert good.noise_ratio["motor_torque"] == pytest.approx(1.0, rel=0.1)
    resonance = noise + 0.3 * math.sqrt(2.0) * np.sin(2 * np.pi * 7.0 * t)
    bad = assess({"motor_torque": resonance}, kin, labels, [], fits(resonance))
    assert not bad.adequate
    assert bad.noise_ratio["motor_torque"] > NOISE_RATIO_MAX
    assert bad.frequency_hz["motor_torque"] == pytest.approx(7.0, abs=0.3)
    said = [float(m) for h in bad.hints for m in re.findall(r"([\d.]+) Hz", h)]
    assert any(abs(f - 7.0) < 0.3 for f in said), bad.hints

"""Candidate effects: names and keys, starting values from the data (effects.py)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from plant_sim.diagnosis.effects import (
    EFFECT_KEYS,
    GENERIC_EXPERIMENT,
    MODELS,
    Effect,
    effects_in,
    experiment_for,
)
from plant_sim.diagnosis.evidence import (
    DataScales,
    Evidence,
    data_scales,
    inverse_dynamics,
    periodic_peaks,
)
from plant_sim.diagnosis.parameters import contact_antiresonance
from plant_sim.diagnosis.replay import prepare_replay, replay
from plant_sim.diagnosis.synthetic import slide_axis
from plant_sim.physics.model import KernelOptions, default_substeps
from plant_sim.physics.simulate import References, simulate
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace
from virtual_bus.shipped import SHARED_DIR

SPEC = SHARED_DIR / "spec" / "axis-file.md"


def rigid_axis() -> AxisConfig:
    return slide_axis()


@pytest.mark.skipif(not SPEC.exists(), reason="shared spec not present")
def test_effect_names_and_keys_are_the_specs_table() -> None:
    """Second source: the table of axis-file.md, parsed."""
    text = SPEC.read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \| (.+?) \|$", text, flags=re.MULTILINE)
    table: dict[str, list[str]] = {}
    for name, keys in rows:
        parts = [k.strip() for k in keys.split(",")]
        section = parts[0].split(".")[0]
        table[name] = [k if "." in k and not k.startswith(".") else f"{section}{k}" for k in parts]
    # the spec's table, plus the effects this project added (docs/diagnosis.md)
    assert set(table) | {"sensor_time_offset"} == {e.value for e in Effect}
    for name, keys in table.items():
        assert list(EFFECT_KEYS[Effect(name)]) == keys, name
    assert EFFECT_KEYS[Effect.SENSOR_TIME_OFFSET] == ("control.sensor_time_offset",)


def test_effects_in_reads_present_keys() -> None:
    axis = rigid_axis()
    assert effects_in(axis) == {Effect.COULOMB_FRICTION, Effect.VISCOUS_FRICTION}
    more = axis.with_values({"control.torque_limit": 3.0, "disturbance.constant_torque": 0.0})
    assert Effect.TORQUE_SATURATION in effects_in(more)
    assert Effect.CONSTANT_LOAD_TORQUE in effects_in(more)  # present with value 0: in the model


#: Pairs the diagnosis can confuse, with what an experiment that separates them must vary
#: (from the physics of each pair, not from effects.py's text).
SEPARATING = {
    (Effect.COULOMB_FRICTION, Effect.VISCOUS_FRICTION): "speed",
    (Effect.COULOMB_FRICTION, Effect.STRIBECK_FRICTION): "speed",
    (Effect.CONSTANT_LOAD_TORQUE, Effect.ASYMMETRIC_FRICTION): "payload",
    (Effect.BACKLASH, Effect.COMPLIANCE): "reversal",
    (Effect.TIME_DELAY, Effect.COMPLIANCE): "frequency",
    (Effect.TIME_DELAY, Effect.TORQUE_SATURATION): "large",
    (Effect.PERIODIC_DISTURBANCE, Effect.CONSTANT_LOAD_TORQUE): "position",
}


@pytest.mark.parametrize(("pair", "word"), SEPARATING.items(), ids=lambda v: str(v))
def test_confusable_pairs_get_an_experiment_that_separates_them(
    pair: tuple[Effect, Effect], word: str
) -> None:
    """Not the generic advice: an experiment that varies what tells the two apart, the same
    whichever effect is named first."""
    a, b = pair
    text = experiment_for(a, b)
    assert text == experiment_for(b, a)
    assert text != GENERIC_EXPERIMENT
    assert word in text, text


def _recording(axis: AxisConfig, seconds: float = 8.0) -> Trace:
    cycle = axis.control.position_cycle
    t = np.arange(round(seconds / cycle)) * cycle
    x = 0.1 + 0.08 * np.sin(2 * np.pi * t / 2.0) + 0.02 * np.sin(2 * np.pi * t / 0.45)
    opts = KernelOptions(substeps=default_substeps(axis))
    sim = simulate(axis, References.from_position(x, cycle), options=opts)
    cols = (
        "time",
        "position_reference",
        "motor_position",
        "load_position",
        "motor_speed",
        "motor_torque",
    )
    return Trace({c: sim[c][::2] for c in cols})


def test_inverse_dynamics_starting_values() -> None:
    """A recording whose torque is the rigid-body balance τ = J·k_r·a + c·sign(v) + b·v + τ0
    exactly: the regression returns J (as the load mass), c, b and τ0."""
    axis = rigid_axis()
    kr = axis.transmission_ratio
    t = np.arange(0.0, 8.0, 0.002)
    w1, w2 = 2 * np.pi / 2.0, 2 * np.pi / 0.45
    x = 0.1 + 0.08 * np.sin(w1 * t) + 0.02 * np.sin(w2 * t)
    v = 0.08 * w1 * np.cos(w1 * t) + 0.02 * w2 * np.cos(w2 * t)
    a = -0.08 * w1**2 * np.sin(w1 * t) - 0.02 * w2**2 * np.sin(w2 * t)
    tau = axis.total_inertia * kr * a + 0.08 * np.sign(v) + 0.4 * v + 0.01
    rec = Trace({"time": t, "position_reference": x, "motor_position": kr * x, "motor_torque": tau})
    inp = prepare_replay(rec, axis)
    est = inverse_dynamics(inp, axis, data_scales(inp))
    assert est["mechanics.load_mass"] == pytest.approx(25.0, rel=0.02)
    assert est["friction.coulomb"] == pytest.approx(0.08, rel=0.02)
    assert est["friction.viscous"] == pytest.approx(0.4, rel=0.02)
    assert est["disturbance.constant_torque"] == pytest.approx(0.01, abs=1e-3)


def test_periodic_peaks_find_period_amplitude_phase() -> None:
    rng = np.random.default_rng(1)
    n = 20_000
    t = np.arange(n) * 0.002
    x = 0.15 + 0.1 * np.sin(2 * np.pi * t / 7.0)
    v = np.gradient(x, t)
    amp, period, phase = 0.02, 0.011, 0.9
    r = amp * np.sin(2 * np.pi * x / period + phase) + 0.02 * rng.standard_normal(n)
    scales = DataScales(
        1.0, 1.0, float(np.max(np.abs(v))), float(np.ptp(x)), 0.01, 0.002, v, np.gradient(v, t), x
    )
    (p, a, b), *_ = periodic_peaks(r, scales)
    assert p == pytest.approx(period, rel=0.01)
    assert math.hypot(a, b) == pytest.approx(amp, rel=0.1)
    assert math.atan2(b, a) == pytest.approx(phase, abs=0.15)


def test_backlash_on_a_rigid_model_adds_a_stiff_contact() -> None:
    axis = rigid_axis()
    inp = prepare_replay(_recording(axis), axis)
    ev = Evidence(inp, replay(axis, inp), data_scales(inp))
    cand = MODELS[Effect.BACKLASH].candidate(axis, axis, ev, 4)
    specs, notes = cand.specs, cand.notes
    base = specs[0].base
    assert base.mechanics.antiresonance == pytest.approx(contact_antiresonance(axis))
    # the contact is much stiffer than the speed loop is fast, and integrable (<= 3 substeps)
    assert contact_antiresonance(axis) > 5 * axis.control.ksp / axis.total_inertia
    assert specs[0].options.substeps <= 3
    assert any("antiresonance" in n for n in notes)
    assert [p.key for p in specs[0].parameters] == ["mechanics.backlash"]

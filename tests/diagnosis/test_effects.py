"""Candidate effects: names and keys, starting values from the data, the registry
(effects.py)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from diagnosis.effects import (
    EFFECT_KEYS,
    GENERIC_EXPERIMENT,
    MODELS,
    Effect,
    effects_in,
    experiment_for,
)
from diagnosis.matrix import SHORT
from diagnosis.parameters import contact_antiresonance, options_for
from diagnosis.screen import effect_values
from diagnosis.synthetic import slide_axis
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.shipped import SHARED_DIR

SPEC = SHARED_DIR / "spec" / "axis-file.md"
#: The project's own axis-file document (its table adds the effects of the kernel's keys).
OWN_SPEC = Path(__file__).resolve().parents[2] / "docs" / "axis-file.md"
#: Effects this project added to the shared spec's table.
ADDED = {"sensor_time_offset", "setpoint_delay", "measurement_delay", "scale_error"}


def rigid_axis() -> AxisConfig:
    return slide_axis()


def _table(path: Path) -> dict[str, list[str]]:
    text = path.read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \| (.+?) \|$", text, flags=re.MULTILINE)
    table: dict[str, list[str]] = {}
    for name, keys in rows:
        parts = [k.strip() for k in keys.split(",")]
        section = parts[0].split(".")[0]
        table[name] = [k if "." in k and not k.startswith(".") else f"{section}{k}" for k in parts]
    return table


@pytest.mark.skipif(not SPEC.exists(), reason="shared spec not present")
def test_effect_names_and_keys_are_the_specs_table() -> None:
    """Second source: the table of the shared spec's axis-file.md, parsed, plus the effects
    the project added (the table of its own docs/axis-file.md)."""
    table = _table(SPEC)
    own = _table(OWN_SPEC)
    assert set(table) | ADDED == {e.value for e in Effect}
    for name, keys in table.items():
        assert list(EFFECT_KEYS[Effect(name)]) == keys, name
    for name in ADDED - {"sensor_time_offset"}:
        assert list(EFFECT_KEYS[Effect(name)]) == own[name], name
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


def test_backlash_on_a_rigid_model_adds_a_stiff_contact() -> None:
    """Free play needs a contact stiffness; on a rigid model the evidence stage adds a stiff
    one (ten times the speed loop's bandwidth, integrable in 3 substeps), and none on a
    lumped model (no motor-side inertia to be elastic against)."""
    axis = rigid_axis()
    values, why = effect_values(Effect.BACKLASH, {"mechanics.backlash": 8e-6}, axis)
    assert not why
    assert values["mechanics.antiresonance"] == pytest.approx(contact_antiresonance(axis))
    assert contact_antiresonance(axis) > 5 * axis.control.ksp / axis.total_inertia
    assert options_for(contact_antiresonance(axis), axis).substeps <= 3
    lumped = axis.with_values({"mechanics.motor_inertia": 0.0, "mechanics.screw_inertia": 0.0})
    values, why = effect_values(Effect.BACKLASH, {"mechanics.backlash": 8e-6}, lumped)
    assert values == {} and "motor-side inertia" in why


def test_an_unphysical_estimate_adds_nothing() -> None:
    axis = rigid_axis().with_values({"friction.coulomb": None})
    for effect, est in (
        (Effect.COULOMB_FRICTION, {"friction.coulomb": -0.01}),
        (Effect.STRIBECK_FRICTION, {"friction.stribeck": -0.01, "friction.stribeck_speed": 0.01}),
        (Effect.SENSOR_TIME_OFFSET, {"control.sensor_time_offset": 0.2}),
    ):
        values, why = effect_values(effect, est, axis)
        assert values == {} and why, effect


def test_the_registry_holds_every_effect_once_with_its_own_column() -> None:
    """Every member of Effect has one model in the registry, whose confusion-matrix column
    (matrix.SHORT) is its own: two effects with one column could not be told apart there."""
    assert set(MODELS) == set(Effect)
    assert all(m.effect is e for e, m in MODELS.items())
    shorts = [m.short for m in MODELS.values()]
    assert len(set(shorts)) == len(shorts) and "none" not in shorts
    assert {e.value: SHORT[e.value] for e in Effect} == {
        e.value: m.short for e, m in MODELS.items()
    }


def test_a_cost_change_is_said_the_right_way_round() -> None:
    """The held-out gate's words: lower where the effect's model predicts better, higher
    (by a factor where it is large) where it predicts worse -- never a negative 'lower'."""
    from diagnosis.summary import change_text

    assert change_text(1.0 - 3.25 / 3.61) == "10.0 % lower"
    assert change_text(1.0 - 3.81 / 3.61) == "5.5 % higher"
    assert change_text(1.0 - 0.0154 / 0.000148) == "104× higher"

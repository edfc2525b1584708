"""The diagnosis on recordings of the independent plant (reference_plants/independent: another
integrator, smooth friction, its own contact law, PI current loop, quantised sensors,
coloured noise) — written apart from the kernel the diagnosis simulates with: effects the
issue's user saw explained away by a re-fit (a dead time, a position-periodic torque, a
constant load force) are named by the evidence at their hidden values; a recording with
nothing left out names nothing. The cases are development data (matrix seed 3)."""

from __future__ import annotations

import tomllib

import pytest

from diagnosis.effects import Effect
from diagnosis.engine import diagnose
from diagnosis.report import axis_text
from diagnosis.synthetic import Case
from diagnosis.testsets.independent import generate
from reference_plants.independent import PlantOptions
from virtual_bus.formats.axis import AxisConfig, axis_from_mapping


def load_axis_text(text: str) -> AxisConfig:
    return axis_from_mapping(tomllib.loads(text))


#: (case, key checked, relative tolerance of the estimate)
CASES = [
    (Case("mill-time_delay", "mill", Effect.TIME_DELAY, 3009, 25.0), "control.delay", 0.35),
    (
        Case("slide-periodic_disturbance", "slide", Effect.PERIODIC_DISTURBANCE, 3020, 25.0),
        "disturbance.periodic_period",
        0.02,
    ),
    (
        Case("mill-constant_load_torque", "mill", Effect.CONSTANT_LOAD_TORQUE, 3006, 25.0),
        "disturbance.constant_torque",
        0.2,
    ),
    (
        Case("slide-compliance", "slide", Effect.COMPLIANCE, 3014, 25.0),
        "mechanics.antiresonance",
        0.1,
    ),
]


@pytest.mark.slow
@pytest.mark.parametrize(("case", "key", "rel"), CASES, ids=[c.name for c, _, _ in CASES])
def test_concealed_effect_named_on_the_independent_plant(case: Case, key: str, rel: float) -> None:
    gen = generate(case)
    d = diagnose(gen.recording, gen.nominal)
    assert d.left_out[:1] == [case.effect]
    assert d.fitted.value(key) == pytest.approx(gen.truth.value(key), rel=rel)
    assert d.fit_after["motor_torque"].fit_percent > d.fit_before["motor_torque"].fit_percent
    # written back as an axis file that reads back the same
    assert load_axis_text(axis_text(d)) == d.fitted


@pytest.mark.slow
def test_nothing_left_out_names_nothing_and_keeps_the_drives_speed_filter() -> None:
    case = Case("slide-none-1", "slide", None, 3024, 25.0)
    gen = generate(case)
    assert gen.nominal.control.speed_filter == PlantOptions().speed_filter_s
    d = diagnose(gen.recording, gen.nominal)
    assert d.left_out == []
    assert d.fitted.control.speed_filter == gen.nominal.control.speed_filter

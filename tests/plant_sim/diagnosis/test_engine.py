"""The whole diagnosis on a small, fast subset of the concealed test set.

The full confusion matrix (every effect, two families, recordings with nothing left out) is
long and runs in ``python -m plant_sim.diagnosis.matrix`` / ``bench_diagnose``; here a few
12 s recordings check that the engine names a concealed effect, names nothing when nothing
is left out, and that the fit on held-out data improves when it names something.
"""

from __future__ import annotations

import pytest

from plant_sim.diagnosis.effects import Effect
from plant_sim.diagnosis.engine import DiagnosisOptions, diagnose
from plant_sim.diagnosis.errors import DiagnosisOptionError
from plant_sim.diagnosis.synthetic import Case, generate

DURATION_S = 12.0

SUBSET = [
    Case("slide-none", "slide", None, 1022, DURATION_S),
    Case("slide-constant_load_torque", "slide", Effect.CONSTANT_LOAD_TORQUE, 1016, DURATION_S),
    Case("mill-backlash", "mill", Effect.BACKLASH, 1000, DURATION_S),
    Case("slide-time_delay", "slide", Effect.TIME_DELAY, 1021, DURATION_S),
]


@pytest.mark.slow
@pytest.mark.parametrize("case", SUBSET, ids=[c.name for c in SUBSET])
def test_concealed_effect_is_named(case: Case) -> None:
    gen = generate(case)
    d = diagnose(gen.recording, gen.nominal)
    expected = [] if case.effect is None else [case.effect]
    assert d.left_out == expected
    if case.effect is None:
        assert d.fitted == d.refit  # nothing added: the re-fitted nominal is the answer
        return
    # the named effect's keys are in the fitted axis; the held-out cost fell significantly
    named = next(c for c in d.candidates if c.accepted)
    assert named.effect is case.effect and named.p_value < 1e-3
    assert d.heldout_final.cost < d.heldout_refit.cost
    # and the simulation of the whole recording fits the torque better than the nominal did
    assert d.fit_after["motor_torque"].fit_percent > d.fit_before["motor_torque"].fit_percent


def test_options_are_validated() -> None:
    with pytest.raises(DiagnosisOptionError, match="alpha = 2"):
        DiagnosisOptions(alpha=2.0)
    with pytest.raises(DiagnosisOptionError, match="jobs = 0"):
        DiagnosisOptions(jobs=0)

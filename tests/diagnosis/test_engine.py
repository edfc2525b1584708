"""The whole diagnosis on a small, fast subset of the concealed test set.

The full confusion matrix (every effect, two families, recordings with nothing left out) is
long and runs in ``python -m diagnosis matrix``; here a few 12 s recordings check that the
evidence names a concealed effect at its hidden value, names nothing when nothing is left
out, and that the closed-loop fit with it improves the held-out data.
"""

from __future__ import annotations

import pytest

from diagnosis.effects import MODELS, Effect
from diagnosis.engine import DiagnosisOptions, diagnose
from diagnosis.errors import DiagnosisOptionError
from diagnosis.synthetic import Case, generate

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
        assert d.fitted == d.refit  # nothing added: the nominal fitted within its data sheet
        assert all(not v.significant for v in d.evidence.verdicts)
        return
    # the evidence named it at the false-alarm level it states, its estimate near the truth
    named = next(v for v in d.evidence.verdicts if v.named)
    assert named.effect is case.effect and named.p < d.evidence.alpha_each
    for key in MODELS[case.effect].keys:
        want = gen.truth.value(key)
        if want and key != "disturbance.periodic_phase":
            assert d.fitted.value(key) == pytest.approx(want, rel=0.35), key
    assert d.heldout_final.cost < d.heldout_refit.cost
    assert d.fit_after["motor_torque"].fit_percent > d.fit_before["motor_torque"].fit_percent


def test_options_are_validated() -> None:
    with pytest.raises(DiagnosisOptionError, match="alpha = 2"):
        DiagnosisOptions(alpha=2.0)
    with pytest.raises(DiagnosisOptionError, match="jobs = 0"):
        DiagnosisOptions(jobs=0)

"""The explanation paragraph of a diagnosis (what an engineer can act on)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from .effects import DESCRIPTION, EFFECT_KEYS, Effect
from .mismatch import ResidualTests
from .results import Diagnosis


def _correlations(tests: Sequence[ResidualTests]) -> str:
    """'speed_sign (motor_torque, motor_position), acceleration (motor_speed)'."""
    found: dict[str, list[str]] = {}
    for t in tests:
        for name, cc in t.cross_correlation.items():
            if cc.significant:
                found.setdefault(name, []).append(t.signal)
    return ", ".join(f"{k.replace('_', ' ')} ({', '.join(v)})" for k, v in found.items())


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def explain(d: Diagnosis) -> str:
    """A paragraph an engineer can act on."""
    parts: list[str] = []
    changed = []
    for key, (nom, new) in d.refit_values.items():
        if math.isfinite(nom) and nom != 0.0:
            changed.append(f"{key} {_fmt(nom)} -> {_fmt(new)} ({100.0 * (new / nom - 1.0):+.1f} %)")
    if changed:
        parts.append(
            "Re-fitting the nominal parameters by simulation error gave " + "; ".join(changed) + "."
        )
    sig_fit = ", ".join(
        f"{s} {d.fit_before[s].fit_percent:.1f} % -> {d.fit_after[s].fit_percent:.1f} %"
        for s in d.fit_after
    )
    if d.left_out:
        names = []
        for e in d.left_out:
            c = next(c for c in d.candidates if c.effect is e and c.accepted)
            keys = [k for k in c.parameters if any(k.startswith(p) for p in _effect_prefixes(e))]
            vals = ", ".join(f"{k} = {_fmt(c.parameters[k])}" for k in keys)
            names.append(
                f"{e.value} ({DESCRIPTION[e]}; {vals}; held-out cost "
                f"-{c.improvement_percent:.1f} %, p = {c.p_value:.2g})"
            )
        parts.append("The model leaves out " + "; then ".join(names) + ".")
        if d.mismatch_by_condition:
            where = ", ".join(
                f"{k} ({v:.2g} s)" for k, v in list(d.mismatch_by_condition.items())[:3]
            )
            parts.append(
                f"The re-fitted nominal simulation departed from the recording beyond noise "
                f"mostly at: {where} (seconds summed over signals)."
            )
        corr = _correlations(d.tests_refit)
        if corr:
            parts.append(f"Its residual correlated with: {corr}.")
        parts.append(f"Simulation fit before -> after: {sig_fit}.")
        parts.append(
            "Add these keys to the axis file (axis_fitted.toml has them) and check the fitted "
            "model on a second recording with `python -m plant_sim simulate --like`."
        )
    else:
        parts.append(
            "No effect of the axis-file table improves the held-out simulation significantly: "
            "nothing is left out that this recording can show; the differences are explained "
            "by the re-fitted parameters and noise."
        )
        parts.append(f"Simulation fit before -> after re-fit: {sig_fit}.")
        nonwhite = [t.signal for t in d.tests_final if not t.white]
        if nonwhite:
            parts.append(
                "The residual of " + ", ".join(nonwhite) + " is still coloured (Ljung-Box): "
                "an unmodelled disturbance or dynamics outside the table, or an excitation too "
                "poor to show an effect; a recording with reversals, several speeds and "
                "standstill would test more."
            )
    for a in d.ambiguous:
        parts.append(
            f"{a.alternative.value} explains the data about as well as {a.named.value} "
            f"(held-out cost ratio {a.cost_ratio:.3f}, p = {a.p_value:.2g}); "
            f"{a.named.value} was named: it needs fewer parameters and the held-out test "
            f"does not show the other better. To tell them apart: {a.experiment}."
        )
    parts += d.notes
    return " ".join(parts)


def _effect_prefixes(e: Effect) -> tuple[str, ...]:
    return EFFECT_KEYS[e]

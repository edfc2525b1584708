"""The explanation paragraph of a diagnosis (what an engineer can act on).

Numbers are the ones written to axis_fitted.toml (rounded there, printed with ``repr``),
with the axis's units (:func:`.parameters.key_unit`). When the best model still leaves a
residual far above the noise, or fits poorly, the paragraph says that the model class cannot
explain the recording, where the unexplained part is and what it points to
(:mod:`.adequacy`) — never that the differences are noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .adequacy import inadequate
from .effects import MODELS
from .mismatch import ResidualTests
from .parameters import MODEL_FORM_KEYS, format_value, rounded
from .results import Diagnosis

#: Held-out gain (per cent) of a candidate that was not named but is worth a sentence.
NEAR_MISS_PERCENT = 5.0


def _correlations(tests: Sequence[ResidualTests]) -> str:
    """'speed_sign (motor_torque, motor_position), acceleration (motor_speed)'."""
    found: dict[str, list[str]] = {}
    for t in tests:
        for name, cc in t.cross_correlation.items():
            if cc.significant:
                found.setdefault(name, []).append(t.signal)
    return ", ".join(f"{k.replace('_', ' ')} ({', '.join(v)})" for k, v in found.items())


def _changes(d: Diagnosis) -> str:
    out = []
    for key, (nom, new) in d.fitted_values.items():
        if key in MODEL_FORM_KEYS and not math.isfinite(nom):
            # the friction law's form: absent in the nominal (set-valued), kept on held-out data
            out.append(f"{key} (absent: set-valued) -> {format_value(key, new, d.fitted)}")
            continue
        if not math.isfinite(nom) or nom == new:
            continue
        old = format_value(key, rounded(nom), d.nominal)
        text = f"{key} {old} -> {format_value(key, new, d.fitted)}"
        if nom != 0.0:
            text += f" ({100.0 * (new / nom - 1.0):+.1f} %)"
        out.append(text)
    return "; ".join(out)


def _suspects(d: Diagnosis) -> str:
    items = []
    for s in d.suspects:
        why = f"on its {s.on_bound} bound" if s.on_bound else ""
        if s.nominal:
            unc = 100 * s.uncertainty
            moved = f"moved {s.change_percent:+.0f} % (data-sheet uncertainty {unc:.0f} %)"
            why = f"{why}, {moved}" if why else moved
        items.append(f"{s.key} ({why})")
    return "; ".join(items)


def _adequacy(d: Diagnosis) -> list[str]:
    a = d.adequacy
    bad = [
        f"{s} (fit {a.fit_percent[s]:.1f} %, residual {a.noise_ratio[s]:.3g} x the noise)"
        for s in a.noise_ratio
        if inadequate(s, a.fit_percent.get(s, 100.0), a.noise_ratio[s])
    ]
    parts = [
        "The model class does not explain this recording: the best model still leaves "
        + ", ".join(bad)
        + "; the difference is not noise."
    ]
    where = [f"{k} ({v:.2g} x its share of time)" for k, v in a.by_condition.items() if v > 1.2]
    if where:
        parts.append("The unexplained part concentrates at: " + ", ".join(where[:3]) + ".")
    freq = ", ".join(f"{s} {f:.3g} Hz" for s, f in a.frequency_hz.items())
    parts.append(f"Dominant residual frequency: {freq}.")
    corr = _correlations(d.tests_final)
    if corr:
        parts.append(f"The residual correlates with: {corr}.")
    if a.hints:
        parts.append(
            "That points to physics outside the axis-file table: " + "; ".join(a.hints) + "."
        )
    return parts


def explain(d: Diagnosis) -> str:
    """A paragraph an engineer can act on."""
    parts: list[str] = [f"Re-fit of the nominal parameters: {d.refit_decision}."]
    if d.suspects:
        parts.append(
            "Signs of missing physics (a re-fitted parameter on a bound of its range or moved "
            "beyond its data-sheet uncertainty): " + _suspects(d) + "."
        )
    changes = _changes(d)
    if changes:
        parts.append(f"axis_fitted.toml (nominal -> fitted): {changes}.")
    sig_fit = ", ".join(
        f"{s} {d.fit_before[s].fit_percent:.1f} % -> {d.fit_after[s].fit_percent:.1f} %"
        for s in d.fit_after
    )
    if d.left_out:
        names = []
        for e in d.left_out:
            c = next(c for c in d.candidates if c.effect is e and c.accepted)
            names.append(
                f"{e.value} ({MODELS[e].description}; {MODELS[e].describe(d.fitted)}; "
                f"held-out cost -{c.improvement_percent:.1f} %, p = {c.p_value:.2g})"
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
    else:
        parts.append(
            "No effect of the axis-file table improves the held-out simulation significantly."
        )
        parts.append(f"Simulation fit before -> after: {sig_fit}.")
    if not d.adequacy.adequate:
        parts += _adequacy(d)
    elif not d.left_out:
        ratios = ", ".join(f"{s} {r:.3g}" for s, r in d.adequacy.noise_ratio.items())
        near_misses = [
            c for c in d.candidates if not c.accepted and c.improvement_percent >= NEAR_MISS_PERCENT
        ]
        if d.suspects or near_misses:
            parts.append(
                f"The best model's residual over the white-noise level: {ratios} (speed and "
                "torque below 10, every fit at least 50 %); but the suspect parameters and the "
                "unnamed candidates in this report say the re-fit may have absorbed an "
                "effect: this recording does not show that nothing is left out."
            )
        else:
            parts.append(
                f"The best model's residual over the white-noise level: {ratios} (speed and "
                "torque below 10, every fit at least 50 %): no effect of the table is needed "
                "to explain this recording."
            )
    if d.left_out:
        parts.append(
            "Check the fitted model on a second recording with `python -m plant_sim simulate "
            "--like` (or `diagnose --validate`)."
        )
    near = [
        f"{c.effect.value} (round {c.round}: held-out cost -{c.improvement_percent:.1f} %, "
        f"p = {c.p_value:.2g}, without the best block p = {c.p_without_best_block:.2g})"
        for c in d.candidates
        if not c.accepted and c.improvement_percent >= NEAR_MISS_PERCENT
    ]
    if near:
        parts.append(
            "Not named, but they improved the held-out data without passing the test (a few "
            "events, or too little excitation; a second recording with more of them, "
            "`--validate`, decides): " + "; ".join(near) + "."
        )
    overfit = [
        f"{c.effect.value} (round {c.round}: fitting data {c.training_improvement_percent:+.1f} %, "
        f"held-out {c.improvement_percent:+.1f} %)"
        for c in d.candidates
        if c.training_improvement_percent >= 100.0 * d.options.min_improvement
        and c.improvement_percent < 0.0
    ]
    if overfit:
        parts.append(
            "Rejected because they fit the fitting data better and the held-out data worse: "
            + "; ".join(overfit)
            + "."
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

"""The explanation paragraph of a diagnosis (what an engineer can act on).

Numbers are the ones written to axis_fitted.toml (rounded there, printed with ``repr``),
with the axis's units (:func:`.parameters.key_unit`). When the fitted model still leaves a
residual far above the noise, the paragraph says that the model class does not explain the
recording and where — time windows, speed and position ranges, frequency band
(:mod:`.unexplained`) — never that nothing was left out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .adequacy import inadequate
from .effects import MODELS, Effect
from .mismatch import ResidualTests
from .outcome import Diagnosis
from .parameters import MODEL_FORM_KEYS, format_value, rounded
from .unexplained import Where


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


def _where(items: Sequence[Where], unit_pos: str) -> list[str]:
    parts = []
    for w in items:
        bits = []
        if w.windows:
            spans = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in w.windows[:4])
            bits.append(f"in {spans}")
        if w.speed_ranges:
            spans = ", ".join(
                f"{r.low:.3g}..{r.high:.3g} {unit_pos}/s ({r.rms_over_noise:.2g} x noise)"
                for r in sorted(w.speed_ranges, key=lambda r: -r.rms_over_noise)[:3]
            )
            bits.append(f"at speeds {spans}")
        if w.position_ranges:
            spans = ", ".join(
                f"{r.low:.4g}..{r.high:.4g} {unit_pos}"
                for r in sorted(w.position_ranges, key=lambda r: -r.rms_over_noise)[:3]
            )
            bits.append(f"at positions {spans}")
        if w.band_hz is not None:
            bits.append(f"in the band {w.band_hz[0]:.3g}-{w.band_hz[1]:.3g} Hz")
        if bits:
            parts.append(f"{w.signal} ({w.noise_ratio:.3g} x the noise): " + "; ".join(bits))
    return parts


def _adequacy(d: Diagnosis) -> list[str]:
    a = d.adequacy
    bad = [
        f"{s} (fit {a.fit_percent[s]:.1f} %, residual {a.noise_ratio[s]:.3g} x the noise)"
        for s in a.noise_ratio
        if inadequate(s, a.fit_percent.get(s, 100.0), a.noise_ratio[s])
    ]
    parts = [
        "Unexplained, here: the model class does not explain this recording — the fitted model "
        "still leaves " + ", ".join(bad) + "; the difference is not noise."
    ]
    where = _where(d.unexplained, d.nominal.load_unit)
    if where:
        parts.append("Where: " + "; ".join(where) + ".")
    conds = [f"{k} ({v:.2g} x its share of time)" for k, v in a.by_condition.items() if v > 1.2]
    if conds:
        parts.append("It concentrates at: " + ", ".join(conds[:3]) + ".")
    corr = _correlations(d.tests_final)
    if corr:
        parts.append(f"The residual correlates with: {corr}.")
    if a.hints:
        parts.append(
            "That points to physics outside the axis-file table: " + "; ".join(a.hints) + "."
        )
    return parts


def _evidence(d: Diagnosis) -> list[str]:
    ev = d.evidence
    parts = [
        f"Evidence (false-alarm rate {ev.alpha:g} per recording: each of the effects tested at "
        f"p < {ev.alpha_each:.2g}):"
    ]
    named = []
    for e in d.left_out:
        v = next((v for v in ev.verdicts if v.effect is e and v.significant), None)
        how = f" ({v.relation}, z = {v.z:.3g}, p = {v.p:.2g})" if v is not None else ""
        named.append(f"{e.value} — {MODELS[e].description}{how}: {MODELS[e].describe(d.fitted)}")
    gated = [g for g in d.closed_loop.gate if not g.kept]
    if named:
        parts.append("the model leaves out " + "; then ".join(named) + ".")
    elif not gated:
        parts.append("no effect of the table shows in the measured signals.")
    if gated:
        parts.append(
            "Evidence without a model gain (significant in the measured signals, but the "
            "closed-loop model with it does not predict the held-out data better by at least "
            f"{100.0 * d.options.min_improvement:g} %; not named): "
            + ", ".join(
                f"{g.effect.value} (held-out cost {-100.0 * g.gain:+.2g} %, z = {g.z:.2g})"
                for g in gated
            )
            + "."
        )
    below = [
        f"{v.effect.value} ({v.note})"
        for v in ev.verdicts
        if v.note and v.p < ev.alpha_each and v.effect not in d.left_out
    ]
    if below:
        parts.append("Significant but not named: " + "; ".join(dict.fromkeys(below)) + ".")
    wrong = [x for x in d.datasheet if x.datasheet_wrong]
    if wrong:
        parts.append(
            "The evidence says the data sheet is wrong for "
            + ", ".join(
                f"{x.key} (data sheet {x.nominal:.6g}, box {x.box[0]:.4g}..{x.box[1]:.4g} "
                f"{x.unit}; evidence {x.evidence:.6g} ± {x.standard_error:.2g})"
                for x in wrong
                if x.box is not None and x.nominal is not None
            )
            + ": it is fitted around the evidence's value."
        )
    return parts


def explain(d: Diagnosis) -> str:
    """A paragraph an engineer can act on."""
    parts = _evidence(d)
    loop = d.closed_loop
    parts.append(
        "Closed loop: held-out cost of the nominal as given "
        f"{loop.nominal.heldout.cost:.4g}, within its data sheet {loop.base.heldout.cost:.4g}, "
        f"with the named effects {loop.final.heldout.cost:.4g}"
        + (
            f" ({loop.improvement_percent:+.1f} % against the data sheet's, p = {loop.p:.2g})."
            if d.left_out
            else "."
        )
    )
    changes = _changes(d)
    if changes:
        parts.append(f"axis_fitted.toml (nominal -> fitted): {changes}.")
    sig_fit = ", ".join(
        f"{s} {d.fit_before[s].fit_percent:.1f} % -> {d.fit_after[s].fit_percent:.1f} %"
        for s in d.fit_after
    )
    parts.append(f"Simulation fit before -> after: {sig_fit}.")
    if not d.adequacy.adequate:
        parts += _adequacy(d)
    elif not d.left_out:
        ratios = ", ".join(f"{s} {r:.3g}" for s, r in d.adequacy.noise_ratio.items())
        parts.append(
            f"The fitted model's residual over the white-noise level: {ratios} (speed and "
            "torque below 10, every fit at least 50 %): nothing of the table is needed to "
            "explain this recording."
        )
    if Effect.CONSTANT_LOAD_TORQUE in d.left_out and d.validation == "interleaved blocks":
        parts.append(
            "Within one recording a load that stays for the whole run (a process force, a "
            "cable chain) and a constant load torque are the same thing: confirm it with "
            "`diagnose --validate` on a recording made at another time, whose held-out gate "
            "drops a load that was only this run's."
        )
    elif d.left_out:
        parts.append(
            "Check the fitted model on a second recording with `python -m diagnosis simulate "
            "--like` (or `diagnose --validate`)."
        )
    for a in d.ambiguous:
        held = (
            f" (held-out cost ratio {a.cost_ratio:.3f}, p = {a.p_value:.2g})"
            if math.isfinite(a.cost_ratio)
            else ""
        )
        parts.append(
            f"{a.alternative.value} explains the same signature as {a.named.value}{held}; "
            f"{a.named.value} is named. To tell them apart: {a.experiment}."
        )
    # the held-out gate's notes are summed up above
    parts += [n for n in d.notes if not n.startswith("evidence without a model gain")]
    return " ".join(parts)

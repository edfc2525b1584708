"""What a diagnosis says, in an engineer's words: the headline, the evidence behind each of
its findings, where the fitted model still misses, the next experiment — shared by the text
summary on stdout (:func:`text_summary`) and the page (:mod:`.report_html`).

Everything is read off the :class:`~.outcome.Diagnosis` as it is, iterating over what it
holds (named effects, data-sheet verdicts, fits per signal, unexplained regions,
ambiguities), so an effect or a signal added to the diagnosis appears without an edit here.
An effect's words are its own (:mod:`.effects`): its name, its ``description``, its keys;
an effect model may also say its finding in one sentence by a method
``headline(fitted: AxisConfig, nominal: AxisConfig) -> str | None`` ("the set point arrives
2.1 ms late"), which is then used instead of the generic "X left out of the model: key = v".
Values are shown with engineer prefixes (:mod:`.quantity`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cmdline.quantity import factor, number, percent, quantities, quantity, ratio

from .adequacy import inadequate
from .closed_loop import GateStep
from .effects import MODELS, Effect
from .outcome import DatasheetVerdict, Diagnosis
from .parameters import key_unit, units
from .unexplained import Range, Where


@dataclass(frozen=True)
class Finding:
    """One line of the headline and the evidence behind it."""

    kind: str  # "left out", "data sheet", "no model gain", "unexplained", "explained"
    text: str
    evidence: str = ""


# ----------------------------------------------------------------------------------------
# words
# ----------------------------------------------------------------------------------------
def effect_name(effect: Effect) -> str:
    """'coulomb friction' (the effect's own name)."""
    return effect.value.replace("_", " ")


def sentence(text: str) -> str:
    return text[:1].upper() + text[1:] if text else text


def key_words(key: str) -> str:
    """Words for an axis-file key: the name of the effect it belongs to ('coulomb friction'
    for friction.coulomb; with the key's own words where the effect has several keys), else
    the key's own words ('load mass')."""
    leaf = key.rsplit(".", 1)[-1].replace("_", " ")
    for effect, model in MODELS.items():
        if key in model.keys:
            name = effect_name(effect)
            return name if len(model.keys) == 1 else f"{name} ({leaf})"
    return leaf


def signal_label(d: Diagnosis, signal: str) -> tuple[str, str]:
    """(quantity, unit) of what ``signal`` is scored on, in the axis's units."""
    u = units(d.nominal)
    motor_pos = "m" if d.nominal.transmission_ratio == 1.0 and u["position"] == "m" else "rad"
    force = "motor torque" if u["torque"] == "N·m" else "motor force"
    known = {
        "motor_position": ("motor following error", motor_pos),
        "load_position": ("load following error", u["position"]),
        "motor_speed": ("motor speed", f"{motor_pos}/s"),
        "motor_torque": (force, u["torque"]),
    }
    return known.get(signal, (signal.replace("_", " "), ""))


def compared(d: Diagnosis, signal: str, values: np.ndarray) -> np.ndarray:
    """What ``signal`` is scored on: the following error for positions, else the signal."""
    ref = d.recording["position_reference"]
    if signal == "motor_position":
        return d.nominal.transmission_ratio * ref - values
    if signal == "load_position":
        return ref - values
    return values


def change_text(gain: float) -> str:
    """A held-out gain (1 - cost with / cost without) in words: '12.3 % lower'; below zero
    '4.2 % higher' or, from twice the cost, '104× higher' (a negative 'lower' reads as
    nonsense)."""
    if gain >= 0.0:
        return f"{percent(100.0 * gain)} lower"
    ratio = 1.0 - gain
    return f"{percent(100.0 * (ratio - 1.0))} higher" if ratio < 2.0 else f"{number(ratio)}× higher"


def p_text(p: float) -> str:
    """'p = 0.0013', 'p < 1e-300' (a p that underflows)."""
    if not math.isfinite(p):
        return "p n/a"
    return "p < 1e-300" if p == 0.0 else f"p = {p:.2g}"


# ----------------------------------------------------------------------------------------
# findings
# ----------------------------------------------------------------------------------------
def _value_text(d: Diagnosis, key: str) -> str | None:
    new = d.fitted.value(key)
    if new is None:
        return None
    old = d.nominal.value(key)
    unit = key_unit(key, d.nominal)
    if old is None or float(old) == float(new):
        return f"{key} = {quantity(float(new), unit)}"
    r = ratio(float(new), float(old))
    how = f", {factor(r)}" if r is not None else ""
    shown_new = quantity(float(new), unit, like=float(old))
    shown_old = quantity(float(old), unit, like=float(new))
    return f"{key} = {shown_new} (data sheet {shown_old}{how})"


def _effect_evidence(d: Diagnosis, effect: Effect) -> str:
    ev = d.evidence
    parts = [MODELS[effect].description]
    v = next((v for v in ev.verdicts if v.effect is effect and v.named), None)
    v = v or next((v for v in ev.verdicts if v.effect is effect and v.significant), None)
    if v is not None:
        parts.append(f"{v.relation}: z = {number(v.z)}, {p_text(v.p)} (named at p < {v.alpha:.2g})")
    g = next((g for g in d.closed_loop.gate if g.effect is effect), None)
    if g is not None:
        parts.append(f"held-out cost {change_text(g.gain)} with it ({d.validation}, {p_text(g.p)})")
    return "; ".join(parts)


def left_out_finding(d: Diagnosis, effect: Effect) -> Finding:
    model = MODELS[effect]
    own = getattr(model, "headline", None)
    text = own(d.fitted, d.nominal) if callable(own) else None
    if not text:
        values = [t for k in model.keys if (t := _value_text(d, k)) is not None]
        text = f"{effect_name(effect)} left out of the model" + (
            ": " + ", ".join(values) if values else ""
        )
    return Finding("left out", sentence(text), _effect_evidence(d, effect))


def datasheet_finding(d: Diagnosis, x: DatasheetVerdict) -> Finding:
    new = x.fitted if x.fitted is not None else x.evidence
    old = x.nominal
    words = key_words(x.key)
    r = ratio(new, old)
    if r is not None and old is not None:
        text = (
            f"{words} is {factor(r)} the data sheet: {quantity(new, x.unit, like=old)} "
            f"instead of {quantity(old, x.unit, like=new)}"
        )
    else:
        text = f"{words} is {quantity(new, x.unit)}, the data sheet says {quantity(old, x.unit)}"
    evidence = f"{x.key}: evidence {quantity(x.evidence, x.unit)} ± " + quantity(
        x.standard_error, x.unit, like=x.evidence
    )
    if x.box is not None:
        evidence += f", outside the data sheet's uncertainty {quantities(list(x.box), x.unit)}"
        if x.standard_error > 0.0:
            dist = min(abs(x.evidence - x.box[0]), abs(x.evidence - x.box[1]))
            evidence += f" by {number(dist / x.standard_error, 2)} standard errors"
    return Finding("data sheet", sentence(text), evidence)


def no_gain_finding(d: Diagnosis, g: GateStep) -> Finding:
    """An effect the evidence named that the held-out gate dropped."""
    v = next((v for v in d.evidence.verdicts if v.effect is g.effect and v.named), None)
    shown = f" (z = {number(v.z)})" if v is not None else ""
    return Finding(
        "no model gain",
        sentence(
            f"{effect_name(g.effect)} shows in the measured signals{shown}, but its model "
            "does not predict the held-out data better: not named"
        ),
        f"held-out cost {number(g.cost_without)} without it, {number(g.cost_with)} with it "
        f"({change_text(g.gain)}, {p_text(g.p)}; at least "
        f"{percent(100.0 * d.options.min_improvement)} needed; {d.validation})",
    )


def range_text(r: Range, unit: str) -> str:
    return f"{quantities([r.low, r.high], unit)} ({number(r.rms_over_noise, 2)}× the noise)"


def where_parts(d: Diagnosis, w: Where, n: int = 2) -> list[str]:
    """'at speeds 0.42 … 42 mm/s (66× the noise)', 'at positions …', 'in 2.56–2.65 s, …',
    'in the band 1–100 Hz' (the strongest ``n`` of each)."""
    pos = d.nominal.load_unit
    out = []
    strongest = sorted(w.speed_ranges, key=lambda r: -r.rms_over_noise)[:n]
    if strongest:
        out.append("at speeds " + ", ".join(range_text(r, f"{pos}/s") for r in strongest))
    strongest = sorted(w.position_ranges, key=lambda r: -r.rms_over_noise)[:n]
    if strongest:
        out.append("at positions " + ", ".join(range_text(r, pos) for r in strongest))
    if w.windows:
        spans = ", ".join(f"{number(a)}–{number(b)} s" for a, b in w.windows[: 2 * n])
        more = f" (+{len(w.windows) - 2 * n} more)" if len(w.windows) > 2 * n else ""
        out.append(f"in {spans}{more}")
    if w.band_hz is not None:
        out.append(f"in the band {number(w.band_hz[0], 2)}–{number(w.band_hz[1], 3)} Hz")
    return out


def misfit_signals(d: Diagnosis) -> list[Where]:
    """The unexplained signals, the worst (residual over the noise) first; each judged by
    :func:`.adequacy.inadequate` when it says so, else listed as the diagnosis located it."""
    a = d.adequacy
    bad = [
        w
        for w in d.unexplained
        if inadequate(w.signal, a.fit_percent.get(w.signal, 100.0), w.noise_ratio)
    ]
    return sorted(bad or list(d.unexplained), key=lambda w: -w.noise_ratio)


def conditions_text(d: Diagnosis, n: int = 2) -> str:
    top = sorted(d.adequacy.by_condition.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{k} ({number(v, 2)}× its share of time)" for k, v in top[:n] if v > 1.2)


def unexplained_finding(d: Diagnosis) -> Finding:
    worst = misfit_signals(d)
    if not worst:
        return Finding(
            "unexplained", "The model class does not explain this recording (see the residuals)"
        )
    w = worst[0]
    name, _ = signal_label(d, w.signal)
    fit = d.adequacy.fit_percent.get(w.signal)
    text = f"Unexplained, here: the {name} residual stays {number(w.noise_ratio, 2)}× the noise"
    if fit is not None:
        text += f" (fit {percent(fit)})"
    parts = where_parts(d, w, n=1)
    if parts:
        text += ", " + "; ".join(parts[:2])
    cond = conditions_text(d, n=1)
    evidence = f"concentrated during {cond}" if cond else ""
    others = [
        f"{signal_label(d, o.signal)[0]} ({number(o.noise_ratio, 2)}× the noise)" for o in worst[1:]
    ]
    if others:
        evidence += ("; " if evidence else "") + "also " + ", ".join(others)
    return Finding("unexplained", text, evidence)


def findings(d: Diagnosis) -> list[Finding]:
    """The headline: effects left out (naming order), data-sheet values the evidence
    contradicts, effects the evidence showed that the held-out gate dropped, then what stays
    unexplained — or that the model explains the recording."""
    out = [left_out_finding(d, e) for e in d.left_out]
    out += [datasheet_finding(d, x) for x in d.datasheet if x.datasheet_wrong]
    out += [no_gain_finding(d, g) for g in d.closed_loop.gate if not g.kept]
    if not d.adequacy.adequate:
        out.append(unexplained_finding(d))
    elif not any(f.kind in ("left out", "data sheet") for f in out):
        ratios = ", ".join(
            f"{signal_label(d, s)[0]} {number(r, 2)}×" for s, r in d.adequacy.noise_ratio.items()
        )
        out.append(
            Finding(
                "explained",
                "The nominal model explains the recording: nothing of the axis-file table is "
                "left out",
                f"residual over the noise: {ratios}" if ratios else "",
            )
        )
    return out


def fit_changes(d: Diagnosis) -> list[tuple[str, float, float, float]]:
    """(signal words, fit of the nominal, within its data sheet, fitted) per signal, %."""
    out = []
    for s, after in d.fit_after.items():
        before = d.fit_before.get(s)
        refit = d.fit_refit.get(s)
        out.append(
            (
                signal_label(d, s)[0],
                before.fit_percent if before else math.nan,
                refit.fit_percent if refit else math.nan,
                after.fit_percent,
            )
        )
    return out


def fit_line(d: Diagnosis) -> str:
    return ", ".join(
        f"{name} {percent(b).removesuffix(' %')} → {percent(a)}" for name, b, _, a in fit_changes(d)
    )


def next_experiments(d: Diagnosis) -> list[tuple[str, str]]:
    """(the question, the experiment that answers it): each ambiguity, then a second
    recording where one recording named an effect."""
    out = [
        (
            f"{sentence(effect_name(a.named))} or {effect_name(a.alternative)}?",
            sentence(a.experiment),
        )
        for a in d.ambiguous
    ]
    if d.left_out and d.validation == "interleaved blocks":
        out.append(
            (
                "Does the fitted model hold on another run?",
                "Record the axis again at another time (other moves, other load) and run "
                "`diagnose --validate SECOND.csv`, or `diagnosis simulate --axis "
                "axis_fitted.toml --like SECOND.csv`",
            )
        )
    return out


# ----------------------------------------------------------------------------------------
# the text summary (stdout)
# ----------------------------------------------------------------------------------------
def recording_line(d: Diagnosis, source: str = "") -> str:
    t = d.recording.time
    name = f"{source}: " if source else ""
    return f"{name}{number(float(t[-1] - t[0]), 3)} s, {len(t):,} samples; held out: {d.validation}"


def text_summary(d: Diagnosis, source: str = "", files: Sequence[str] = ()) -> list[str]:
    """The lines the command prints: headline with its evidence, fits, unexplained, next
    experiments, timings, files."""
    lines = [f"diagnosis of {recording_line(d, source)}"]
    for f in findings(d):
        lines.append(f"* {f.text}")
        if f.evidence:
            lines.append(f"    {f.evidence}")
    lines.append(f"simulation fit (nominal → fitted): {fit_line(d)}")
    loop = d.closed_loop
    lines.append(
        f"held-out cost (lower is better): nominal {number(loop.nominal.heldout.cost)}, "
        f"within its data sheet {number(loop.base.heldout.cost)}, fitted "
        f"{number(loop.final.heldout.cost)}"
    )
    for question, experiment in next_experiments(d):
        lines.append(f"next experiment: {question} {experiment}")
    t = d.timings_s
    if "total" in t:
        took = f"took {t['total']:.1f} s"
        if "evidence" in t:
            took += f" (evidence {t['evidence']:.1f} s)"
        lines.append(f"{took}, {d.n_simulations} simulations")
    if files:
        lines.append("wrote " + ", ".join(files))
    return lines

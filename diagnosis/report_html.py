"""``report.html``: the diagnosis as a page a maintenance engineer reads.

One self-contained file (figures embedded as PNG data URIs, the style inline, no script, no
request to anything): the headline in engineer terms with the evidence behind each finding
(:mod:`.summary`), the fit before and after with figures (:mod:`.report_figures`), the
evidence (effects named, parameters against the data sheet, every test, the held-out gate),
what stays unexplained and where, and the next experiment. The page iterates over what the
:class:`~.outcome.Diagnosis` holds: tables of the outcome's records show every field they
have (fields this module does not know get a column of their own), and fields of the outcome
this module does not know are shown in "Also in the outcome" — an effect, a signal or a field
added to the diagnosis appears without an edit here.
"""

from __future__ import annotations

import base64
import dataclasses
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from enum import Enum
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from cmdline.quantity import number, percent, quantities, quantity
from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from . import report_figures as figs
from .effects import MODELS
from .outcome import Diagnosis
from .parameters import key_unit
from .results import DECISION_RULE
from .summary import (
    change_text,
    effect_name,
    findings,
    fit_changes,
    misfit_signals,
    next_experiments,
    p_text,
    sentence,
    signal_label,
    where_parts,
)

#: Fields of the outcome the page shows in its own sections (the rest: "Also in the outcome").
SHOWN = frozenset(
    {
        "left_out", "evidence", "closed_loop", "ambiguous", "mismatch", "mismatch_by_condition",
        "tests_final", "fit_before", "fit_refit", "fit_after", "heldout_nominal",
        "heldout_refit", "heldout_final", "nominal", "refit", "fitted", "fitted_values",
        "datasheet", "adequacy", "unexplained", "notes", "explanation", "simulated_before",
        "simulated_refit", "simulated_after", "recording", "validation", "timings_s",
        "n_simulations", "options",
    }
)  # fmt: skip
#: Rows of a table before the rest folds away.
MAX_ROWS = 40

STYLE = """
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1d2430;
  background: #f4f6f9; margin: 0; }
main { max-width: 1180px; margin: 0 auto; padding: 24px 28px 60px; background: #fff; }
header h1 { font-size: 26px; margin: 0 0 4px; }
header p { margin: 2px 0; color: #4a5566; }
h2 { font-size: 20px; border-bottom: 2px solid #d8dee8; padding-bottom: 4px; margin-top: 34px; }
h3 { font-size: 16px; margin: 20px 0 6px; }
ol.findings { list-style: none; padding: 0; margin: 12px 0; }
ol.findings li { border-left: 6px solid #888; background: #f7f8fa; margin: 10px 0;
  padding: 10px 14px; border-radius: 3px; }
ol.findings li.left-out { border-color: #c0392b; }
ol.findings li.data-sheet { border-color: #d35400; }
ol.findings li.unexplained { border-color: #7d3c98; }
ol.findings li.no-model-gain { border-color: #b7950b; }
ol.findings li.explained { border-color: #1e8449; }
.what { font-size: 19px; font-weight: 600; margin: 0; }
.why { margin: 4px 0 0; color: #4a5566; font-size: 14px; }
.kind { font-size: 11px; text-transform: uppercase; letter-spacing: .06em; color: #6b7585; }
table { border-collapse: collapse; margin: 8px 0 14px; font-size: 13.5px; }
th, td { border: 1px solid #d8dee8; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #eef1f6; font-weight: 600; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
tr.named td { background: #fdf0ee; }
.bars { display: grid; grid-template-columns: 190px 1fr 150px; gap: 8px 12px;
  align-items: center; max-width: 860px; margin: 10px 0 6px; font-size: 14px; }
.bar { height: 9px; margin: 2px 0; border-radius: 2px; }
.bar.before { background: #d9534f; } .bar.after { background: #2e75b6; }
.track { background: #edf0f4; border-radius: 2px; padding: 1px 0; }
.legend { font-size: 12.5px; color: #4a5566; }
.legend i { display: inline-block; width: 22px; height: 9px; margin: 0 4px 0 10px;
  border-radius: 2px; }
figure { margin: 12px 0 22px; }
figure img { max-width: 100%; border: 1px solid #e2e6ec; }
figcaption { font-size: 13px; color: #4a5566; margin-top: 4px; }
.pair { display: flex; flex-wrap: wrap; gap: 16px; align-items: flex-start; }
.card { border: 1px solid #d8dee8; border-radius: 4px; padding: 8px 14px; margin: 10px 0; }
.muted { color: #6b7585; }
code { font-size: 13px; background: #f0f2f5; padding: 0 3px; border-radius: 2px; }
details { margin: 8px 0; } summary { cursor: pointer; font-weight: 600; }
"""


# ----------------------------------------------------------------------------------------
# HTML pieces
# ----------------------------------------------------------------------------------------
def e(text: object) -> str:
    return escape(str(text), quote=True)


def prose(text: str) -> str:
    """Escaped text with `commands` set as code."""
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", e(text))


def plain(value: Any) -> str:
    """Any value of the outcome as short text (numbers with three significant digits)."""
    if value is None:
        return "—"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, Enum):
        return str(value.value)
    if isinstance(value, int | np.integer):
        return f"{int(value):,}"
    if isinstance(value, float | np.floating):
        return number(float(value))
    if isinstance(value, Mapping):
        items = list(value.items())
        text = "; ".join(f"{plain(k)}: {plain(v)}" for k, v in items[:12])
        return text + (f"; … ({len(items) - 12} more)" if len(items) > 12 else "")
    if isinstance(value, np.ndarray):
        return f"array {value.shape}"
    if isinstance(value, list | tuple | set | frozenset):
        items = list(value)
        text = ", ".join(plain(v) for v in items[:12])
        return text + (f", … ({len(items) - 12} more)" if len(items) > 12 else "")
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return "; ".join(f"{f.name}: {plain(getattr(value, f.name))}" for f in _fields(value))
    return str(value)


def _fields(obj: Any) -> list[dataclasses.Field]:
    return list(dataclasses.fields(obj))


def image(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{e(alt)}">'


Cell = Callable[[Any], str]  # a record -> the cell's HTML


def table(
    rows: Sequence[Any],
    columns: Sequence[tuple[str, Cell, bool]],
    known: Iterable[str] = (),
    row_class: Callable[[Any], str] | None = None,
) -> str:
    """A table of records: the given columns (header, cell, numeric), then for records that
    are dataclasses a column for each of their fields not in ``known`` (new fields show)."""
    if not rows:
        return '<p class="muted">none</p>'
    cols = list(columns)
    first = rows[0]
    if dataclasses.is_dataclass(first) and not isinstance(first, type):
        skip = set(known)
        for f in _fields(first):
            if f.name not in skip:
                cols.append(
                    (f.name.replace("_", " "), lambda r, n=f.name: e(plain(getattr(r, n))), False)
                )
    head = "".join(f"<th>{e(h)}</th>" for h, _, _ in cols)
    body = []
    for i, r in enumerate(rows):
        if i == MAX_ROWS:
            body.append(
                f'<tr><td colspan="{len(cols)}" class="muted">… {len(rows) - MAX_ROWS} more '
                "(report.json)</td></tr>"
            )
            break
        cls = f' class="{row_class(r)}"' if row_class and row_class(r) else ""
        cells = "".join(
            f'<td class="num">{cell(r)}</td>' if num else f"<td>{cell(r)}</td>"
            for _, cell, num in cols
        )
        body.append(f"<tr{cls}>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def generic(value: Any, depth: int = 0) -> str:
    """Any value of the outcome as HTML: records as tables of their fields, lists of records
    as tables, mappings as two columns; traces, arrays and objects that are not records as
    their kind (they are in the CSV files and report.json)."""
    if isinstance(value, Trace):
        return f"<span class='muted'>trace, {len(value):,} samples (fit_*.csv)</span>"
    if isinstance(value, AxisConfig):
        return "<span class='muted'>axis file (axis_fitted.toml)</span>"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        if depth >= 2:
            return e(plain(value))
        rows = [
            f"<tr><th>{e(f.name.replace('_', ' '))}</th>"
            f"<td>{generic(getattr(value, f.name), depth + 1)}</td></tr>"
            for f in _fields(value)
        ]
        return f"<table>{''.join(rows)}</table>"
    if (
        isinstance(value, list | tuple)
        and value
        and all(dataclasses.is_dataclass(v) and not isinstance(v, type) for v in value)
    ):
        return table(list(value), [])
    if isinstance(value, Mapping) and value and depth < 2:
        rows = [
            f"<tr><th>{e(plain(k))}</th><td>{generic(v, depth + 1)}</td></tr>"
            for k, v in list(value.items())[:MAX_ROWS]
        ]
        return f"<table>{''.join(rows)}</table>"
    if isinstance(value, str | int | float | bool | Enum | list | tuple | Mapping | np.generic):
        return e(plain(value))
    if value is None:
        return "—"
    return f"<span class='muted'>{e(type(value).__name__)}</span>"


def estimate_unit(name: str, d: Diagnosis) -> str:
    """Unit of an evidence estimate: an axis-file key's, a difference of two keys' (the
    first's), a key times cos/sin of an angle (the key's); anything else composed of keys
    ('mechanics.load_mass/antiresonance^2'): none known, the number alone."""
    if re.fullmatch(r"[a-z_]+\.[a-z_]+", name):
        return key_unit(name, d.nominal)
    left, sep, right = name.partition("-")
    if sep and re.fullmatch(r"[a-z_]+\.[a-z_]+", left) and re.fullmatch(r"[a-z_]+", right):
        return key_unit(left, d.nominal)
    left, sep, right = name.partition("*")
    if sep and re.fullmatch(r"[a-z_]+\.[a-z_]+", left) and re.fullmatch(r"(cos|sin)\(\w+\)", right):
        return key_unit(left, d.nominal)
    return ""


def _scalars(obj: Any, skip: Iterable[str] = ()) -> str:
    """The plain-valued fields of a record (numbers, text, flags) as one line."""
    out = []
    for f in _fields(obj):
        v = getattr(obj, f.name)
        if f.name in skip or not isinstance(v, int | float | str | bool):
            continue
        out.append(f"{e(f.name.replace('_', ' '))} <b>{e(plain(v))}</b>")
    return " · ".join(out)


# ----------------------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------------------
def _header(d: Diagnosis, source: str, axis_source: str) -> str:
    title = Path(source).name if source else "a recording"
    t = d.recording.time
    rec = f"<code>{e(source)}</code>, " if source else ""
    axis = f"Nominal model: <code>{e(axis_source)}</code> · " if axis_source else ""
    named = ", ".join(effect_name(x) for x in d.left_out) or "none"
    return (
        f"<header><h1>Diagnosis of {e(title)}</h1>"
        f"<p>Recording: {rec}{e(number(float(t[-1] - t[0])))} s, {len(t):,} samples · "
        f"{axis}held out: {e(d.validation)}</p>"
        f"<p class='muted'>python -m diagnosis diagnose · effects named: {e(named)} · "
        f"false-alarm rate {e(plain(d.evidence.alpha))} per recording</p></header>"
    )


def _headline(d: Diagnosis) -> str:
    items = []
    for f in findings(d):
        cls = f.kind.replace(" ", "-")
        why = f'<p class="why">{e(f.evidence)}</p>' if f.evidence else ""
        items.append(
            f'<li class="{cls}"><span class="kind">{e(f.kind)}</span>'
            f'<p class="what">{e(f.text)}</p>{why}</li>'
        )
    bars = []
    for name, before, _, after in fit_changes(d):
        pair = []
        for v, cls in ((before, "before"), (after, "after")):
            width = max(0.0, min(100.0, v)) if math.isfinite(v) else 0.0
            pair.append(f"<div class='bar {cls}' style='width:{width:.1f}%'></div>")
        bars.append(
            f"<span>{e(name)}</span><div class='track'>{''.join(pair)}</div>"
            f"<span class='num'>{e(percent(before))} → <b>{e(percent(after))}</b></span>"
        )
    return (
        "<section id='headline'><h2>What is wrong</h2>"
        f"<ol class='findings'>{''.join(items)}</ol>"
        "<h3>Simulation fit, nominal → fitted</h3>"
        f"<div class='bars'>{''.join(bars)}</div>"
        "<p class='legend'><i class='bar before'></i>nominal <i class='bar after'></i>fitted "
        "(fit = 100 % × (1 − ‖recording − simulation‖ / ‖recording − its mean‖); 100 %: the "
        "recording itself)</p></section>"
    )


def _fit(d: Diagnosis) -> str:
    rows = []
    for s, after in d.fit_after.items():
        name, unit = signal_label(d, s)
        cells = [d.fit_before.get(s), d.fit_refit.get(s), after]
        held = [sc.fits.get(s) for sc in (d.heldout_nominal, d.heldout_refit, d.heldout_final)]
        rows.append((name, unit, after.compared, cells, held))
    cols = [("signal", lambda r: e(f"{r[0]} ({r[1]})"), False)]
    for i, label in enumerate(("nominal", "within data sheet", "fitted")):
        cols.append(
            (
                f"fit, {label}",
                lambda r, i=i: e(percent(r[3][i].fit_percent)) if r[3][i] else "—",
                True,
            )
        )
    for i, label in enumerate(("nominal", "within data sheet", "fitted")):
        cols.append(
            (
                f"held out, {label}",
                lambda r, i=i: e(percent(r[4][i].fit_percent)) if r[4][i] else "—",
                True,
            )
        )
    loop = d.closed_loop
    cost = (
        f"<p>Held-out cost ({e(d.validation)}; lower is better): nominal as given "
        f"<b>{e(number(loop.nominal.heldout.cost))}</b>, within its data sheet "
        f"<b>{e(number(loop.base.heldout.cost))}</b>, fitted "
        f"<b>{e(number(loop.final.heldout.cost))}</b>"
        + (
            f" ({e(percent(loop.improvement_percent))} against the data sheet's, "
            f"{e(p_text(loop.p))})"
            if d.left_out
            else ""
        )
        + ".</p>"
    )
    figures = []
    for s in d.fit_after:
        name, _ = signal_label(d, s)
        full = figs.signal_figure(d, s)
        zoom = ""
        span = figs.zoom_window(d, s)
        if span is not None:
            alt = f"{name}, {span[0]:.2f}-{span[1]:.2f} s"
            zoom = (
                f"<div class='pair'><figure>{image(figs.zoom_figure(d, s, span), alt)}</figure>"
                f"<p class='why' style='max-width:420px'>Up close: the strongest departure of "
                f"the nominal in the {e(name)}, {e(number(span[0]))}–{e(number(span[1]))} s, "
                "with the nominal within its data sheet (dashed) and the fitted model.</p></div>"
            )
        figures.append(
            f"<h3>{e(sentence(name))}</h3><figure>{image(full, name)}<figcaption>Recording, "
            "nominal and fitted model over the whole recording (upper), what the models leave "
            "(lower); shaded: where the nominal departs beyond the noise; hatched: where the "
            f"fitted model still does.</figcaption></figure>{zoom}"
        )
    return (
        "<section id='fit'><h2>Fit before and after</h2>"
        + table(rows, cols)
        + cost
        + "".join(figures)
        + "</section>"
    )


def _named(d: Diagnosis) -> str:
    ev = d.evidence
    cards = []
    for effect in d.left_out:
        model = MODELS[effect]
        values = []
        for k in model.keys:
            new = d.fitted.value(k)
            if new is None:
                continue
            old = d.nominal.value(k)
            unit = key_unit(k, d.nominal)
            values.append(
                f"<tr><td><code>{e(k)}</code></td><td class='num'>"
                f"{e(quantity(None if old is None else float(old), unit))}</td>"
                f"<td class='num'>{e(quantity(float(new), unit))}</td></tr>"
            )
        v = next((v for v in ev.verdicts if v.effect is effect and v.named), None)
        test = (
            f"<p>Named by the {e(v.relation)} test in round {e(v.round)}: z = "
            f"{e(number(v.z))}, {e(p_text(v.p))} against the level {e(plain(v.alpha))}.</p>"
            if v is not None
            else ""
        )
        g = next((g for g in d.closed_loop.gate if g.effect is effect), None)
        gate = (
            f"<p>Held-out gate: cost {e(number(g.cost_without))} without it, "
            f"{e(number(g.cost_with))} with it ({e(change_text(g.gain))}, "
            f"{e(p_text(g.p))}): {'kept' if g.kept else 'not kept'}.</p>"
            if g is not None
            else ""
        )
        cards.append(
            f"<div class='card'><h3>{e(sentence(effect_name(effect)))}</h3>"
            f"<p class='muted'>{e(model.description)}</p>"
            "<table><thead><tr><th>axis-file key</th><th>nominal</th><th>fitted</th></tr></thead>"
            f"<tbody>{''.join(values)}</tbody></table>{test}{gate}</div>"
        )
    return "".join(cards) or "<p>No effect of the table is named.</p>"


def _datasheet(d: Diagnosis) -> str:
    def q(attr: str) -> Cell:
        return lambda x: e(quantity(getattr(x, attr), x.unit, like=x.nominal))

    cols = [
        ("key", lambda x: f"<code>{e(x.key)}</code>", False),
        ("data sheet", q("nominal"), True),
        (
            "uncertainty",
            lambda x: e(quantities(list(x.box), x.unit)) if x.box is not None else "—",
            True,
        ),
        (
            "evidence",
            lambda x: e(
                f"{quantity(x.evidence, x.unit, like=x.nominal)} ± "
                f"{quantity(x.standard_error, x.unit, like=x.nominal)}"
            ),
            True,
        ),
        ("fitted", q("fitted"), True),
        ("data sheet wrong", lambda x: "<b>yes</b>" if x.datasheet_wrong else "no", False),
    ]
    known = ("key", "nominal", "box", "evidence", "standard_error", "fitted", "unit",
             "datasheet_wrong")  # fmt: skip
    changes = [
        (k, old, new)
        for k, (old, new) in d.fitted_values.items()
        if not (math.isfinite(old) and old == new)
    ]
    change_cols = [
        ("key", lambda r: f"<code>{e(r[0])}</code>", False),
        (
            "nominal",
            lambda r: (
                e(quantity(r[1], key_unit(r[0], d.nominal), like=r[2]))
                if math.isfinite(r[1])
                else "absent"
            ),
            True,
        ),
        ("fitted", lambda r: e(quantity(r[2], key_unit(r[0], d.nominal), like=r[1])), True),
        (
            "change",
            lambda r: (
                e(percent(100.0 * (r[2] / r[1] - 1.0)))
                if math.isfinite(r[1]) and r[1] != 0.0
                else "—"
            ),
            True,
        ),
    ]
    return (
        "<h3>Parameters against the data sheet</h3>"
        + table(d.datasheet, cols, known, lambda x: "named" if x.datasheet_wrong else "")
        + "<h3>axis_fitted.toml against the nominal</h3>"
        + table(changes, change_cols)
    )


def _tests(d: Diagnosis) -> str:
    ev = d.evidence

    def estimate(v: Any) -> str:
        return "<br>".join(
            f"<code>{e(k)}</code> {e(quantity(float(x), estimate_unit(k, d)))}"
            for k, x in v.estimate.items()
        )

    cols = [
        ("round", lambda v: e(v.round), True),
        ("effect", lambda v: e(effect_name(v.effect)), False),
        ("relation", lambda v: e(v.relation), False),
        ("z", lambda v: e(number(v.z)), True),
        ("p", lambda v: e(p_text(v.p).removeprefix("p = ")), True),
        ("level", lambda v: e(plain(v.alpha)), True),
        (
            "verdict",
            lambda v: "<b>named</b>" if v.named else ("significant" if v.significant else "—"),
            False,
        ),
        ("estimate", estimate, False),
        ("note", lambda v: e(v.note), False),
    ]
    known = ("round", "effect", "relation", "z", "p", "alpha", "named", "significant",
             "estimate", "note", "statistic", "replay_estimate", "n_blocks")  # fmt: skip
    not_tested = "".join(
        f"<li>{e(effect_name(x))}: {e(why)}</li>" for x, why in ev.not_tested.items()
    )
    gate_cols = [
        ("effect", lambda g: e(effect_name(g.effect)), False),
        ("cost without", lambda g: e(number(g.cost_without)), True),
        ("cost with", lambda g: e(number(g.cost_with)), True),
        ("gain", lambda g: e(percent(100.0 * g.gain)), True),
        ("z", lambda g: e(number(g.z)), True),
        ("p", lambda g: e(p_text(g.p).removeprefix("p = ")), True),
        ("kept", lambda g: "<b>yes</b>" if g.kept else "no", False),
    ]
    gate_known = ("effect", "cost_without", "cost_with", "gain", "z", "p", "kept")
    return (
        f"<h3>Every test</h3><p class='muted'>{_scalars(ev)}</p>"
        + table(ev.verdicts, cols, known, lambda v: "named" if v.named else "")
        + (f"<p>Not tested:</p><ul>{not_tested}</ul>" if not_tested else "")
        + "<h3>Held-out gate</h3><p class='muted'>An effect stays named only if the model with "
        "it predicts the held-out data better than the model without it, both fitted alike.</p>"
        + table(d.closed_loop.gate, gate_cols, gate_known)
    )


def _evidence(d: Diagnosis) -> str:
    return (
        "<section id='evidence'><h2>The evidence</h2><h3>Effects named</h3>"
        + _named(d)
        + _datasheet(d)
        + _tests(d)
        + "</section>"
    )


def _unexplained(d: Diagnosis) -> str:
    a = d.adequacy
    parts = ["<section id='unexplained'><h2>What stays unexplained, and where</h2>"]
    ratios = ", ".join(
        f"{signal_label(d, s)[0]} {number(r, 2)}× (fit {percent(a.fit_percent.get(s, math.nan))})"
        for s, r in a.noise_ratio.items()
    )
    if a.adequate:
        parts.append(
            f"<p>Nothing: the fitted model's residual over the white noise is {e(ratios)}.</p>"
        )
    else:
        parts.append(
            "<p><b>Unexplained, here.</b> The fitted model still leaves, over the white noise: "
            f"{e(ratios)}.</p>"
        )
        for w in misfit_signals(d):
            name, _ = signal_label(d, w.signal)
            where = "".join(f"<li>{e(p)}</li>" for p in where_parts(d, w, n=3))
            fig = figs.where_figure(d, w)
            parts.append(
                f"<h3>{e(sentence(name))}: {e(number(w.noise_ratio, 2))}× the noise</h3>"
                f"<ul>{where}</ul>"
                + (f"<figure>{image(fig, name + ' where')}</figure>" if fig else "")
            )
        conds = ", ".join(f"{k} {number(v, 2)}×" for k, v in a.by_condition.items())
        if conds:
            parts.append(
                f"<p>Share of the residual per operating condition, against its share of time: "
                f"{e(conds)}.</p>"
            )
        corr = "; ".join(
            f"{signal_label(d, s)[0]}: {', '.join(x.replace('_', ' ') for x in v)}"
            for s, v in a.correlated_with.items()
            if v
        )
        if corr:
            parts.append(f"<p>The residual correlates with: {e(corr)}.</p>")
        if a.hints:
            hints = "".join(f"<li>{e(h)}</li>" for h in a.hints)
            parts.append(
                f"<p>That points to physics outside the axis-file table:</p><ul>{hints}</ul>"
            )
    cols = [
        ("time", lambda m: e(f"{number(m.t_start)}–{number(m.t_end)} s"), True),
        ("signal", lambda m: e(signal_label(d, m.signal)[0]), False),
        ("condition", lambda m: e(m.condition), False),
        (
            "positions",
            lambda m: e(quantities([m.position_min, m.position_max], d.nominal.load_unit)),
            True,
        ),
        (
            "peak residual",
            lambda m: e(quantity(m.peak_residual, signal_label(d, m.signal)[1])),
            True,
        ),
        ("× threshold", lambda m: e(number(m.peak_over_threshold, 2)), True),
        ("explained by the fitted model", lambda m: "yes" if m.explained else "<b>no</b>", False),
    ]
    known = ("t_start", "t_end", "signal", "condition", "conditions", "position_min",
             "position_max", "peak_residual", "peak_over_threshold", "explained",
             "speed_sign")  # fmt: skip
    windows = sorted(d.mismatch, key=lambda m: (m.explained, m.t_start))
    still = sum(not m.explained for m in windows)
    parts.append(
        "<h3>Where the nominal departs from the recording</h3>"
        f"<details{' open' if still else ''}><summary>{len(windows)} mismatch windows of the "
        f"nominal within its data sheet; the fitted model explains {len(windows) - still}"
        "</summary>"
        + table(windows, cols, known, lambda m: "" if m.explained else "named")
        + "</details>"
    )
    parts.append("</section>")
    return "".join(parts)


def _next(d: Diagnosis) -> str:
    items = "".join(
        f"<li><p class='what'>{prose(q)}</p><p class='why'>{prose(x)}</p></li>"
        for q, x in next_experiments(d)
    )
    notes = "".join(f"<li>{e(n)}</li>" for n in d.notes)
    return (
        "<section id='next'><h2>Next experiment</h2>"
        + (f"<ol class='findings'>{items}</ol>" if items else "<p>None needed.</p>")
        + (f"<h3>Notes</h3><ul>{notes}</ul>" if notes else "")
        + "</section>"
    )


def _details(d: Diagnosis) -> str:
    extra = [f for f in _fields(d) if f.name not in SHOWN]
    also = "".join(
        f"<h3>{e(f.name.replace('_', ' '))}</h3>{generic(getattr(d, f.name))}" for f in extra
    )
    timings = ", ".join(f"{k} {v:.2f} s" for k, v in d.timings_s.items())
    options = _scalars(d.options)
    try:
        rule = DECISION_RULE.format(**dataclasses.asdict(d.options))
    except (KeyError, IndexError, ValueError):
        rule = DECISION_RULE
    return (
        "<section id='details'><h2>Details</h2>"
        + (f"<h3>Also in the outcome</h3>{also}" if also else "")
        + "<details><summary>The explanation paragraph</summary>"
        + f"<p>{e(d.explanation)}</p></details>"
        + f"<details><summary>The decision rule</summary><p>{e(rule)}</p></details>"
        + "<details><summary>Residual tests of the fitted model</summary>"
        + generic(d.tests_final)
        + "</details>"
        + f"<p class='muted'>Options: {options}. Timings: {e(timings)}; "
        f"{e(d.n_simulations)} simulations. Files beside this page: report.json, "
        "axis_fitted.toml, fit_before.csv, fit_after.csv, report.png.</p></section>"
    )


def page(d: Diagnosis, source: str = "", axis_source: str = "") -> str:
    """The whole page."""
    body = (
        _header(d, source, axis_source)
        + _headline(d)
        + _fit(d)
        + _evidence(d)
        + _unexplained(d)
        + _next(d)
        + _details(d)
    )
    title = f"Diagnosis: {Path(source).name}" if source else "Diagnosis"
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{e(title)}</title><style>{STYLE}</style></head>"
        f"<body><main>{body}</main></body></html>\n"
    )


def write_html(d: Diagnosis, path: str | Path, source: str = "", axis_source: str = "") -> Path:
    out = Path(path)
    write_atomic(out, page(d, source, axis_source))
    return out

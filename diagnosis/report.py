"""Write a :class:`~diagnosis.engine.Diagnosis`: report.html (the page an engineer reads,
:mod:`.report_html`), report.json, axis_fitted.toml, fit_before.csv / fit_after.csv
(simulated traces with the recording's columns and time base) and report.png (recording vs
before vs after per signal, mismatch windows shaded, residuals; :mod:`.report_figures`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, is_dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import dump_axis
from virtual_bus.formats.trace import Trace

from .closed_loop import ModelFit
from .fit import plain_floats
from .outcome import Diagnosis
from .parameters import key_unit
from .report_figures import plot_report
from .report_html import write_html
from .results import DECISION_RULE

REPORT_FILES = (
    "report.html",
    "report.json",
    "axis_fitted.toml",
    "fit_before.csv",
    "fit_after.csv",
    "report.png",
)


def _jsonable(value: Any) -> Any:
    """Dataclasses, enums, numpy scalars -> JSON types; inf/NaN -> None."""
    if is_dataclass(value) and not isinstance(value, type):
        return {k: _jsonable(v) for k, v in asdict(value).items()}
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, dict):
        return {str(_jsonable(k)): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def _model_fit(m: ModelFit) -> dict[str, Any]:
    return {
        "name": m.name,
        "effects": [e.value for e in m.effects],
        "heldout_cost": m.heldout.cost,
        "heldout_fit_percent": {s: f.fit_percent for s, f in m.heldout.fits.items()},
        "training_cost": m.result.cost,
        "n_free": m.heldout.n_free,
        "bounds": [
            {"key": b.key, "low": b.low, "high": b.high, "start": b.start, "source": b.source}
            for b in m.bounds
        ],
    }


def report_dict(d: Diagnosis) -> dict[str, Any]:
    """The content of report.json."""
    rec = d.recording
    ev, loop = d.evidence, d.closed_loop
    return _jsonable(
        {
            "left_out": [e.value for e in d.left_out],
            "evidence": {
                "alpha": ev.alpha,
                "alpha_per_test": ev.alpha_each,
                "named": [e.value for e in ev.named],
                "tests": [
                    {
                        "effect": v.effect.value,
                        "round": v.round,
                        "relation": v.relation,
                        "statistic": v.statistic,
                        "z": v.z,
                        "p_value": v.p,
                        "significant": v.significant,
                        "named": v.named,
                        "estimate": v.estimate,
                        "replay_estimate": v.replay_estimate,
                        "blocks": v.n_blocks,
                        "note": v.note,
                    }
                    for v in ev.verdicts
                ],
                "not_tested": {e.value: why for e, why in ev.not_tested.items()},
                "relations": ev.relations,
                "replays": ev.n_replays,
                "seconds": ev.seconds,
            },
            "datasheet": [
                {
                    "key": x.key,
                    "nominal": x.nominal,
                    "uncertainty_box": x.box,
                    "evidence": x.evidence,
                    "standard_error": x.standard_error,
                    "datasheet_wrong": x.datasheet_wrong,
                    "fitted": x.fitted,
                    "unit": x.unit,
                }
                for x in d.datasheet
            ],
            "closed_loop": {
                "nominal": _model_fit(loop.nominal),
                "within_datasheet": _model_fit(loop.base),
                "final": _model_fit(loop.final),
                "alternatives": [_model_fit(m) for m in loop.alternatives],
                "held_out_gate": [
                    {
                        "effect": g.effect.value,
                        "cost_without": g.cost_without,
                        "cost_with": g.cost_with,
                        "gain_percent": 100.0 * g.gain,
                        "z": g.z,
                        "p_value": g.p,
                        "kept": g.kept,
                    }
                    for g in loop.gate
                ],
                "improvement_percent": loop.improvement_percent,
                "z": loop.z,
                "p_value": loop.p,
                "swaps": loop.swaps,
                "simulations": loop.n_simulations,
                "seconds": loop.seconds,
            },
            "ambiguous": [
                {
                    "named": a.named.value,
                    "alternative": a.alternative.value,
                    "cost_ratio": a.cost_ratio,
                    "p_value": a.p_value,
                    "experiment": a.experiment,
                }
                for a in d.ambiguous
            ],
            "mismatch": d.mismatch,
            "mismatch_by_condition_s": d.mismatch_by_condition,
            "tests": d.tests_final,
            "fit_before": d.fit_before,
            "fit_refit": d.fit_refit,
            "fit_after": d.fit_after,
            "heldout": {
                "nominal": d.heldout_nominal,
                "refit": d.heldout_refit,
                "final": d.heldout_final,
            },
            "fitted": {
                k: {"nominal": n, "fitted": f, "unit": key_unit(k, d.nominal)}
                for k, (n, f) in d.fitted_values.items()
            },
            "adequacy": d.adequacy,
            "unexplained": d.unexplained,
            "explanation": d.explanation,
            "decision_rule": DECISION_RULE.format(
                alpha=d.options.alpha,
                min_improvement=100.0 * d.options.min_improvement,
                choice_alpha=d.options.choice_alpha,
            ),
            "recording": {
                "samples": len(rec),
                "duration_s": float(rec.time[-1] - rec.time[0]),
                "signals": list(d.fit_before),
                "validation": d.validation,
            },
            "notes": d.notes,
            "timings_s": d.timings_s,
            "n_simulations": d.n_simulations,
        }
    )


def simulated_like(recording: Trace, simulated: Trace) -> Trace:
    """The recording's columns and time base, simulated values where the simulation has them."""
    return Trace({n: simulated.columns.get(n, v) for n, v in recording.columns.items()})


def axis_text(d: Diagnosis, source: str = "") -> str:
    added = ", ".join(e.value for e in d.left_out) or "none"
    header = [
        "Fitted by python -m diagnosis diagnose" + (f" from {source}" if source else "") + ".",
        f"Effects added: {added}.",
        "Uncertain parameters re-fitted by closed-loop simulation error, within their "
        "data-sheet uncertainty unless the evidence put them beyond it.",
        *d.notes,
    ]
    return dump_axis(plain_floats(d.fitted), header="\n".join(header))


def write_report(
    d: Diagnosis, out_dir: str | Path, source: str = "", axis_source: str = ""
) -> list[Path]:
    """Write the report files into ``out_dir`` (created if needed); returns their paths.
    ``source``, ``axis_source``: the recording's and the nominal axis file's names."""
    import json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = dict(zip(REPORT_FILES, (out / name for name in REPORT_FILES), strict=True))
    write_atomic(paths["report.json"], json.dumps(report_dict(d), indent=2) + "\n")
    write_atomic(paths["axis_fitted.toml"], axis_text(d, source))
    simulated_like(d.recording, d.simulated_before).to_csv(paths["fit_before.csv"])
    simulated_like(d.recording, d.simulated_after).to_csv(paths["fit_after.csv"])
    plot_report(d, paths["report.png"])
    write_html(d, paths["report.html"], source, axis_source)
    return list(paths.values())

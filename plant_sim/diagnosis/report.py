"""Write a :class:`~plant_sim.diagnosis.engine.Diagnosis`: report.json, axis_fitted.toml,
fit_before.csv / fit_after.csv (simulated traces with the recording's columns and time base)
and report.png (recording vs before vs after per signal, mismatch windows shaded, residuals).
"""

from __future__ import annotations

import math
from dataclasses import asdict, is_dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from virtual_bus.atomic import replacing, write_atomic
from virtual_bus.formats.axis import dump_axis
from virtual_bus.formats.trace import Trace

from .closed_loop import ModelFit
from .fit import plain_floats
from .outcome import Diagnosis
from .parameters import key_unit, units
from .results import DECISION_RULE

REPORT_FILES = ("report.json", "axis_fitted.toml", "fit_before.csv", "fit_after.csv", "report.png")


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
        "Fitted by python -m plant_sim diagnose" + (f" from {source}" if source else "") + ".",
        f"Effects added: {added}.",
        "Uncertain parameters re-fitted by closed-loop simulation error, within their "
        "data-sheet uncertainty unless the evidence put them beyond it.",
        *d.notes,
    ]
    return dump_axis(plain_floats(d.fitted), header="\n".join(header))


def _compared(d: Diagnosis, signal: str, values: np.ndarray) -> np.ndarray:
    ref = d.recording["position_reference"]
    if signal == "motor_position":
        return d.nominal.transmission_ratio * ref - values
    if signal == "load_position":
        return ref - values
    return values


def _label(d: Diagnosis, signal: str) -> tuple[str, str]:
    """(quantity, unit) of what ``signal`` is scored on, in the axis's units."""
    u = units(d.nominal)
    motor_pos = "m" if d.nominal.transmission_ratio == 1.0 and u["position"] == "m" else "rad"
    return {
        "motor_position": ("motor following error", motor_pos),
        "load_position": ("load following error", u["position"]),
        "motor_speed": ("motor speed", f"{motor_pos}/s"),
        "motor_torque": ("motor torque" if u["torque"] == "N·m" else "motor force", u["torque"]),
    }[signal]


def plot_report(d: Diagnosis, path: str | Path) -> None:
    """Per signal: recording, nominal and fitted simulation (upper panel) and the residuals
    of the nominal, the re-fitted nominal and the fitted model (lower panel); every axis
    with its unit, mismatch windows shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    signals = list(d.fit_before)
    t = d.recording.time
    fig, axes = plt.subplots(
        2 * len(signals), 1, figsize=(13, 2.8 * 2 * len(signals)), sharex=True, squeeze=False
    )
    axes = axes[:, 0]
    for i, s in enumerate(signals):
        name, unit = _label(d, s)
        rec = _compared(d, s, d.recording[s])
        before = _compared(d, s, d.simulated_before[s])
        after = _compared(d, s, d.simulated_after[s])
        refit = _compared(d, s, d.simulated_refit[s])
        ax, axr = axes[2 * i], axes[2 * i + 1]
        ax.plot(t, rec, lw=0.6, color="0.35", label="recording")
        ax.plot(
            t,
            before,
            lw=0.8,
            color="tab:red",
            label=f"nominal, fit {d.fit_before[s].fit_percent:.1f} %",
        )
        ax.plot(
            t,
            after,
            lw=0.8,
            color="tab:blue",
            label=f"fitted, fit {d.fit_after[s].fit_percent:.1f} %",
        )
        ax.set_ylabel(f"{name}\n({unit})", fontsize=9)
        axr.plot(t, rec - before, lw=0.4, color="tab:red", alpha=0.5, label="recording − nominal")
        axr.plot(
            t,
            rec - refit,
            lw=0.5,
            color="tab:orange",
            label="recording − nominal within data sheet",
        )
        axr.plot(t, rec - after, lw=0.5, color="tab:blue", label="recording − fitted")
        axr.axhline(0.0, color="k", lw=0.5)
        axr.set_ylabel(f"residual\n({unit})", fontsize=9)
        shaded = False
        for m in d.mismatch:
            if m.signal == s:
                shaded = True
                for a in (ax, axr):
                    a.axvspan(m.t_start, m.t_end, color="orange", alpha=0.25, lw=0)
        extra = [Patch(color="orange", alpha=0.25, label="mismatch window")] if shaded else []
        for a in (ax, axr):
            handles, _ = a.get_legend_handles_labels()
            a.legend(
                handles=handles + extra,
                loc="upper left",
                bbox_to_anchor=(1.005, 1.0),
                fontsize=8,
                frameon=False,
            )
            a.tick_params(labelsize=8)
            a.grid(True, lw=0.3, alpha=0.5)
    axes[-1].set_xlabel("time (s)", fontsize=9)
    named = ", ".join(e.value for e in d.left_out) or "nothing"
    verdict = "" if d.adequacy.adequate else " — the model class does not explain the recording"
    fig.suptitle(f"Diagnosis: left out {named}{verdict}", fontsize=11)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.985))
    with replacing(Path(path)) as tmp:
        fig.savefig(tmp, dpi=90, format=Path(path).suffix[1:])
    plt.close(fig)


def write_report(d: Diagnosis, out_dir: str | Path, source: str = "") -> list[Path]:
    """Write the five report files into ``out_dir`` (created if needed); returns their paths."""
    import json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in REPORT_FILES]
    write_atomic(paths[0], json.dumps(report_dict(d), indent=2) + "\n")
    write_atomic(paths[1], axis_text(d, source))
    simulated_like(d.recording, d.simulated_before).to_csv(paths[2])
    simulated_like(d.recording, d.simulated_after).to_csv(paths[3])
    plot_report(d, paths[4])
    return paths

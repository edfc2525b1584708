"""Figures and reports of the commissioning tests: the Bode figure of the frequency response
(Fig. 2's kind), one panel per tuning trial, and the JSON reports. matplotlib is imported only
when a figure is drawn (Agg backend, files only)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from regulator.tuning import SearchResult, TrialResult
from regulator.units import fine_scale
from virtual_bus.atomic import replacing, write_atomic

from .freqresp import FrequencyResponse


def available() -> bool:
    """matplotlib is installed (the 'sim' extra): a bridge-only install writes the JSON and
    CSV reports and says which figure it could not draw."""
    import importlib.util

    return importlib.util.find_spec("matplotlib") is not None


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def bode_figure(
    fr: FrequencyResponse,
    path: Path,
    title: str,
    reference: tuple[str, np.ndarray, np.ndarray] | None = None,
) -> None:
    """Magnitude and phase of omega_m / omega_r with +- one standard deviation, the notch and
    the -3 dB bandwidth marked; ``reference``: (label, frequency Hz, complex response) drawn
    dashed (an analytic model)."""
    plt = _pyplot()
    loop = fr.loop
    f = loop.frequency_hz
    mag = np.abs(loop.response)
    fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    lo = np.maximum(mag - loop.std, mag * 1e-3)
    ax_m.fill_between(f, 20 * np.log10(lo), 20 * np.log10(mag + loop.std), alpha=0.3, lw=0)
    ax_m.semilogx(f, 20 * np.log10(mag), lw=1.2, label="measured omega_m / omega_r")
    ax_p.semilogx(f, loop.phase_deg(), lw=1.2)
    if reference is not None:
        label, rf, rg = reference
        ax_m.semilogx(rf, 20 * np.log10(np.abs(rg)), "k--", lw=1, label=label)
        ax_p.semilogx(rf, np.degrees(np.unwrap(np.angle(rg))), "k--", lw=1)
    a, b = fr.antiresonance, fr.bandwidth
    if a.resolved:
        lo_hz = (a.rad_s - a.uncertainty_rad_s) / (2 * math.pi)
        hi_hz = (a.rad_s + a.uncertainty_rad_s) / (2 * math.pi)
        for ax in (ax_m, ax_p):
            ax.axvspan(lo_hz, hi_hz, color="C3", alpha=0.2)
        ax_m.axvline(a.hz, color="C3", lw=1, label=f"antiresonance {a.rad_s:.0f} rad/s")
    if not math.isnan(b.frequency_hz):
        ax_m.axvline(b.frequency_hz, color="C2", lw=1, label=f"-3 dB {b.frequency_hz:.1f} Hz")
    ax_m.axhline(-3.0, color="0.6", lw=0.8)
    ax_m.set_ylabel("magnitude, dB")
    ax_p.set_ylabel("phase, degrees")
    ax_p.set_xlabel("frequency, Hz")
    ax_m.set_title(title)
    ax_m.legend(loc="lower left", fontsize=8)
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", lw=0.3)
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix[1:])
    plt.close(fig)


def trials_figure(result: SearchResult, cycle_s: float, path: Path) -> None:
    """One panel per trial -- the following error less eq. 1's (v / k_v: the ramps' own
    error), in µm, the view scaled to what the judged windows (shaded) hold so that a
    vibration of tens of µm is not dwarfed by a ramp's transient of millimetres; the verdict in
    the title -- and a last panel of the oscillation measured against beta_T with the limit and
    the result."""
    plt = _pyplot()
    scale, fine = fine_scale(result.unit)
    trials = [result.reference, *result.trials]
    if result.confirmation is not None:
        trials.append(result.confirmation)
    cols = 3
    rows = math.ceil((len(trials) + 1) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.6 * rows), squeeze=False)
    flat = list(axes.flat)
    for row in axes:
        row[0].set_ylabel(f"following error - eq. 1, {fine}", fontsize=8)
    profile = result.profile
    windows = () if profile is None else (*profile.watch, *profile.rest)
    for ax, trial in zip(flat, trials, strict=False):
        rec = trial.record
        e = rec.position_reference - rec.load_position
        if not math.isnan(result.kv):
            e = e - result.expected_error(rec, cycle_s)
        e = e * scale
        t = np.arange(e.size) * cycle_s
        ax.plot(t, e, lw=0.6)
        inside = [e[a:b] for a, b in windows if b <= e.size]
        if inside:
            peak = max(float(np.max(np.abs(w))) for w in inside)
            span = 1.3 * max(peak, 3.0 * result.limits.vibration * scale, 0.5)
            ax.set_ylim(-span, span)
            for a, b in windows:
                ax.axvspan(a * cycle_s, b * cycle_s, color="0.9", lw=0, zorder=0)
        name = "regulator off" if trial.beta_t_rad_s is None else f"beta_T {trial.beta_t_rad_s:.3g}"
        verdict = trial.verdict.value
        if trial.beta_t_rad_s is None:
            verdict = "limit cycle" if trial.verdict.value == "vibrating" else "no limit cycle"
        ax.set_title(f"{name}: {verdict}", fontsize=9)
        ax.set_xlabel("s", fontsize=7)
        ax.tick_params(labelsize=7)
    summary = flat[len(trials)]
    betas = [t.beta_t_rad_s for t in result.trials if t.metrics is not None]
    vib = [t.metrics.vibration * scale for t in result.trials if t.metrics is not None]
    summary.loglog(betas, np.maximum(vib, 1e-6), "o", ms=3)
    summary.axhline(result.limits.vibration * scale, color="C3", lw=1, label="limit")
    if result.reference.metrics is not None:
        summary.axhline(
            result.reference.metrics.vibration * scale, color="0.5", lw=1, label="regulator off"
        )
    if result.beta_t_rad_s is not None:
        summary.axvline(result.beta_t_rad_s, color="C2", lw=1, label="result")
    summary.set_xlabel("beta_T, rad/s", fontsize=8)
    summary.set_ylabel(f"oscillation, {fine}", fontsize=8)
    summary.set_title("oscillation in eq. 13's band", fontsize=9)
    summary.legend(fontsize=7)
    for ax in flat[len(trials) + 1 :]:
        ax.axis("off")
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=100, format=path.suffix[1:])
    plt.close(fig)


def trial_dict(trial: TrialResult) -> dict[str, Any]:
    m = trial.metrics
    return {
        "beta_t_rad_s": trial.beta_t_rad_s,
        "motion": trial.motion,
        "verdict": trial.verdict.value,
        "reason": trial.reason,
        "metrics": None
        if m is None
        else {
            "vibration": m.vibration,
            "following_deviation": m.following_deviation,
            "standstill_error": m.standstill_error,
            "settle_s": m.settle_s,
            "lambda_at_rest": m.lambda_at_rest,
            "beta_max_rad_s": m.beta_max,
        },
    }


def search_dict(result: SearchResult) -> dict[str, Any]:
    """The search as JSON: lengths in load units (``unit``: m or rad)."""
    return {
        "outcome": result.outcome.value,
        "beta_t_rad_s": result.beta_t_rad_s,
        "last_stable_rad_s": result.last_stable_rad_s,
        "first_vibrating_rad_s": result.first_vibrating_rad_s,
        "margin": result.margin,
        "reason": result.reason,
        "cost": result.cost,
        "unit": result.unit,
        "provoked_by": result.reference.motion,
        "tried": [
            {
                "motion": t.name,
                "description": t.description,
                "vibration": t.vibration,
                "skipped": t.skipped,
            }
            for t in result.tried
        ],
        "limits": {
            "vibration": result.limits.vibration,
            "standstill_error": result.limits.standstill_error,
        },
        "reference": trial_dict(result.reference),
        "trials": [trial_dict(t) for t in result.trials],
        "confirmation": None if result.confirmation is None else trial_dict(result.confirmation),
    }


def _clean(value: object) -> object:
    """JSON-ready: numpy scalars to Python, nan and inf to None."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, data: dict[str, Any]) -> None:
    write_atomic(path, json.dumps(_clean(data), indent=2, allow_nan=False) + "\n")

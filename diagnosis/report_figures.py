"""The report's figures (matplotlib, Agg): ``report.png`` and the page's figures as PNG bytes.

* :func:`plot_report`: per signal the recording, the nominal and the fitted simulation and
  the residuals, mismatch windows shaded (``report.png``);
* :func:`signal_figure`: the same for one signal, in engineer units (µm, mm/s, N), with the
  windows where the fitted model still misses outlined;
* :func:`zoom_figure`: one window of one signal up close (before and after);
* :func:`where_figure`: where a residual stays above the noise over speed and position.

Lines of many samples are drawn as their min/max envelope per pixel column
(:func:`envelope`): the same picture, a fraction of the drawing time.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cmdline.quantity import prefix_for
from virtual_bus.atomic import replacing

from .outcome import Diagnosis
from .summary import compared, effect_name, signal_label
from .unexplained import Range, Where

#: Colours of the three models and of the marked windows.
RECORDING, NOMINAL, REFIT, FITTED = "0.35", "tab:red", "tab:orange", "tab:blue"
MISMATCH, UNEXPLAINED = "orange", "tab:purple"
#: Points per line: the envelope keeps min and max of this many columns.
COLUMNS = 1500


def envelope(t: np.ndarray, y: np.ndarray, columns: int = COLUMNS) -> tuple[np.ndarray, ...]:
    """(t, y) reduced to the min and max of each of ``columns`` equal slices, in time order
    (unchanged when short; the last few samples that do not fill a slice are kept as they
    are)."""
    n = len(t)
    per = n // columns
    if per < 4:
        return t, y
    m = per * columns
    blocks = np.where(np.isfinite(y[:m]), y[:m], np.nan).reshape(columns, per)
    if np.isnan(blocks).all(axis=1).any():  # a slice without a finite value: keep all
        return t, y
    lo = np.nanargmin(blocks, axis=1)
    hi = np.nanargmax(blocks, axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    base = np.arange(columns) * per
    idx = np.column_stack((base + first, base + second)).ravel()
    idx = np.concatenate((idx, np.arange(m, n)))
    return t[idx], y[idx]


def _scaled(d: Diagnosis, signal: str, *series: np.ndarray) -> tuple[float, str, str]:
    """(scale, unit shown, quantity words) for ``series`` of ``signal``."""
    name, unit = signal_label(d, signal)
    peak = max((float(np.nanmax(np.abs(s))) for s in series if len(s)), default=0.0)
    scale, shown = prefix_for(unit, peak)
    return scale, shown, name


def _png(fig: object) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)  # type: ignore[attr-defined]
    return buf.getvalue()


def _figure(width_in: float, height_in: float, rows: int = 1, heights: Sequence[float] = ()):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=96, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False, height_ratios=heights or None)
    return fig, list(axes[:, 0])


def _series(d: Diagnosis, signal: str) -> dict[str, np.ndarray]:
    return {
        "recording": compared(d, signal, d.recording[signal]),
        "nominal": compared(d, signal, d.simulated_before[signal]),
        "refit": compared(d, signal, d.simulated_refit[signal]),
        "fitted": compared(d, signal, d.simulated_after[signal]),
    }


def _shade(d: Diagnosis, signal: str, axes: Sequence, t0: float = -np.inf, t1: float = np.inf):
    """Mismatch windows (the model within its data sheet) shaded, windows where the fitted
    model still misses outlined; returns legend patches for what was drawn."""
    from matplotlib.patches import Patch

    drawn = []
    mism = [m for m in d.mismatch if m.signal == signal and m.t_end > t0 and m.t_start < t1]
    for m in mism:
        for ax in axes:
            ax.axvspan(m.t_start, m.t_end, color=MISMATCH, alpha=0.22, lw=0)
    if mism:
        drawn.append(Patch(color=MISMATCH, alpha=0.3, label="mismatch of the nominal"))
    still = [
        (a, b)
        for w in d.unexplained
        if w.signal == signal
        for a, b in w.windows
        if b > t0 and a < t1
    ]
    for a, b in still:
        for ax in axes:
            ax.axvspan(a, b, fill=False, edgecolor=UNEXPLAINED, hatch="//", lw=0.8, alpha=0.6)
    if still:
        drawn.append(
            Patch(fill=False, edgecolor=UNEXPLAINED, hatch="//", label="fitted model still misses")
        )
    return drawn


def signal_figure(d: Diagnosis, signal: str) -> bytes:
    """One signal over the whole recording: recording, nominal and fitted (upper panel),
    residuals of the nominal within its data sheet and of the fitted model (lower)."""
    t = d.recording.time
    s = _series(d, signal)
    res_refit = s["recording"] - s["refit"]
    res_fitted = s["recording"] - s["fitted"]
    scale, unit, name = _scaled(d, signal, s["recording"])
    rscale, runit, _ = _scaled(d, signal, res_refit, res_fitted)
    fig, (ax, axr) = _figure(11.0, 4.6, rows=2, heights=(3, 2))
    fb, fa = d.fit_before.get(signal), d.fit_after.get(signal)
    lines = (
        ("recording", s["recording"], RECORDING, 0.7, "recording"),
        (
            "nominal",
            s["nominal"],
            NOMINAL,
            0.8,
            "nominal" + (f", fit {fb.fit_percent:.1f} %" if fb else ""),
        ),
        (
            "fitted",
            s["fitted"],
            FITTED,
            0.8,
            "fitted" + (f", fit {fa.fit_percent:.1f} %" if fa else ""),
        ),
    )
    for _, y, colour, lw, label in lines:
        ax.plot(*envelope(t, y / scale), lw=lw, color=colour, label=label)
    ax.set_ylabel(f"{name} ({unit})")
    axr.plot(
        *envelope(t, res_refit / rscale), lw=0.6, color=REFIT, label="− nominal within data sheet"
    )
    axr.plot(*envelope(t, res_fitted / rscale), lw=0.6, color=FITTED, label="− fitted")
    axr.axhline(0.0, color="k", lw=0.5)
    axr.set_ylabel(f"recording − model ({runit})")
    axr.set_xlabel("time (s)")
    extra = _shade(d, signal, (ax, axr))
    for a in (ax, axr):
        handles, _ = a.get_legend_handles_labels()
        a.legend(
            handles=handles + (extra if a is ax else []),
            loc="upper right",
            fontsize=8,
            framealpha=0.85,
            ncols=2,
        )
        a.grid(True, lw=0.3, alpha=0.5)
        a.tick_params(labelsize=8)
    return _png(fig)


def zoom_window(d: Diagnosis, signal: str) -> tuple[float, float] | None:
    """The strongest mismatch window of ``signal`` (peak over threshold × duration), widened
    to show what comes before and after it; None when there is none."""
    ws = [m for m in d.mismatch if m.signal == signal]
    if not ws:
        return None
    m = max(ws, key=lambda m: m.peak_over_threshold * (m.t_end - m.t_start))
    pad = max(0.5 * (m.t_end - m.t_start), 0.1)
    t = d.recording.time
    return max(float(t[0]), m.t_start - pad), min(float(t[-1]), m.t_end + pad)


def zoom_figure(d: Diagnosis, signal: str, span: tuple[float, float]) -> bytes:
    """``signal`` within ``span``: recording, nominal, within data sheet and fitted."""
    t = d.recording.time
    sel = (t >= span[0]) & (t <= span[1])
    s = {k: v[sel] for k, v in _series(d, signal).items()}
    scale, unit, name = _scaled(d, signal, s["recording"])
    fig, (ax,) = _figure(5.4, 3.2)
    ax.plot(t[sel], s["recording"] / scale, lw=1.2, color=RECORDING, label="recording")
    ax.plot(t[sel], s["nominal"] / scale, lw=1.0, color=NOMINAL, label="nominal")
    ax.plot(t[sel], s["refit"] / scale, lw=0.9, color=REFIT, ls="--", label="within data sheet")
    ax.plot(t[sel], s["fitted"] / scale, lw=1.0, color=FITTED, label="fitted")
    _shade(d, signal, (ax,), *span)
    ax.set_xlim(*span)
    ax.set_ylabel(f"{name} ({unit})", fontsize=8)
    ax.set_xlabel("time (s)", fontsize=8)
    ax.legend(fontsize=7, framealpha=0.85)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.tick_params(labelsize=7)
    return _png(fig)


def _ranges(ax, ranges: Sequence[Range], unit: str, what: str) -> None:
    peak = max((max(abs(r.low), abs(r.high)) for r in ranges), default=0.0)
    scale, shown = prefix_for(unit, peak)
    for r in ranges:
        ax.bar(
            r.low / scale,
            r.rms_over_noise,
            width=(r.high - r.low) / scale,
            align="edge",
            color=UNEXPLAINED,
            alpha=0.55,
            edgecolor="k",
            lw=0.4,
        )
    ax.set_xlabel(f"{what} ({shown})", fontsize=8)
    ax.set_ylabel("residual RMS / noise", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, lw=0.3, alpha=0.5)


def where_figure(d: Diagnosis, w: Where) -> bytes | None:
    """Where ``w``'s residual stays above the noise: its RMS over the white noise in each
    speed and position range listed (ranges within 3× the noise are left out)."""
    if not (w.speed_ranges or w.position_ranges):
        return None
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 2.6), dpi=96, layout="constrained")
    ax_v, ax_x = fig.subplots(1, 2, squeeze=True)
    pos = d.nominal.load_unit
    _ranges(ax_v, w.speed_ranges, f"{pos}/s", "load speed")
    _ranges(ax_x, w.position_ranges, pos, "load position")
    fig.suptitle(f"{signal_label(d, w.signal)[0]}: where the fitted model misses", fontsize=9)
    return _png(fig)


def plot_report(d: Diagnosis, path: str | Path) -> None:
    """``report.png``: per signal the recording, the nominal and the fitted simulation
    (upper panel) and the residuals of the nominal, the re-fitted nominal and the fitted
    model (lower panel); every axis with its unit, mismatch windows shaded."""
    signals = list(d.fit_before)
    t = d.recording.time
    fig, axes = _figure(13.0, 2.8 * 2 * len(signals), rows=2 * len(signals))
    fig.set_dpi(90)
    for i, sig in enumerate(signals):
        s = _series(d, sig)
        scale, unit, name = _scaled(d, sig, s["recording"])
        ax, axr = axes[2 * i], axes[2 * i + 1]
        ax.plot(*envelope(t, s["recording"] / scale), lw=0.6, color=RECORDING, label="recording")
        ax.plot(
            *envelope(t, s["nominal"] / scale),
            lw=0.8,
            color=NOMINAL,
            label=f"nominal, fit {d.fit_before[sig].fit_percent:.1f} %",
        )
        ax.plot(
            *envelope(t, s["fitted"] / scale),
            lw=0.8,
            color=FITTED,
            label=f"fitted, fit {d.fit_after[sig].fit_percent:.1f} %",
        )
        ax.set_ylabel(f"{name}\n({unit})", fontsize=9)
        res = {k: s["recording"] - s[k] for k in ("nominal", "refit", "fitted")}
        rscale, runit, _ = _scaled(d, sig, *res.values())
        axr.plot(
            *envelope(t, res["nominal"] / rscale),
            lw=0.4,
            color=NOMINAL,
            alpha=0.5,
            label="recording − nominal",
        )
        axr.plot(
            *envelope(t, res["refit"] / rscale),
            lw=0.5,
            color=REFIT,
            label="recording − nominal within data sheet",
        )
        axr.plot(
            *envelope(t, res["fitted"] / rscale), lw=0.5, color=FITTED, label="recording − fitted"
        )
        axr.axhline(0.0, color="k", lw=0.5)
        axr.set_ylabel(f"residual\n({runit})", fontsize=9)
        extra = _shade(d, sig, (ax, axr))
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
    named = ", ".join(effect_name(e) for e in d.left_out) or "nothing"
    verdict = "" if d.adequacy.adequate else " — the model class does not explain the recording"
    fig.suptitle(f"Diagnosis: left out {named}{verdict}", fontsize=11)
    with replacing(Path(path)) as tmp:  # a kill leaves the old figure or the new one
        fig.savefig(tmp, dpi=90, format=Path(path).suffix[1:])

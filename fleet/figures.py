"""Figures a maintenance engineer would rather look at than read, and the HTML index.

* ``fig4_fleet.png``: the paper's Fig. 4 for the fleet: vibration frequency of every episode
  against its axis' k_v, with eq. 13's band k_v/4 <= f <= k_v;
* ``trends.png``: backlash over the recordings' dates for the most urgent axes (the ranked
  list's top 12), fitted growth line, warned axes in red;
* ``index.html``: the limits the axes were judged against, the ranked list of axes to
  inspect, links to figures and tables, the files that could not be read.

A figure with nothing to draw (no vibration episode; no recording with a backlash estimate,
i.e. without reversals measured by both systems) is not written: the page says why instead of
showing empty axes.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cmdline.quantity import quantity
from virtual_bus.atomic import replacing, write_atomic

from .analyse import RecordingResult
from .episodes import Verdict
from .ranking import DAYS_PER_MONTH, AxisTrend, Limits

TREND_PANELS = 12


def _unit_scale(unit: str) -> tuple[float, str]:
    return (1e6, "µm") if unit == "m" else (1e6, "µrad") if unit == "rad" else (1.0, unit)


def has_episodes(results: Sequence[RecordingResult]) -> bool:
    """Whether :func:`fig4_fleet` has a point to draw."""
    return any(r.episodes for r in results)


def trend_axes(ranked: Sequence[AxisTrend]) -> list[AxisTrend]:
    """The axes :func:`trends_figure` draws: the most urgent with at least one dated backlash
    (or lost motion) estimate."""
    return [
        t
        for t in ranked
        if any(r.date is not None and math.isfinite(t.measure(r)) for r in t.results)
    ][:TREND_PANELS]


def fig4_fleet(results: Sequence[RecordingResult], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0), constrained_layout=True)
    kvs = [r.kv_per_s for r in results if r.ok and math.isfinite(r.kv_per_s)]
    k_hi = max(kvs, default=50.0) * 1.15
    k = np.linspace(0.0, k_hi, 50)
    ax.fill_between(
        k, k / 4.0, k, color="tab:green", alpha=0.12, label="eq. 13 band  k_v/4 ≤ f ≤ k_v"
    )
    ax.plot(k, k / 4.0, color="tab:green", lw=0.8)
    ax.plot(k, k, color="tab:green", lw=0.8)
    for verdict, color, label in (
        (Verdict.IN_BAND, "tab:red", "episode in band (backlash limit cycle)"),
        (Verdict.OUTSIDE_BAND, "tab:blue", "episode outside band"),
    ):
        xs = [r.kv_per_s for r in results for e in r.episodes if e.verdict is verdict]
        ys = [e.frequency_hz for r in results for e in r.episodes if e.verdict is verdict]
        if xs:
            ax.scatter(xs, ys, s=18, color=color, label=f"{label} ({len(xs)})", zorder=3)
    ax.set_xlabel("position gain k_v (1/s)")
    ax.set_ylabel("vibration frequency f (Hz)")
    f_all = [e.frequency_hz for r in results for e in r.episodes]
    ax.set_xlim(0.0, k_hi)
    ax.set_ylim(0.0, max([k_hi * 1.1, *(f * 1.05 for f in f_all)]))
    ax.set_title("Fleet vibration frequency against k_v (the paper's Fig. 4)")
    ax.legend(loc="upper left", fontsize=9, framealpha=0.9)
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix[1:])
    plt.close(fig)
    return path


def trends_figure(ranked: Sequence[AxisTrend], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = trend_axes(ranked)
    cols = 3
    rows = max(1, math.ceil(len(shown) / cols))
    fig, axes = plt.subplots(
        rows, cols, figsize=(4.0 * cols, 2.6 * rows), squeeze=False, constrained_layout=True
    )
    for ax in axes.flat[len(shown) :]:
        ax.axis("off")
    for ax, t in zip(axes.flat, shown, strict=False):
        dated = [r for r in t.results if r.date is not None and math.isfinite(t.measure(r))]
        scale, unit = _unit_scale(dated[0].load_unit if dated else "m")
        dates = [r.date for r in dated]
        values = np.array([t.measure(r) for r in dated]) * scale
        color = "tab:red" if t.growth_warning else "tab:gray"
        ax.plot(dates, values, "o-", color=color, ms=3, lw=1)
        if math.isfinite(t.growth_per_month) and len(dated) >= 2:
            d0 = dates[0]
            months = np.array([(d - d0).total_seconds() / 86400 / DAYS_PER_MONTH for d in dates])
            fit = values.mean() + t.growth_per_month * scale * (months - months.mean())
            ax.plot(dates, fit, "--", color=color, lw=0.8)
        vib = [r.date for r in dated if r.verdict is Verdict.IN_BAND]
        if vib:
            top = values.max() + max(0.05 * np.ptp(values), 1.0)
            ax.scatter(
                vib,
                [top] * len(vib),
                marker="v",
                color="tab:orange",
                s=14,
                label="vibrates in band",
            )
            ax.legend(loc="lower right", fontsize=7)
        growth = (
            f"{_signed(t.growth_per_month, dated[0].load_unit)}/month"
            if math.isfinite(t.growth_per_month)
            else "no trend"
        )
        ax.set_title(f"{t.axis_id}: {growth}", fontsize=9, color=color)
        ax.set_ylabel(f"backlash ({unit})", fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False)
        if values.size:
            mid, half = 0.5 * (values.max() + values.min()), 0.5 * np.ptp(values)
            half = max(half * 1.15, 2.0)  # a flat trend is drawn flat, not as noise
            ax.set_ylim(mid - half, mid + half * (1.12 if vib else 1.0))
        ax.tick_params(labelsize=7)
        for label in ax.get_xticklabels():
            label.set_rotation(30)
    fig.suptitle(f"Backlash trend of the {len(shown)} most urgent axes (ranked)", fontsize=11)
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=100, format=path.suffix[1:])
    plt.close(fig)
    return path


def _signed(value: float, unit: str, like: float | None = None) -> str:
    """'+2.41 µm', '−30 nm', '0 µm' (never '-0.00')."""
    text = quantity(value, unit, like=like)
    return text if text.startswith(("−", "0 ")) else "+" + text


def _growth(t: AxisTrend, unit: str) -> str:
    if not math.isfinite(t.growth_per_month):
        return "–"
    sigma = quantity(t.growth_sigma, unit, like=t.growth_per_month)
    return f"{_signed(t.growth_per_month, unit, like=t.growth_sigma)} ± {sigma} per month"


def index_html(
    ranked: Sequence[AxisTrend],
    results: Sequence[RecordingResult],
    files: Sequence[Path],
    path: Path,
    limits: Limits | None = None,
) -> Path:
    limits = limits or Limits()
    bad = [r for r in results if not r.ok]
    ok = [r for r in results if r.ok]
    rows = []
    for i, t in enumerate(ranked, 1):
        latest = t.latest
        load_unit = latest.load_unit if latest else "m"
        measure = t.measure(latest) if latest else math.nan
        rows.append(
            "<tr{cls}><td>{i}</td><td>{a}</td><td>{n}</td><td>{b}</td><td>{g}</td>"
            "<td>{f}</td><td>{reasons}</td></tr>".format(
                cls=' class="warn"' if t.reasons else "",
                i=i,
                a=html.escape(t.axis_id),
                n=len(t.results),
                b=quantity(measure, load_unit) if math.isfinite(measure) else "–",
                g=_growth(t, load_unit),
                f=f"{t.median_frequency_hz:.1f} Hz"
                if math.isfinite(t.median_frequency_hz)
                else "–",
                reasons=html.escape("; ".join(t.reasons)) or "ok",
            )
        )
    links = "".join(
        f'<li><a href="{html.escape(p.name)}">{html.escape(p.name)}</a></li>' for p in files
    )
    names = {p.name for p in files}
    figures = []
    if "fig4_fleet.png" in names:
        figures.append('<p><img src="fig4_fleet.png" alt="Fig. 4 of the fleet"></p>')
    else:
        figures.append(
            "<p>No vibration episode in any recording: no Fig. 4 of the fleet to draw.</p>"
        )
    if "trends.png" in names:
        figures.append('<p><img src="trends.png" alt="backlash trends"></p>')
    else:
        figures.append(
            "<p>No backlash trend to draw: no dated recording has a backlash estimate (it "
            "needs reversals measured by both the motor and the load measuring system).</p>"
        )
    unit = ok[0].load_unit if ok else "m"
    rotary = " (µrad on a rotary axis)" if unit == "m" else ""
    judged = (
        "<ul>"
        f"<li>backlash limit: {quantity(limits.backlash, unit)}{rotary} "
        "(<code>--backlash-limit</code>): an axis whose latest backlash is larger is "
        "listed;</li>"
        f"<li>growth limit: {quantity(limits.growth_per_month, unit)}/month{rotary} "
        "(<code>--growth-limit</code>): an axis whose backlash grows faster, the least-squares "
        "slope over at least 3 dated recordings, 2σ above zero, is listed;</li>"
        "<li>vibration: an episode of the paper's detector (Fig. 5) whose frequency lies in "
        "eq. 13's band k_v/4 ≤ f ≤ k_v of its axis file, in the latest recording of an "
        "axis.</li></ul>"
    )
    bad_rows = "".join(f"<li><code>{html.escape(r.error)}</code></li>" for r in bad)
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>Fleet condition monitoring</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 72em; }}
table {{ border-collapse: collapse; }} td, th {{ border: 1px solid #ccc; padding: 3px 8px; }}
tr.warn td {{ background: #fde8e6; }} img {{ max-width: 100%; border: 1px solid #ddd; }}
</style></head><body>
<h1>Fleet condition monitoring</h1>
<p>{len(ok)} recordings of {len(ranked)} axes analysed, {len(bad)} could not be read.
Vibration episodes: the paper's detector (Fig. 5) run over each recording; band verdict:
eq. 13 (k_v/4 ≤ f ≤ k_v); backlash: lost motion at reversals less the elastic wind-up.</p>
<h2>Judged against</h2>
{judged}
<h2>Axes to inspect first</h2>
<table><tr><th>rank</th><th>axis</th><th>recordings</th><th>latest backlash</th>
<th>growth</th><th>vibration</th><th>reasons</th></tr>
{"".join(rows)}
</table>
<h2>Figures</h2>
{"".join(figures)}
<h2>Files</h2><ul>{links}</ul>
<h2>Recordings that could not be read</h2><ul>{bad_rows or "<li>none</li>"}</ul>
</body></html>
"""
    write_atomic(path, page)
    return path

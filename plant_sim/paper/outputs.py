"""Figures and summary of the section X reproduction (Fig. 8, Fig. 9), shared by
``python -m plant_sim paper`` and ``python -m hil demo`` (which runs the same scenario over
the bus): one place computes the metrics and draws the panels.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from regulator.analysis import condition_monitoring, vibration_band_hz
from virtual_bus.atomic import replacing, write_atomic
from virtual_bus.formats.axis import AxisConfig, dump_axis
from virtual_bus.formats.trace import Trace

from .scenarios import P2P_START_S, SectionX

#: A vibration whose FFT amplitude in the following error is below this fraction of the total
#: backlash δ is "none" (a backlash limit cycle has an amplitude of the order of δ/2: the sweep
#: measures 0.45–0.68·δ in the vibrating cells and at most 0.01·δ elsewhere) ...
VIBRATION_FLOOR_OF_BACKLASH = 0.05
#: ... and never below this absolute floor (load units), for axes without backlash.
VIBRATION_FLOOR = 1e-6
#: The frequency analysis starts this long after the disturbance ends (its transient).
SETTLE_AFTER_DISTURBANCE_S = 0.25


@dataclass(frozen=True)
class RunSummary:
    """Per run of section X (the numbers the issue asks for; SI units)."""

    dominant_frequency_hz: float | None  # after the disturbance; None: no vibration
    vibration_amplitude: float  # load units, FFT amplitude of the following error there
    in_band: bool  # dominant frequency inside eq. 13's band
    p2p_following_error: float  # load units, over [P2P_START_S, stop)
    final_standstill_error: float  # load units, |x_ref - x_l| at the end of the run
    max_beta_rad_s: float
    min_lambda: float


def p2p_window(scenario: SectionX = SectionX()) -> tuple[float, float]:
    """The window of the peak-to-peak following error, s: [P2P_START_S, stop). One window for
    summary.json's ``p2p_following_error``, the figures' zoom A' and its title."""
    return P2P_START_S, scenario.stop_s


def frequency_window(scenario: SectionX = SectionX()) -> tuple[float, float]:
    """The window of the frequency analysis, s: from SETTLE_AFTER_DISTURBANCE_S after the
    disturbance to the stop of the interpolator."""
    return scenario.disturbance_end_s + SETTLE_AFTER_DISTURBANCE_S, scenario.stop_s


def p2p_window_mask(t: np.ndarray, scenario: SectionX = SectionX()) -> np.ndarray:
    start, end = p2p_window(scenario)
    return (t >= start) & (t < end)


def summarize(trace: Trace, axis: AxisConfig, scenario: SectionX = SectionX()) -> RunSummary:
    """Metrics of one section X run from its trace."""
    t = trace.time
    e = trace["position_reference"] - trace["load_position"]
    cycle = axis.control.position_cycle
    f0, f1 = frequency_window(scenario)
    after = (t >= f0) & (t < f1)
    # below half the band's lower edge (k_v/8) lies drift (the error returning to eq. 1), not
    # vibration
    verdict = condition_monitoring(e[after], cycle, axis.control.kv, f_min_hz=axis.control.kv / 8)
    floor = max(VIBRATION_FLOOR, VIBRATION_FLOOR_OF_BACKLASH * (axis.mechanics.backlash or 0.0))
    vibrating = verdict.amplitude >= floor and not math.isnan(verdict.frequency_hz)
    p2p = p2p_window_mask(t, scenario)
    return RunSummary(
        dominant_frequency_hz=verdict.frequency_hz if vibrating else None,
        vibration_amplitude=verdict.amplitude,
        in_band=vibrating and verdict.in_band,
        p2p_following_error=float(np.ptp(e[p2p])),
        final_standstill_error=float(abs(e[-1])),
        max_beta_rad_s=float(np.max(trace["beta"])),
        min_lambda=float(np.min(trace["lambda"])),
    )


def plot_section_x(
    trace: Trace,
    axis: AxisConfig,
    path: Path,
    title: str,
    with_lambda: bool,
    scenario: SectionX = SectionX(),
    note: str | None = None,
) -> str:
    """Fig. 8 / Fig. 9 panels: A following errors (eq. 1 vs load vs motor) over the run,
    A' the same zoomed onto the time after the disturbance (where the limit cycle lives, µm),
    B disturbance torque, C vibration level β, D switching factor λ (regulated run).
    ``note``: what differs from the paper, written under the title. Returns the zoom's title
    (it states the window and the peak-to-peak of summary.json)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = trace.time
    kr, kv = axis.transmission_ratio, axis.control.kv
    x_ref = trace["position_reference"]
    eq1 = trace["omega_s"] / (kr * kv) if "omega_s" in trace else np.gradient(x_ref, t) / kv
    e_load = x_ref - trace["load_position"]
    e_motor = x_ref - trace["motor_position"] / kr
    unit = "mm" if axis.load_unit == "m" else "mrad"
    fine = "µm" if axis.load_unit == "m" else "µrad"
    n_panels = 5 if with_lambda else 4
    heights = [1.3, 1.3, 0.8, 0.8] + ([0.6] if with_lambda else [])
    fig, axes = plt.subplots(
        n_panels, 1, figsize=(9, 1.75 * sum(heights) + 1.6), height_ratios=heights
    )
    a = axes[0]
    a.plot(t, e_load * 1e3, lw=0.8, label="load following error $x_{ref}-x_l$")
    a.plot(
        t, e_motor * 1e3, lw=0.8, alpha=0.8, label=r"motor following error $x_{ref}-\theta_m/k_r$"
    )
    a.plot(t, eq1 * 1e3, "k--", lw=1.0, label="eq. 1: speed / $k_v$")
    a.set_ylabel(f"A  error [{unit}]")
    # legend above the panel: it covers no data
    a.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize=7, frameon=False)
    z0, z1 = p2p_window(scenario)
    # drawn up to two position cycles before the interpolator stops (eq. 1 drops to 0 there);
    # the peak-to-peak in the title is summary.json's, over the whole window
    zoom = (t >= z0) & (t < z1 - 2 * axis.control.position_cycle)
    a.axvspan(z0, z1, color="0.92", zorder=0)
    a.annotate("A'", xy=((z0 + z1) / 2, 0.02), xycoords=("data", "axes fraction"), fontsize=8)
    z = axes[1]
    z.plot(t[zoom], e_load[zoom] * 1e6, lw=0.8, color="C0")
    z.plot(t[zoom], e_motor[zoom] * 1e6, lw=0.8, alpha=0.8, color="C1")
    z.plot(t[zoom], eq1[zoom] * 1e6, "k--", lw=1.0)
    shown = np.concatenate([e_load[zoom], e_motor[zoom]]) * 1e6
    lo, hi = float(shown.min()), float(shown.max())
    pad = 0.15 * (hi - lo) + 1e-3
    z.set_ylim(lo - pad, hi + pad)
    z.set_xlim(z0, z1)
    z.set_ylabel(f"A' error [{fine}]")
    p2p = float(np.ptp(e_load[p2p_window_mask(t, scenario)])) * 1e6
    zoom_title = (
        f"A' zoom on {z0:g}–{z1:g} s (shaded in A): load following error peak-to-peak "
        f"{p2p:.3g} {fine} (summary.json's p2p_following_error)"
    )
    z.set_title(zoom_title, fontsize=8, loc="left")
    axes[2].plot(t, trace["disturbance"], color="C3", lw=1.0)
    axes[2].set_ylabel("B  disturbance\n[N m at motor]")
    axes[3].plot(t, trace["beta"], color="C2", lw=1.0)
    axes[3].set_ylabel(r"C  $\beta$ [rad/s]")
    if with_lambda:
        axes[4].plot(t, trace["lambda"], color="C4", lw=1.0)
        axes[4].set_ylabel(r"D  $\lambda$ [1]")
        axes[4].set_ylim(-0.05, 1.05)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("time [s]", fontsize=8)
    for ax in (axes[0], *axes[2:]):
        ax.set_xlim(t[0], t[-1])
    fig.suptitle(title, fontsize=10)
    if note:
        fig.text(0.5, 0.005, note, ha="center", va="bottom", fontsize=7.5, color="C3", wrap=True)
    fig.tight_layout(rect=(0, 0.035 if note else 0, 1, 1))
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix[1:])
    plt.close(fig)
    return zoom_title


def changes_note(axis_file: str, changes: Mapping[str, float] | None) -> str | None:
    """One sentence for a figure: which values differ from the axis file (the paper's)."""
    if not changes:
        return None
    what = ", ".join(f"{k} = {v:g}" for k, v in changes.items())
    name = Path(axis_file).name
    return (
        f"Changed from the paper ({name}): {what} N m s/m (the paper's 57.3 damps the limit "
        "cycle out: no vibration; docs/paper_reproduction.md)"
        if set(changes) == {"friction.viscous"}
        else f"Changed from {name}: {what}"
    )


def write_paper_outputs(
    out_dir: Path,
    runs: Mapping[str, Trace],
    axis: AxisConfig,
    scenario: SectionX = SectionX(),
    extra: Mapping[str, object] | None = None,
) -> dict[str, object]:
    """Write fig8.png (run "ordinary"), fig9.png (run "regulated"), each run's CSV and
    summary.json; returns the summary. ``extra`` is merged into summary.json."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary: dict[str, object] = {
        "band_hz": list(vibration_band_hz(axis.control.kv)),
        "kv_per_s": axis.control.kv,
        "load_unit": axis.load_unit,
        "backlash": axis.mechanics.backlash,
        "scenario": asdict(scenario),
        "p2p_window_s": list(p2p_window(scenario)),
        "frequency_window_s": list(frequency_window(scenario)),
        "runs": {},
    }
    figures = {"ordinary": ("fig8.png", False), "regulated": ("fig9.png", True)}
    titles = {
        "ordinary": "Fig. 8: ordinary control (Fig. 1), no regulator",
        "regulated": "Fig. 9: with the speed regulator (Fig. 6, eq. 15)",
    }
    extra = dict(extra or {})
    changes = extra.get("figures_axis_changes")
    note = changes_note(
        str(extra.get("axis_file", "the axis file")),
        changes if isinstance(changes, Mapping) else None,
    )
    files = [str(f) for f in extra.pop("files_written", [])]
    for name, trace in runs.items():
        trace.to_csv(out_dir / f"{name}.csv")
        files.append(f"{name}.csv")
        summary["runs"][name] = asdict(summarize(trace, axis, scenario))  # type: ignore[index]
        if name in figures:
            fig, with_lambda = figures[name]
            title = titles[name]
            if changes:
                title += " — " + ", ".join(f"{k} = {v:g}" for k, v in changes.items())
                if set(changes) == {"friction.viscous"}:
                    title += " N m s/m, not the paper's 57.3"
            plot_section_x(trace, axis, out_dir / fig, title, with_lambda, scenario, note)
            files.append(fig)
    runs_summary = summary["runs"]
    if isinstance(runs_summary, dict) and {"ordinary", "regulated"} <= runs_summary.keys():
        before = runs_summary["ordinary"]["p2p_following_error"]
        after = runs_summary["regulated"]["p2p_following_error"]
        summary["p2p_reduction"] = 1.0 - after / before if before > 0 else None
    summary.update(extra)
    files.append("summary.json")
    summary["files"] = sorted(set(files))
    write_atomic(out_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def files_line(out_dir: Path, summary: Mapping[str, object]) -> str:
    """The one summary line of what a command wrote: ``wrote DIR/: a, b, c``."""
    names = summary.get("files", [])
    listed = ", ".join(str(n) for n in names) if isinstance(names, list) else ""
    return f"wrote {out_dir}/: {listed}"


def write_as_given(out_dir: Path, runs: Mapping[str, Trace]) -> tuple[list[str], str]:
    """Write the runs of the axis as given: ``as_given_{run}.csv``, or one ``as_given.csv``
    when the runs are identical -- with the paper's friction the ordinary run never vibrates,
    so β never reaches β_T, the regulator keeps λ = 1 and the regulated run is the ordinary
    one sample for sample. Returns the file names and a sentence saying which it was."""
    traces = list(runs.values())
    same = all(
        t.names == traces[0].names
        and all(np.array_equal(t[c], traces[0][c]) for c in traces[0].names)
        for t in traces[1:]
    )
    if same and len(traces) > 1:
        traces[0].to_csv(out_dir / "as_given.csv")
        return ["as_given.csv"], (
            "as_given.csv: the axis as given; its runs with and without the regulator are "
            "identical (no vibration, so beta stays below beta_T and lambda stays 1)"
        )
    names = []
    for name, trace in runs.items():
        trace.to_csv(out_dir / f"as_given_{name}.csv")
        names.append(f"as_given_{name}.csv")
    return names, "as_given_{run}.csv: the runs of the axis as given"


#: N·m per (m/s) at the motor: guideway viscous friction low enough for the limit cycle (the
#: paper's 57.3 damps it out; docs/paper_reproduction.md: sustained up to ~10, gone from ~15).
LIMIT_CYCLE_VISCOUS = 5.0


def limit_cycle_variant(
    axis: AxisConfig, published: Mapping[str, RunSummary], axis_name: str, out_dir: Path
) -> tuple[AxisConfig, dict[str, object]] | None:
    """The decision ``paper`` and ``hil demo`` share: if the ordinary run of the axis as
    given shows no sustained limit cycle, the figures are drawn from the same axis with
    ``friction.viscous = LIMIT_CYCLE_VISCOUS``. Returns that axis and the summary.json entries
    that record the decision (and writes ``axis_limit_cycle.toml``), or None to keep the axis.
    """
    if published["ordinary"].dominant_frequency_hz is not None:
        return None
    variant = axis.with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(  # listed in extra["files_written"]
        out_dir / "axis_limit_cycle.toml",
        dump_axis(variant, f"{axis_name} with friction.viscous = {LIMIT_CYCLE_VISCOUS}"),
    )
    extra: dict[str, object] = {
        "as_given": {name: asdict(s) for name, s in published.items()},
        "finding": (
            "With the axis as given the ordinary control shows no sustained limit cycle after "
            "the disturbance: the load's viscous friction damps it out "
            "(docs/paper_reproduction.md). Figures, traces and 'runs' are from the same axis "
            f"with friction.viscous = {LIMIT_CYCLE_VISCOUS} N m s/m."
        ),
        "figures_axis_changes": {"friction.viscous": LIMIT_CYCLE_VISCOUS},
        "files_written": ["axis_limit_cycle.toml"],
    }
    return variant, extra

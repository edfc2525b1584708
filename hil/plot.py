"""The figure of one servo trace (``docs/trace-file.md``): what ``python -m hil plot`` draws.

Panels, each in the user's units (positions in mm or rad, errors in µm or mrad) with the unit
in every axis label and title: the positions (reference, load, motor / k_r), the following
error (reference − load; reference − motor / k_r on an axis without a load measuring
system), the deflection between the two measuring systems (motor / k_r − load, the
difference commissioning step 5 asks for), the motor torque, the motor speed, β and λ
(eq. 15), and the amplitude spectrum of the following error with eq. 13's band
f = k_v/4 .. k_v (Hz, k_v in 1/s) marked when the axis file gives k_v.

A panel whose columns the trace lacks is left out (nothing rather than empty axes). The
HTML page is self-contained: the PNG embedded as base64 and a table of every panel's data
range, no external URL.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from virtual_bus.atomic import replacing
from virtual_bus.formats.trace import Trace


@dataclass(frozen=True)
class Units:
    """How load units are shown: ``position`` (mm or rad) and ``error`` (µm or mrad)."""

    position: str
    position_scale: float  # shown value = load units * scale
    error: str
    error_scale: float

    @classmethod
    def of(cls, load_unit: str) -> Units:
        if load_unit == "m":
            return cls("mm", 1e3, "µm", 1e6)
        return cls("rad", 1.0, "mrad", 1e3)


@dataclass(frozen=True)
class Curve:
    label: str
    values: np.ndarray  # in the panel's unit


@dataclass(frozen=True)
class Panel:
    """One plot: its title and y label (both with the unit), its x quantity and curves."""

    title: str
    ylabel: str
    x: np.ndarray
    xlabel: str
    curves: tuple[Curve, ...]
    band_hz: tuple[float, float] | None = None  # eq. 13's band, shaded on a spectrum

    def range_text(self) -> str:
        lo = min(float(np.min(c.values)) for c in self.curves)
        hi = max(float(np.max(c.values)) for c in self.curves)
        unit = self.ylabel.rsplit(", ", 1)[-1]
        return f"{lo:.6g} .. {hi:.6g} {unit}"


@dataclass(frozen=True)
class PlotSetup:
    """What the trace alone does not say: k_r (motor rad per load unit), k_v (1/s) and the
    load unit (``m`` or ``rad``), from the axis file when one is given."""

    load_unit: str = "m"
    transmission_ratio: float | None = None
    kv_per_s: float | None = None


def _p2p(values: np.ndarray) -> float:
    return float(np.max(values) - np.min(values))


def spectrum(time_s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-sided amplitude spectrum (Hz, amplitude in the values' unit) of a signal on its
    mean sample time (a trace's time base is uniform up to jitter), mean removed, Hann
    window with its coherent gain divided out, so a sine of amplitude A shows as A."""
    n = len(values)
    dt = float(time_s[-1] - time_s[0]) / (n - 1)
    window = np.hanning(n)
    amp = np.abs(np.fft.rfft((values - np.mean(values)) * window)) * 2.0 / np.sum(window)
    return np.fft.rfftfreq(n, dt), amp


def panels(trace: Trace, setup: PlotSetup) -> list[Panel]:
    """The panels this trace can fill (module docstring)."""
    cols = trace.columns
    units = Units.of(setup.load_unit)
    t = cols["time"]
    time_label = "time, s"
    kr = setup.transmission_ratio
    out: list[Panel] = []
    motor_load = cols["motor_position"] / kr if kr else None  # load units
    position_curves = []
    if "position_reference" in cols:
        position_curves.append(
            Curve("reference", cols["position_reference"] * units.position_scale)
        )
    if "load_position" in cols:
        position_curves.append(Curve("load", cols["load_position"] * units.position_scale))
    if motor_load is not None:
        position_curves.append(Curve("motor / k_r", motor_load * units.position_scale))
    if position_curves:
        out.append(
            Panel(
                f"positions, {units.position}",
                f"position, {units.position}",
                t,
                time_label,
                tuple(position_curves),
            )
        )
    else:  # no k_r and no load scale: the motor position in its own unit
        out.append(
            Panel(
                "motor position, rad (motor)",
                "motor position, rad (motor)",
                t,
                time_label,
                (Curve("motor", cols["motor_position"]),),
            )
        )
    measured = cols.get("load_position", motor_load)
    error = None
    if "position_reference" in cols and measured is not None:
        error = (cols["position_reference"] - measured) * units.error_scale
        which = "load" if "load_position" in cols else "motor / k_r"
        out.append(
            Panel(
                f"following error (reference − {which}), {units.error}: "
                f"p2p {_p2p(error):.4g} {units.error}",
                f"following error, {units.error}",
                t,
                time_label,
                (Curve("following error", error),),
            )
        )
    if motor_load is not None and "load_position" in cols:
        deflection = (motor_load - cols["load_position"]) * units.error_scale
        out.append(
            Panel(
                f"deflection motor / k_r − load, {units.error}: "
                f"p2p {_p2p(deflection):.4g} {units.error}",
                f"motor / k_r − load, {units.error}",
                t,
                time_label,
                (Curve("motor / k_r − load", deflection),),
            )
        )
    out.append(
        Panel(
            "motor torque, N m",
            "torque, N m",
            t,
            time_label,
            (Curve("motor torque", cols["motor_torque"]),),
        )
    )
    speeds = [
        Curve(name.replace("_", " "), cols[name])
        for name in ("speed_setpoint", "motor_speed")
        if name in cols
    ]
    if speeds:
        out.append(
            Panel("motor speed, rad/s", "speed, rad/s (motor)", t, time_label, tuple(speeds))
        )
    if "beta" in cols:
        out.append(
            Panel(
                "β, vibration level (eq. 15), rad/s",
                "β, rad/s",
                t,
                time_label,
                (Curve("β", cols["beta"]),),
            )
        )
    if "lambda" in cols:
        out.append(
            Panel(
                "λ, switching factor (eq. 15), 1",
                "λ, 1",
                t,
                time_label,
                (Curve("λ", cols["lambda"]),),
            )
        )
    if error is not None:
        freq, amp = spectrum(t, error)
        band = (setup.kv_per_s / 4.0, setup.kv_per_s) if setup.kv_per_s else None
        title = f"following error spectrum, {units.error}"
        if band is not None:
            title += f" (eq. 13 band {band[0]:.3g}..{band[1]:.3g} Hz shaded)"
        out.append(
            Panel(
                title,
                f"amplitude, {units.error}",
                freq[1:],
                "frequency, Hz",
                (Curve("|FFT|", amp[1:]),),
                band,
            )
        )
    return out


def figure(plots: Sequence[Panel], title: str):  # -> matplotlib.figure.Figure
    """The panels one above the other (matplotlib, Agg: no display needed)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 2.3 * len(plots) + 0.6), layout="constrained")
    fig.suptitle(title)
    axes = fig.subplots(len(plots), 1, squeeze=False)[:, 0]
    for ax, p in zip(axes, plots, strict=True):
        for c in p.curves:
            ax.plot(p.x, c.values, lw=0.8, label=c.label)
        if p.band_hz is not None:
            ax.axvspan(*p.band_hz, color="0.85", zorder=0, label="eq. 13 band k_v/4..k_v")
            ax.set_xlim(0.0, min(float(p.x[-1]), 4.0 * p.band_hz[1]))
        ax.set_title(p.title, fontsize=9)
        ax.set_ylabel(p.ylabel, fontsize=8)
        ax.set_xlabel(p.xlabel, fontsize=8)
        ax.grid(True, lw=0.3)
        if len(p.curves) > 1 or p.band_hz is not None:
            ax.legend(fontsize=7, loc="upper right")
    return fig


def write(plots: Sequence[Panel], title: str, png: Path, page: Path) -> None:
    """The PNG and the self-contained HTML page (the same PNG inline, a range table)."""
    fig = figure(plots, title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    data = buf.getvalue()
    with replacing(png) as tmp:
        tmp.write_bytes(data)
    rows = "\n".join(
        f"<tr><td>{html.escape(p.title)}</td><td>{html.escape(p.range_text())}</td></tr>"
        for p in plots
    )
    doc = (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title></head><body>\n"
        f"<h1>{html.escape(title)}</h1>\n"
        f"<img alt='trace plot' src='data:image/png;base64,{base64.b64encode(data).decode()}'>\n"
        "<table border='1'><tr><th>panel</th><th>data range</th></tr>\n"
        f"{rows}\n</table>\n</body></html>\n"
    )
    with replacing(page) as tmp:
        tmp.write_text(doc, encoding="utf-8")

"""The circular test's polar plot: the radial deviation, magnified, around the nominal circle
(as a ballbar's software draws it). matplotlib is imported only when a figure is drawn (Agg
backend, files only): a bridge-only install writes the reports and says it drew nothing."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from virtual_bus.atomic import replacing

from .ballbar import BallbarReport, MeasuredPath
from .circular import CircularTest, Direction

_COLOURS = {Direction.CCW: "tab:blue", Direction.CW: "tab:red"}


@dataclass(frozen=True)
class PolarPanel:
    """One polar plot: its title, the test, both directions' paths and their report."""

    title: str
    test: CircularTest
    paths: Sequence[MeasuredPath]
    report: BallbarReport


def available() -> bool:
    import importlib.util

    return importlib.util.find_spec("matplotlib") is not None


def radial_deviation(test: CircularTest, path: MeasuredPath) -> tuple[np.ndarray, np.ndarray]:
    """Angle (rad, about the commanded centre) and radial deviation (load units) of a path."""
    cx, cy = test.centre
    return (
        np.arctan2(path.y - cy, path.x - cx),
        np.hypot(path.x - cx, path.y - cy) - test.radius,
    )


def polar_figure(panels: Sequence[PolarPanel], path: Path, suptitle: str = "") -> None:
    """One magnified polar plot per panel, side by side, each on its own scale (µm, on the
    radial grid) so that each shape shows; the titles give each panel's G(b)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    um = 1e6
    cols = len(panels)
    fig = plt.figure(figsize=(4.2 * cols, 4.9))
    for i, panel in enumerate(panels, start=1):
        ax = fig.add_subplot(1, cols, i, projection="polar")
        devs = [float(np.max(np.abs(radial_deviation(panel.test, q)[1]))) * um for q in panel.paths]
        span = _nice(max([*devs, 1.0]))
        base = 2.0 * span  # the nominal circle sits here; the centre is -2 spans
        grid = np.linspace(0, 2 * math.pi, 721)
        ax.plot(grid, np.full(grid.size, base), color="0.4", lw=0.8, ls="--")
        for p in panel.paths:
            a, dr = radial_deviation(panel.test, p)
            ax.plot(a, base + dr * um, lw=0.9, color=_COLOURS[p.direction], label=p.direction.label)
        ticks = np.arange(-span, span + 0.5 * span, span / 2)
        ax.set_rgrids(base + ticks, [f"{t:+g}" for t in ticks], fontsize=7, color="0.3")
        ax.set_ylim(0, base + span)
        ax.set_thetagrids(range(0, 360, 45), fontsize=8)
        r = panel.report
        ax.set_title(
            f"{panel.title}\nG(b) = {r.contour_error * um:.1f} µm",
            fontsize=10,
        )
        if i == 1:
            ax.legend(loc="lower left", bbox_to_anchor=(-0.15, -0.18), fontsize=7, frameon=False)
    test = panels[0].test
    head = suptitle or (
        f"circular test R = {test.radius * 1e3:g} mm, F = {test.feed * 6e4:g} mm/min; "
        "radial deviation in µm about the nominal circle (dashed)"
    )
    fig.suptitle(head, fontsize=10)
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def _nice(value: float) -> float:
    """The next of 1, 2, 5 × 10^k at or above ``value``."""
    k = 10 ** math.floor(math.log10(value))
    for m in (1, 2, 5, 10):
        if m * k >= value:
            return m * k
    return 10 * k

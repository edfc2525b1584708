"""``python -m plant_sim sweep --out DIR``: vibration frequency over k_v and δ.

Tests the paper's claims (section VI, eq. 12-13): the limit-cycle frequency lies in the band
k_v/4..k_v, is proportional to k_v, and does not depend on the backlash δ. Every cell runs
section X with the ordinary control and measures the dominant frequency of the following
error after the disturbance (plant_sim.paper.outputs.summarize). Writes sweep.csv, sweep.md (the
table and the verdicts), sweep.png and sweep.json.
"""

from __future__ import annotations

import argparse
import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cmdline import cli
from cmdline.progress import Progress, silent
from virtual_bus.atomic import replacing, write_atomic
from virtual_bus.formats.axis import AxisConfig

from ..paper.outputs import LIMIT_CYCLE_VISCOUS, summarize
from ..paper.scenarios import SectionX, run_section_x
from .common import add_axis_argument, read_axis

NAME = "sweep"
HELP = "vibration frequency over k_v and backlash: band, proportionality, independence of δ"

DEFAULT_KV = (15.0, 20.0, 25.0, 30.0, 40.0, 50.0)
DEFAULT_BACKLASH_MM = (0.05, 0.1, 0.2, 0.4)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_output_dir(parser)
    add_axis_argument(parser)
    cli.number_list(parser, "--kv", DEFAULT_KV, "k_v values, 1/s")
    cli.number_list(parser, "--backlash-mm", DEFAULT_BACKLASH_MM, "δ values, mm")
    parser.add_argument(
        "--viscous",
        type=cli.bounded_float(0.0, 1e9),
        default=LIMIT_CYCLE_VISCOUS,
        metavar="B",
        help="friction.viscous for the sweep (N m s/m; default: the limit-cycle variant of "
        "`paper`, not the paper's 57.3; give the axis file's own value to sweep it as is)",
    )
    cli.add_quiet(parser)


@dataclass(frozen=True)
class Cell:
    kv: float
    backlash_m: float
    frequency_hz: float | None
    amplitude_m: float

    @property
    def in_band(self) -> bool:
        return self.frequency_hz is not None and self.kv / 4 <= self.frequency_hz <= self.kv


def sweep(
    axis: AxisConfig,
    kvs: tuple[float, ...],
    backlash_m: tuple[float, ...],
    progress: Progress | None = None,
) -> list[Cell]:
    progress = progress or silent()
    cells = []
    with progress.bar(len(kvs) * len(backlash_m), "section X per (k_v, δ)", unit="cell") as bar:
        for kv in kvs:
            for delta in backlash_m:
                variant = axis.with_values({"control.kv": kv, "mechanics.backlash": delta})
                s = summarize(run_section_x(variant, with_regulator=False), variant, SectionX())
                cells.append(Cell(kv, delta, s.dominant_frequency_hz, s.vibration_amplitude))
                bar.update()
    return cells


def verdicts(cells: list[Cell]) -> dict[str, object]:
    """The paper's three claims, measured on the vibrating cells."""
    vib = [c for c in cells if c.frequency_hz is not None]
    out: dict[str, object] = {
        "cells": len(cells),
        "vibrating_cells": len(vib),
        "in_band": sum(c.in_band for c in vib),
    }
    if len(vib) >= 2:
        kv = np.array([c.kv for c in vib])
        f = np.array([c.frequency_hz for c in vib], dtype=float)
        ratio = float(np.sum(kv * f) / np.sum(kv * kv))  # least squares f = ratio * kv
        resid = f - ratio * kv
        r2 = 1.0 - float(np.sum(resid**2) / np.sum((f - f.mean()) ** 2))
        out["f_over_kv"] = ratio
        out["f_over_kv_r2"] = r2
        out["equivalent_restitution_e"] = (4 * ratio - 1) / (4 * ratio + 1)  # eq. 12 inverted
        spreads = []
        for k in sorted({c.kv for c in vib}):
            fs = [c.frequency_hz for c in vib if c.kv == k]
            if len(fs) >= 2:
                spreads.append((max(fs) - min(fs)) / float(np.mean(fs)))
        out["max_relative_spread_over_backlash"] = max(spreads) if spreads else None
    if vib:
        # FFT amplitude of the following error over half the total backlash δ/2
        ratios = [c.amplitude_m / (c.backlash_m / 2) for c in vib]
        out["amplitude_over_half_backlash_min"] = min(ratios)
        out["amplitude_over_half_backlash_max"] = max(ratios)
    return out


def _plot(cells: list[Cell], path: Path, viscous: float, axis_name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kvs = sorted({c.kv for c in cells})
    deltas = sorted({c.backlash_m for c in cells})
    fig, ax = plt.subplots(figsize=(8, 5.2))
    k = np.linspace(min(kvs) * 0.9, max(kvs) * 1.1, 50)
    ax.fill_between(k, k / 4, k, color="0.9", label="eq. 13 band $k_v/4..k_v$")
    # each δ's cells side by side around its k_v so that equal frequencies stay visible
    step = 0.012 * (max(kvs) - min(kvs) or 1.0)
    for i, delta in enumerate(deltas):
        color = f"C{i}"
        shift = (i - (len(deltas) - 1) / 2) * step
        pts = [(c.kv + shift, c.frequency_hz) for c in cells if c.backlash_m == delta]
        vib = [(x, y) for x, y in pts if y is not None]
        if vib:
            x, y = zip(*vib, strict=True)
            ax.plot(x, y, "o-", color=color, ms=5, label=f"δ = {delta * 1e3:g} mm")
        else:
            ax.plot([], [], "o-", color=color, ms=5, label=f"δ = {delta * 1e3:g} mm (no cell)")
        quiet_cells = [x for x, y in pts if y is None]
        ax.plot(quiet_cells, [min(kvs) / 8] * len(quiet_cells), "x", color=color, ms=7, mew=1.5)
    ax.plot([], [], "x", color="k", ms=7, mew=1.5, label="no limit cycle (amplitude < 5 % of δ)")
    ax.axhline(min(kvs) / 8 * 1.6, color="0.6", lw=0.6, ls=":")
    ax.set_ylim(0, max(kvs) * 1.12)
    ax.set_xlabel("$k_v$ [1/s]")
    ax.set_ylabel("limit-cycle frequency [Hz]")
    n_vib = sum(c.frequency_hz is not None for c in cells)
    ax.set_title(
        f"Limit-cycle frequency over $k_v$ and backlash δ (section X, ordinary control): "
        f"{n_vib} of {len(cells)} cells vibrate\n"
        f"{Path(axis_name).name} with friction.viscous = {viscous:g} N m s/m, not the paper's "
        "57.3\n(with 57.3 no cell vibrates: docs/paper_reproduction.md)",
        fontsize=9,
    )
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix[1:])
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    progress = Progress(f"plant_sim {NAME}", quiet=args.quiet)
    axis = read_axis(args.axis).with_values({"friction.viscous": args.viscous})
    backlash = tuple(d * 1e-3 for d in args.backlash_mm)
    print(
        f"note: friction.viscous = {args.viscous:g} N m s/m for every cell (the axis file "
        f"{args.axis} says {read_axis(args.axis).friction.viscous:g}; --viscous to change)"
    )
    cells = sweep(axis, args.kv, backlash, progress)
    args.out.mkdir(parents=True, exist_ok=True)
    with replacing(args.out / "sweep.csv") as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["kv_per_s", "backlash_m", "frequency_hz", "amplitude_m", "in_band"])
        for c in cells:
            w.writerow([c.kv, c.backlash_m, c.frequency_hz or "", c.amplitude_m, c.in_band])
    v = verdicts(cells)
    lines = [
        "| k_v [1/s] | band [Hz] | " + " | ".join(f"δ={d:g} mm" for d in args.backlash_mm) + " |"
    ]
    lines.append("|---" * (2 + len(backlash)) + "|")
    for kv in args.kv:
        row = [f"{kv:g}", f"{kv / 4:g}..{kv:g}"]
        for d in backlash:
            c = next(c for c in cells if c.kv == kv and c.backlash_m == d)
            row.append("none" if c.frequency_hz is None else f"{c.frequency_hz:.2f}")
        lines.append("| " + " | ".join(row) + " |")
    table = "\n".join(lines)
    write_atomic(
        args.out / "sweep.md", table + "\n\n```json\n" + json.dumps(v, indent=2) + "\n```\n"
    )
    write_atomic(
        args.out / "sweep.json",
        json.dumps({"verdicts": v, "cells": [c.__dict__ for c in cells]}, indent=2),
    )
    _plot(cells, args.out / "sweep.png", args.viscous, str(args.axis))
    print(table)
    print(json.dumps(v, indent=2))
    print(f"wrote {args.out}/: sweep.csv, sweep.json, sweep.md, sweep.png")
    return 0

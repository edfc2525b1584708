"""``circular``: the circular test (ISO 230-4, :mod:`hil.contour`) with the seed's axis as X
and a clean axis of the family (seed + 100, family 0) as Y: the backlash the test measures,
the reversal spikes of X, and the contour error of the four controls."""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from bridge.contour import CircularTest
from plant_sim.fmu import FmuSpec

from .base import Row, Task, fmu_source, truth

#: The Y axis: this many seeds above X's, family 0 (clean).
Y_SEED_OFFSET = 100
#: R = 10 mm at 1,000 mm/min (docs/contour.md).
TEST = CircularTest(radius=0.01, feed=1e-3 * 1000 / 60)


def run_circular(spec: FmuSpec, options: Mapping[str, str]) -> Row:
    from hil.contour import ContourSetup, Control, compare

    x = fmu_source(spec)
    seed = int(spec.parameter("seed") or 0)
    y = fmu_source(spec.with_parameters(seed=seed + Y_SEED_OFFSET, family=0))
    beta_t = float(options["beta_t"]) if "beta_t" in options else None
    runs = compare(ContourSetup.of([x, y], beta_t_rad_s=beta_t), TEST)
    ordinary = runs[Control.ORDINARY].report
    row: Row = {
        "y_seed": seed + Y_SEED_OFFSET,
        "backlash_x_m": ordinary.backlash.get("X"),
        "backlash_y_m": ordinary.backlash.get("Y"),
        "spike_x_max_m": max((s.height for s in ordinary.spikes if s.axis == "X"), default=0.0),
    }
    for control, run in runs.items():
        row[f"contour_error_{control.value}_m"] = run.report.contour_error
    return row | truth(x, "effect", "backlash")


def summarize_circular(rows: Sequence[Row]) -> dict[str, Any]:
    good = [r for r in rows if not r.get("error")]
    scored = [r for r in good if 20e-6 <= (r.get("truth_backlash") or 0.0) <= 200e-6]
    within = [r for r in scored if abs(r["backlash_x_m"] / r["truth_backlash"] - 1) <= 0.10]
    out: dict[str, Any] = {
        "axes": len(good),
        "with backlash 20-200 um": len(scored),
        "of them estimated within 10 %": len(within),
    }
    for key in sorted(k for k in good[0] if k.startswith("contour_error_")) if good else []:
        um = [r[key] * 1e6 for r in good]
        out[key.removesuffix("_m") + "_um_min_median_max"] = [
            min(um),
            statistics.median(um),
            max(um),
        ]
    return out


TASK = Task(
    "circular",
    "the circular test with the seed's axis as X and a clean axis as Y: backlash estimate, "
    "reversal spikes, contour error of ordinary control, regulator, shared lambda, "
    "compensation",
    run_circular,
    summarize_circular,
    ("beta_t",),
)

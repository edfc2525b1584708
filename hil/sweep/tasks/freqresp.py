"""``freqresp``: the speed loop's frequency response on each axis (``hil freqresp`` with the
command's defaults), omega_a scored against the data sheet's.

The excitation is the command's (1 rad/s peak, 1-450 Hz, 8 realizations of 3 periods) at an
offset feed (option ``offset``, load units/s; default: the larger of 10 mm/s and twice the
excitation's peak load speed 1 rad/s / k_r, so the motion never reverses and a gap stays
closed), the torque limit the data sheet's. What a user gets is the row: the estimate, its
uncertainty (about 95 %), resolved or why not. Scoring: the data sheet's
``mechanics.antiresonance`` is the axis as built (the FMU's README; its clean family conceals
nothing), so an estimate called resolved must hold it within its uncertainty, and the issue's
5 %.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping, Sequence
from typing import Any

from plant_sim.fmu import FmuSpec

from .base import Row, Task, fmu_source, truth

#: The default offset feed's floor, load units/s.
OFFSET_FLOOR = 0.01
#: The issue's bound on a resolved estimate's error.
REQUIRED_SHARE = 0.05


def run_freqresp(spec: FmuSpec, options: Mapping[str, str]) -> Row:
    from bridge.commands.freqresp import add_excitation_arguments, plan_maker
    from hil.offline import frequency_response

    source = fmu_source(spec)
    axis = source.axis
    kr = axis.transmission_ratio
    # the command's own excitation: its arguments at their defaults (the one required, the
    # torque limit, is the data sheet's), at the offset feed
    parser = argparse.ArgumentParser()
    add_excitation_arguments(parser)
    args = parser.parse_args(["--torque-limit", "1"])
    args.torque_limit = axis.control.torque_limit or math.inf
    args.offset_speed = float(options.get("offset", max(OFFSET_FLOOR, 2.0 * args.amplitude / kr)))
    plan = plan_maker(args)(axis.control.position_cycle, axis.mechanics.damping_ratio)
    with source.plant() as plant:
        fr = frequency_response(plant, plan, kr, axis.control.kv)
    a = fr.antiresonance
    sheet = axis.mechanics.antiresonance
    # the command's own summary (freqresp.json's scalars), and the data sheet beside it
    row: Row = {k: v for k, v in fr.summary().items() if not isinstance(v, list)}
    row |= {"datasheet_rad_s": sheet, "datasheet_damping": axis.mechanics.damping_ratio}
    if sheet:
        row["error_share"] = a.rad_s / sheet - 1.0
        row["within_uncertainty"] = a.contains(sheet)
    return row | truth(source, "effect", "backlash")


def summarize_freqresp(rows: Sequence[Row]) -> dict[str, Any]:
    good = [r for r in rows if not r.get("error") and r.get("datasheet_rad_s")]
    resolved = [r for r in good if r.get("antiresonance_resolved")]
    right = [
        r
        for r in resolved
        if r.get("within_uncertainty") and abs(r["error_share"]) <= REQUIRED_SHARE
    ]
    wrong = [r for r in resolved if r not in right]
    n = len(good)
    errors = sorted(abs(r["error_share"]) for r in resolved)
    return {
        "axes": n,
        "resolved": len(resolved),
        "resolved, within its uncertainty and 5 % of the data sheet": len(right),
        "share": len(right) / n if n else None,
        "resolved but wrong": {str(r["seed"]): r["antiresonance_rad_s"] for r in wrong},
        "not resolved": {
            str(r["seed"]): r.get("antiresonance_reason", "")
            for r in good
            if not r["antiresonance_resolved"]
        },
        "|error| of the resolved, min / median / max": (
            [errors[0], errors[len(errors) // 2], errors[-1]] if errors else None
        ),
    }


TASK = Task(
    "freqresp",
    "on each axis: the speed loop's frequency response at an offset feed (hil freqresp's "
    "defaults) and omega_a against the data sheet's",
    run_freqresp,
    summarize_freqresp,
    ("offset",),
)

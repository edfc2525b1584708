"""``tune``: on each axis with a backlash limit cycle, the beta_T procedure as ``hil tune``
runs it, and what its beta_T does to the limit cycle of a disturbance scenario.

1. **Select**: section X scaled to the axis (:func:`.limit_cycle.limit_cycle_scenario`) has a
   sustained limit cycle in the eq. 13 band under ordinary control; axes without one get a row
   that says so and nothing else.
2. **Tune**: :func:`hil.offline.tune_offline` with the command's defaults on the axis's data
   sheet (what a user knows), the test's torque limit :data:`TORQUE_LIMIT_OVER_DRIVE` times the
   drive's own (the drive saturates at its limit; the test stops the axis above it) and the
   bridge's 2008h; the seconds it took.
3. **Score** (the issue's figures): section X again at that feed with the regulator at the
   beta_T found, its standstill watched as long as the procedure's wait (the dwell, 3 T_v, at
   least section X's 1 s): the vibration amplitude's cut against ordinary control and the
   standstill error (mean |x_ref - x_l| over the last 0.1 s). A run the bridge's supervision
   stopped (2008h, 2009h, 2014h of the data sheet's defaults) is not kept, with its reason:
   its figures after the stop are those of a halted axis.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from plant_sim.fmu import FmuSpec
from regulator import RegulatorConfig

from .base import Row, Task, fmu_source, truth
from .limit_cycle import limit_cycle_scenario

#: The test's torque limit over the drive's own (data sheet).
TORQUE_LIMIT_OVER_DRIVE = 1.25
#: The issue's figures: the cut of the limit cycle and the standstill error a result must keep.
REQUIRED_CUT = 0.9
REQUIRED_STANDSTILL_M = 1e-6


def run_tune(spec: FmuSpec, options: Mapping[str, str]) -> Row:
    from bridge.commission.tune import TuneOptions
    from bridge.params import BridgeParams
    from hil.demo import late_verdict, offline_stopped
    from hil.offline import base_regulator, tune_offline
    from regulator.tuning import Outcome, TuningError
    from regulator.tuning.motion import DWELL_TIMES_TV, STANDSTILL_AVERAGE_S, tv_s

    source = fmu_source(spec)
    axis = source.axis
    kv, cycle = axis.control.kv, axis.control.position_cycle
    row: Row = {"kv_per_s": kv, "limit_cycle": False}
    found = limit_cycle_scenario(source)
    if found is None:
        return row | truth(source, "effect", "backlash")
    scenario, _, v_off = found
    torque_limit = TORQUE_LIMIT_OVER_DRIVE * (axis.control.torque_limit or math.inf)
    following = BridgeParams.for_axis(axis, base_regulator(axis)).following_error_limit
    start = time.perf_counter()
    try:
        result = tune_offline(source, TuneOptions(torque_limit=torque_limit), following)
    except TuningError as exc:
        return (
            row
            | {
                "limit_cycle": True,
                "feed_m_s": scenario.feed,
                "outcome": "refused",
                "reason": str(exc),
                "tune_seconds": time.perf_counter() - start,
            }
            | truth(source, "effect", "backlash")
        )
    seconds = time.perf_counter() - start
    trials = [result.reference, *result.trials]
    row |= {
        "limit_cycle": True,
        "feed_m_s": scenario.feed,
        "outcome": result.outcome.value,
        "reason": result.reason,
        "beta_t_rad_s": result.beta_t_rad_s,
        "provocation": result.reference.motion,
        "tried": len(result.tried),
        "trials": len(trials) + (result.confirmation is not None),
        "tune_seconds": seconds,
        "cost": result.cost,
        "amplitude_ordinary_m": v_off.vibration_amplitude,
    }
    if result.outcome is not Outcome.FOUND or result.beta_t_rad_s is None:
        return row | truth(source, "effect", "backlash")
    wait = max(scenario.end_s - scenario.stop_s, DWELL_TIMES_TV * tv_s(kv))
    watched = replace(scenario, end_s=scenario.stop_s + wait)
    refs = watched.references(axis)
    ordinary = RegulatorConfig(kv=kv, cycle_s=cycle, enabled=False)
    regulated = replace(ordinary, enabled=True, beta_t_rad_s=result.beta_t_rad_s)
    last = round(STANDSTILL_AVERAGE_S / cycle)

    def standstill(trace: Any) -> float:
        e = trace["position_reference"] - trace["load_position"]
        return abs(float(np.mean(e[-last:])))

    off, stop_off = offline_stopped(source, axis, refs, ordinary)
    on, stop_on = offline_stopped(source, axis, refs, regulated)
    v_on = late_verdict(on, axis, watched)
    row |= {
        "stopped_ordinary": stop_off or "",
        "stopped": stop_on or "",
        "amplitude_regulated_m": v_on.vibration_amplitude,
        "reduction": 1.0 - v_on.vibration_amplitude / v_off.vibration_amplitude,
        "standstill_error_ordinary_m": standstill(off),
        "standstill_error_m": standstill(on),
        "standstill_wait_s": wait,
    }
    return row | truth(source, "effect", "backlash")


def _spread(values: Sequence[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = sorted(values)
    return {"min": v[0], "median": v[len(v) // 2], "max": v[-1]}


def summarize_tune(rows: Sequence[Row]) -> dict[str, Any]:
    good = [r for r in rows if not r.get("error")]
    cycling = [r for r in good if r.get("limit_cycle")]
    found = [r for r in cycling if r.get("outcome") == "found"]
    kept = [
        r
        for r in found
        if not r.get("stopped")
        and (r.get("reduction") or 0.0) >= REQUIRED_CUT
        and (r.get("standstill_error_m") or math.inf) <= REQUIRED_STANDSTILL_M
    ]
    n = len(cycling)
    provocations: dict[str, int] = {}
    for r in found:
        provocations[r["provocation"]] = provocations.get(r["provocation"], 0) + 1
    return {
        "axes": len(good),
        "with a backlash limit cycle (section X)": n,
        "beta_T found": len(found),
        "beta_T found, share": len(found) / n if n else None,
        f"cut >= {REQUIRED_CUT:.0%} and standstill <= 1 um": len(kept),
        f"cut >= {REQUIRED_CUT:.0%} and standstill <= 1 um, share": len(kept) / n if n else None,
        "tuning run seconds": _spread([r["tune_seconds"] for r in cycling]),
        "provoked by": provocations,
        "not found": {str(r["seed"]): r.get("reason", "") for r in cycling if r not in found},
        "found, not kept": {
            str(r["seed"]): {
                "reduction": r.get("reduction"),
                "standstill_error_m": r.get("standstill_error_m"),
                "standstill_error_ordinary_m": r.get("standstill_error_ordinary_m"),
                "stopped by the bridge": r.get("stopped") or None,
                "ordinary stopped by the bridge": r.get("stopped_ordinary") or None,
            }
            for r in found
            if r not in kept
        },
    }


TASK = Task(
    "tune",
    "on each axis with a section X limit cycle: the beta_T procedure (hil tune's defaults) "
    "and its beta_T's cut of the limit cycle and standstill error",
    run_tune,
    summarize_tune,
)

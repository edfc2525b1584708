"""``limit-cycle``: section X scaled to each axis; a sustained limit cycle in the eq. 13 band
under ordinary control, and the default regulator's cut of it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from plant_sim.fmu import FmuSpec
from plant_sim.fmu.arguments import AxisSource
from plant_sim.paper.scenarios import SectionX
from regulator import RegulatorConfig

from .base import Row, Task, fmu_source, truth

# --- limit-cycle ---------------------------------------------------------------------------------
#: The section X disturbance as a share of the data sheet's torque limit: the paper's 20 N·m
#: against the 120 N·m of its axis (the family's seed 0), so that an axis of any size is
#: pushed as hard.
DISTURBANCE_SHARE_OF_LIMIT = 20.0 / 120.0


def section_x_for(axis_source: AxisSource, feed: float | None = None) -> SectionX:
    """Section X scaled to the axis: the disturbance :data:`DISTURBANCE_SHARE_OF_LIMIT` of its
    torque limit (as a force on the load); the paper's feed unless ``feed``."""
    axis = axis_source.axis
    limit = axis.control.torque_limit or 20.0 / DISTURBANCE_SHARE_OF_LIMIT
    force = DISTURBANCE_SHARE_OF_LIMIT * limit * axis.transmission_ratio
    scenario = SectionX(disturbance_force_n=force)
    return scenario if feed is None else replace(scenario, feed=feed)


def limit_cycle_scenario(source: AxisSource) -> tuple[SectionX, Any, Any] | None:
    """Section X on the axis's data-sheet loop (k_v, cycles) through the bridge's loop without
    a bus, at the paper's feed or the first lower feed of the demo (:data:`hil.demo.FMU_FEEDS`)
    where ordinary control has a sustained limit cycle in the eq. 13 band: (the scenario, the
    ordinary run's trace, its late verdict); None when there is none."""
    from hil.demo import FMU_FEEDS, late_verdict, offline_run

    axis = source.axis
    ordinary = RegulatorConfig(
        kv=axis.control.kv, cycle_s=axis.control.position_cycle, enabled=False
    )
    for feed in (None, *FMU_FEEDS):
        scenario = section_x_for(source, feed)
        off = offline_run(source, axis, scenario.references(axis), ordinary)
        verdict = late_verdict(off, axis, scenario)
        if verdict.in_band:
            return scenario, off, verdict
    return None


def run_limit_cycle(spec: FmuSpec, options: Mapping[str, str]) -> Row:
    """Is there a sustained limit cycle in section X under ordinary control
    (:func:`limit_cycle_scenario`), and how much does the regulator with its default beta_T
    cut it (a run the bridge's supervision stopped, 2008h / 2009h / 2014h of the data sheet's
    defaults, is not counted as cut, and says why)."""
    from hil.demo import late_verdict, offline_stopped

    source = fmu_source(spec)
    axis = source.axis
    row: Row = {"kv_per_s": axis.control.kv, "feed_m_s": None, "limit_cycle": False}
    found = limit_cycle_scenario(source)
    if found is not None:
        scenario, _, v_off = found
        regulated = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
        on, stopped = offline_stopped(source, axis, scenario.references(axis), regulated)
        v_on = late_verdict(on, axis, scenario)
        row |= {
            "feed_m_s": scenario.feed,
            "limit_cycle": True,
            # a run the bridge's supervision stopped holds a halted axis: its cut is no cut
            "stopped": stopped or "",
            "frequency_hz": v_off.dominant_frequency_hz,
            "amplitude_ordinary_m": v_off.vibration_amplitude,
            "amplitude_regulated_m": v_on.vibration_amplitude,
            "reduction": 1.0 - v_on.vibration_amplitude / v_off.vibration_amplitude,
            "standstill_error_ordinary_m": v_off.final_standstill_error,
            "standstill_error_regulated_m": v_on.final_standstill_error,
        }
    return row | truth(source, "effect", "backlash", "backlash_mid")


def summarize_limit_cycle(rows: Sequence[Row]) -> dict[str, Any]:
    good = [r for r in rows if not r.get("error")]
    cycling = [r for r in good if r.get("limit_cycle")]
    cut = [r for r in cycling if r.get("reduction", 0.0) >= 0.9 and not r.get("stopped")]
    return {
        "axes": len(good),
        "with a sustained limit cycle": len(cycling),
        "of them cut by >= 90 % by the default beta_T": len(cut),
        "stopped by the bridge with the regulator in": {
            str(r["seed"]): r["stopped"] for r in cycling if r.get("stopped")
        },
        "limit-cycling seeds": [r["seed"] for r in cycling],
    }


TASK = Task(
    "limit-cycle",
    "section X on each axis: a sustained limit cycle in the eq. 13 band under ordinary "
    "control, and the default regulator's cut of it",
    run_limit_cycle,
    summarize_limit_cycle,
)

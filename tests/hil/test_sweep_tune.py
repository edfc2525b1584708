"""``hil sweep tune``: the beta_T procedure on axes of the FMU family (a plant written apart
from this project, a binary only) and its score, development seeds only (0-199); and the
rule it shares with ``hil sweep limit-cycle``'s count.

The score runs the bridge's own loop with its supervision (2008h, 2009h, 2014h): a run the
bridge stopped is a halted axis, and its figures after the stop (a standstill error of the
whole remaining travel) are not the law's. Axis 41 of family 1 is one: under section X's
disturbance, its motor encoder and load scale drift apart past the default 2009h (0.5 mm)
with the regulator's beta_T in the loop, while ordinary control stays inside.
"""

from __future__ import annotations

import pytest

from hil.sweep.tasks.tune import REQUIRED_CUT, REQUIRED_STANDSTILL_M, run_tune, summarize_tune
from plant_sim.fmu import FmuSpec
from tests.plant_sim.fmu.fmus import family_fmu


def _row(seed: int) -> dict[str, object]:
    spec = FmuSpec.from_text(family_fmu(), f"seed={seed},family=1")
    return {"seed": seed} | run_tune(spec, {})


@pytest.mark.slow
def test_a_run_the_bridge_stopped_is_not_scored_as_a_standstill() -> None:
    kept, stopped = _row(0), _row(41)
    assert kept["outcome"] == stopped["outcome"] == "found"
    assert kept["stopped"] == kept["stopped_ordinary"] == ""
    assert kept["reduction"] >= REQUIRED_CUT  # type: ignore[operator]
    assert kept["standstill_error_m"] <= REQUIRED_STANDSTILL_M  # type: ignore[operator]
    assert "2009h" in str(stopped["stopped"]) and stopped["stopped_ordinary"] == ""
    summary = summarize_tune([kept, stopped])
    assert summary["beta_T found"] == 2
    assert summary["cut >= 90% and standstill <= 1 um"] == 1
    assert "2009h" in summary["found, not kept"]["41"]["stopped by the bridge"]


def test_the_limit_cycle_sweep_counts_no_cut_of_a_run_the_bridge_stopped() -> None:
    """The twin of the tune task's rule in ``hil sweep limit-cycle``: a regulated run the
    bridge's supervision stopped is a halted axis, whatever cut its figures show."""
    from hil.sweep.tasks.limit_cycle import summarize_limit_cycle

    ran = {"seed": 1, "limit_cycle": True, "reduction": 0.97, "stopped": ""}
    halted = {"seed": 2, "limit_cycle": True, "reduction": 0.99, "stopped": "2009h: 0.51 mm"}
    summary = summarize_limit_cycle([ran, halted, {"seed": 3, "limit_cycle": False}])
    assert summary["with a sustained limit cycle"] == 2
    assert summary["of them cut by >= 90 % by the default beta_T"] == 1
    assert summary["stopped by the bridge with the regulator in"] == {"2": "2009h: 0.51 mm"}

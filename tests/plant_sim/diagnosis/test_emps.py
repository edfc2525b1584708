"""The issue's real-data proof: diagnose the EMPS estimation recording starting from the
published model with Coulomb friction and the offset left out, then score the fitted model
and the published reference model by the same code on both recordings."""

from __future__ import annotations

from pathlib import Path

import pytest

from plant_sim.datasets.emps import import_emps
from plant_sim.datasets.force_error import relative_force_error
from plant_sim.diagnosis import diagnose
from tests.paths import ROOT
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import read_trace
from virtual_bus.shipped import SHARED_DIR

REPO = ROOT
DATA = SHARED_DIR / "data" / "emps"

pytestmark = pytest.mark.skipif(not DATA.exists(), reason=f"EMPS data not found at {DATA}")


@pytest.mark.slow
def test_fitted_model_beats_the_published_reference_on_both_recordings(tmp_path: Path) -> None:
    import_emps([DATA / "DATA_EMPS.mat", DATA / "DATA_EMPS_PULSES.mat"], tmp_path)
    estimation = read_trace(tmp_path / "DATA_EMPS.csv")
    validation = read_trace(tmp_path / "DATA_EMPS_PULSES.csv")
    result = diagnose(estimation, load_axis(REPO / "config" / "emps_nominal.toml"))
    # the nominal model lacks friction at low speed: the tool must name a friction effect
    assert result.left_out
    assert all(
        e.value.endswith("friction") or e.value == "constant_load_torque" for e in result.left_out
    )
    reference = load_axis(REPO / "config" / "emps_reference.toml")
    for trace in (estimation, validation):
        fitted_error = relative_force_error(result.fitted, trace).percent
        reference_error = relative_force_error(reference, trace).percent
        assert fitted_error < reference_error, (fitted_error, reference_error)

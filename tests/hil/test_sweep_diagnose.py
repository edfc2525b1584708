"""``hil sweep diagnose``: the diagnosis on recordings of the FMU family (a plant written apart
from this project, a binary only), scored against what its README says each family conceals.

Development seeds only (0-199; held-out seeds >= 1000 are for reported figures). ``truth_*``
is read in the scoring step of these tests, never by the code under test.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from diagnosis.engine import diagnose
from diagnosis.testsets import fmu
from hil.__main__ import main
from hil.sweep.tasks.diagnose import summarize_diagnose
from tests.plant_sim.fmu.fmus import family_fmu


def _recording(seed: int, code: int, duration_s: float):
    rng = np.random.default_rng([seed + fmu.SEED_SHIFT, code, 0, 0])
    rec, nominal, _ = fmu.make_recording(seed, code, duration_s, rng)
    return rec, nominal


@pytest.mark.slow
def test_a_set_point_applied_late_is_named_at_its_size() -> None:
    """FMU axis 9 with a constant set-point dead time (family 11): the diagnosis names
    ``setpoint_delay`` and the re-fit puts it within 0.5 ms of the FMU's truth."""
    rec, nominal = _recording(9, 11, 10.0)
    d = diagnose(rec, nominal)
    assert [e.value for e in d.left_out][:1] == ["setpoint_delay"], d.left_out
    truth = fmu.truth_values(fmu.spec_for(9, 11).load())["truth_delay"]
    fitted = d.fitted.control.setpoint_delay
    assert fitted is not None and abs(fitted - truth) < 5e-4, (fitted, truth)
    assert d.heldout_final.cost < d.heldout_nominal.cost


@pytest.mark.slow
def test_a_clean_axis_is_neither_named_nor_unexplained() -> None:
    rec, nominal = _recording(4, 0, 10.0)
    d = diagnose(rec, nominal)
    assert d.left_out == [] and not d.unexplained, (d.left_out, d.adequacy.hints)


@pytest.mark.slow
def test_the_sweep_scores_the_family_it_ran(tmp_path: Path) -> None:
    """One seed in this process, family given: the row and the summary say what was named
    and score it against the README's family."""
    out = tmp_path / "sweep"
    argv = ["sweep", "diagnose", "--fmu", str(family_fmu()), "--fmu-param", "family=11"]
    argv += ["--seeds", "9", "--out", str(out), "--workers", "0", "-q"]
    argv += ["--option", "duration=10"]
    assert main(argv) == 0
    (row,) = pq.read_table(out / "results.parquet").to_pylist()
    assert (row["family"], row["first"], row["verdict"]) == (11, "setpoint_delay", "named")
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["figures"]["effect named correctly"] == "1/1 (100.0 %)"


def test_the_summary_counts_correct_names_and_clean_verdicts() -> None:
    rows = [
        {"family": 0, "first": "none", "verdict": "explained", "diagnosis_s": 1.0},
        {"family": 0, "first": "none", "verdict": "unexplained", "diagnosis_s": 2.0},
        {"family": 11, "first": "setpoint_delay", "verdict": "named", "diagnosis_s": 3.0},
        {"family": 12, "first": "time_delay", "verdict": "named", "diagnosis_s": 4.0},
        {"family": 14, "first": "periodic_disturbance", "verdict": "named", "diagnosis_s": 5.0},
        {"family": 1, "error": "boom"},
    ]
    for r in rows:
        r.setdefault("evidence_s", 0.5)
    s = summarize_diagnose(rows)
    assert s["recordings"] == 5
    assert s["effect named correctly"] == "2/3 (66.7 %)"
    assert s["clean: something named"] == "0/2 (0.0 %)"
    assert s["clean: unexplained"] == "1/2 (50.0 %)"
    assert (
        s["per family (first named correct / recordings)"]["12 slowly growing set-point dead time"]
        == "0/1"
    )
    assert s["diagnosis seconds"] == {"min": 1.0, "median": 3.0, "max": 5.0}

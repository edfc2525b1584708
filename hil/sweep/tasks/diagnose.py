"""``diagnose``: the diagnosis on one recording of each axis, its concealed effect scored.

Each seed is one axis of the FMU family and one recording of it (:mod:`diagnosis.testsets.fmu`:
a test plan of moves a user runs, planned from the data sheet, the FMU's own noise), with the
family its ``--fmu-param family=N`` gives or, without one, the seed's place in
:data:`diagnosis.testsets.fmu.SWEEP_CYCLE` (the effect families and clean axes in turn). The
diagnosis gets the recording and the data sheet (``plant_sim.fmu.nominal_axis``), nothing
else. The row says what it named, its verdict and fits; the summary scores it against the
family (what the FMU's README says each conceals) with ``truth_*`` copied for scoring only.

Options: ``duration`` (s, default 25), ``validate`` (0 or 1: a second recording of the same
axis made at another time held out), ``alpha`` (the diagnosis's ``--alpha``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from plant_sim.fmu import FmuSpec

from .base import Row, Task

TRUTH_NAMES = (
    "effect",
    "backlash",
    "stribeck",
    "ripple1",
    "scale_error_amp",
    "load_force",
    "torque_limit",
    "delay",
    "delay_rate",
    "nut_ripple",
    "scale_latency",
    "coulomb_positive",
)


def _family(spec: FmuSpec, seed: int) -> int:
    from diagnosis.testsets.fmu import SWEEP_CYCLE

    given = spec.parameter("family")
    return int(given) if given is not None else SWEEP_CYCLE[seed % len(SWEEP_CYCLE)]


def run_diagnose(spec: FmuSpec, options: Mapping[str, str]) -> Row:
    from diagnosis.engine import diagnose
    from diagnosis.results import DiagnosisOptions
    from diagnosis.testsets import fmu

    seed = int(spec.parameter("seed") or 0)
    code = _family(spec, seed)
    duration = float(options.get("duration", "25"))
    validate = int(options.get("validate", "0"))
    alpha = float(options.get("alpha", str(DiagnosisOptions().alpha)))
    base = FmuSpec(spec.path, (), spec.mapping)
    rng = np.random.default_rng([seed + fmu.SEED_SHIFT, code, 0, 0])
    rec, nominal, _ = fmu.make_recording(seed, code, duration, rng, base)
    second = []
    for take in range(1, validate + 1):
        r2 = np.random.default_rng([seed + fmu.SEED_SHIFT, code, 0, take])
        second.append(fmu.make_recording(seed, code, duration, r2, base, nominal)[0])
    d = diagnose(rec, nominal, validation=second or None, options=DiagnosisOptions(alpha=alpha))
    named = [e.value for e in d.left_out]
    row: Row = {
        "family": code,
        "expected": fmu.FAMILIES[code].effect.value if fmu.FAMILIES[code].effect else "none",
        "named": ",".join(named),
        "first": named[0] if named else "none",
        "verdict": "named" if named else ("unexplained" if d.unexplained else "explained"),
        "why_unexplained": "; ".join(d.adequacy.hints) if d.unexplained else "",
        "datasheet_wrong": ",".join(v.key for v in d.datasheet if v.datasheet_wrong),
        "fit_torque_before": d.fit_before["motor_torque"].fit_percent,
        "fit_torque_after": d.fit_after["motor_torque"].fit_percent,
        "evidence_s": d.timings_s.get("evidence", float("nan")),
        "diagnosis_s": d.timings_s.get("total", float("nan")),
    }
    model = fmu.spec_for(seed, code, base=base).load()
    truth = fmu.truth_values(model)
    return row | {f"truth_{n}": truth[f"truth_{n}"] for n in TRUTH_NAMES if f"truth_{n}" in truth}


def summarize_diagnose(rows: Sequence[Row]) -> dict[str, Any]:
    from diagnosis.testsets.fmu import FAMILIES

    good = [r for r in rows if not r.get("error")]
    clean = [r for r in good if r["family"] == 0]
    effect = [r for r in good if r["family"] != 0]

    def correct(r: Row) -> bool:
        return r["first"] in FAMILIES[r["family"]].accepted_names

    per_family = {}
    for code in sorted({r["family"] for r in good}):
        mine = [r for r in good if r["family"] == code]
        ok = sum(correct(r) for r in mine)
        per_family[f"{code:02d} {FAMILIES[code].label}"] = f"{ok}/{len(mine)}"
    return {
        "recordings": len(good),
        "effect named correctly": _rate(sum(correct(r) for r in effect), len(effect)),
        "clean: something named": _rate(sum(r["verdict"] == "named" for r in clean), len(clean)),
        "clean: unexplained": _rate(sum(r["verdict"] == "unexplained" for r in clean), len(clean)),
        "per family (first named correct / recordings)": per_family,
        "diagnosis seconds": _spread([r["diagnosis_s"] for r in good]),
        "evidence seconds": _spread([r["evidence_s"] for r in good]),
    }


def _rate(k: int, n: int) -> str:
    return f"{k}/{n} ({100.0 * k / n:.1f} %)" if n else "0/0"


def _spread(values: Sequence[float]) -> dict[str, float] | None:
    v = sorted(x for x in values if x == x)
    return {"min": v[0], "median": v[len(v) // 2], "max": v[-1]} if v else None


TASK = Task(
    "diagnose",
    "the diagnosis on one recording per axis (family by seed), its effect scored",
    run_diagnose,
    summarize_diagnose,
    ("duration", "validate", "alpha"),
)

"""Confusion matrix and fit improvements of the diagnosis on the concealed test set.

``python -m diagnosis matrix [--plant kernel|independent|third] [--seed 2] [--duration 25]
[--cases NAME ...] [--validate N] [--out DIR]`` runs :func:`run_matrix` on the plant's test
set and prints the markdown tables (confusion matrix, per-case results with concealment and fit
before/after, timings); ``--out`` also writes them to ``DIR/matrix_<plant>_seed<S>.md`` (and
the results as JSON lines).

The plant that makes the recordings is a :class:`MatrixPlant`: ``kernel`` is this package's
compiled kernel (:func:`synthetic.generate`), ``independent`` the test suite's independent
plant (``reference_plants/independent``: other integrator, friction and contact laws, sensors,
current loop and noise) on the same test set, ``third`` the third plant with its own
families and test set (``reference_plants/third``: three masses, LuGre friction, ...), both found
relative to this checkout.
The full set takes several minutes (one diagnosis per case); the test suite runs a few cases.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from virtual_bus.formats.trace import Trace

from .effects import MODELS, Effect, effects_in
from .engine import DiagnosisOptions, diagnose
from .synthetic import (
    Case,
    GeneratedCase,
    another_recording,
    concealment,
    generate,
    test_set,
    truth_simulator,
)

DEFAULT_OPTIONS = DiagnosisOptions()


@dataclass(frozen=True)
class MatrixPlant:
    """What makes the recordings: ``cases`` the test set of a seed and duration,
    ``generate`` turns a case into a recording, nominal file and hidden truth,
    ``concealment`` says how hidden its effect is (the same plant noise-free),
    ``another`` makes a second recording of a generated case's hidden truth at another time
    (take 1, 2, ...: new moves, unrecorded load and noise; the matrix's ``--validate``)."""

    name: str
    cases: Callable[[int, float], list[Case]]
    generate: Callable[[Case], GeneratedCase]
    concealment: Callable[[GeneratedCase], dict[str, float]]
    another: Callable[[GeneratedCase, int], Trace]


def _kernel_cases(seed: int, duration_s: float) -> list[Case]:
    return test_set(seed=seed, duration_s=duration_s)


def _kernel_concealment(gen: GeneratedCase) -> dict[str, float]:
    return concealment(gen, truth_simulator)


KERNEL_PLANT = MatrixPlant(
    "kernel", _kernel_cases, generate, _kernel_concealment, another_recording
)
PLANTS = ("kernel", "independent", "third", "fmu")


def load_plant(name: str) -> MatrixPlant:
    """``kernel`` (the simulator's own), ``independent`` or ``third`` (the plants of
    :mod:`reference_plants`, their test sets in :mod:`diagnosis.testsets`), ``fmu`` (the
    shared FMU family, :mod:`diagnosis.testsets.fmu`: the seed is the axis's)."""
    if name == "kernel":
        return KERNEL_PLANT
    if name == "independent":
        from .testsets import independent

        def conceal(gen: GeneratedCase) -> dict[str, float]:
            return concealment(gen, independent.simulator)

        return MatrixPlant(
            "independent",
            _kernel_cases,
            independent.generate,
            conceal,
            independent.another_recording,
        )
    if name == "third":
        from .testsets import third

        return MatrixPlant(
            "third", third.test_set, third.generate, third.concealment, third.another_recording
        )
    if name == "fmu":
        from .testsets import fmu

        def fmu_cases(seed: int, duration_s: float) -> list[Case]:
            return fmu.test_set(seed, duration_s)

        return MatrixPlant("fmu", fmu_cases, fmu.generate, fmu.concealment, fmu.another_recording)
    raise ValueError(f"plant {name!r}: allowed {PLANTS}")


@dataclass(frozen=True)
class CaseResult:
    name: str
    family: str
    truth: str  # effect name or "none"
    left_out: list[str]
    first: str  # first named effect or "none"
    correct: bool  # the first named effect is the concealed one (or [] for none)
    exact: bool  # left_out is exactly what the truth has and the nominal lacks (or [])
    expected: list[str]  # that set
    ambiguous_with: list[str]
    #: the verdict: "named" (an effect left out), "unexplained" (nothing named, the residual
    #: beyond what the model class explains) or "explained" (nothing left out)
    verdict: str
    concealment: dict[str, float]
    fit_before: dict[str, float]  # fit % of the nominal as given
    fit_refit: dict[str, float]  # ... after re-fitting its parameters
    fit_after: dict[str, float]  # ... of the fitted model
    heldout_gain_percent: float  # held-out cost reduction refit -> final
    seconds: float
    n_samples: int


def run_case(
    case: Case,
    options: DiagnosisOptions = DEFAULT_OPTIONS,
    plant: MatrixPlant = KERNEL_PLANT,
    validate: int = 0,
) -> CaseResult:
    """Diagnose ``case``'s recording; ``validate``: that many second recordings of the same
    hidden truth held out (``diagnose(..., validation=...)``) instead of interleaved blocks."""
    gen = plant.generate(case)
    second = [plant.another(gen, take) for take in range(1, validate + 1)]
    t0 = time.perf_counter()
    d = diagnose(gen.recording, gen.nominal, validation=second or None, options=options)
    secs = time.perf_counter() - t0
    named = [e.value for e in d.left_out]
    first = named[0] if named else "none"
    truth = case.effect.value if case.effect else "none"
    if gen.expected is not None:
        expected = sorted(gen.expected)
    else:
        # what the nominal really leaves out: the effects of the hidden truth it lacks
        # (backlash on a rigid slide brings the truth's contact stiffness, compliance, with it)
        left = effects_in(gen.truth) - effects_in(gen.nominal)
        expected = sorted(e.value for e in left)
    accepted = gen.accepted or (truth,)
    verdict = "named" if named else ("unexplained" if d.unexplained else "explained")
    gain = 100.0 * (1.0 - d.heldout_final.cost / d.heldout_refit.cost)
    return CaseResult(
        name=case.name,
        family=case.family,
        truth=truth,
        left_out=named,
        first=first,
        correct=first in accepted if named else truth == "none",
        exact=sorted(named) == expected,
        expected=expected,
        ambiguous_with=[a.alternative.value for a in d.ambiguous],
        verdict=verdict,
        concealment=plant.concealment(gen),
        fit_before={k: v.fit_percent for k, v in d.fit_before.items()},
        fit_refit={k: v.fit_percent for k, v in d.fit_refit.items()},
        fit_after={k: v.fit_percent for k, v in d.fit_after.items()},
        heldout_gain_percent=gain,
        seconds=secs,
        n_samples=len(gen.recording),
    )


def run_matrix(
    cases: Sequence[Case],
    options: DiagnosisOptions = DEFAULT_OPTIONS,
    on_result: Callable[[CaseResult], None] | None = None,
    plant: MatrixPlant = KERNEL_PLANT,
    on_error: Callable[[Case, Exception], None] | None = None,
    validate: int = 0,
) -> list[CaseResult]:
    """One result per case (``validate``: :func:`run_case`); with ``on_error`` a case whose
    diagnosis raises is reported there and left out (without it the exception propagates)."""
    results = []
    for case in cases:
        try:
            r = run_case(case, options, plant, validate)
        except Exception as exc:
            if on_error is None:
                raise
            on_error(case, exc)
            continue
        results.append(r)
        if on_result is not None:
            on_result(r)
    return results


LABELS = ["none", *(e.value for e in Effect)]
SHORT = {"none": "none", **{e.value: m.short for e, m in MODELS.items()}}


def confusion_markdown(results: Sequence[CaseResult]) -> str:
    """Rows: concealed effect; columns: first effect named (``none``: left_out = [])."""
    labels = LABELS + sorted({x for r in results for x in (r.truth, r.first)} - set(LABELS))
    counts = {(t, p): 0 for t in labels for p in labels}
    for r in results:
        counts[(r.truth, r.first)] += 1
    rows = [t for t in labels if any(counts[(t, p)] for p in labels)]
    head = "| concealed \\ named first | " + " | ".join(SHORT.get(p, p) for p in labels) + " |"
    sep = "|---|" + "---|" * len(labels)
    lines = [head, sep]
    for t in rows:
        cells = [str(counts[(t, p)]) if counts[(t, p)] else "." for p in labels]
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    n = len(results)
    correct = sum(r.correct for r in results)
    exact = sum(r.exact for r in results)
    lines.append("")
    lines.append(
        f"{correct}/{n} first-named correct, {exact}/{n} exact (left_out is exactly what the "
        "hidden truth has and the nominal lacks, [] when nothing is left out). "
        f"{sum(r.truth in r.ambiguous_with for r in results)} of the misses were reported as "
        "ambiguous with the concealed effect."
    )
    return "\n".join(lines)


def _signal_short(name: str) -> str:
    return {
        "motor_position": "θm",
        "load_position": "xl",
        "motor_speed": "ωm",
        "motor_torque": "τ",
    }[name]


def cases_markdown(results: Sequence[CaseResult]) -> str:
    """Per case: what is hidden, what was named, how hidden it was (effect RMS over noise
    std and over signal spread, torque and the signal where it shows most), the torque's
    simulation fit, the held-out cost reduction, the diagnosis time."""
    head = (
        "| case | hidden | left_out | ambiguous with | effect/noise τ (max) | effect/spread τ "
        "| fit % τ: nominal → re-fit → fitted | held-out gain | s |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        c = r.concealment
        if c:
            snrs = {k[4:]: v for k, v in c.items() if k.startswith("snr_")}
            top = max(snrs, key=lambda k: snrs[k])
            snr = f"{c['snr_motor_torque']:.2f} ({_signal_short(top)} {snrs[top]:.3g})"
            share = f"{100 * c['share_motor_torque']:.1f} %"
        else:
            snr = share = "-"
        tau = "motor_torque"
        fits = f"{r.fit_before[tau]:.1f} → {r.fit_refit[tau]:.1f} → {r.fit_after[tau]:.1f}"
        named = ", ".join(r.left_out) or "[]"
        mark = "" if r.exact else (" (first ok)" if r.correct else " ✗")
        hidden = ", ".join(r.expected) or "[]"
        amb = ", ".join(r.ambiguous_with) or ""
        lines.append(
            f"| {r.name} | {hidden} | {named}{mark} | {amb} | {snr} | {share} | {fits} | "
            f"{r.heldout_gain_percent:.1f} % | {r.seconds:.0f} |"
        )
    secs = sorted(r.seconds for r in results)
    if secs:
        lines.append("")
        lines.append(
            f"Diagnosis time per {results[0].n_samples}-sample recording: median "
            f"{secs[len(secs) // 2]:.0f} s, max {secs[-1]:.0f} s."
        )
    return "\n".join(lines)

"""The whole diagnosis: recording + nominal axis file -> what the model leaves out.

1. :func:`prepare` — the recording checked against the axis file and resampled for the
   closed-loop replay (:mod:`.replay`); its scales; the blocks held out (the odd ones of about
   1 s, or the ``validation`` recordings).
2. **Evidence** (:func:`.screen.screen`) — every effect the model lacks tested on the
   measured signals by regressors linear in its parameters (the torque balance of the inverse
   dynamic model, the deflection between two measuring systems, the closed-loop signature of a
   dead time or a torque limit), calibrated on replays of the model with the recording's
   noise, each test's null distribution from the recording's own residual; the effects named
   by forward selection at a stated false-alarm rate, every parameter estimated.
3. **Closed loop** (:func:`.closed_loop.closed_loop`) — the named effects modelled, the
   whole model re-fitted by closed-loop simulation error with the nominal's parameters within
   their data-sheet uncertainty (unless the evidence says the data sheet is wrong), scored on
   the held-out data, which decide between ambiguous explanations.
4. :func:`_finish` — where the simulation departed from the recording (:mod:`.mismatch`),
   whether the model class explains it (:mod:`.adequacy`) and where it does not
   (:mod:`.unexplained`), the explanation (:mod:`.explain`).

docs/diagnosis.md describes the method and the decision rule (:data:`.results.DECISION_RULE`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from threadpoolctl import threadpool_limits

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import Trace

from .adequacy import assess
from .closed_loop import ClosedLoop, closed_loop
from .effects import MODELS, Effect, experiment_for
from .errors import DiagnosisInputError
from .evidence import data_scales
from .explain import explain
from .fit import PERIODIC_COS, PERIODIC_SIN, plain_floats
from .mismatch import (
    classify,
    condition_summary,
    find_windows,
    reference_kinematics,
    residual_tests,
)
from .outcome import DatasheetVerdict, Diagnosis
from .parameters import MODEL_FORM_KEYS, UNCERTAIN_KEYS, key_unit, rounded
from .replay import compared_quantity, prepare_replay, replay
from .results import (
    COMPARED,
    DECISION_RULE,
    Ambiguity,
    DiagnosisOptions,
    ProgressBar,
    Score,
    SignalFit,
    signal_fits,
)
from .scoring import training_blocks
from .screen import Screening, screen
from .stages import Context
from .unexplained import local_misfit, where

__all__ = [
    "COMPARED",
    "DECISION_RULE",
    "Ambiguity",
    "DatasheetVerdict",
    "Diagnosis",
    "DiagnosisOptions",
    "ProgressBar",
    "Score",
    "SignalFit",
    "diagnose",
    "prepare",
    "signal_fits",
]

DEFAULT_OPTIONS = DiagnosisOptions()
#: Fewest held-out-block pairs a recording needs (a shorter one is refused).
MIN_BLOCKS = 2
#: Shortest fit / held-out block a short recording's blocks are cut to (s): a 2 s recording
#: is diagnosed on blocks of 0.5 s; below this the held-out check has too little to judge.
MIN_BLOCK_S = 0.25


def diagnose(
    recording: Trace,
    nominal: AxisConfig,
    validation: Trace | Sequence[Trace] | None = None,
    options: DiagnosisOptions = DEFAULT_OPTIONS,
    progress: ProgressBar | None = None,
    prepared: Context | None = None,
) -> Diagnosis:
    """Diagnose what ``nominal`` leaves out of ``recording`` (see the module docstring).
    ``validation``: one or more second recordings held out instead of the odd blocks.
    ``prepared``: what :func:`prepare` returned for these inputs (a caller that checks them
    before any long work passes its check on instead of having it done twice).

    Raises DiagnosisInputError when a recording and the axis do not fit together or the
    recording cannot be diagnosed (too short, the axis never moves)."""
    ctx = prepared if prepared is not None else prepare(recording, nominal, validation, options)
    ctx.progress = progress
    pool = ThreadPoolExecutor(max_workers=options.jobs) if options.jobs > 1 else None
    # the linear algebra here is on small matrices and the simulations run in ``pool``:
    # BLAS threads would only compete with them
    blas = threadpool_limits(limits=1, user_api="blas")
    try:
        ctx.stage("evidence")
        t0 = time.perf_counter()
        screening = screen(
            ctx.inp,
            recording,
            nominal,
            options.effects,
            options.alpha,
            options.max_effects,
            options.seed,
            pool,
        )
        ctx.timings["evidence"] = time.perf_counter() - t0
        ctx.tick(screening.n_replays)
        t0 = time.perf_counter()
        loop = closed_loop(ctx, screening, pool)
        ctx.timings["closed_loop"] = time.perf_counter() - t0
        return _finish(ctx, screening, loop)
    finally:
        blas.unregister()
        if pool is not None:
            pool.shutdown()


# ----------------------------------------------------------------------------------------
# 1. prepare
# ----------------------------------------------------------------------------------------
def prepare(
    recording: Trace,
    nominal: AxisConfig,
    validation: Trace | Sequence[Trace] | None = None,
    options: DiagnosisOptions = DEFAULT_OPTIONS,
    sources: Sequence[str] = (),
) -> Context:
    """The one check that the recordings and the axis file fit together and can be
    diagnosed (:func:`.replay.prepare_replay`, the length, a reference that moves), and the
    recording resampled for the replay. ``sources``: names of the recording and of each
    validation recording for the messages (file names; default "recording", "validation
    recording N"). Raises DiagnosisInputError (one line) otherwise."""
    t_start = time.perf_counter()
    inp = prepare_replay(recording, nominal, sources[0] if sources else "recording")
    if validation is None:
        vals: list[Trace] = []
    elif isinstance(validation, Trace):
        vals = [validation]
    else:
        vals = list(validation)
    val_inps = [
        prepare_replay(
            v, nominal, sources[i + 1] if len(sources) > i + 1 else f"validation recording {i + 1}"
        )
        for i, v in enumerate(vals)
    ]
    notes: list[str] = []
    if not val_inps and inp.duration_s < 2 * MIN_BLOCKS * options.block_s:
        # a short recording: shorter blocks, as long as each still holds MIN_BLOCK_S
        block = inp.duration_s / (2 * MIN_BLOCKS)
        if block < MIN_BLOCK_S:
            raise DiagnosisInputError(
                f"the recording lasts {inp.duration_s:.3g} s; the diagnosis needs at least "
                f"{2 * MIN_BLOCKS * MIN_BLOCK_S:g} s (fitted and held-out blocks of at least "
                f"{MIN_BLOCK_S:g} s), or a second recording to hold out (--validate)"
            )
        notes.append(
            f"a short recording ({inp.duration_s:.3g} s): fitted and held-out blocks of "
            f"{block:.3g} s instead of {options.block_s:g} s"
        )
        options = replace(options, block_s=block)
    ref = inp.recorded["position_reference"]
    if not np.ptp(ref) > 0.0:
        raise DiagnosisInputError(
            "position_reference never moves: a recording of an axis at rest shows no dynamics "
            "to diagnose",
            column="position_reference",
        )
    train = (
        training_blocks(inp.time_s, options.block_s)
        if not val_inps
        else np.ones(inp.n_samples, dtype=bool)
    )
    ctx = Context(
        recording, nominal, inp, val_inps, data_scales(inp), train, options, None, t_start
    )
    ctx.notes.extend(notes)
    return ctx


# ----------------------------------------------------------------------------------------
# 4. where, adequacy, explanation
# ----------------------------------------------------------------------------------------
def _ambiguities(screening: Screening, loop: ClosedLoop) -> list[Ambiguity]:
    out = []
    finals = {f.name: f for f in loop.alternatives}
    for a, b in screening.ambiguous:
        named, other = (a, b) if a in loop.left_out else (b, a)
        alt = next((f for f in finals.values() if other in f.effects), None)
        if alt is not None:
            ratio = alt.heldout.cost / loop.final.heldout.cost if loop.final.heldout.cost else 1.0
            _, p = (
                loop.scorer.test(alt.loss, loop.final.loss)
                if alt.heldout.cost > loop.final.heldout.cost
                else loop.scorer.test(loop.final.loss, alt.loss)
            )
        else:
            ratio, p = math.nan, math.nan
        out.append(Ambiguity(named, other, ratio, p, experiment_for(named, other)))
    return out


def _datasheet(ctx: Context, screening: Screening, fitted: AxisConfig) -> list[DatasheetVerdict]:
    out = []
    for p in screening.parameters:
        if p.nominal is None:
            continue
        value = fitted.value(p.key)
        out.append(
            DatasheetVerdict(
                key=p.key,
                nominal=p.nominal,
                box=p.box,
                evidence=p.estimate,
                standard_error=p.standard_error,
                datasheet_wrong=p.beyond,
                fitted=None if value is None else float(value),
                unit=key_unit(p.key, ctx.nominal),
            )
        )
    return out


def _finish(ctx: Context, screening: Screening, loop: ClosedLoop) -> Diagnosis:
    inp, nominal = ctx.inp, ctx.nominal
    t0 = time.perf_counter()
    fitted = rounded_axis(loop.final.result.axis, nominal)
    refit = rounded_axis(loop.base.result.axis, nominal)
    sim_before = replay(nominal, inp, loop.nominal.result.options)
    sim_refit = replay(loop.base.result.axis, inp, loop.base.result.options)
    sim_after = replay(fitted, inp, loop.final.result.options)
    kin = reference_kinematics(inp.time_s, inp.recorded["position_reference"], ctx.scales.position)
    labels = classify(kin, nominal.control.kv)
    base_res = {s: inp.compared(s) - compared_quantity(inp, s, sim_refit[s]) for s in inp.signals}
    final_res = {s: inp.compared(s) - compared_quantity(inp, s, sim_after[s]) for s in inp.signals}
    left_out = list(loop.left_out)
    windows = find_windows(base_res, kin, labels, final_res if left_out else None)
    fit_after = signal_fits(inp, sim_after)
    tests_final = residual_tests(final_res, kin)
    adequacy = assess(final_res, kin, labels, tests_final, fit_after)
    located = where(
        final_res,
        inp.time_s,
        ctx.scales.speed,
        ctx.scales.position,
        find_windows(final_res, kin, labels),
        tuple(s for s in inp.signals if s in adequacy.noise_ratio),
    )
    local = local_misfit(located)
    if local:
        adequacy = replace(adequacy, adequate=False, hints=[*adequacy.hints, *local])
    unexplained = located if not adequacy.adequate else []
    notes = [*ctx.notes, *screening.notes, *loop.notes, *loop.swaps]
    for e, why in screening.not_tested.items():
        notes.append(f"{e.value} not tested: {why}")
    ctx.timings["finish"] = time.perf_counter() - t0
    ctx.timings["total"] = time.perf_counter() - ctx.t_start
    n_val = len(ctx.val_inps)
    diag = Diagnosis(
        left_out=left_out,
        evidence=screening,
        closed_loop=loop,
        ambiguous=_ambiguities(screening, loop),
        mismatch=windows,
        mismatch_by_condition=condition_summary(windows),
        tests_final=tests_final,
        fit_before=signal_fits(inp, sim_before),
        fit_refit=signal_fits(inp, sim_refit),
        fit_after=fit_after,
        heldout_nominal=loop.nominal.heldout,
        heldout_refit=loop.base.heldout,
        heldout_final=loop.final.heldout,
        nominal=nominal,
        refit=refit,
        fitted=fitted,
        fitted_values=_changes(nominal, fitted, left_out),
        datasheet=_datasheet(ctx, screening, fitted),
        adequacy=adequacy,
        unexplained=unexplained,
        notes=notes,
        explanation="",
        simulated_before=sim_before,
        simulated_refit=sim_refit,
        simulated_after=sim_after,
        recording=ctx.recording,
        validation="interleaved blocks" if not n_val else f"{n_val} second recording(s)",
        timings_s=ctx.timings,
        n_simulations=screening.n_replays + loop.n_simulations + 3,
        options=ctx.options,
    )
    diag.explanation = explain(diag)
    return diag


def _changes(
    nominal: AxisConfig, axis: AxisConfig, added: Sequence[Effect] = ()
) -> dict[str, tuple[float, float]]:
    """key -> (nominal value or NaN, value in ``axis``) for the uncertain keys and the keys of
    the added effects."""
    keys = [k for k in UNCERTAIN_KEYS if k not in (PERIODIC_COS, PERIODIC_SIN)]
    keys += ["disturbance.periodic_phase"]
    keys += [k for e in added for k in MODELS[e].keys if k not in keys]
    keys += [k for k in MODEL_FORM_KEYS if k not in keys]
    out = {}
    for k in keys:
        v = axis.value(k)
        if v is None:
            continue
        n = nominal.value(k)
        out[k] = (float(n) if n is not None else math.nan, float(v))
    return out


def rounded_axis(axis: AxisConfig, nominal: AxisConfig) -> AxisConfig:
    """``axis`` with every value that differs from the nominal rounded to the significant
    digits of :func:`.parameters.rounded` (axis_fitted.toml and the explanation then hold
    the same numbers)."""
    changes: dict[str, float | None] = {}
    for section in ("mechanics", "friction", "disturbance", "control"):
        for name, value in vars(getattr(axis, section)).items():
            key = f"{section}.{name}"
            if isinstance(value, float) and value != nominal.value(key):
                changes[key] = rounded(value)
    try:
        return plain_floats(axis.with_values(changes)) if changes else plain_floats(axis)
    except AxisFileError:
        return plain_floats(axis)

"""The whole diagnosis: recording + nominal axis file -> what the model leaves out.

Stages (one function each):

1. :func:`_prepare` — the closed-loop replay (:mod:`.replay`), the recording's scales, and the
   blocks: about 1 s each, the even ones fitted and the odd ones held out (or the whole
   recording fitted and one or more second recordings held out, ``validation``).
2. :func:`_refit_nominal` — re-fit the nominal model's uncertain parameters by simulation
   error (:mod:`.fit`), signals weighted by the RMS residual of the nominal, then of the
   re-fitted model. A re-fitted parameter that ends on a bound of its box or moves further
   than its data-sheet uncertainty (:mod:`.parameters`) is a *suspect*, a sign of missing
   physics: the re-fit is repeated with the suspects held at nominal. A parameter change is
   kept only when it improves the held-out data: of the nominal as given, the re-fit and the
   re-fit with suspects at nominal the one with the lowest held-out cost is the base model.
3. :func:`_locate` — the base model's residual in time and by operating condition, its
   whiteness and correlations (:mod:`.mismatch`).
4. :func:`.selection.select` — forward selection: every effect of the table
   (:data:`.effects.MODELS`) the model lacks is added with the suspects held within their
   data-sheet uncertainty (an effect is compared with the re-fit on equal terms: a dead time
   is not explained away by damping moved beyond what a data sheet allows)
   and scored on the held-out data (:mod:`.scoring`); the best one that passes the decision
   rule is named, all parameters are re-fitted with it, and the next round starts.
5. :func:`_finish` — final scores; a fitted model worse than the nominal on the held-out
   data is rejected; the adequacy of the model class (:mod:`.adequacy`) and the
   explanation (:mod:`.explain`).

Decision rule (``docs/diagnosis.md``, :data:`DECISION_RULE`): the held-out cost reduction
judged against the noise where the candidate changes the simulation
(:func:`~plant_sim.diagnosis.metrics.improvement_test`), p < alpha (0.001), a held-out cost
reduction of at least ``min_improvement`` (0.5 %), and without the held-out block that gains
most p < 0.1. Candidates that the best one does not beat by the same test explain the data
equally well and are reported with an experiment that tells them apart; the one with fewest
parameters is named unless the best one beats it at ``choice_alpha`` (0.05) by at least
``min_improvement`` (:func:`.selection.name_among`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import Trace

from .adequacy import assess
from .effects import MODELS, Effect
from .evidence import data_scales, inverse_dynamics
from .explain import explain
from .fit import (
    PERIODIC_COS,
    PERIODIC_SIN,
    FitResult,
    FitSpec,
    Objective,
    Parameter,
    fit,
    plain_floats,
    restart,
)
from .mismatch import (
    classify,
    condition_summary,
    find_windows,
    reference_kinematics,
    residual_tests,
)
from .parameters import (
    MODEL_FORM_KEYS,
    beyond_uncertainty,
    held_at_nominal,
    nominal_spec,
    parameter_for,
    rounded,
    suspects,
    uncertainty_box,
)
from .replay import compared_quantity, prepare_replay, replay
from .results import (
    COMPARED,
    DECISION_RULE,
    Ambiguity,
    CandidateResult,
    Diagnosis,
    DiagnosisOptions,
    ProgressBar,
    Score,
    SignalFit,
    signal_fits,
)
from .scoring import (
    Scorer,
    heldout_blocks,
    rescaled,
    signal_weights,
    training_blocks,
    validation_objectives,
)
from .selection import SCREEN_NFEV, Selection, select
from .stages import Base, Context, Located, axis_values

__all__ = [
    "COMPARED",
    "DECISION_RULE",
    "Ambiguity",
    "CandidateResult",
    "Diagnosis",
    "DiagnosisOptions",
    "ProgressBar",
    "Score",
    "SignalFit",
    "axis_values",
    "diagnose",
    "signal_fits",
]

DEFAULT_OPTIONS = DiagnosisOptions()


def diagnose(
    recording: Trace,
    nominal: AxisConfig,
    validation: Trace | Sequence[Trace] | None = None,
    options: DiagnosisOptions = DEFAULT_OPTIONS,
    progress: ProgressBar | None = None,
) -> Diagnosis:
    """Diagnose what ``nominal`` leaves out of ``recording`` (see the module docstring).
    ``validation``: one or more second recordings held out instead of the odd blocks.

    Raises DiagnosisInputError when a recording and the axis do not fit together.
    """
    ctx = _prepare(recording, nominal, validation, options, progress)
    base = _refit_nominal(ctx)
    located = _locate(ctx, base)
    selection = select(ctx, base, located)
    return _finish(ctx, base, located, selection)


# ----------------------------------------------------------------------------------------
# 1. prepare
# ----------------------------------------------------------------------------------------
def _prepare(
    recording: Trace,
    nominal: AxisConfig,
    validation: Trace | Sequence[Trace] | None,
    options: DiagnosisOptions,
    progress: ProgressBar | None,
) -> Context:
    t_start = time.perf_counter()
    inp = prepare_replay(recording, nominal)
    if validation is None:
        vals: list[Trace] = []
    elif isinstance(validation, Trace):
        vals = [validation]
    else:
        vals = list(validation)
    val_inps = [
        prepare_replay(v, nominal, f"validation recording {i + 1}") for i, v in enumerate(vals)
    ]
    train = (
        training_blocks(inp.time_s, options.block_s)
        if not val_inps
        else np.ones(inp.n_samples, dtype=bool)
    )
    return Context(
        recording, nominal, inp, val_inps, data_scales(inp), train, options, progress, t_start
    )


# ----------------------------------------------------------------------------------------
# 2. re-fit of the nominal model
# ----------------------------------------------------------------------------------------
def _refit_nominal(ctx: Context) -> Base:
    ctx.stage("nominal")
    opts, nominal, inp = ctx.options, ctx.nominal, ctx.inp
    spec0 = nominal_spec(
        nominal, ctx.scales, inverse_dynamics(inp, nominal, ctx.scales), opts.n_global_nominal
    )
    obj_unit = Objective(inp, ctx.train, {s: 1.0 for s in inp.signals})
    before_res = obj_unit.residuals(nominal, spec0.options)
    nominal_fit = FitResult({}, nominal, 0.0, before_res, 0, 1, 1, "as given", spec0.options)
    obj1 = Objective(inp, ctx.train, signal_weights(obj_unit, nominal_fit))
    ctx.stage("re-fit nominal")
    refit1 = fit(spec0, obj1, opts.max_nfev, opts.n_starts, opts.seed, ctx.tick)
    weights = signal_weights(obj1, refit1)
    obj = Objective(inp, ctx.train, weights)
    refit = fit(restart(spec0, refit1.values), obj, opts.max_nfev, 1, opts.seed, ctx.tick)
    ctx.retired += [obj_unit, obj1]
    nominal_fit = rescaled(nominal_fit, obj_unit, obj)
    val_objs = validation_objectives(ctx.val_inps, weights, [], ctx.retired)
    blocks = heldout_blocks(inp.time_s, ctx.train, ctx.val_inps, opts.block_s)
    scorer = Scorer(obj, val_objs, blocks)
    s_nom, l_nom = scorer.score(nominal_fit, 0)
    s_raw, l_raw = scorer.score(refit, spec0.n_free)
    scorer.lags = max(5, round(2.0 * s_raw.n_samples / s_raw.n_eff))
    found = suspects(refit, spec0.parameters, nominal)
    hold = [s.key for s in found if s.key not in (PERIODIC_COS, PERIODIC_SIN)]
    options_tried = [("the re-fit", refit, s_raw, l_raw)]
    free = {"the nominal": (), "the re-fit": spec0.parameters}
    if hold:
        ctx.stage("re-fit with suspects at nominal")
        params = tuple(p for p in spec0.parameters if p.key not in hold)
        spec_c = restart(
            FitSpec(held_at_nominal(refit.axis, nominal, hold), params, options=spec0.options),
            refit.values,
        )
        constrained = fit(spec_c, obj, opts.max_nfev, 1, opts.seed, ctx.tick)
        s_con, l_con = scorer.score(constrained, len(params))
        name_c = f"the re-fit with {', '.join(hold)} at nominal"
        options_tried.append((name_c, constrained, s_con, l_con))
        free[name_c] = params
    name, best, s_best, l_best = min(options_tried, key=lambda o: o[2].cost)
    if s_nom.cost <= s_best.cost:
        decision = (
            f"re-fit rejected: {name} fits the fitting data better (training cost "
            f"{nominal_fit.cost:.4g} -> {best.cost:.4g}) and the held-out data worse "
            f"({s_nom.cost:.4g} -> {s_best.cost:.4g}); the nominal values are kept"
        )
        best, s_best, l_best = nominal_fit, s_nom, l_nom
    else:
        costs = ", ".join(f"{n} {s.cost:.4g}" for n, _, s, _ in options_tried)
        decision = (
            f"kept {name}: held-out cost nominal {s_nom.cost:.4g}, {costs} "
            f"({100.0 * (1.0 - s_best.cost / s_nom.cost):.1f} % below the nominal)"
        )
    kept = "the nominal" if best is nominal_fit else name
    creep = _creep_option(ctx, obj, scorer, (kept, best, s_best, l_best), free[kept])
    if creep is not None and creep[2].cost < s_best.cost:
        decision += (
            f"; the friction law: {creep[0]} (creep speed "
            f"{creep[1].values['friction.creep_speed']:.3g}) lowers the held-out cost "
            f"{s_best.cost:.4g} -> {creep[2].cost:.4g} and is kept"
        )
        _, best, s_best, l_best = creep
    elif creep is not None:
        decision += (
            f"; a creeping friction law does not lower the held-out cost "
            f"({s_best.cost:.4g} -> {creep[2].cost:.4g}): set-valued friction kept"
        )
    ctx.timings["nominal_refit"] = time.perf_counter() - ctx.t_start
    return Base(spec0, obj, scorer, nominal_fit, refit, best, s_best, l_best, found, hold, decision)


def _creep_option(
    ctx: Context,
    obj: Objective,
    scorer: Scorer,
    on: tuple[str, FitResult, Score, np.ndarray],
    free: Sequence[Parameter],
) -> tuple[str, FitResult, Score, np.ndarray] | None:
    """The friction law is part of the model's form, not of a data sheet: a set-valued
    Coulomb/Stribeck law (stiction) or one regularised below a creep speed (pre-sliding
    creep, ``friction.creep_speed``). When the nominal has sign-law friction and no creep
    speed, the creep speed is fitted alone on the model kept so far (the nominal as given or
    its re-fit, whichever has the lower held-out cost; starts over three decades of
    :data:`.parameters.CREEP_RANGE`), then jointly with ``free``, the parameters that model
    re-fitted (none for the nominal as given): every candidate is later fitted jointly with
    those parameters, so a base left at the creep speed's partial optimum would credit each
    candidate with the rest of the base's own fit (equal terms, as after naming an effect).
    It becomes the base only if it lowers the held-out cost, like every other parameter
    change."""
    nominal, sc = ctx.nominal, ctx.scales
    fr = nominal.friction
    if fr.creep_speed is not None or not ((fr.coulomb or 0.0) > 0.0 or fr.stribeck):
        return None
    ctx.stage("re-fit with a creeping friction law")
    name, base_fit, s_on, _ = on
    key = "friction.creep_speed"
    starts = [{key: f * sc.speed_max} for f in (1e-4, 1e-3, 1e-2)]
    par = parameter_for(key, starts[1][key], sc, nominal, base_fit.axis)
    spec = FitSpec(
        base_fit.axis.with_values({key: starts[1][key]}),
        (par,),
        tuple(starts[::2]),
        options=base_fit.options,
        n_global=0,
    )
    res = fit(spec, obj, SCREEN_NFEV, 2, ctx.options.seed, ctx.tick)
    res = replace(res, values={**base_fit.values, **res.values})
    if free:
        joint_spec = restart(FitSpec(res.axis, (*free, par), options=base_fit.options), res.values)
        joint = fit(joint_spec, obj, ctx.options.max_nfev, 1, ctx.options.seed, ctx.tick)
        if joint.cost < res.cost:
            res = replace(joint, values={**res.values, **joint.values})
    score, loss = scorer.score(res, s_on.n_free + 1)
    return (f"{name} with a creeping friction law", res, score, loss)


# ----------------------------------------------------------------------------------------
# 3. where and when
# ----------------------------------------------------------------------------------------
def _locate(ctx: Context, base: Base) -> Located:
    t0 = time.perf_counter()
    inp = ctx.inp
    sim = replay(base.base.axis, inp, base.base.options)
    kin = reference_kinematics(inp.time_s, inp.recorded["position_reference"], ctx.scales.position)
    labels = classify(kin, ctx.nominal.control.kv)
    res = {s: inp.compared(s) - compared_quantity(inp, s, sim[s]) for s in inp.signals}
    ctx.timings["mismatch"] = time.perf_counter() - t0
    return Located(kin, labels, res, residual_tests(res, kin), sim)


# ----------------------------------------------------------------------------------------
# 5. final scores, adequacy, explanation
# ----------------------------------------------------------------------------------------
def _finish(ctx: Context, base: Base, located: Located, sel: Selection) -> Diagnosis:
    inp, nominal = ctx.inp, ctx.nominal
    fitted = rounded_axis(sel.current.axis, nominal)
    sim_after = (
        sel.simulated if fitted == sel.current.axis else replay(fitted, inp, sel.current.options)
    )
    final = replace(sel.current, axis=fitted)
    s_nom, _ = sel.scorer.score(rescaled(base.nominal_fit, base.obj, sel.obj), 0)
    if sel.added and s_nom.cost < sel.score.cost:
        # cannot happen by construction (every step improved the held-out data); guard
        ctx.notes.append(
            "fitted model rejected: it fits the held-out data worse than the nominal "
            f"({s_nom.cost:.4g} < {sel.score.cost:.4g}); axis_fitted.toml is the nominal"
        )
        fitted, final, sim_after = nominal, base.nominal_fit, replay(nominal, inp)
    sim_before = replay(nominal, inp, base.spec0.options)
    final_res = {s: inp.compared(s) - compared_quantity(inp, s, sim_after[s]) for s in inp.signals}
    tests_final = residual_tests(final_res, located.kin)
    windows = find_windows(
        located.residuals, located.kin, located.labels, final_res if sel.added else None
    )
    fit_after = signal_fits(inp, sim_after)
    adequacy = assess(final_res, located.kin, located.labels, tests_final, fit_after)
    if sel.hold and sel.added:
        where = ", ".join(f"{k} ({_held_where(k, fitted, nominal)})" for k in sel.hold)
        ctx.notes.append(
            "held within their data-sheet uncertainty while effects were compared (a re-fit "
            f"moved them beyond it or onto a bound): {where}"
        )
    ranked = sorted(
        sel.candidates.values(), key=lambda c: (c.round, not c.accepted, -c.improvement_percent)
    )
    ctx.timings["total"] = time.perf_counter() - ctx.t_start
    n_val = len(ctx.val_inps)
    diag = Diagnosis(
        left_out=list(sel.added) if final is not base.nominal_fit else [],
        candidates=ranked,
        ambiguous=sel.ambiguous,
        mismatch=windows,
        mismatch_by_condition=condition_summary(windows),
        tests_refit=located.tests,
        tests_final=tests_final,
        fit_before=signal_fits(inp, sim_before),
        fit_refit=signal_fits(inp, located.simulated),
        fit_after=fit_after,
        heldout_refit=sel.scorer.score(rescaled(base.base, base.obj, sel.obj), base.spec0.n_free)[
            0
        ],
        heldout_final=sel.score,
        nominal=nominal,
        refit=rounded_axis(base.base.axis, nominal),
        fitted=fitted,
        refit_values=_changes(nominal, base.refit.axis, base.spec0),
        fitted_values=_changes(nominal, fitted, base.spec0, sel.added),
        suspects=base.suspects,
        refit_decision=base.decision,
        heldout_nominal=s_nom,
        adequacy=adequacy,
        notes=ctx.notes,
        explanation="",
        simulated_before=sim_before,
        simulated_refit=located.simulated,
        simulated_after=sim_after,
        recording=ctx.recording,
        validation="interleaved blocks" if not n_val else f"{n_val} second recording(s)",
        timings_s=ctx.timings,
        n_simulations=sum(o.n_simulations for o in {id(o): o for o in ctx.retired}.values())
        + sel.obj.n_simulations
        + sum(v.n_simulations for v in sel.scorer.val_objs),
        options=ctx.options,
    )
    diag.explanation = explain(diag)
    return diag


def _changes(
    nominal: AxisConfig, axis: AxisConfig, spec0: FitSpec, added: Sequence[Effect] = ()
) -> dict[str, tuple[float, float]]:
    """key -> (nominal value or NaN, value in ``axis``) for the re-fitted keys and the keys
    of the added effects."""
    keys = [p.key for p in spec0.parameters if p.key not in (PERIODIC_COS, PERIODIC_SIN)]
    if any(p.key == PERIODIC_COS for p in spec0.parameters):
        keys += ["disturbance.periodic_amplitude", "disturbance.periodic_phase"]
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


def _held_where(key: str, fitted: AxisConfig, nominal: AxisConfig) -> str:
    """Where a held parameter is in axis_fitted.toml: at nominal, within its data-sheet
    uncertainty, or beyond it (a polish after the last named effect moved it)."""
    value = fitted.value(key)
    if value is None or uncertainty_box(key, nominal) is None:
        return "not in axis_fitted.toml"
    if value == nominal.value(key):
        return "nominal in axis_fitted.toml"
    beyond = beyond_uncertainty(key, value, nominal)
    return f"{'beyond' if beyond else 'within'} its uncertainty in axis_fitted.toml"

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
4. :func:`_select` — forward selection: every effect of the table (:data:`.effects.MODELS`)
   the model lacks is added with the suspects held at their nominal values (an effect is
   compared with the re-fit on equal terms: a dead time is not explained away by damping)
   and scored on the held-out data (:mod:`.scoring`); the best one that passes the decision
   rule is named, all parameters are re-fitted with it, and the next round starts.
5. :func:`_finish` — final scores; a fitted model worse than the nominal on the held-out
   data is rejected; the adequacy of the model class (:mod:`.adequacy`) and the
   explanation (:mod:`.explain`).

Decision rule (``docs/diagnosis.md``, :data:`DECISION_RULE`): the held-out cost reduction
judged against the noise where the candidate changes the simulation
(:func:`~plant_sim.diagnose.metrics.improvement_test`), p < alpha (0.001), a held-out cost
reduction of at least ``min_improvement`` (0.5 %), and without the held-out block that gains
most p < 0.1. Candidates that the best one does not beat by the same test explain the data
equally well: the one with fewest parameters is named, the others are reported with an
experiment that tells them apart.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from ..axis import AxisConfig
from ..errors import AxisFileError
from ..trace import Trace
from .adequacy import assess
from .effects import MODELS, Effect, Evidence, effects_in, experiment_for
from .evidence import DataScales, data_scales, inverse_dynamics
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
from .metrics import f_test
from .mismatch import (
    Kinematics,
    ResidualTests,
    classify,
    condition_summary,
    find_windows,
    reference_kinematics,
    residual_tests,
)
from .parameters import (
    Suspect,
    base_parameters,
    free_keys,
    held_at_nominal,
    nominal_spec,
    rounded,
    suspects,
)
from .replay import ReplayInput, compared_quantity, prepare_replay, replay
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

#: A candidate whose own parameters alone gain less than SCREEN x min_improvement of the
#: training cost is not re-fitted jointly (it cannot become significant); iterations of that
#: screening fit.
SCREEN = 0.25
#: Largest p-value of the held-out test without the block that gains most (an effect must
#: show in more than one place).
P_REST = 0.1
SCREEN_NFEV = 15


@dataclass
class _Context:
    """What every stage reads: the inputs, the options and the bookkeeping."""

    recording: Trace
    nominal: AxisConfig
    inp: ReplayInput
    val_inps: list[ReplayInput]
    scales: DataScales
    train: np.ndarray
    options: DiagnosisOptions
    progress: ProgressBar | None
    t_start: float
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: objectives no longer used (their simulation counts still add up)
    retired: list[Objective] = field(default_factory=list)

    def tick(self, n: int) -> None:
        if self.progress is not None:
            self.progress.update(n)

    def stage(self, desc: str) -> None:
        if self.progress is not None:
            self.progress.set_description(desc)


@dataclass
class _Base:
    """Stage 2's result: the base model every effect is compared with."""

    spec0: FitSpec
    obj: Objective
    scorer: Scorer
    nominal_fit: FitResult  # the nominal as given, residuals under ``obj``
    refit: FitResult  # the unconstrained re-fit
    base: FitResult  # the one kept (lowest held-out cost)
    score: Score
    loss: np.ndarray
    suspects: list[Suspect]
    hold: list[str]  # keys held at nominal when effects are compared
    decision: str


@dataclass
class _Located:
    kin: Kinematics
    labels: np.ndarray
    residuals: dict[str, np.ndarray]
    tests: list[ResidualTests]
    simulated: Trace


@dataclass
class _Selection:
    added: list[Effect]
    current: FitResult
    score: Score
    loss: np.ndarray
    simulated: Trace
    obj: Objective
    scorer: Scorer
    candidates: dict[tuple[Effect, int], CandidateResult]
    ambiguous: list[Ambiguity]
    hold: list[str]


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
    selection = _select(ctx, base, located)
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
) -> _Context:
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
    return _Context(
        recording, nominal, inp, val_inps, data_scales(inp), train, options, progress, t_start
    )


# ----------------------------------------------------------------------------------------
# 2. re-fit of the nominal model
# ----------------------------------------------------------------------------------------
def _refit_nominal(ctx: _Context) -> _Base:
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
    if hold:
        ctx.stage("re-fit with suspects at nominal")
        params = tuple(p for p in spec0.parameters if p.key not in hold)
        spec_c = restart(
            FitSpec(held_at_nominal(refit.axis, nominal, hold), params, options=spec0.options),
            refit.values,
        )
        constrained = fit(spec_c, obj, opts.max_nfev, 1, opts.seed, ctx.tick)
        s_con, l_con = scorer.score(constrained, len(params))
        options_tried.append(
            (f"the re-fit with {', '.join(hold)} at nominal", constrained, s_con, l_con)
        )
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
    ctx.timings["nominal_refit"] = time.perf_counter() - ctx.t_start
    return _Base(
        spec0, obj, scorer, nominal_fit, refit, best, s_best, l_best, found, hold, decision
    )


# ----------------------------------------------------------------------------------------
# 3. where and when
# ----------------------------------------------------------------------------------------
def _locate(ctx: _Context, base: _Base) -> _Located:
    t0 = time.perf_counter()
    inp = ctx.inp
    sim = replay(base.base.axis, inp, base.base.options)
    kin = reference_kinematics(inp.time_s, inp.recorded["position_reference"], ctx.scales.position)
    labels = classify(kin, ctx.nominal.control.kv)
    res = {s: inp.compared(s) - compared_quantity(inp, s, sim[s]) for s in inp.signals}
    ctx.timings["mismatch"] = time.perf_counter() - t0
    return _Located(kin, labels, res, residual_tests(res, kin), sim)


# ----------------------------------------------------------------------------------------
# 4. forward selection
# ----------------------------------------------------------------------------------------
def _select(ctx: _Context, base: _Base, located: _Located) -> _Selection:
    t0 = time.perf_counter()
    opts = ctx.options
    sel = _Selection(
        added=[],
        current=base.base,
        score=base.score,
        loss=base.loss,
        simulated=located.simulated,
        obj=base.obj,
        scorer=base.scorer,
        candidates={},
        ambiguous=[],
        hold=list(base.hold),
    )
    model_effects = set(effects_in(ctx.nominal))
    fixed: list[str] = []
    last_gain: dict[Effect, float] = {}
    pool = ThreadPoolExecutor(max_workers=opts.jobs) if opts.jobs > 1 else None
    try:
        for rnd in range(1, opts.max_effects + 1):
            cands = [e for e in opts.effects if e not in model_effects]
            if rnd > 1:
                cands = [e for e in cands if last_gain.get(e, 1.0) > 0.0]
            if not cands:
                break
            ctx.stage(f"round {rnd}: {len(cands)} candidates")
            scored = _round(ctx, sel, rnd, cands, fixed, pool, last_gain)
            chosen = _decide(ctx, sel, scored)
            if chosen is None:
                break
            cr, chosen_fit, chosen_loss = chosen
            sel.candidates[(cr.effect, rnd)] = replace(cr, accepted=True)
            sel.added.append(cr.effect)
            model_effects.add(cr.effect)
            ctx.notes.extend(cr.notes)
            fixed += MODELS[cr.effect].fixed_after_naming(sel.current.axis)
            if cr.effect is Effect.COMPLIANCE:
                fixed = [k for k in fixed if not k.startswith("mechanics.")]
            _adopt(ctx, sel, cr, chosen_fit, chosen_loss, fixed)
    finally:
        if pool is not None:
            pool.shutdown()
    ctx.timings["candidates"] = time.perf_counter() - t0
    return sel


def _added_keys(added: Sequence[Effect]) -> list[str]:
    return [k for e in added for k in MODELS[e].refit_keys]


def _round(
    ctx: _Context,
    sel: _Selection,
    rnd: int,
    cands: Sequence[Effect],
    fixed: Sequence[str],
    pool: ThreadPoolExecutor | None,
    last_gain: dict[Effect, float],
) -> list[tuple[CandidateResult, FitResult, np.ndarray]]:
    """Fit every candidate of a round on the model with the suspects at nominal; score,
    test and record them."""
    keys = free_keys(sel.current.axis, _added_keys(sel.added), [*fixed, *sel.hold])
    on = sel.current
    if sel.hold:
        held_axis = held_at_nominal(on.axis, ctx.nominal, sel.hold)
        res = sel.obj.residuals(held_axis, on.options)
        on = replace(on, axis=held_axis, residuals=res, cost=sel.obj.cost(res))
    evidence = Evidence(ctx.inp, sel.simulated, ctx.scales)

    def run(effect: Effect) -> tuple[Effect, FitResult | None, int, list[str], float]:
        t = time.perf_counter()
        out = _fit_candidate(effect, on, keys, ctx, evidence, sel.obj)
        return (*out, time.perf_counter() - t)

    outcomes = list(pool.map(run, cands)) if pool else [run(e) for e in cands]
    scored = []
    cur = sel.score
    for effect, res, n_effect, cnotes, secs in outcomes:
        if res is None:
            if rnd == 1:  # why a candidate was not tried: said once
                ctx.notes.extend(cnotes)
            continue
        score, loss = sel.scorer.score(res, cur.n_free + n_effect)
        f, f_p = f_test(cur.cost, score.cost, cur.n_free, score.n_free, score.n_eff)
        z, p = sel.scorer.test(sel.loss, loss)
        p_rest = sel.scorer.test_without_best_block(sel.loss, loss)
        gain = (cur.cost - score.cost) / cur.cost
        present = MODELS[effect].significant(res.axis, ctx.scales)
        opts = ctx.options
        significant = (
            p < opts.alpha and p_rest < P_REST and gain >= opts.min_improvement and present
        )
        last_gain[effect] = gain
        cr = CandidateResult(
            effect=effect,
            round=rnd,
            parameters=axis_values(res.values),
            heldout=score,
            improvement_percent=100.0 * gain,
            training_improvement_percent=100.0 * (1.0 - res.cost / sel.current.cost),
            z_statistic=z,
            p_value=p,
            p_without_best_block=p_rest,
            f_statistic=f,
            f_p_value=f_p,
            significant=significant,
            accepted=False,
            notes=cnotes,
            n_simulations=res.n_simulations,
            seconds=secs,
        )
        sel.candidates[(effect, rnd)] = cr
        scored.append((cr, res, loss))
    return scored


def _decide(
    ctx: _Context,
    sel: _Selection,
    scored: list[tuple[CandidateResult, FitResult, np.ndarray]],
) -> tuple[CandidateResult, FitResult, np.ndarray] | None:
    """The effect named in a round (None: none qualifies); records the ambiguities."""
    alpha = ctx.options.alpha
    sig = [item for item in scored if item[0].significant]
    if not sig:
        return None
    scorer = sel.scorer
    best_cr, _, best_loss = min(sig, key=lambda item: item[0].heldout.cost)
    losses = {id(cr): lo for cr, _, lo in sig}
    # a candidate the best one does not beat at the naming level explains the data as well;
    # of those the one with fewest parameters is named
    equal = [cr for cr, _, lo in sig if cr is best_cr or scorer.test(lo, best_loss)[1] >= alpha]
    chosen = min(equal, key=lambda c: (c.heldout.n_free, c.heldout.cost))
    chosen_fit, chosen_loss = next((r, lo) for c, r, lo in sig if c is chosen)

    def ambiguity(cr: CandidateResult, p: float) -> Ambiguity:
        return Ambiguity(
            chosen.effect,
            cr.effect,
            cr.heldout.cost / chosen.heldout.cost,
            p,
            experiment_for(chosen.effect, cr.effect),
        )

    for cr in equal:
        if cr is chosen:
            continue
        lo = losses[id(cr)]
        if cr.heldout.cost < chosen.heldout.cost:
            _, p = scorer.test(chosen_loss, lo)
        else:
            _, p = scorer.test(lo, chosen_loss)
        sel.ambiguous.append(ambiguity(cr, p))
    # a candidate that fits the held-out data at least as well as the named one but failed
    # the test on its own (more parameters, more variance) is an alternative too
    for cr, _, lo in scored:
        if cr.significant or cr.heldout.cost > chosen.heldout.cost:
            continue
        sel.ambiguous.append(ambiguity(cr, scorer.test(chosen_loss, lo)[1]))
    return chosen, chosen_fit, chosen_loss


def _adopt(
    ctx: _Context,
    sel: _Selection,
    chosen: CandidateResult,
    chosen_fit: FitResult,
    chosen_loss: np.ndarray,
    fixed: Sequence[str],
) -> None:
    """Make the named effect's model the current one: re-weight the signals by its RMS
    residuals (an effect that removed a large error from one signal would leave that signal
    under-weighted), re-fit all free parameters together under those weights (the next
    candidate must not be credited with what a re-fit of the model's own parameters gains),
    and add parameters the polish drove out of their uncertainty to the held ones."""
    opts = ctx.options
    current = chosen_fit
    weights = signal_weights(sel.obj, current)
    ctx.retired.append(sel.obj)
    old_obj, sel.obj = sel.obj, Objective(ctx.inp, ctx.train, weights)
    val_objs = validation_objectives(ctx.val_inps, weights, sel.scorer.val_objs, ctx.retired)
    sel.scorer = Scorer(sel.obj, val_objs, sel.scorer.blocks, sel.scorer.lags)
    current = rescaled(current, old_obj, sel.obj)
    ctx.stage(f"re-fit with {chosen.effect.value}")
    keys = free_keys(current.axis, _added_keys(sel.added), [*fixed, *sel.hold])
    params = base_parameters(current.axis, keys, ctx.scales, ctx.nominal)
    spec_all = FitSpec(current.axis, params, options=current.options, n_global=0)
    polished = fit(spec_all, sel.obj, 2 * opts.max_nfev, 1, opts.seed, ctx.tick)
    if polished.cost < current.cost:
        current = polished
        more = [s.key for s in suspects(polished, params, ctx.nominal) if s.key in keys]
        sel.hold += [k for k in more if k not in (PERIODIC_COS, PERIODIC_SIN)]
    sel.current = current
    sel.score, sel.loss = sel.scorer.score(current, chosen.heldout.n_free)
    sel.simulated = replay(current.axis, ctx.inp, current.options)


def _fit_candidate(
    effect: Effect,
    base: FitResult,
    keys: Sequence[str],
    ctx: _Context,
    evidence: Evidence,
    obj: Objective,
) -> tuple[Effect, FitResult | None, int, list[str]]:
    """Add ``effect`` to ``base``: (A) fit its own parameters alone from the data-derived
    starts; unless that gains less than SCREEN x min_improvement on the training cost,
    (B) re-fit them jointly with the free parameters of the model from A's optimum.
    Returns the best fit and the number of parameters the effect adds; a candidate that
    cannot be built as a valid axis is skipped with a note (never an abort)."""
    opts = ctx.options
    try:
        cand = MODELS[effect].candidate(base.axis, ctx.nominal, evidence, opts.n_global_candidate)
    except AxisFileError as exc:
        return (
            effect,
            None,
            0,
            [f"{effect.value} not tried: its candidate is no valid axis ({exc})"],
        )
    best: FitResult | None = None
    best_spec: FitSpec | None = None
    try:
        for sp in cand.specs:
            r = fit(sp, obj, SCREEN_NFEV, 1, opts.seed, ctx.tick)
            if best is None or r.cost < best.cost:
                best, best_spec = r, sp
        if best is None or best_spec is None:
            return effect, None, 0, cand.notes
        n_effect = best_spec.n_free
        gain = (base.cost - best.cost) / base.cost
        if gain < SCREEN * opts.min_improvement:
            return effect, best, n_effect, cand.notes
        coupled = base_parameters(base.axis, keys, evidence.scales, ctx.nominal)
        own = [
            Parameter(p.key, p.low, p.high, best.values[p.key], p.scale, p.log)
            for p in best_spec.parameters
        ]
        joint_spec = FitSpec(best.axis, (*coupled, *own), options=best.options, n_global=0)
        joint = fit(joint_spec, obj, opts.max_nfev, 1, opts.seed, ctx.tick)
    except AxisFileError as exc:
        note = f"{effect.value} skipped: a fitted value made the axis invalid ({exc})"
        return effect, None, 0, [*cand.notes, note]
    if joint.cost < best.cost:
        best = replace(joint, values={**best.values, **joint.values})
    return effect, best, n_effect, cand.notes


# ----------------------------------------------------------------------------------------
# 5. final scores, adequacy, explanation
# ----------------------------------------------------------------------------------------
def _finish(ctx: _Context, base: _Base, located: _Located, sel: _Selection) -> Diagnosis:
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
        where = ", ".join(
            f"{k} ({'nominal' if fitted.value(k) == nominal.value(k) else 're-fitted'} in "
            "axis_fitted.toml)"
            for k in sel.hold
        )
        ctx.notes.append(
            "held at their nominal values while effects were compared (a re-fit moved them "
            f"beyond their data-sheet uncertainty or onto a bound): {where}"
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


def axis_values(values: Mapping[str, float]) -> dict[str, float]:
    """Fitted values keyed by axis keys (the periodic pseudo-keys become amplitude/phase)."""
    out = {k: float(v) for k, v in values.items() if k not in (PERIODIC_COS, PERIODIC_SIN)}
    if PERIODIC_COS in values or PERIODIC_SIN in values:
        c, s = values.get(PERIODIC_COS, 0.0), values.get(PERIODIC_SIN, 0.0)
        out["disturbance.periodic_amplitude"] = math.hypot(c, s)
        out["disturbance.periodic_phase"] = math.atan2(s, c)
    return out

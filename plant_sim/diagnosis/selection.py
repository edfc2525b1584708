"""Forward selection of the effects the model leaves out (stage 4 of :func:`.engine.diagnose`).

Every effect of the table the model lacks (:data:`.effects.MODELS`) is added to the current
model with the suspects held within their data-sheet uncertainty and scored on the held-out data
(:class:`.scoring.Scorer`); the best one that passes the decision rule is named
(:func:`_decide`), all parameters are re-fitted with it (:func:`_adopt`), and the next round
starts, until none qualifies.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import Trace

from .effects import MODELS, Effect, Evidence, effects_in, experiment_for
from .fit import PERIODIC_COS, PERIODIC_SIN, FitResult, FitSpec, Objective, Parameter, fit
from .metrics import f_test
from .parameters import base_parameters, free_keys, held_within, suspects
from .replay import replay
from .results import Ambiguity, CandidateResult, Score
from .scoring import Scorer, rescaled, signal_weights, validation_objectives
from .stages import Base, Context, Located, axis_values

#: A candidate whose own parameters alone gain less than SCREEN x min_improvement of the
#: training cost is not re-fitted jointly (it cannot become significant); iterations of that
#: screening fit.
SCREEN = 0.25
#: Largest p-value of the held-out test without the block that gains most (an effect must
#: show in more than one place).
P_REST = 0.1
SCREEN_NFEV = 15


@dataclass
class Selection:
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


def select(ctx: Context, base: Base, located: Located) -> Selection:
    t0 = time.perf_counter()
    opts = ctx.options
    sel = Selection(
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
    ctx: Context,
    sel: Selection,
    rnd: int,
    cands: Sequence[Effect],
    fixed: Sequence[str],
    pool: ThreadPoolExecutor | None,
    last_gain: dict[Effect, float],
) -> list[tuple[CandidateResult, FitResult, np.ndarray]]:
    """Fit every candidate of a round on the model with the suspects within their data-sheet
    uncertainty; score, test and record them."""
    keys = free_keys(sel.current.axis, _added_keys(sel.added), fixed)
    on = sel.current
    if sel.hold:
        held_axis = held_within(on.axis, ctx.nominal, sel.hold)
        res = sel.obj.residuals(held_axis, on.options)
        on = replace(on, axis=held_axis, residuals=res, cost=sel.obj.cost(res))
    evidence = Evidence(ctx.inp, sel.simulated, ctx.scales)

    def run(effect: Effect) -> tuple[Effect, FitResult | None, int, list[str], float]:
        t = time.perf_counter()
        out = _fit_candidate(effect, on, keys, sel.hold, ctx, evidence, sel.obj)
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
    ctx: Context,
    sel: Selection,
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
    p_best = [1.0 if cr is best_cr else scorer.test(lo, best_loss)[1] for cr, _, lo in sig]
    i_chosen, i_equal = name_among(
        [cr.heldout.n_free for cr, _, _ in sig],
        [cr.heldout.cost for cr, _, _ in sig],
        p_best,
        alpha,
        ctx.options.choice_alpha,
        ctx.options.min_improvement,
    )
    chosen = sig[i_chosen][0]
    equal = [sig[i][0] for i in i_equal]
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


def name_among(
    n_free: Sequence[int],
    cost: Sequence[float],
    p_best: Sequence[float],
    alpha: float,
    choice_alpha: float,
    min_improvement: float,
) -> tuple[int, list[int]]:
    """Which of the significant candidates of a round is named, and which explain the data as
    well (indices into the inputs: parameters counted, held-out cost, and the one-sided p
    that the lowest-cost candidate fits the held-out data better than this one, 1 for
    itself).

    A candidate that the best one does not beat at the naming level ``alpha`` explains the
    data as well: it is ambiguous with the named one. Which one is named is a choice
    between explanations of an effect the data already show, made by the naming rule's own
    two conditions at the usual level (Occam): the one with fewest parameters (then the lower
    cost) among those that the best one does not beat at p < ``choice_alpha`` with a held-out
    cost at least ``min_improvement`` lower. Asymmetric Coulomb friction and a constant load
    torque are the same law while the axis moves; the asymmetric friction, one parameter
    more, is named only when it fits the held-out data better by both conditions."""
    n = len(cost)
    best = min(cost)
    equal = [i for i in range(n) if p_best[i] >= alpha]
    beaten = [
        p_best[i] < choice_alpha and cost[i] - best >= min_improvement * cost[i] for i in range(n)
    ]
    chosen = min((i for i in equal if not beaten[i]), key=lambda i: (n_free[i], cost[i]))
    return chosen, equal


def _adopt(
    ctx: Context,
    sel: Selection,
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
    keys = free_keys(current.axis, _added_keys(sel.added), fixed)
    params = base_parameters(current.axis, keys, ctx.scales, ctx.nominal, sel.hold)
    spec_all = FitSpec(current.axis, params, options=current.options, n_global=0)
    polished = fit(spec_all, sel.obj, 2 * opts.max_nfev, 1, opts.seed, ctx.tick)
    if polished.cost < current.cost:
        current = polished
        more = [s.key for s in suspects(polished, params, ctx.nominal) if s.key in keys]
        sel.hold += [k for k in more if k not in (PERIODIC_COS, PERIODIC_SIN, *sel.hold)]
    sel.current = current
    sel.score, sel.loss = sel.scorer.score(current, chosen.heldout.n_free)
    sel.simulated = replay(current.axis, ctx.inp, current.options)


def _fit_candidate(
    effect: Effect,
    base: FitResult,
    keys: Sequence[str],
    hold: Sequence[str],
    ctx: Context,
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
        coupled = base_parameters(base.axis, keys, evidence.scales, ctx.nominal, hold)
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

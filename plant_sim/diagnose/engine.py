"""The whole diagnosis: recording + nominal axis file -> what the model leaves out.

1. Prepare the closed-loop replay (:mod:`.replay`) and cut the recording into blocks of about
   1 s, the even ones to fit on and the odd ones held out (or fit on the whole recording and
   hold out a second one, ``validation``).
2. Re-fit the nominal model's uncertain parameters (mass, friction, elasticity, ... that are
   present) by simulation error, bounded, robust and multi-start (:mod:`.fit`): a model that
   only had wrong parameters ends here with nothing left out. Signals are weighted by the RMS
   residual of the nominal model, then of the re-fitted one (maximum-likelihood weighting,
   re-estimated after every named effect).
3. Forward selection: every effect of the axis-file table the model lacks is added (its own
   parameters first, then jointly with all free parameters) and scored on the held-out data
   (:mod:`.scoring`). The best one is named when its held-out improvement passes the decision
   rule below; all parameters are re-fitted with it and the next round starts, until no
   candidate qualifies.
4. Locate the re-fitted nominal model's residual in time and by operating condition, test
   its whiteness and its correlation with set point, speed sign, acceleration and position
   (:mod:`.mismatch`), and explain (:mod:`.explain`).

Decision rule (``docs/diagnosis.md``, :data:`DECISION_RULE`): the held-out cost reduction
judged against the noise where the candidate changes the simulation
(:func:`~plant_sim.diagnose.metrics.improvement_test`), p < alpha (0.001, about 1 % over the
ten candidates of a round), and a held-out cost reduction of at least ``min_improvement``
(0.5 %), and without the held-out block that gains most p < 0.1 (an effect shows in
more than one place, not only where one event of another error sits). Candidates that the
best one does not beat by the same test at the same level
explain the data equally well: the one with fewest parameters is named, the others are
reported with an experiment that tells them apart.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from ..axis import AxisConfig
from ..trace import Trace
from .effects import (
    Effect,
    Evidence,
    base_parameters,
    candidate_specs,
    data_scales,
    effect_present,
    effects_in,
    experiment_for,
    free_keys,
    inverse_dynamics,
    nominal_spec,
)
from .explain import explain
from .fit import (
    PERIODIC_COS,
    PERIODIC_SIN,
    FitResult,
    FitSpec,
    Objective,
    Parameter,
    fit,
    restart,
)
from .metrics import (
    f_test,
)
from .mismatch import (
    classify,
    condition_summary,
    find_windows,
    reference_kinematics,
    residual_tests,
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
    block_index,
    rescaled,
    signal_weights,
    training_blocks,
    validation_objective,
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


def diagnose(
    recording: Trace,
    nominal: AxisConfig,
    validation: Trace | None = None,
    options: DiagnosisOptions = DEFAULT_OPTIONS,
    progress: ProgressBar | None = None,
) -> Diagnosis:
    """Diagnose what ``nominal`` leaves out of ``recording`` (see the module docstring).

    Raises DiagnosisInputError when the recording and the axis do not fit together.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    inp = prepare_replay(recording, nominal)
    val_inp = prepare_replay(validation, nominal, "validation recording") if validation else None
    scales = data_scales(inp)
    train = (
        training_blocks(inp.time_s, options.block_s)
        if val_inp is None
        else np.ones(inp.n_samples, dtype=bool)
    )

    def tick(n: int) -> None:
        if progress is not None:
            progress.update(n)

    def stage(desc: str) -> None:
        if progress is not None:
            progress.set_description(desc)

    # --- 1. nominal as given, and the re-fit (two weighting passes) -------------------------
    stage("nominal")
    unit = {s: 1.0 for s in inp.signals}
    spec0 = nominal_spec(
        nominal, scales, inverse_dynamics(inp, nominal, scales), options.n_global_nominal
    )
    obj_unit = Objective(inp, train, unit)
    before_res = obj_unit.residuals(nominal, spec0.options)
    before_fit = FitResult({}, nominal, 0.0, before_res, spec0.n_free, 1, 1, "", spec0.options)
    weights = signal_weights(obj_unit, before_fit)
    obj1 = Objective(inp, train, weights)
    stage("re-fit nominal")
    refit1 = fit(spec0, obj1, options.max_nfev, options.n_starts, options.seed, tick)
    weights = signal_weights(obj1, refit1)
    obj = Objective(inp, train, weights)
    refit = fit(restart(spec0, refit1.values), obj, options.max_nfev, 1, options.seed, tick)
    timings["nominal_refit"] = time.perf_counter() - t_start
    retired: list[Objective] = [obj_unit, obj1]
    obj_refit = obj
    val_obj = validation_objective(val_inp, weights, None, retired)
    if val_inp is None:
        blocks = block_index(inp.time_s, options.block_s)[~train]
    else:
        blocks = block_index(val_inp.time_s, options.block_s)
    scorer = Scorer(obj, val_obj, blocks)
    base_score, base_loss = scorer.score(refit, spec0.n_free)
    scorer.lags = max(5, round(2.0 * base_score.n_samples / base_score.n_eff))

    # --- 2. where and when ------------------------------------------------------------------
    t0 = time.perf_counter()
    sim_refit = replay(refit.axis, inp, refit.options)
    kin = reference_kinematics(inp.time_s, inp.recorded["position_reference"], scales.position)
    labels = classify(kin, nominal.control.kv)
    phys_res = {s: inp.compared(s) - compared_quantity(inp, s, sim_refit[s]) for s in inp.signals}
    tests_refit = residual_tests(phys_res, kin)
    timings["mismatch"] = time.perf_counter() - t0

    # --- 3. forward selection --------------------------------------------------------------
    t0 = time.perf_counter()
    model_effects = set(effects_in(nominal))
    added: list[Effect] = []
    fixed: list[str] = []
    notes: list[str] = []
    current = refit
    current_score = base_score
    current_loss = base_loss
    current_sim = sim_refit
    all_results: dict[tuple[Effect, int], CandidateResult] = {}
    ambiguous: list[Ambiguity] = []
    last_improvement: dict[Effect, float] = {}
    pool = ThreadPoolExecutor(max_workers=options.jobs) if options.jobs > 1 else None
    try:
        for rnd in range(1, options.max_effects + 1):
            cands = [e for e in options.effects if e not in model_effects]
            if rnd > 1:
                cands = [e for e in cands if last_improvement.get(e, 1.0) > 0.0]
            if not cands:
                break
            stage(f"round {rnd}: {len(cands)} candidates")
            keys = free_keys(current.axis, added, fixed)
            evidence = Evidence(inp, current_sim, scales)

            def run(
                effect: Effect,
                keys: Sequence[str] = keys,
                ev: Evidence = evidence,
                base: FitResult = current,
                objective: Objective = obj,
            ) -> tuple[Effect, FitResult | None, int, list[str], float]:
                t = time.perf_counter()
                return (
                    *_fit_candidate(effect, base, keys, nominal, ev, objective, options, tick),
                    time.perf_counter() - t,
                )

            outcomes = list(pool.map(run, cands)) if pool else [run(e) for e in cands]
            round_results = []
            for effect, res, n_effect, cnotes, secs in outcomes:
                if res is None:
                    continue
                score, loss = scorer.score(res, current_score.n_free + n_effect)
                round_results.append((effect, res, n_effect, cnotes, secs, score, loss))
            scored = []
            for effect, res, _n_effect, cnotes, secs, score, loss in round_results:
                f, f_p = f_test(
                    current_score.cost, score.cost, current_score.n_free, score.n_free, score.n_eff
                )
                z, p = scorer.test(current_loss, loss)
                p_rest = scorer.test_without_best_block(current_loss, loss)
                gain = (current_score.cost - score.cost) / current_score.cost
                present = effect_present(effect, res.axis, scales)
                significant = (
                    p < options.alpha
                    and p_rest < P_REST
                    and gain >= options.min_improvement
                    and present
                )
                last_improvement[effect] = gain
                cr = CandidateResult(
                    effect=effect,
                    round=rnd,
                    parameters=axis_values(res.values),
                    heldout=score,
                    improvement_percent=100.0 * gain,
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
                all_results[(effect, rnd)] = cr
                scored.append((cr, res, loss))
            sig = [item for item in scored if item[0].significant]
            if not sig:
                break
            best_cr, _, best_loss = min(sig, key=lambda item: item[0].heldout.cost)
            losses = {id(cr): lo for cr, _, lo in sig}
            # a candidate the best one does not beat at the naming level explains the data
            # as well; of those the one with fewest parameters is named
            equal = [
                cr
                for cr, _, lo in sig
                if cr is best_cr or scorer.test(lo, best_loss)[1] >= options.alpha
            ]
            chosen = min(equal, key=lambda c: (c.heldout.n_free, c.heldout.cost))
            chosen_fit, chosen_loss = next((r, lo) for c, r, lo in sig if c is chosen)
            for cr in equal:
                if cr is chosen:
                    continue
                lo = losses[id(cr)]
                if cr.heldout.cost < chosen.heldout.cost:
                    _, p = scorer.test(chosen_loss, lo)
                else:
                    _, p = scorer.test(lo, chosen_loss)
                ambiguous.append(
                    Ambiguity(
                        chosen.effect,
                        cr.effect,
                        cr.heldout.cost / chosen.heldout.cost,
                        p,
                        experiment_for(chosen.effect, cr.effect),
                    )
                )
            # a candidate that fits the held-out data at least as well as the named one but
            # failed the test on its own (more parameters, more variance) is an alternative too
            for cr, _, lo in scored:
                if cr.significant or cr.heldout.cost > chosen.heldout.cost:
                    continue
                _, p = scorer.test(chosen_loss, lo)
                ambiguous.append(
                    Ambiguity(
                        chosen.effect,
                        cr.effect,
                        cr.heldout.cost / chosen.heldout.cost,
                        p,
                        experiment_for(chosen.effect, cr.effect),
                    )
                )
            all_results[(chosen.effect, rnd)] = replace(chosen, accepted=True)
            added.append(chosen.effect)
            model_effects.add(chosen.effect)
            notes += chosen.notes
            if chosen.effect is Effect.BACKLASH and current.axis.is_rigid:
                fixed += ["mechanics.antiresonance", "mechanics.damping_ratio"]
            if chosen.effect is Effect.COMPLIANCE:
                fixed = [k for k in fixed if not k.startswith("mechanics.")]
            current = chosen_fit
            current_score = chosen.heldout
            current_loss = chosen_loss
            # re-weight the signals by the new model's RMS residuals (an effect that removed
            # a large error from one signal would leave that signal under-weighted), then
            # re-fit all free parameters together under those weights before the next round
            # (the next candidate must not be credited with what a re-fit of the model's own
            # parameters gains)
            weights = signal_weights(obj, current)
            retired.append(obj)
            old_obj, obj = obj, Objective(inp, train, weights)
            val_obj = validation_objective(val_inp, weights, val_obj, retired)
            scorer = Scorer(obj, val_obj, scorer.blocks, scorer.lags)
            current = rescaled(current, old_obj, obj)
            stage(f"round {rnd}: re-fit with {chosen.effect.value}")
            keys = free_keys(current.axis, added, fixed)
            spec_all = FitSpec(
                current.axis,
                base_parameters(current.axis, keys, scales, nominal),
                options=current.options,
                n_global=0,
            )
            polished = fit(spec_all, obj, 2 * options.max_nfev, 1, options.seed, tick)
            if polished.cost < current.cost:
                current = polished
            current_score, current_loss = scorer.score(current, current_score.n_free)
            current_sim = replay(current.axis, inp, current.options)
    finally:
        if pool is not None:
            pool.shutdown()
    timings["candidates"] = time.perf_counter() - t0

    # --- 4. final scores ------------------------------------------------------------------
    sim_before = replay(nominal, inp, spec0.options)
    sim_after = current_sim
    final_res = {s: inp.compared(s) - compared_quantity(inp, s, sim_after[s]) for s in inp.signals}
    tests_final = residual_tests(final_res, kin)
    windows = find_windows(phys_res, kin, labels, final_res if added else None)
    refit_values = {}
    for key, value in axis_values(refit.values).items():
        nominal_value = nominal.value(key)
        refit_values[key] = (
            float(nominal_value) if nominal_value is not None else math.nan,
            value,
        )
    # every try, ranked: round by round, the named one first, then by held-out improvement
    ranked = sorted(
        all_results.values(),
        key=lambda c: (c.round, not c.accepted, -c.improvement_percent),
    )
    timings["total"] = time.perf_counter() - t_start
    diag = Diagnosis(
        left_out=list(added),
        candidates=ranked,
        ambiguous=ambiguous,
        mismatch=windows,
        mismatch_by_condition=condition_summary(windows),
        tests_refit=tests_refit,
        tests_final=tests_final,
        fit_before=signal_fits(inp, sim_before),
        fit_refit=signal_fits(inp, sim_refit),
        fit_after=signal_fits(inp, sim_after),
        heldout_refit=(
            base_score
            if obj is obj_refit
            else scorer.score(rescaled(refit, obj_refit, obj), spec0.n_free)[0]
        ),
        heldout_final=current_score,
        nominal=nominal,
        refit=refit.axis,
        fitted=current.axis,
        refit_values=refit_values,
        notes=notes,
        explanation="",
        simulated_before=sim_before,
        simulated_refit=sim_refit,
        simulated_after=sim_after,
        recording=recording,
        validation="interleaved blocks" if val_inp is None else "second recording",
        timings_s=timings,
        n_simulations=sum(o.n_simulations for o in [*retired, obj])
        + (val_obj.n_simulations if val_obj else 0),
        options=options,
    )
    diag.explanation = explain(diag)
    return diag


def axis_values(values: Mapping[str, float]) -> dict[str, float]:
    """Fitted values keyed by axis keys (the periodic pseudo-keys become amplitude/phase)."""
    out = {k: float(v) for k, v in values.items() if k not in (PERIODIC_COS, PERIODIC_SIN)}
    if PERIODIC_COS in values or PERIODIC_SIN in values:
        c, s = values.get(PERIODIC_COS, 0.0), values.get(PERIODIC_SIN, 0.0)
        out["disturbance.periodic_amplitude"] = math.hypot(c, s)
        out["disturbance.periodic_phase"] = math.atan2(s, c)
    return out


def _fit_candidate(
    effect: Effect,
    base: FitResult,
    keys: Sequence[str],
    nominal: AxisConfig,
    evidence: Evidence,
    obj: Objective,
    options: DiagnosisOptions,
    tick: Callable[[int], None],
) -> tuple[Effect, FitResult | None, int, list[str]]:
    """Add ``effect`` to ``base``: (A) fit its own parameters alone from the data-derived
    starts; unless that gains less than SCREEN x min_improvement on the training cost,
    (B) re-fit them jointly with all free parameters of the model from A's optimum.
    Returns the best fit and the number of parameters the effect adds."""
    specs, notes = candidate_specs(effect, base.axis, nominal, evidence, options.n_global_candidate)
    best: FitResult | None = None
    best_spec: FitSpec | None = None
    for sp in specs:
        r = fit(sp, obj, SCREEN_NFEV, 1, options.seed, tick)
        if best is None or r.cost < best.cost:
            best, best_spec = r, sp
    if best is None or best_spec is None:
        return effect, None, 0, notes
    n_effect = best_spec.n_free
    gain = (base.cost - best.cost) / base.cost
    coupled = base_parameters(base.axis, keys, evidence.scales, nominal)
    if gain < SCREEN * options.min_improvement:
        return effect, best, n_effect, notes
    own = [
        Parameter(p.key, p.low, p.high, best.values[p.key], p.scale, p.log)
        for p in best_spec.parameters
    ]
    joint_spec = FitSpec(best.axis, (*coupled, *own), options=best.options, n_global=0)
    joint = fit(joint_spec, obj, options.max_nfev, 1, options.seed, tick)
    if joint.cost < best.cost:
        values = {**best.values, **joint.values}
        best = replace(joint, values=values)
    return effect, best, n_effect, notes

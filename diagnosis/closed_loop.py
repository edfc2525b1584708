"""Stage 2: the named effects modelled and re-fitted in closed loop, checked on held-out data
(docs/diagnosis.md, "Closed loop").

The evidence stage (:mod:`.screen`) has named the effects and estimated every parameter by
linear regressions. Here the whole axis is fitted by closed-loop simulation error
(:mod:`.fit`, :mod:`.replay`) — the model a user simulates with — from those estimates:

* **the nominal within its data sheet**: the nominal with its uncertain parameters where the
  evidence puts them, within their data-sheet uncertainty (:data:`.parameters.UNCERTAINTY`),
  the reference the named effects are scored against (re-fitted in closed loop within those
  boxes when nothing is named: then it is the fitted model);
* **the model with the named effects**: the same, with the named effects' parameters free
  around their evidence estimates. A parameter the evidence puts beyond its data-sheet
  uncertainty (beyond three standard errors: the data sheet is wrong) is free around the
  evidence's value instead, and the report says so (:class:`Bound`);
* **each ambiguous alternative** (two effects that explain the same signature, e.g. a load
  torque and direction-dependent Coulomb friction while the axis moves): the model with the
  other one instead. The held-out data decide between them: the evidence named the one with
  fewer parameters; the other is named instead when it fits the held-out data at least as
  well with fewer parameters, or better at ``choice_alpha`` by at least ``min_improvement``.

Held-out data: the odd blocks of the recording, or the ``--validate`` recordings
(:mod:`.scoring`); every model is scored there and the improvement of the model with the
named effects over the nominal within its data sheet is tested against the noise
(:func:`.metrics.improvement_test`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace

import numpy as np

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.errors import AxisFileError

from .effects import MODELS, Effect
from .fit import (
    PERIODIC_COS,
    PERIODIC_SIN,
    DiscreteParameter,
    FitResult,
    FitSpec,
    Objective,
    Parameter,
    fit,
)
from .parameters import (
    UNCERTAIN_KEYS,
    current_value,
    max_antiresonance,
    options_for,
    parameter_for,
    physical,
    uncertainty_box,
    with_contact,
    within_format,
)
from .results import Score
from .scoring import Scorer, heldout_blocks, signal_weights, validation_objectives
from .screen import Screening, effect_values
from .stages import Context

#: Dead times around the evidence's estimate, in speed cycles either side.
DELAY_SPAN = 2
#: The held-out data are cut into this many consecutive parts (the early and the late moves of
#: a recording, the slow and the fast part of a chirp): the re-fit within the data sheet
#: replaces the nominal only if it predicts every part at least as well.
HELDOUT_PARTS = 2
#: Relative half-width of the box of a parameter the evidence puts beyond its data sheet,
#: at least (three standard errors otherwise).
EVIDENCE_BOX = 0.1


@dataclass(frozen=True)
class Bound:
    """How far the closed-loop fit may move a parameter, and why."""

    key: str
    low: float
    high: float
    start: float
    source: str  # "data sheet", "evidence (data sheet wrong)", "named effect", "fixed"


@dataclass(frozen=True)
class ModelFit:
    """One model fitted in closed loop and scored on the held-out data."""

    name: str
    effects: tuple[Effect, ...]
    result: FitResult
    heldout: Score
    loss: np.ndarray
    bounds: tuple[Bound, ...] = ()


@dataclass(frozen=True)
class GateStep:
    """The held-out gate of one effect the evidence named: the held-out cost of the model
    without it and with it (both fitted alike), the gain, the improvement test, kept or not."""

    effect: Effect
    cost_without: float
    cost_with: float
    gain: float
    z: float
    p: float
    kept: bool


@dataclass
class ClosedLoop:
    """Stage 2's result (module docstring)."""

    nominal: ModelFit  # as given, not fitted
    base: ModelFit  # the nominal within its data sheet
    final: ModelFit  # with the named effects
    alternatives: list[ModelFit]
    left_out: list[Effect]
    swaps: list[str]
    improvement_percent: float  # held-out cost base -> final
    z: float
    p: float
    obj: Objective
    scorer: Scorer
    n_simulations: int
    seconds: float
    notes: list[str] = field(default_factory=list)
    gate: list[GateStep] = field(default_factory=list)


def worse_part(
    nominal_loss: np.ndarray, loss: np.ndarray, share: float, parts: int = HELDOUT_PARTS
) -> int:
    """The first of ``parts`` consecutive parts of the held-out samples where ``loss`` (rows:
    signals, the scaled held-out residuals of :meth:`.scoring.Scorer.score`) costs more than
    ``nominal_loss`` by more than ``share`` of the nominal's whole held-out cost (the least
    improvement an effect must bring, the same bar the other way); -1 where none does."""
    n = loss.shape[1]
    tol = share * float(np.sum(nominal_loss**2))
    edges = np.linspace(0, n, parts + 1).astype(int)
    for i in range(parts):
        a, b = edges[i], edges[i + 1]
        more = float(np.sum(loss[:, a:b] ** 2)) - float(np.sum(nominal_loss[:, a:b] ** 2))
        if b > a and more > tol:
            return i
    return -1


def _present_uncertain(axis: AxisConfig) -> list[str]:
    keys = [k for k in UNCERTAIN_KEYS if axis.value(k) is not None]
    if axis.is_rigid and "mechanics.backlash" in keys:
        keys.remove("mechanics.backlash")
    out: list[str] = []
    for k in keys:
        if k == "disturbance.periodic_amplitude":
            out += [PERIODIC_COS, PERIODIC_SIN]
        elif k not in ("disturbance.periodic_phase", "friction.creep_speed"):
            out.append(k)
    return out


def _effect_keys(effects: Sequence[Effect], axis: AxisConfig) -> list[str]:
    out: list[str] = []
    for e in effects:
        for k in MODELS[e].keys:
            if k == "disturbance.periodic_amplitude":
                out += [PERIODIC_COS, PERIODIC_SIN]
            elif k == "disturbance.periodic_phase" or k == "control.delay":
                continue
            elif axis.value(k) is not None:
                out.append(k)
        if e is Effect.ASYMMETRIC_FRICTION and axis.friction.coulomb is not None:
            # the friction of the positive direction is the other half of the effect: it
            # may leave the data sheet's box as the negative one does
            out.append("friction.coulomb")
    return out


def parameters_for_fit(
    ctx: Context, axis: AxisConfig, effects: Sequence[Effect], screening: Screening
) -> tuple[tuple[Parameter, ...], DiscreteParameter | None, list[Bound]]:
    """The free parameters of ``axis`` (the nominal's uncertain keys, within their data
    sheet or around the evidence's value where it says the sheet is wrong, and the keys of
    ``effects`` around their evidence estimates), the dead time as a discrete parameter when
    it is one of ``effects``."""
    nominal, scales = ctx.nominal, ctx.scales
    wrong = {p.key: p for p in screening.parameters if p.beyond}
    effect_keys = _effect_keys(effects, axis)
    fixed_keys: set[str] = set()
    if Effect.BACKLASH in effects and nominal.is_rigid and Effect.COMPLIANCE not in effects:
        # the free play's contact stiffness on a rigid model is not fitted
        fixed_keys |= {"mechanics.antiresonance", "mechanics.damping_ratio"}
    params: list[Parameter] = []
    bounds: list[Bound] = []
    for k in dict.fromkeys(_present_uncertain(axis) + effect_keys):
        if k in fixed_keys:
            continue
        value = current_value(axis, k)
        try:
            p = parameter_for(k, value, scales, nominal, axis)
        except KeyError:
            continue
        source = "named effect" if k in effect_keys else "data sheet"
        if k in wrong:
            ev = wrong[k]
            half = max(3.0 * ev.standard_error, EVIDENCE_BOX * abs(ev.estimate))
            lo, hi = ev.estimate - half, ev.estimate + half
            if p.log:
                lo = max(lo, 1e-12 * abs(ev.estimate))
            elif not physical(k, lo):
                lo = max(lo, 0.0)
            if lo < hi:
                p = Parameter(k, lo, hi, value, p.scale, p.log)
                source = "evidence (data sheet wrong)"
        elif k not in effect_keys:
            box = uncertainty_box(k, nominal)
            if box is not None and box[0] < box[1]:
                lo, hi = max(p.low, box[0]), min(p.high, box[1])
                if lo < hi:
                    p = Parameter(k, lo, hi, value, p.scale, p.log)
        if k == "mechanics.antiresonance":
            wmax = max_antiresonance(axis)
            if wmax > p.low:
                p = Parameter(k, p.low, min(p.high, max(wmax, value * 1.01)), value, p.scale, p.log)
        p = within_format(p)
        params.append(p)
        bounds.append(Bound(k, p.low, p.high, p.start, source))
    discrete = None
    if Effect.TIME_DELAY in effects and axis.control.delay:
        cyc = axis.control.speed_cycle
        n = max(1, round(axis.control.delay / cyc))
        grid = tuple(m * cyc for m in range(max(1, n - DELAY_SPAN), n + DELAY_SPAN + 1))
        discrete = DiscreteParameter("control.delay", grid, axis.control.delay)
        bounds.append(Bound("control.delay", grid[0], grid[-1], axis.control.delay, "named effect"))
    return tuple(params), discrete, bounds


def _fit_model(
    ctx: Context,
    name: str,
    axis: AxisConfig,
    effects: Sequence[Effect],
    screening: Screening,
    obj: Objective,
    scorer: Scorer,
    pool: Executor | None,
) -> ModelFit:
    params, discrete, bounds = parameters_for_fit(ctx, axis, effects, screening)
    wa_hi = next((p.high for p in params if p.key == "mechanics.antiresonance"), None)
    options = options_for(wa_hi if wa_hi is not None else axis.mechanics.antiresonance, axis)
    spec = FitSpec(axis, params, (), discrete, options, n_global=0)
    res = fit(spec, obj, ctx.options.max_nfev, 1, ctx.options.seed, ctx.tick, pool)
    n_free = len(params) + (1 if discrete is not None else 0)
    score, loss = scorer.score(res, n_free)
    return ModelFit(name, tuple(effects), res, score, loss, tuple(bounds))


def _equivalent(
    named: Effect, other: Effect, axis: AxisConfig
) -> tuple[dict[str, float | None], str]:
    """The values of ``other`` that make the same torque as ``named`` at the fitted ``axis``,
    where the two are one torque law while the axis moves: a load torque τ_L on Coulomb
    friction c is friction c + τ_L in the positive direction and c − τ_L in the negative
    one (exact at any speed ≠ 0). Empty where no such rule is known (the evidence's
    estimate is used then)."""
    f = axis.friction
    pair = (named, other) == (Effect.CONSTANT_LOAD_TORQUE, Effect.ASYMMETRIC_FRICTION)
    if pair and f.coulomb is not None:
        load = axis.disturbance.constant_torque or 0.0
        pos, neg = f.coulomb + load, f.coulomb - load
        if pos < 0.0 or neg < 0.0:
            return {}, f"the load torque exceeds the Coulomb friction ({load:.3g})"
        return {
            "friction.coulomb": pos,
            "friction.coulomb_negative": neg,
            "friction.viscous_negative": f.viscous or 0.0,
        }, ""
    return {}, "no equivalence rule"


def _without(axis: AxisConfig, effect: Effect, nominal: AxisConfig) -> AxisConfig:
    """``axis`` with ``effect`` taken out again (its keys as in the nominal)."""
    return axis.with_values({k: nominal.value(k) for k in MODELS[effect].keys})


def _only(
    model: AxisConfig, keep: Sequence[Effect], named: Sequence[Effect], nominal: AxisConfig
) -> AxisConfig:
    """``model`` (the evidence's, with every named effect) with the named effects not in
    ``keep`` taken out again. Free play kept on a rigid nominal without the compliance keeps
    the stiff contact it was tested with (:func:`.parameters.with_contact`)."""
    out = model
    for e in named:
        if e in keep:
            continue
        if e is Effect.COMPLIANCE and Effect.BACKLASH in keep and nominal.is_rigid:
            play = out.mechanics.backlash
            rigid = _without(_without(out, Effect.BACKLASH, nominal), e, nominal)
            contact = with_contact(rigid)
            if contact is None:
                raise AxisFileError("free play on a lumped rigid model has no contact")
            out = contact.with_values({"mechanics.backlash": play})
        else:
            out = _without(out, e, nominal)
    return out


def closed_loop(ctx: Context, screening: Screening, pool: Executor | None = None) -> ClosedLoop:
    """Stage 2 (module docstring)."""
    t0 = time.perf_counter()
    opts, nominal, inp = ctx.options, ctx.nominal, ctx.inp
    model = screening.model
    named = list(screening.named)
    # one weighting of the signals for every model: the RMS residual of the evidence's model
    unit = Objective(inp, ctx.train, {s: 1.0 for s in inp.signals})
    ev_options = options_for(model.mechanics.antiresonance, model)
    ev_res = unit.residuals(model, ev_options)
    ev_fit = FitResult({}, model, unit.cost(ev_res), ev_res, 0, 1, 1, "evidence", ev_options)
    weights = signal_weights(unit, ev_fit)
    obj = Objective(inp, ctx.train, weights)
    val_objs = validation_objectives(ctx.val_inps, weights, [], ctx.retired)
    blocks = heldout_blocks(inp.time_s, ctx.train, ctx.val_inps, opts.block_s)
    scorer = Scorer(obj, val_objs, blocks)
    ctx.retired.append(unit)
    # the nominal as given
    nom_options = options_for(nominal.mechanics.antiresonance, nominal)
    nom_res = obj.residuals(nominal, nom_options)
    nom_fit = FitResult({}, nominal, obj.cost(nom_res), nom_res, 0, 1, 1, "as given", nom_options)
    s_nom, l_nom = scorer.score(nom_fit, 0)
    scorer.lags = max(5, round(2.0 * s_nom.n_samples / s_nom.n_eff))
    nominal_mf = ModelFit("the nominal as given", (), nom_fit, s_nom, l_nom)
    # the nominal within its data sheet, started where the evidence puts its parameters
    start = {k: model.value(k) for k in UNCERTAIN_KEYS if nominal.value(k) is not None}
    try:
        base_axis = nominal.with_values(start)
    except AxisFileError:
        base_axis = nominal
    # the reference the named effects are scored against: the nominal re-fitted within its
    # data sheet exactly as the models with effects are fitted (same data, same iterations),
    # so an effect is not credited with what the re-fit of the nominal's own parameters gains
    ctx.stage("closed loop: the nominal within its data sheet")
    base = _fit_model(
        ctx, "the nominal within its data sheet", base_axis, (), screening, obj, scorer, pool
    )
    alternatives: list[ModelFit] = []
    swaps: list[str] = []
    notes: list[str] = []
    if base.heldout.cost > nominal_mf.heldout.cost:
        # the held-out data decide: a re-fit that fits the training data better and
        # predicts the held-out data worse is not kept
        notes.append(
            "the re-fit within the data sheet predicts the held-out data worse than the "
            f"nominal as given ({nominal_mf.heldout.cost:.4g} -> {base.heldout.cost:.4g}): "
            "the nominal's values are kept"
        )
        base = nominal_mf

    final = base
    gate: list[GateStep] = []
    if named:
        # the held-out gate: in naming order, an effect is kept only when the model with it
        # (and the effects kept before it) predicts the held-out data better than the model
        # without it, both fitted alike, by at least min_improvement; the improvement test's
        # z and p are reported (requiring p < choice_alpha as well dropped correct effects
        # with held-out gains of 12-17 % on the development data: the held-out residual of
        # a recording with a wandering load is too noisy for it)
        kept: list[Effect] = []
        for e in named:
            trial = [*kept, e]
            try:
                axis_e = _only(model, trial, named, nominal)
            except AxisFileError as exc:
                notes.append(f"{e.value}: no valid model with it alone ({exc}); not kept")
                continue
            ctx.stage(f"closed loop: with {', '.join(x.value for x in trial)}")
            cand = _fit_model(
                ctx,
                "the model with " + ", ".join(x.value for x in trial),
                axis_e,
                trial,
                screening,
                obj,
                scorer,
                pool,
            )
            z_e, p_e = scorer.test(final.loss, cand.loss)
            gain_e = 1.0 - cand.heldout.cost / final.heldout.cost if final.heldout.cost else 0.0
            ok = gain_e >= opts.min_improvement
            gate.append(GateStep(e, final.heldout.cost, cand.heldout.cost, gain_e, z_e, p_e, ok))
            if ok:
                kept.append(e)
                final = cand
            else:
                notes.append(
                    f"evidence without a model gain: {e.value} is significant in the measured "
                    f"signals, but the closed-loop model with it changes the held-out cost by "
                    f"{-100.0 * gain_e:+.2g} % (z = {z_e:.2g}; needed at least "
                    f"{-100.0 * opts.min_improvement:g} %): not named"
                )
        named = kept
        if named:
            final = replace(final, name="the model with the named effects")
        for a, b in screening.ambiguous:
            if a not in named or b in named:
                continue
            est = next(
                (v.estimate for v in screening.verdicts if v.effect is b and v.significant), None
            )
            if est is None:
                continue
            stripped = _without(final.result.axis, a, nominal)
            vals, why = _equivalent(a, b, final.result.axis)
            if not vals:
                vals, why = effect_values(b, est, stripped)
            if not vals:
                notes.append(f"{b.value} (ambiguous with {a.value}) not fitted: {why}")
                continue
            try:
                alt_axis = stripped.with_values(vals)
            except AxisFileError as exc:
                notes.append(f"{b.value} (ambiguous with {a.value}) not fitted: {exc}")
                continue
            effects = [b if e is a else e for e in named]
            ctx.stage(f"closed loop: {b.value} instead of {a.value}")
            alt = _fit_model(
                ctx,
                f"{b.value} instead of {a.value}",
                alt_axis,
                effects,
                screening,
                obj,
                scorer,
                pool,
            )
            alternatives.append(alt)
            _, p_alt = scorer.test(final.loss, alt.loss)
            gain = 1.0 - alt.heldout.cost / final.heldout.cost
            fewer = len(MODELS[b].keys) < len(MODELS[a].keys)
            if (fewer and alt.heldout.cost <= final.heldout.cost) or (
                p_alt < opts.choice_alpha and gain >= opts.min_improvement
            ):
                swaps.append(
                    f"{b.value} named instead of {a.value}: held-out cost "
                    f"{final.heldout.cost:.4g} -> {alt.heldout.cost:.4g} (p = {p_alt:.2g})"
                )
                named = effects
                final = alt
    part = worse_part(nominal_mf.loss, final.loss, opts.min_improvement)
    if final is not nominal_mf and part >= 0:
        # better overall, worse on one part of the held-out motions: the data disagree
        # between parts (a load or an inertia that changes, a motion the fit did not see);
        # the model returned is never worse than the nominal anywhere it was checked
        dropped = f"; {', '.join(e.value for e in named)} not named" if named else ""
        notes.append(
            f"the data disagree between parts: {final.name} predicts the held-out data "
            f"better overall ({nominal_mf.heldout.cost:.4g} -> {final.heldout.cost:.4g}) but "
            f"part {part + 1} of {HELDOUT_PARTS} (in time) worse than the nominal as given by "
            f"more than {100.0 * opts.min_improvement:g} % of its held-out cost: "
            f"the nominal is kept{dropped}"
        )
        final, named = nominal_mf, []
    z, p = scorer.test(base.loss, final.loss) if final is not base else (0.0, 1.0)
    gain = 100.0 * (1.0 - final.heldout.cost / base.heldout.cost) if base.heldout.cost else 0.0
    n_sims = obj.n_simulations + sum(v.n_simulations for v in val_objs)
    return ClosedLoop(
        nominal=nominal_mf,
        base=base,
        final=final,
        alternatives=alternatives,
        left_out=named,
        swaps=swaps,
        improvement_percent=gain,
        z=z,
        p=p,
        obj=obj,
        scorer=scorer,
        n_simulations=n_sims,
        seconds=time.perf_counter() - t0,
        notes=notes,
        gate=gate,
    )

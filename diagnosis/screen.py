"""Evidence first: which effects of the axis-file table the measured signals show, before any
closed-loop fit (stage 1 of :func:`.engine.diagnose`; docs/diagnosis.md, "Evidence").

Every effect the model lacks is tested where it acts, by regressors linear in its parameters:

* on the **torque balance** from the measured motion (:mod:`.idim`, the inverse dynamic model
  of the EMPS authors): friction laws, load torques, position-periodic torque, and an elastic
  element with one measuring system;
* on the **deflection** between two measuring systems (:mod:`.deflection`): compliance, free
  play (lost motion at reversals), a sensor time offset;
* through the **loop** (:mod:`.loop_tests`): a dead time, a torque limit, and free play with
  one measuring system, by their signature in the closed-loop replay.

Each relation is fitted on the recording and on the replay of the current model with the same
estimator (:mod:`.regression`): the replay calibrates what the estimator does by itself.
Each test's null distribution comes from the recording's own residual (:mod:`.randomization`),
at the level ``alpha`` divided by the number of effects tested (Bonferroni): the family's
false-alarm rate per round is ``alpha``.

Forward selection: the effect with the largest z among those significant is named — unless
another significant effect of the same relation explains it (the named one adds nothing to
it, it adds to the named one: it dominates and is named instead); two that explain each other
are ambiguous, the one with fewer parameters is named and the held-out comparison of the
closed-loop stage decides (:mod:`.closed_loop`). The named effect joins the model at its
estimate, the model's base parameters move to their calibrated estimates (within their
data-sheet uncertainty), the replay is redone and the next round tests the rest. Effects of
the control path are tested once the plant effects are in (their signature is taken against
the model with them).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace

import numpy as np

from plant_sim.physics.model import KernelOptions
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import Trace

from . import deflection as dfl
from . import idim
from . import standstill as rest
from .clipping import clipping_test
from .clipping import effect_test as clipping_effect_test
from .effects import (
    MODELS,
    SCALE_COS,
    SCALE_PERIOD,
    SCALE_SIN,
    Effect,
    effects_in,
    scale_error_values,
)
from .errors import DiagnosisInputError
from .evidence import DataScales, data_scales
from .fit import PERIODIC_COS, PERIODIC_SIN
from .loop_tests import NAME as LOOP_NAME
from .loop_tests import loop_candidates, loop_tests
from .measured import Measured, measured, measurement_noise, with_noise
from .parameters import (
    max_antiresonance,
    options_for,
    physical,
    uncertainty_box,
    with_contact,
)
from .regression import Candidate, EffectTest, Fitted, Relation, evaluate_candidates, fit_relation
from .replay import ReplayInput, like_recording, replay

#: Effects tested through the loop (after the plant effects).
LOOP_EFFECTS = frozenset(e for e, m in MODELS.items() if m.tested_in_loop)
#: Effects of the table the evidence has no test for yet, and why (the report says so).
UNTESTED = {e: m.untested for e, m in MODELS.items() if m.untested}
#: A loop test whose p was below this is run again once the model changed (a plant effect
#: named); above it the loop showed nothing and its verdict stands.
LOOP_AGAIN_P = 0.05
#: Standard errors beyond the data-sheet box before the evidence says the data sheet is wrong.
DATASHEET_SIGMAS = 3.0


@dataclass(frozen=True)
class Verdict:
    """One test of one effect in one round."""

    effect: Effect
    round: int
    relation: str
    statistic: float
    p: float
    z: float
    alpha: float
    significant: bool
    named: bool
    estimate: dict[str, float]
    replay_estimate: dict[str, float]
    n_blocks: int
    note: str = ""


@dataclass(frozen=True)
class ParameterEvidence:
    """A model parameter as the evidence estimates it, against its data sheet."""

    key: str
    nominal: float | None
    estimate: float
    standard_error: float
    box: tuple[float, float] | None  # data-sheet uncertainty box
    beyond: bool  # the evidence says the data sheet is wrong
    relation: str


@dataclass
class Screening:
    """What the evidence stage found (:func:`screen`)."""

    named: list[Effect]
    model: AxisConfig
    verdicts: list[Verdict]
    ambiguous: list[tuple[Effect, Effect]]
    parameters: list[ParameterEvidence]
    not_tested: dict[Effect, str]
    alpha: float
    alpha_each: float
    relations: dict[str, dict[str, float]]
    n_replays: int
    seconds: float
    estimates: dict[Effect, dict[str, float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------------------
# estimates -> axis values
# ----------------------------------------------------------------------------------------
def effect_values(
    effect: Effect, est: Mapping[str, float], model: AxisConfig
) -> tuple[dict[str, float | None], str]:
    """Axis-file values that add ``effect`` at its estimate to ``model`` ({} and the reason
    when the estimate is not physical): the effect's own
    :meth:`~diagnosis.effects.EffectModel.values`."""
    return MODELS[effect].values(est, model)


#: Relation keys that are axis keys (the others are converted).
_AXIS_KEYS = (
    "mechanics.load_mass",
    "friction.coulomb",
    "friction.viscous",
    "friction.coulomb_negative",
    "friction.viscous_negative",
    "friction.stribeck",
    "disturbance.constant_torque",
    "mechanics.backlash",
    "control.sensor_time_offset",
)


def base_values(
    corrected: Mapping[str, float], model: AxisConfig, nominal: AxisConfig, clip: bool = True
) -> dict[str, float]:
    """Axis values of a relation's calibrated base estimates, each within its data-sheet box
    when ``clip`` (a key the nominal lacks, or one of a named effect, is not clipped)."""
    out: dict[str, float] = {}
    for k in _AXIS_KEYS:
        if k in corrected:
            out[k] = corrected[k]
    if PERIODIC_COS in corrected and PERIODIC_SIN in corrected:
        c, s = corrected[PERIODIC_COS], corrected[PERIODIC_SIN]
        out["disturbance.periodic_amplitude"] = math.hypot(c, s)
        out["disturbance.periodic_phase"] = math.atan2(s, c)
    if SCALE_COS in corrected and SCALE_SIN in corrected:
        out.update(scale_error_values(corrected[SCALE_COS], corrected[SCALE_SIN]))
    mass = out.get("mechanics.load_mass", model.mechanics.load_mass)
    wa0 = model.mechanics.antiresonance
    if wa0 and dfl.FLEXIBILITY in corrected and corrected[dfl.FLEXIBILITY] > 0.0:
        wa = math.sqrt(1.0 / (corrected[dfl.FLEXIBILITY] * mass))
        # a calibrated correction, not a new estimate: within a factor 2 of the model's
        if 0.5 * wa0 <= wa <= 2.0 * wa0:
            out["mechanics.antiresonance"] = min(wa, 0.99 * max(max_antiresonance(model, 50), 1e-9))
            if dfl.DAMPING in corrected:
                xi = 0.5 * corrected[dfl.DAMPING] * wa
                if 0.0 <= xi <= 1.0:
                    out["mechanics.damping_ratio"] = xi
    final = {}
    for k, v in out.items():
        if not math.isfinite(v):
            continue
        if clip:
            box = uncertainty_box(k, nominal)
            if box is not None:
                v = min(box[1], max(box[0], v))
        final[k] = v
    return final


def _safe(model: AxisConfig, values: Mapping[str, float | None]) -> AxisConfig:
    """``model`` with every value it accepts (an out-of-range one is left as it was)."""
    try:
        return model.with_values(values)
    except AxisFileError:
        ok = dict(values)
        for k in list(values):
            try:
                model.with_values({k: values[k]})
            except AxisFileError:
                ok.pop(k)
        try:
            return model.with_values(ok)
        except AxisFileError:
            return model


# ----------------------------------------------------------------------------------------
# the stage
# ----------------------------------------------------------------------------------------
#: Noise draws of a calibration replay (their mean calibrates; the null is widened by 1/R).
REPLAY_DRAWS = 2


@dataclass
class _Round:
    relations: dict[str, tuple[Relation, list[Relation]]]
    fitted: dict[str, Fitted]
    simulated: Trace
    m_sims: list[Measured]
    noise: dict[str, float]
    force: np.ndarray | None  # load-side force of the recording (two systems)
    sim_forces: list[np.ndarray]


class _Unstable(Exception):
    """The closed-loop replay of a model diverged (non-finite signals)."""


def _kernel_options(model: AxisConfig) -> KernelOptions:
    return options_for(model.mechanics.antiresonance, model)


def _calibrate(
    inp: ReplayInput,
    recording: Trace,
    m_rec: Measured,
    model: AxisConfig,
    scans: idim.Scans,
    seed: int,
    effects: frozenset[Effect] = frozenset(),
    contact: bool = False,
) -> _Round:
    """Replay ``model`` like the recording, give it the recording's measurement noise
    (:func:`.measured.measurement_noise`, REPLAY_DRAWS independent draws) and build every
    relation on the recording and on the draws (the deflection with the load-side force of
    the calibrated torque balance; ``contact``: :func:`.deflection.deflection_relation`)."""
    sim = replay(model, inp, _kernel_options(model))
    used = ("motor_position", "load_position", "motor_speed", "motor_torque")
    if not all(np.all(np.isfinite(sim[c])) for c in used if c in sim.names):
        raise _Unstable(model)
    like = like_recording(inp, sim)
    noise = measurement_noise(recording, like)
    rng = np.random.default_rng(seed)
    m_sims = [measured(with_noise(like, noise, rng), model) for _ in range(REPLAY_DRAWS)]
    t_rec = idim.torque_relation(m_rec, model, scans)
    t_sims = [idim.torque_relation(ms, model, scans) for ms in m_sims]
    rels: dict[str, tuple[Relation, list[Relation]]] = {idim.NAME: (t_rec, t_sims)}
    fitted = {
        idim.NAME: fit_relation(t_rec, t_sims, idim.torque_candidates(m_rec, model, scans, effects))
    }
    force = None
    sim_forces: list[np.ndarray] = []
    if m_rec.two_systems:
        coef = fitted[idim.NAME].corrected
        kr = model.transmission_ratio
        force = dfl.load_side_force(t_rec.columns, coef, kr)
        sim_forces = [dfl.load_side_force(t.columns, coef, kr) for t in t_sims]
        thr = dfl.force_threshold(force)
        d_rec = dfl.deflection_relation(m_rec, model, force, thr, t_rec.mask, contact)
        d_sims = [
            dfl.deflection_relation(ms, model, f, thr, t.mask, contact)
            for ms, f, t in zip(m_sims, sim_forces, t_sims, strict=True)
        ]
        if d_rec is not None:
            rels[dfl.NAME] = (d_rec, [d for d in d_sims if d is not None])
            cands = dfl.deflection_candidates(m_rec, force, effects)
            fitted[dfl.NAME] = fit_relation(*rels[dfl.NAME], cands)
    return _Round(rels, fitted, sim, m_sims, noise, force, sim_forces)


@dataclass(frozen=True)
class _Periods:
    """The periods a position-periodic term is tested at: the torque's (a periodic force)
    and the deflection's (a periodic error of the load scale), each from its own relation's
    residual (:func:`_periods`)."""

    torque: idim.PeriodChoice | None = None
    scale: idim.PeriodChoice | None = None


def _plant_candidates(
    m: Measured,
    force: np.ndarray | None,
    model: AxisConfig,
    scans: idim.Scans,
    effects: frozenset[Effect],
    periods: _Periods = _Periods(),
) -> list[Candidate]:
    out = idim.torque_candidates(m, model, scans, effects, periods.torque)
    if force is not None:
        out += dfl.deflection_candidates(m, force, effects, periods.scale)
    return out


def _residual_period(
    rnd: _Round, name: str, m_rec: Measured, scans: idim.Scans
) -> idim.PeriodChoice | None:
    """The period of relation ``name``'s residual's largest peak over position (recording)."""
    if scans.period_band is None or name not in rnd.relations:
        return None
    rec = rnd.relations[name][0]
    f = rnd.fitted[name]
    keys = list(f.keys)
    fitted = rec.matrix(keys) @ np.array([f.recording[k] for k in keys]) if keys else 0.0
    return idim.choose_period(m_rec, rec.y - fitted, rec.mask, scans.period_band)


def _periods(
    rnd: _Round, m_rec: Measured, scans: idim.Scans, effects: frozenset[Effect]
) -> _Periods:
    """The periods of the periodic effects in ``effects`` (the others are not looked for)."""
    return _Periods(
        _residual_period(rnd, idim.NAME, m_rec, scans)
        if Effect.PERIODIC_DISTURBANCE in effects
        else None,
        _residual_period(rnd, dfl.NAME, m_rec, scans) if Effect.SCALE_ERROR in effects else None,
    )


def _plant_tests(
    rnd: _Round,
    m_rec: Measured,
    model: AxisConfig,
    scans: idim.Scans,
    effects: frozenset[Effect],
    rng: np.random.Generator,
) -> dict[Effect, EffectTest]:
    periods = _periods(rnd, m_rec, scans, effects)
    cands = _plant_candidates(m_rec, rnd.force, model, scans, effects, periods)
    forces: list[np.ndarray | None] = list(rnd.sim_forces) or [None] * len(rnd.m_sims)
    sim_cands = [
        {c.effect: c for c in _plant_candidates(ms, f, model, scans, effects, periods)}
        for ms, f in zip(rnd.m_sims, forces, strict=True)
    ]
    out: dict[Effect, EffectTest] = {}
    for name, (rec, reps) in rnd.relations.items():
        mine = [c for c in cands if c.relation == name]
        if mine:
            out.update(
                evaluate_candidates(rec, reps, rnd.fitted[name], mine, sim_cands[: len(reps)], rng)
            )
    return out


def _conditional_p(
    rnd: _Round,
    m_rec: Measured,
    model: AxisConfig,
    scans: idim.Scans,
    given: EffectTest,
    tested: Effect,
    rng: np.random.Generator,
) -> float:
    """p of ``tested`` with ``given``'s regressors (at its best scan point) added to the base
    of their common relation (on the recording; the calibration's offsets are small next to
    an effect that is significant, and this asks only whether one explains the other)."""
    rec = rnd.relations[given.relation][0]
    pair = frozenset({given.effect, tested})
    cands = {
        c.effect: c
        for c in _plant_candidates(
            m_rec, rnd.force, model, scans, pair, _periods(rnd, m_rec, scans, pair)
        )
        if c.relation == given.relation
    }
    if given.effect not in cands or tested not in cands:
        return 0.0
    cols = cands[given.effect].scan[given.test.best]
    extended = Relation(
        rec.name, rec.y, {**rec.columns, **{f"given {k}": v for k, v in cols.items()}}, rec.mask
    )
    if _in_span(extended, cands[tested]):
        # nothing of ``tested`` is left beside ``given`` (a load torque beside direction-
        # dependent Coulomb friction on moving rows: 1 = [v>0] + [v<0]); its test would
        # judge a round-off column
        return 1.0
    res = evaluate_candidates(extended, [], fit_relation(extended), [cands[tested]], [], rng)
    return res[tested].p if tested in res else 0.0


#: Relative norm below which a candidate's column counts as lying in the base's span.
SPAN_TOLERANCE = 1e-8


def _in_span(rel: Relation, cand: Candidate) -> bool:
    """Every column of ``cand`` (at every scan point) lies in the span of ``rel``'s columns
    on its rows (least squares leaves a relative norm below :data:`SPAN_TOLERANCE`)."""
    base = rel.matrix(list(rel.columns))[rel.mask]
    ok = np.all(np.isfinite(base), axis=1)
    for cols in cand.scan:
        for col in cols.values():
            z = np.asarray(col, dtype=float)[rel.mask]
            good = ok & np.isfinite(z)
            norm = float(np.linalg.norm(z[good]))
            if norm == 0.0:
                continue
            coef, *_ = np.linalg.lstsq(base[good], z[good], rcond=None)
            if float(np.linalg.norm(z[good] - base[good] @ coef)) > SPAN_TOLERANCE * norm:
                return False
    return True


def _choose(
    significant: Sequence[EffectTest],
    rnd: _Round,
    m_rec: Measured,
    model: AxisConfig,
    scans: idim.Scans,
    alpha: float,
    rng: np.random.Generator,
) -> tuple[EffectTest, list[tuple[Effect, Effect]]]:
    """The effect named among the significant ones, and the ambiguous pairs (docstring of
    the module)."""
    ranked = sorted(significant, key=lambda t: -t.z)
    best = ranked[0]
    ambiguous: list[tuple[Effect, Effect]] = []
    for other in ranked[1:]:
        if other.relation != best.relation or other.relation == LOOP_NAME:
            continue
        p_best_given_other = _conditional_p(rnd, m_rec, model, scans, other, best.effect, rng)
        p_other_given_best = _conditional_p(rnd, m_rec, model, scans, best, other.effect, rng)
        if p_best_given_other >= alpha and p_other_given_best < alpha:
            best = other  # it explains the best one and more
        elif p_best_given_other >= alpha and p_other_given_best >= alpha:
            ambiguous.append((best.effect, other.effect))
    # among mutually ambiguous effects the one with fewer parameters is named
    group = [best.effect] + [b for a, b in ambiguous if a is best.effect]
    fewest = min(
        group, key=lambda e: (len(MODELS[e].keys), -next(t.z for t in ranked if t.effect is e))
    )
    if fewest is not best.effect:
        best = next(t for t in ranked if t.effect is fewest)
        ambiguous = [(best.effect, e) for e in group if e is not best.effect]
    return best, ambiguous


def _rest_residual(
    rnd: _Round, m_rec: Measured, model: AxisConfig, scans: idim.Scans, given: EffectTest
) -> np.ndarray | None:
    """The torque balance's residual (moving rows, time order) with ``given``'s regressors at
    its best scan point added to the base, least squares on the recording."""
    rec = rnd.relations[idim.NAME][0]
    cands = {
        c.effect: c for c in idim.torque_candidates(m_rec, model, scans, frozenset({given.effect}))
    }
    if given.effect not in cands:
        return None
    cols = list(cands[given.effect].scan[given.test.best].values())
    x = np.column_stack([rec.matrix(list(rnd.fitted[idim.NAME].keys)), *cols])[rec.mask]
    y = rec.y[rec.mask]
    ok = np.all(np.isfinite(x), axis=1) & np.isfinite(y)
    coef, *_ = np.linalg.lstsq(x[ok], y[ok], rcond=None)
    return y[ok] - x[ok] @ coef


def _at_rest(
    best: EffectTest,
    ambiguous: list[tuple[Effect, Effect]],
    significant: Sequence[EffectTest],
    rnd: _Round,
    m_rec: Measured,
    model: AxisConfig,
    scans: idim.Scans,
    alpha: float,
    notes: list[str],
) -> tuple[EffectTest, list[tuple[Effect, Effect]], list[Effect]]:
    """Ambiguous pairs of the torque balance that predict different torques at rest before
    the first move (:meth:`.effects.EffectModel.at_rest`, :mod:`.standstill`): the one the
    recording's rest torque matches is named, the other dropped (returned as the losers);
    pairs it does not decide stay ambiguous."""
    tests = {t.effect: t for t in significant}
    losers: list[Effect] = []
    left: list[tuple[Effect, Effect]] = []
    for a, b in ambiguous:
        if a not in tests or b not in tests or tests[a].relation != idim.NAME:
            left.append((a, b))
            continue
        pa, pb = MODELS[a].at_rest(tests[a].estimate), MODELS[b].at_rest(tests[b].estimate)
        if pa is None or pb is None or pa == pb:
            left.append((a, b))
            continue
        residual = _rest_residual(rnd, m_rec, model, scans, tests[a])
        found = None
        if residual is not None:
            found = rest.rest_torque(m_rec.time_s, m_rec.reference, m_rec.torque, residual)
        if found is None:
            notes.append(f"{a.value} or {b.value}: no rest before the first move to tell them")
            left.append((a, b))
            continue
        d = rest.decide((pa, pb), found, alpha)
        notes.append(f"{a.value} or {b.value}: {d.describe((a.value, b.value))}")
        if d.winner is None:
            left.append((a, b))
            continue
        win, lose = (a, b) if d.winner == 0 else (b, a)
        losers.append(lose)
        if win is not best.effect:
            best = tests[win]
    left = [(best.effect, e) for _, e in left if e is not best.effect and e not in losers]
    return best, left, losers


def _judge(
    tests: Mapping[Effect, EffectTest],
    model: AxisConfig,
    alpha_each: float,
    rnd_no: int,
    data: DataScales,
) -> tuple[list[EffectTest], list[Verdict]]:
    """The significant tests and the verdicts. Significant: p below the level, a physical
    estimate, and one above the effect's "absent" value (:meth:`.effects.EffectModel.
    significant`: 0.1 % of the peak torque for torques, 0.1 % of the following error's
    spread for free play, 5 % of the sample time for a sensor time offset): the deflection
    between two measuring systems is measured to a few nm, where a sensor offset of 2 µs is
    significant and no finding."""
    sig, out = [], []
    for e, t in tests.items():
        ok, note = t.p < alpha_each, ""
        if ok:
            vals, why = effect_values(e, t.estimate, model)
            if not vals:
                ok, note = False, f"significant but not physical: {why}"
            elif not MODELS[e].significant(_safe(model, vals), data):
                ok, note = False, "significant but below the effect's absent value"
        if ok:
            sig.append(t)
        out.append(
            Verdict(
                effect=e,
                round=rnd_no,
                relation=t.relation,
                statistic=t.test.statistic,
                p=t.p,
                z=t.z,
                alpha=alpha_each,
                significant=ok,
                named=False,
                estimate=dict(t.estimate),
                replay_estimate=dict(t.replay_estimate),
                n_blocks=t.test.n_blocks,
                note=note,
            )
        )
    return sig, out


def _contact(named: Sequence[Effect], nominal: AxisConfig) -> bool:
    """Free play named on a rigid model brought a stiff contact that is not fitted (until
    compliance is named too)."""
    return nominal.is_rigid and Effect.BACKLASH in named and Effect.COMPLIANCE not in named


def _base_update(rnd: _Round, model: AxisConfig, nominal: AxisConfig) -> dict[str, float]:
    """The model's parameters at their calibrated estimates, within their data-sheet box."""
    base: dict[str, float] = {}
    for f in rnd.fitted.values():
        base.update(base_values(f.corrected, model, nominal))
    return base


#: Points of the local refinement of a scanned parameter (between the best point's
#: neighbours on the scan).
REFINE_POINTS = 17


def _refine(
    best: EffectTest, rnd: _Round, m_rec: Measured, model: AxisConfig, scans: idim.Scans
) -> EffectTest:
    """A named effect with a scanned parameter (Stribeck speed, period): the parameter
    refined between the best scan point's neighbours (least squares on the recording), the
    coefficients re-fitted there. Estimation only: the test was the scan's."""
    if best.effect is Effect.STRIBECK_FRICTION:
        grid, key = scans.stribeck_speeds, "friction.stribeck_speed"
        i = best.test.best
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    elif best.effect in (Effect.PERIODIC_DISTURBANCE, Effect.SCALE_ERROR):
        key = SCALE_PERIOD if best.effect is Effect.SCALE_ERROR else "disturbance.periodic_period"
        p0, span = best.estimate[key], float(np.ptp(m_rec.load_position))
        # within a quarter of a period's drift over the travel either way
        lo, hi = p0 / (1.0 + p0 / span), p0 * (1.0 + p0 / span)
    else:
        return best
    rec = rnd.relations[best.relation][0]
    f = rnd.fitted[best.relation]
    w, valid = f.whitener, f.valid
    keys = list(f.keys)
    xw = w.apply(rec.matrix(keys))[valid]
    yw = w.apply(rec.y)[valid]
    found = (math.inf, best.estimate)
    for value in np.geomspace(lo, hi, REFINE_POINTS):
        cols = (
            dfl.scale_columns(m_rec, float(value))
            if best.effect is Effect.SCALE_ERROR
            else idim.scan_columns(best.effect, m_rec, float(value))
        )
        z = w.apply(np.column_stack(list(cols.values())))[valid]
        design = np.column_stack([xw, z])
        coef, *_ = np.linalg.lstsq(design, yw, rcond=None)
        rss = float(np.sum((yw - design @ coef) ** 2))
        if rss < found[0]:
            est = {k: float(c) for k, c in zip(cols, coef[len(keys) :], strict=True)}
            est[key] = float(value)
            found = (rss, est)
    return replace(best, estimate=found[1])


def screen(
    inp: ReplayInput,
    recording: Trace,
    nominal: AxisConfig,
    effects: Sequence[Effect],
    alpha: float,
    max_effects: int,
    seed: int,
    pool: Executor | None = None,
) -> Screening:
    """The evidence stage (module docstring)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    m_rec = measured(recording, nominal)
    scans = idim.scans_for(m_rec)
    data = data_scales(inp)
    following = float(np.std(m_rec.reference - m_rec.feedback))
    candidates = frozenset(effects) - effects_in(nominal)
    limit = nominal.control.torque_limit
    tau_max = float(np.max(np.abs(recording["motor_torque"])))
    if Effect.TORQUE_SATURATION in effects and limit and tau_max < limit:
        # a limit lower than the data sheet's (the drive's parameter set otherwise than
        # stated): the recorded torque never reaches the stated one, so the loop scans limits
        # at the top of the recorded torque (a plateau there is the drive's real limit)
        candidates |= {Effect.TORQUE_SATURATION}
    # clipping seen in the recorded torque itself (plateaus at one level on both signs,
    # :mod:`.clipping`) is the direct evidence of a limit; the loop's signature at face value
    # misses it where the model without the limit runs far from the recording
    clip = (
        clipping_test(recording["motor_torque"], data.sample_time_s)
        if Effect.TORQUE_SATURATION in candidates
        else None
    )
    not_tested: dict[Effect, str] = {}
    for e in candidates & UNTESTED.keys():
        not_tested[e] = UNTESTED[e]
    candidates = candidates - UNTESTED.keys()
    plant_effects = candidates - LOOP_EFFECTS
    testable_plant = set()
    for e in plant_effects:
        if e in (Effect.BACKLASH, Effect.SENSOR_TIME_OFFSET) and not m_rec.two_systems:
            if e is Effect.SENSOR_TIME_OFFSET:
                not_tested[e] = "needs two measuring systems (motor and load positions recorded)"
            continue
        if e is Effect.COMPLIANCE and not max_antiresonance(nominal, 50) > 0.0:
            not_tested[e] = (
                "the model lumps all inertia into the load (motor_inertia + screw_inertia = 0): "
                "an elastic element cannot be added to it"
            )
            continue
        testable_plant.add(e)
    n_tests = len(testable_plant) + len(candidates & LOOP_EFFECTS)
    if Effect.BACKLASH in candidates and not m_rec.two_systems:
        n_tests += 1
    alpha_each = alpha / max(1, n_tests)
    model = nominal
    named: list[Effect] = []
    verdicts: list[Verdict] = []
    ambiguous: list[tuple[Effect, Effect]] = []
    estimates: dict[Effect, dict[str, float]] = {}
    notes: list[str] = []
    remaining = set(testable_plant)
    loop_left = set(candidates & LOOP_EFFECTS)
    if Effect.BACKLASH in candidates and not m_rec.two_systems:
        loop_left.add(Effect.BACKLASH)

    def calibrate(axis: AxisConfig, tested: set[Effect], with_named: list[Effect]) -> _Round:
        """The relations of ``axis`` calibrated on its replays (:func:`_calibrate`)."""
        return _calibrate(
            inp,
            recording,
            m_rec,
            axis,
            scans,
            seed,
            frozenset(tested),
            _contact(with_named, nominal),
        )

    try:
        rnd = calibrate(model, remaining, named)
    except _Unstable:
        raise DiagnosisInputError(
            "the axis file's closed loop diverges when replayed like the recording "
            "(check the controller keys and the units)"
        ) from None
    n_replays = 1
    # the model's own parameters where the evidence puts them (within their data-sheet
    # uncertainty) before anything is tested through the loop
    moved = _safe(model, _base_update(rnd, model, nominal))
    if moved != model:
        n_replays += 1
        try:
            rnd_moved = calibrate(moved, remaining, named)
        except _Unstable:
            notes.append(
                "the model's parameters at the evidence's values make the closed loop unstable; "
                "they stay at the data sheet's"
            )
        else:
            model, rnd = moved, rnd_moved
    loop_model: AxisConfig | None = None
    loop_pending = False
    rnd_no = 0
    while len(named) < max_effects and (remaining or loop_left):
        rnd_no += 1
        tests = _plant_tests(rnd, m_rec, model, scans, frozenset(remaining), rng)
        sig, round_verdicts = _judge(tests, model, alpha_each, rnd_no, data)
        if loop_left and loop_model is not model and (rnd_no == 1 or loop_pending):
            lc = loop_candidates(
                model, inp, frozenset(loop_left), not m_rec.two_systems, following, with_contact
            )
            lt, n_loop = loop_tests(inp, model, _kernel_options(model), lc, rng, pool)
            if clip is not None and clip.clipped and Effect.TORQUE_SATURATION in loop_left:
                lt[Effect.TORQUE_SATURATION] = clipping_effect_test(clip, LOOP_NAME)
                notes.append(f"torque_saturation: {clip.describe()}")
            n_replays += n_loop
            loop_model = model
            loop_sig, loop_verdicts = _judge(lt, model, alpha_each, rnd_no, data)
            # tested again against a changed model only where something showed (p < 0.05)
            loop_pending = any(t.p < LOOP_AGAIN_P for t in lt.values())
            sig += loop_sig
            round_verdicts += loop_verdicts
            tests.update(lt)
        verdicts += round_verdicts
        if not sig:
            break
        plant_sig = [t for t in sig if t.relation != LOOP_NAME]
        loop_sig = [t for t in sig if t.relation == LOOP_NAME]
        if plant_sig and loop_sig:
            # a loop effect changes what the estimator sees (a dead time moves the sampled
            # torque within the cycle); it is named first when, with it in the model, none
            # of the significant plant effects is left (it explains them), else the plant
            # effects come first and the loop is tested again against the model with them
            lead = max(loop_sig, key=lambda t: t.z)
            vals_l, _ = effect_values(lead.effect, lead.estimate, model)
            trial = _safe(model, vals_l)
            n_replays += 1
            try:
                rnd_l = calibrate(trial, remaining, named)
            except _Unstable:
                sig = plant_sig  # the loop effect at its estimate explains nothing
            else:
                again = _plant_tests(
                    rnd_l, m_rec, trial, scans, frozenset(t.effect for t in plant_sig), rng
                )
                left, _ = _judge(again, trial, alpha_each, rnd_no, data)
                sig = [lead] if not left else plant_sig
        best, amb = _choose(sig, rnd, m_rec, model, scans, alpha_each, rng)
        best, amb, losers = _at_rest(best, amb, sig, rnd, m_rec, model, scans, alpha_each, notes)
        for e in losers:
            remaining.discard(e)
            loop_left.discard(e)
        best = _refine(best, rnd, m_rec, model, scans)
        vals, _ = effect_values(best.effect, best.estimate, model)
        new_model = _safe(_safe(model, _base_update(rnd, model, nominal)), vals)
        remaining.discard(best.effect)
        loop_left.discard(best.effect)
        if any(new_model.value(k) != v for k, v in vals.items()):
            notes.append(f"{best.effect.value}: its estimate gives no valid axis; not named")
            continue
        try:
            new_rnd = calibrate(new_model, remaining - {b for _, b in amb}, [*named, best.effect])
        except _Unstable:
            notes.append(
                f"{best.effect.value}: the model with its estimate is unstable in closed loop; "
                "not named"
            )
            continue
        finally:
            n_replays += 1
        ambiguous += amb
        for _, b in amb:
            remaining.discard(b)
            loop_left.discard(b)
        model = new_model
        named.append(best.effect)
        estimates[best.effect] = dict(best.estimate)
        verdicts = [
            replace(v, named=True, estimate=dict(best.estimate))
            if (v.effect is best.effect and v.round == rnd_no)
            else v
            for v in verdicts
        ]
        rnd = new_rnd
    # final calibration: every parameter of the model as the evidence estimates it
    params: list[ParameterEvidence] = []
    relations_info: dict[str, dict[str, float]] = {}
    for name, (rec, _) in rnd.relations.items():
        f = rnd.fitted[name]
        se = f.standard_errors(rec)
        relations_info[name] = {
            "rows": float(f.valid.sum()),
            "whitening_order": float(f.whitener.order),
            "noise": f.noise,
            "blocks": float(f.blocks.max() + 1) if f.valid.any() else 0.0,
        }
        for k in f.keys:
            if k not in _AXIS_KEYS:
                continue
            n = nominal.value(k)
            box = uncertainty_box(k, nominal)
            est = f.corrected[k]
            # a non-physical estimate (a negative mass) says the relation is inconsistent
            # here, not that the data sheet is wrong
            beyond = (
                box is not None
                and physical(k, est)
                and (
                    est + DATASHEET_SIGMAS * se[k] < box[0]
                    or est - DATASHEET_SIGMAS * se[k] > box[1]
                )
            )
            params.append(
                ParameterEvidence(k, None if n is None else float(n), est, se[k], box, beyond, name)
            )
    # the model handed on: named effects at their calibrated estimates, base parameters at
    # theirs, within the data-sheet box unless the evidence puts them beyond it
    wrong = {p.key for p in params if p.beyond}
    final_values: dict[str, float] = {}
    for f in rnd.fitted.values():
        clipped = base_values(f.corrected, model, nominal, clip=True)
        free = base_values(f.corrected, model, nominal, clip=False)
        for k in clipped:
            final_values[k] = free[k] if k in wrong else clipped[k]
    model = _safe(model, final_values)
    return Screening(
        named=named,
        model=model,
        verdicts=verdicts,
        ambiguous=ambiguous,
        parameters=params,
        not_tested=not_tested,
        alpha=alpha,
        alpha_each=alpha_each,
        relations=relations_info,
        n_replays=n_replays,
        seconds=time.perf_counter() - t0,
        estimates=estimates,
        notes=notes,
    )

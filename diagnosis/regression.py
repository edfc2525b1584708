"""Linear relations of the measured signals, fitted on a recording and on a replay of the
current model with the same estimator, and the test of an effect's regressors between them.

A :class:`Relation` is y = Σ_j θ_j·x_j + e on the rows where it holds (the torque balance of
:mod:`.idim`, the deflection of :mod:`.deflection`); its base columns are the parameters the
current model has, named by their axis-file keys (or a pseudo-key), so that a coefficient is
the parameter's value. A :class:`Candidate` is one effect's columns, one set per point of a
scan of its non-linear parameter (a Stribeck speed, a period).

Calibration. The same relation is built from the recording and from the closed-loop replay
of the current model (:mod:`.replay`), and both are fitted with the same pre-whitening filter
(the recording's). What the estimator does to the signals (derivative smoothing, a torque
sampled once per position cycle) then acts on both alike: the candidate's coefficients on the
replay — where the model does not have the effect — are what the estimator alone produces, and
the test asks whether the recording's coefficients differ from them (:func:`evaluate_candidates`,
:mod:`.randomization` for the null). The base parameters are corrected the same way,
θ = θ_recording − θ_replay + θ_model (one step of indirect inference: the value for which the
estimator on the model's simulation would give what it gives on the recording).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .effects import Effect
from .randomization import (
    ScanResult,
    Whitener,
    fit_whitener,
    long_run_factor,
    scan_test,
    time_blocks,
)


@dataclass(frozen=True)
class Relation:
    """y = Σ columns[key]·θ[key] + e on the rows of ``mask`` (one trace)."""

    name: str
    y: np.ndarray
    columns: dict[str, np.ndarray]
    mask: np.ndarray
    #: the model's value of every column's parameter (for the calibration; replay side)
    model_values: dict[str, float] = field(default_factory=dict)

    def matrix(self, keys: Sequence[str]) -> np.ndarray:
        if not keys:
            return np.zeros((len(self.y), 0))
        return np.column_stack([self.columns[k] for k in keys])


@dataclass(frozen=True)
class Candidate:
    """One effect's regressors: per scan point the columns by parameter key and the scanned
    value (None without a scan)."""

    effect: Effect
    relation: str
    scan: list[dict[str, np.ndarray]]
    scan_values: list[float | None]
    scan_key: str | None = None  # the axis key the scan sets (stribeck_speed, period)
    #: a choice made before the test among this many independent values (the period from
    #: the residual's spectrum): the test's p is multiplied by it (Bonferroni)
    look_elsewhere: float = 1.0


@dataclass(frozen=True)
class EffectTest:
    """The evidence for one effect in one relation: the test (:mod:`.randomization`) and the
    recording's estimate of its parameters, calibrated on the replay."""

    effect: Effect
    relation: str
    test: ScanResult
    estimate: dict[str, float]  # candidate keys (and scan_key) -> value
    replay_estimate: dict[str, float]

    @property
    def p(self) -> float:
        return self.test.p

    @property
    def z(self) -> float:
        return self.test.z


@dataclass(frozen=True)
class Fitted:
    """A relation fitted on a recording with its replay's calibration."""

    relation: str
    keys: tuple[str, ...]
    recording: dict[str, float]
    replay: dict[str, float]
    corrected: dict[str, float]
    whitener: Whitener
    blocks: np.ndarray
    residual: np.ndarray  # whitened base residual on the recording (all rows, 0 off-rows)
    valid: np.ndarray
    noise: float  # std of the whitened residual

    def standard_errors(self, rec: Relation) -> dict[str, float]:
        """Block-robust standard errors of the base coefficients (sandwich over blocks), each
        widened by its scores' correlation between blocks (:func:`.randomization.
        long_run_factor`)."""
        keys = list(self.keys)
        if not keys:
            return {}
        x = self.whitener.apply(rec.matrix(keys))[self.valid]
        e = self.residual[self.valid]
        bl = self.blocks[self.valid]
        xtx_inv = np.linalg.pinv(x.T @ x)
        nb = int(bl.max()) + 1 if len(bl) else 0
        g = np.stack([np.bincount(bl, x[:, j] * e, nb) for j in range(x.shape[1])], axis=1)
        cov = xtx_inv @ (g.T @ g) @ xtx_inv
        # the coefficient's own score: the block sums of (XᵀX)⁻¹x·e
        own = g @ xtx_inv
        return {
            k: float(np.sqrt(max(cov[i, i], 0.0) * long_run_factor(own[:, i : i + 1])[0]))
            for i, k in enumerate(keys)
        }


def _lstsq(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    if x.shape[1] == 0:
        return np.zeros(0)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    return coef


def fit_relation(
    rec: Relation, reps: Sequence[Relation] = (), candidates: Sequence[Candidate] = ()
) -> Fitted:
    """Fit the base columns on the recording and on the replays (their mean: the replays are
    one simulation with independent draws of the recording's measurement noise), both
    pre-whitened by one filter: fitted to the ordinary-least-squares residual of the largest
    model, the base with every candidate's columns (their first scan point). Fitted to the
    base's residual instead, a large smooth effect the base lacks would set the filter, which
    then removes the frequencies where that effect's regressor is accurate and leaves those
    where its measurement noise is (on the test set's slide the compliance came out 10 times
    too small)."""
    keys = tuple(rec.columns)
    m = rec.mask
    x = rec.matrix(keys)
    extra = [c.scan[0][k] for c in candidates for k in c.scan[0]]
    x_big = np.column_stack([x, *extra]) if extra else x
    coef0 = _lstsq(x_big[m], rec.y[m])
    res0 = np.where(m, rec.y - x_big @ coef0 if x_big.shape[1] else rec.y, 0.0)
    w = fit_whitener(res0, m)
    valid = w.valid(m)
    yw, xw = w.apply(rec.y), w.apply(x)
    coef = _lstsq(xw[valid], yw[valid])
    resid = np.where(valid, yw - (xw @ coef if len(keys) else 0.0), 0.0)
    # blocks as long as the noise's correlation: that of the largest model's whitened residual
    xbw = w.apply(x_big)
    coef_big = _lstsq(xbw[valid], yw[valid])
    res_big = np.where(valid, yw - (xbw @ coef_big if x_big.shape[1] else 0.0), 0.0)
    blocks, _ = time_blocks(valid, res_big)
    rec_vals = {k: float(c) for k, c in zip(keys, coef, strict=True)}
    rep_vals: dict[str, float] = {}
    corrected = dict(rec_vals)
    usable = [r for r in reps if all(k in r.columns for k in keys)]
    if usable:
        acc = np.zeros(len(keys))
        for rep in usable:
            v2 = w.valid(rep.mask)
            acc += _lstsq(w.apply(rep.matrix(keys))[v2], w.apply(rep.y)[v2])
        c2 = acc / len(usable)
        rep_vals = {k: float(c) for k, c in zip(keys, c2, strict=True)}
        for k in keys:
            if k in usable[0].model_values:
                corrected[k] = rec_vals[k] - rep_vals[k] + usable[0].model_values[k]
    noise = float(np.std(resid[valid])) if valid.any() else 0.0
    return Fitted(rec.name, keys, rec_vals, rep_vals, corrected, w, blocks, resid, valid, noise)


def evaluate_candidates(
    rec: Relation,
    reps: Sequence[Relation],
    fitted: Fitted,
    candidates: Sequence[Candidate],
    rep_candidates: Sequence[Mapping[Effect, Candidate]],
    rng: np.random.Generator,
) -> dict[Effect, EffectTest]:
    """Test every candidate against the base of ``fitted``: H0 — the recording's candidate
    coefficients equal the replays' mean (the estimator's own), per scan point. The null
    distribution is widened by 1 + 1/(number of replays): the replays' mean carries their
    drawn noise too."""
    w, valid, blocks = fitted.whitener, fitted.valid, fitted.blocks
    keys = list(fitted.keys)
    xw = w.apply(rec.matrix(keys))
    yw = w.apply(rec.y)
    out: dict[Effect, EffectTest] = {}
    sides = []
    for rep, cands in zip(reps, rep_candidates, strict=True):
        v2 = w.valid(rep.mask)
        # the base projected out once per replay: each scan point is then a small fit
        xr = w.apply(rep.matrix(keys))[v2]
        q = np.linalg.qr(xr)[0] if xr.shape[1] else np.zeros((int(v2.sum()), 0))
        yr = w.apply(rep.y)[v2]
        sides.append((v2, q, yr - q @ (q.T @ yr), cands))
    inflation = 1.0 + 1.0 / len(sides) if sides else 1.0
    for cand in candidates:
        zs, offsets, rep_coefs = [], [], []
        for i, cols in enumerate(cand.scan):
            ck = list(cols)
            z = w.apply(np.column_stack([cols[k] for k in ck]))
            zs.append(z)
            gamma = np.zeros(len(ck))
            n_used = 0
            for v2, q, r_rep, cands in sides:
                other = cands.get(cand.effect)
                if other is None:
                    continue
                zr = w.apply(np.column_stack([other.scan[i][k] for k in ck]))[v2]
                zr = zr - q @ (q.T @ zr)
                gamma = gamma + _lstsq(zr, r_rep)
                n_used += 1
            if n_used:
                gamma = gamma / n_used
            rep_coefs.append(gamma)
            offsets.append(z @ gamma)
        result = scan_test(
            yw, xw, zs, np.where(valid, blocks, -1), rng, offsets=offsets, inflation=inflation
        )
        if cand.look_elsewhere > 1.0:
            result = replace(result, p=min(1.0, result.p * cand.look_elsewhere))
        best = result.best
        ck = list(cand.scan[best])
        # the calibrated estimate: the recording's coefficient less the estimator's own (replay)
        est = {k: float(v) for k, v in zip(ck, result.coefficients, strict=True)}
        rep_est = {k: float(v) for k, v in zip(ck, rep_coefs[best], strict=True)}
        if cand.scan_key is not None and cand.scan_values[best] is not None:
            est[cand.scan_key] = float(cand.scan_values[best])  # type: ignore[arg-type]
            rep_est[cand.scan_key] = est[cand.scan_key]
        out[cand.effect] = EffectTest(cand.effect, cand.relation, result, est, rep_est)
    return out

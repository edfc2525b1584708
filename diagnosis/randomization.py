"""Tests whose null distribution is taken from the recording itself.

Every test of the evidence stage asks one question of a linear regression: do the candidate
regressors Z (an effect's signature, or one of a scan of them) explain part of the residual
y − X·β that the base regressors X leave, beyond what the recording's own noise would?

* **Pre-whitening** (:func:`fit_whitener`): the residual of a servo recording is coloured (an
  unrecorded load torque varies over tenths of a second, the loop colours the noise). An
  autoregressive filter fitted to the base residual (Yule–Walker) is applied to y, X and Z
  alike, so the regression is generalised least squares and the residual it leaves is close
  to white.
* **Statistic**: the reduction of the residual sum of squares by Z, T = ‖Qᵀr‖² (Q an
  orthonormal basis of Z with X projected out, r the base residual); for a scan (Stribeck
  speeds, periods, dead times, torque limits) the largest T over the scan.
* **Null distribution** (:func:`scan_test`): a wild block bootstrap. The residual e of the
  best alternative is cut into short blocks (a few autocorrelation times of the whitened
  residual); each replicate multiplies every block by an independent standard normal weight
  (Gaussian multipliers; the replicate's projections are then normal with the block sums'
  covariance, drawn directly) and recomputes the statistic on that noise — the largest over
  the scan, like the observed one (the scan's look-elsewhere effect is in the null). Whole
  blocks are weighted, so the recording's own autocorrelation within a block and its
  heteroscedasticity (noise that is larger where the axis accelerates) are kept. A residual
  that wanders for longer than a block (an unrecorded load that steps and stays) leaves the
  block sums correlated; the null is widened by that correlation (:func:`long_run_factor`:
  summed over a 16th of the recording, :func:`between_blocks_factor`, or measured at the
  recording's lowest frequencies with its degrees of freedom, :func:`low_frequency_factor`).
  p = (1 + #{T* ≥ T}) / (1 + replicates).

A test at level α names an effect that is not there with probability ≈ α when the residual
is noise symmetric within blocks and independent between them; the engine divides the
family's level by the number of effects tested (Bonferroni), docs/diagnosis.md states the
rate and measures it on the test set's recordings with nothing left out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import linalg, stats

from .metrics import autocorrelation_time

#: Largest order of the pre-whitening filter.
MAX_AR_ORDER = 12
#: Replicates of the wild block bootstrap.
REPLICATES = 5000
#: Blocks are this many autocorrelation times of the whitened residual long (at least
#: MIN_BLOCK samples).
BLOCK_TAUS = 3.0
MIN_BLOCK = 4


@dataclass(frozen=True)
class Whitener:
    """An autoregressive pre-whitening filter e_t = Σ_k coef_k·x_{t−k} (coef_0 = 1)."""

    coef: np.ndarray

    @property
    def order(self) -> int:
        return len(self.coef) - 1

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Filter along the first axis (columns of a matrix each); the first ``order`` rows
        are passed through (they are not valid rows, :meth:`valid`)."""
        x = np.asarray(x, dtype=float)
        if self.order == 0:
            return x.copy()
        out = np.empty_like(x)
        c = self.coef
        p = self.order
        out[:p] = x[:p]
        tail = x[p:] * c[0]
        for k in range(1, p + 1):
            tail = tail + c[k] * x[p - k : len(x) - k]
        out[p:] = tail
        return out

    def valid(self, mask: np.ndarray) -> np.ndarray:
        """Rows whose filter window lies wholly in ``mask`` (the model holds there)."""
        m = np.asarray(mask, dtype=bool)
        out = m.copy()
        for k in range(1, self.order + 1):
            out[k:] &= m[:-k]
        out[: self.order] = False
        return out


def fit_whitener(residual: np.ndarray, mask: np.ndarray, max_order: int = MAX_AR_ORDER) -> Whitener:
    """Yule–Walker AR fit to ``residual`` on ``mask`` (other rows count as zero), order chosen
    by Akaike's criterion up to ``max_order``; an unstable or degenerate fit gives no filter."""
    r = np.where(mask, residual - np.mean(residual[mask]) if mask.any() else 0.0, 0.0)
    n = int(mask.sum())
    if n < 10 * (max_order + 1):
        return Whitener(np.array([1.0]))
    size = 1 << (2 * len(r) - 1).bit_length()
    spec = np.fft.rfft(r, size)
    acov = np.fft.irfft(spec * np.conj(spec), size)[: max_order + 1] / n
    if acov[0] <= 0.0:
        return Whitener(np.array([1.0]))
    best = (math.log(acov[0]), np.array([1.0]))
    for p in range(1, max_order + 1):
        try:
            a = linalg.solve_toeplitz(acov[:p], acov[1 : p + 1])
        except (linalg.LinAlgError, ValueError):
            break
        var = float(acov[0] - a @ acov[1 : p + 1])
        if not var > 0.0:
            break
        aic = math.log(var) + 2.0 * p / n
        if aic < best[0]:
            best = (aic, np.concatenate([[1.0], -a]))
    coef = best[1]
    if len(coef) > 1 and np.max(np.abs(np.roots(coef))) >= 1.0:
        return Whitener(np.array([1.0]))
    return Whitener(coef)


#: Fewest blocks a test is given (the block length is cut to keep them).
MIN_BLOCKS = 20
#: The scores' correlation *between* blocks is summed (Bartlett weights) over lags up to this
#: share of the recording (:func:`between_blocks_factor`).
BETWEEN_BLOCKS_SHARE = 1.0 / 16.0


def between_blocks_factor(g: np.ndarray) -> float:
    """How much the block bootstrap under-states the null's spread when the scores z_t·e_t
    stay correlated for longer than a block: ``g`` the block sums of the scores (rows: blocks
    in time order, columns: a candidate's whitened, base-projected regressors), the factor
    Var(Σ g) / Σ g² with Var(Σ g) the Bartlett long-run variance over lags up to
    BETWEEN_BLOCKS_SHARE of the blocks; at least 1.

    The blocks are a few correlation times of the *whitened residual* long, which a residual
    that wanders over seconds (an unrecorded load that steps and stays) does not reach: its
    whitened part still correlates over a second (measured: 8 times the variance at 0.6 s,
    35 times at 5 s on the third plant). A regressor that alternates with the moves (sign(v))
    averages such a wander out within a few blocks (factor near 1); a constant or a slow
    period does not, and its test is judged against the wander, not against the noise."""
    g = np.atleast_2d(np.asarray(g, dtype=float))
    if g.shape[0] == 1 and g.shape[1] > 1:
        g = g.T
    nb = g.shape[0]
    lags = int(nb * BETWEEN_BLOCKS_SHARE)
    fine = float(np.sum(g**2))
    if lags < 1 or not fine > 0.0:
        return 1.0
    total = fine
    for k in range(1, lags + 1):
        total += 2.0 * (1.0 - k / (lags + 1.0)) * float(np.sum(g[k:] * g[:-k]))
    return max(1.0, total / fine)


#: Cosines of the low-frequency estimate of the scores' long-run variance
#: (:func:`low_frequency_factor`): the lowest 8 frequencies of the recording, j/(2·T).
LOW_FREQUENCY_COSINES = 8


def low_frequency_factor(g: np.ndarray) -> float:
    """The equal-weighted cosine (EWC) estimate of the scores' long-run variance over their
    white one: ``g`` the block sums of the scores (rows: blocks in time order, columns: a
    candidate's regressors), Λ_j = √(2/B)·Σ_b cos(πj(b+½)/B)·g_b for j = 1..ν
    (ν = LOW_FREQUENCY_COSINES), the factor B·Σ_j‖Λ_j‖²/ν / Σ_b‖g_b‖²; 1 for white scores.

    A load that steps and stays for seconds (a process force, a cable chain, the axis warming)
    has its power at the lowest frequencies of the recording, below what a lag window of a
    16th of the recording sums (:func:`between_blocks_factor`): its mean over the recording is
    as large as its spread, and a constant regressor projects on exactly that. The cosines
    measure that power where it is; the estimate has ν degrees of freedom, so a test widened
    by it is judged against F(k, ν) (Müller 2007; Lazarus, Lewis, Stock & Watson 2018,
    "HAR inference: recommendations for practice"), which :func:`scan_test` and
    :func:`face_value_test` do by dividing each replicate by an independent χ²_ν/ν."""
    g = np.atleast_2d(np.asarray(g, dtype=float))
    if g.shape[0] == 1 and g.shape[1] > 1:
        g = g.T
    nb = g.shape[0]
    nu = LOW_FREQUENCY_COSINES
    fine = float(np.sum(g**2))
    if nu < 1 or nb < 4 * nu or not fine > 0.0:
        return 1.0
    j = np.arange(1, nu + 1)[:, None]
    cosines = math.sqrt(2.0 / nb) * np.cos(math.pi * j * (np.arange(nb) + 0.5) / nb)
    lam = cosines @ g
    return nb * float(np.sum(lam**2)) / nu / fine


def long_run_factor(g: np.ndarray) -> tuple[float, int | None]:
    """The factor the null is widened by for scores ``g`` (block sums), at least 1: the
    larger of the lag window's (:func:`between_blocks_factor`, taken as exact: None) and
    the low frequencies' (:func:`low_frequency_factor`, with its ν degrees of freedom).
    On white scores the low frequencies' estimate is the larger half of the time and the
    test then pays F(k, ν)'s heavier tail: a conservative null, the price of not taking a
    load that stays for the recording's length for an effect."""
    lag = between_blocks_factor(g)
    low = low_frequency_factor(g)
    if low > lag:
        return low, LOW_FREQUENCY_COSINES
    return lag, None


def _variance_draws(
    dof: int | None, replicates: int, rng: np.random.Generator
) -> np.ndarray | float:
    """Per replicate, the factor ν/χ²_ν that turns a null with an estimated variance into
    the F (or t) distribution it then has (1 when the variance is taken as known)."""
    if dof is None:
        return 1.0
    return dof / rng.chisquare(dof, replicates)


def long_run_tau(r: np.ndarray) -> float:
    """Correlation length of ``r`` in samples as the variance of its sum sees it: the largest
    over batch sizes B (10 samples up to a 20th of the series) of B·var(batch means)/var(r)
    (batch means; 1 for white noise). The autocorrelation time's cut-off at the first small
    correlation misses a slow component of small variance — an unrecorded load torque that
    varies over tenths of a second — which is what a regressor as slow as a constant or the
    direction of a long move projects on."""
    n = len(r)
    var = float(np.var(r))
    if n < 40 or var <= 0.0:
        return 1.0
    best = 1.0
    b = 10
    while b <= n // MIN_BLOCKS:
        k = n // b
        means = r[: k * b].reshape(k, b).mean(axis=1)
        best = max(best, b * float(np.var(means)) / var)
        b *= 2
    return best


def time_blocks(valid: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, int]:
    """Block number of every valid row (−1 elsewhere): runs of valid rows cut into blocks of
    BLOCK_TAUS correlation lengths of ``residual`` (whitened; :func:`long_run_tau` and the
    autocorrelation time, whichever is longer), at least MIN_BLOCK rows, at most a
    MIN_BLOCKS-th of the rows."""
    r = residual[valid]
    tau = 1.0
    if len(r) > 4:
        r = r - r.mean()
        tau = max(autocorrelation_time(r), long_run_tau(r))
    length = max(MIN_BLOCK, min(math.ceil(BLOCK_TAUS * tau), max(1, len(r) // MIN_BLOCKS)))
    blocks = np.full(len(valid), -1, dtype=int)
    idx = np.nonzero(valid)[0]
    if len(idx) == 0:
        return blocks, length
    # a new block at every gap and every ``length`` valid rows
    gap = np.concatenate([[True], np.diff(idx) > 1])
    run = np.cumsum(gap) - 1
    pos_in_run = np.arange(len(idx)) - np.maximum.accumulate(np.where(gap, np.arange(len(idx)), 0))
    key = run * (len(idx) + 1) + pos_in_run // length
    _, blocks[idx] = np.unique(key, return_inverse=True)
    return blocks, length


@dataclass(frozen=True)
class ScanResult:
    """A scan test: the largest residual reduction over the scan (``statistic``, in units of
    the whitened target squared), the index of the scan point, its p-value from the wild
    block bootstrap (``p_bootstrap``; ``p_tail`` a scaled-χ² fit to the replicates, used as
    ``p`` only where no replicate reaches the statistic), ``z`` = Φ⁻¹(1 − p), the number of
    blocks and replicates."""

    statistic: float
    best: int
    p: float  # the bootstrap's p; the tail fit's where no replicate is as large
    p_bootstrap: float
    p_tail: float
    z: float
    n_blocks: int
    replicates: int
    coefficients: np.ndarray  # of the best scan point's candidate regressors
    residual: np.ndarray  # whitened residual of the best alternative (valid rows)


def _orth(z: np.ndarray, rcond: float = 1e-9) -> np.ndarray:
    if z.ndim == 1:
        z = z[:, None]
    q, r, _ = linalg.qr(z, mode="economic", pivoting=True)
    d = np.abs(np.diag(r))
    keep = d > rcond * (d[0] if len(d) and d[0] > 0 else 1.0)
    return q[:, keep]


def scan_test(
    y: np.ndarray,
    base: np.ndarray,
    candidates: Sequence[np.ndarray],
    blocks: np.ndarray,
    rng: np.random.Generator,
    replicates: int = REPLICATES,
    offsets: Sequence[np.ndarray] | None = None,
    inflation: float = 1.0,
) -> ScanResult:
    """Test ``candidates`` (one regressor matrix per scan point, rows like ``y``) against the
    base regressors ``base`` on the rows where ``blocks`` >= 0 (all already whitened).
    ``offsets`` (per scan point, like ``y``): the candidate's contribution under the null
    (the replay's coefficients times its regressors); point k tests y − offsets[k].
    ``inflation``: factor on the null's replicates (the offsets' own sampling variance)."""
    rows = blocks >= 0
    yv, bv, bl = y[rows], base[rows], blocks[rows]
    nb = int(bl.max()) + 1 if len(bl) else 0
    q0 = _orth(bv) if bv.shape[1] else np.zeros((len(yv), 0))
    r0 = yv - q0 @ (q0.T @ yv)
    offs = [
        np.zeros(len(yv)) if offsets is None else offsets[i][rows] for i in range(len(candidates))
    ]
    qs, stats_ = [], []
    for z, off in zip(candidates, offs, strict=True):
        zv = z[rows] if z.ndim == 2 else z[rows][:, None]
        zt = zv - q0 @ (q0.T @ zv)
        q = _orth(zt)
        qs.append(q)
        stats_.append(float(np.sum((q.T @ (r0 - off)) ** 2)) if q.shape[1] else 0.0)
    if not qs or nb < 2 or not any(q.shape[1] for q in qs):
        # nothing to test: no blocks, or every candidate lies within the base regressors
        # (a short or motionless recording: the demo's 7 s at standstill between moves)
        width = candidates[0].shape[1] if candidates and candidates[0].ndim == 2 else 1
        return ScanResult(0.0, 0, 1.0, 1.0, 1.0, -math.inf, nb, 0, np.zeros(width), r0)
    best = int(np.argmax(stats_))
    t_obs = stats_[best]
    qb = qs[best]
    rb = r0 - offs[best] + q0 @ (q0.T @ offs[best])
    e1 = rb - qb @ (qb.T @ rb)
    # Gaussian multipliers per block: the replicate of every scan point's projection is
    # Σ_b ξ_b·g_b with ξ_b ~ N(0, 1), i.e. a normal vector with covariance GᵀG (G: block sums
    # of Q ⊙ e over all points); drawn through its eigen-decomposition, so the cost does not
    # grow with the number of blocks
    widths = [q.shape[1] for q in qs]
    g = np.concatenate(
        [
            np.stack([np.bincount(bl, q[:, j] * e1, nb) for j in range(q.shape[1])], axis=1)
            for q in qs
            if q.shape[1]
        ],
        axis=1,
    )
    cov = g.T @ g
    evals, evecs = np.linalg.eigh(cov)
    root = evecs * np.sqrt(np.clip(evals, 0.0, None))
    draws = rng.standard_normal((replicates, cov.shape[0])) @ root.T
    t_null = np.zeros(replicates)
    start = 0
    for wdt in widths:
        if wdt:
            t_null = np.maximum(t_null, np.sum(draws[:, start : start + wdt] ** 2, axis=1))
            start += wdt
    # the scores' correlation between blocks, at the best point (where the statistic is)
    col0 = sum(widths[:best])
    kappa, dof = long_run_factor(g[:, col0 : col0 + widths[best]])
    t_null *= inflation * kappa * _variance_draws(dof, replicates, rng)
    p_emp = (1.0 + float(np.sum(t_null >= t_obs))) / (1.0 + replicates)
    mean, var = float(np.mean(t_null)), float(np.var(t_null))
    if mean > 0.0 and var > 0.0:
        # the replicates fitted by a scaled χ²: c·χ²_ν with the replicates' mean and variance
        c, nu = var / (2.0 * mean), 2.0 * mean**2 / var
        p_tail = float(stats.chi2.sf(t_obs / c, nu))
        # Wilson–Hilferty: the normal quantile of that χ² (does not saturate for huge T)
        h = 2.0 / (9.0 * nu)
        z = ((max(t_obs, 0.0) / (c * nu)) ** (1.0 / 3.0) - (1.0 - h)) / math.sqrt(h)
    else:
        p_tail = 0.0 if t_obs > 0.0 else 1.0
        z = math.inf if t_obs > 0.0 else -math.inf
    # beyond the replicates' resolution the tail fit decides (never the floor 1/(1+R))
    p = p_tail if p_emp <= 1.5 / (1.0 + replicates) else p_emp
    # coefficients of the best candidate in the full regression (least squares on the rows)
    zb = candidates[best][rows] if candidates[best].ndim == 2 else candidates[best][rows][:, None]
    design = np.column_stack([bv, zb]) if bv.shape[1] else zb
    coef, *_ = np.linalg.lstsq(design, yv - offs[best], rcond=None)
    return ScanResult(
        statistic=t_obs,
        best=best,
        p=p,
        p_bootstrap=p_emp,
        p_tail=p_tail,
        z=z,
        n_blocks=nb,
        replicates=replicates,
        coefficients=coef[bv.shape[1] :],
        residual=e1,
    )


def face_value_test(
    y: np.ndarray,
    base: np.ndarray,
    candidates: Sequence[np.ndarray],
    blocks: np.ndarray,
    rng: np.random.Generator,
    replicates: int = REPLICATES,
) -> ScanResult:
    """Test an effect *at its own size*: each candidate z_k is the whole signature of the
    effect at one value of a scan (a dead time, a torque limit), so the residual sum of
    squares it saves at gain 1, T_k = 2·z̃_k·r − ‖z̃_k‖² (z̃ with the base projected out, r the
    base residual), is the statistic, the largest over the scan. A residual that only
    resembles the signature in part — a misfit of the model's own loops that looks a little
    like a dead time — saves nothing at gain 1 (T < 0 for a fitted gain below 1/2), where a
    free-gain test would still find the resemblance significant. H0: T_k <= 0 at every point;
    at its boundary the saving's error is 2·z̃·e, normal with the covariance of its block sums
    (e = r − z̃ of the most saving point, the blocks with Gaussian multipliers, as in
    :func:`scan_test`). The statistic is studentised, max_k T_k / sd_k, its null the largest
    of the correlated standard normals. ``best``: the point that saves most (the estimate);
    ``coefficients``: the free gain there (for the report)."""
    rows = blocks >= 0
    yv, bv, bl = y[rows], base[rows], blocks[rows]
    nb = int(bl.max()) + 1 if len(bl) else 0
    q0 = _orth(bv) if bv.shape[1] else np.zeros((len(yv), 0))
    r0 = yv - q0 @ (q0.T @ yv)
    zt = []
    for z in candidates:
        zv = z[rows]
        zt.append(zv - q0 @ (q0.T @ zv))
    if not zt or nb < 2:
        return ScanResult(0.0, 0, 1.0, 1.0, 1.0, -math.inf, nb, 0, np.zeros(1), r0)
    cross = np.array([float(z @ r0) for z in zt])
    sq = np.array([float(z @ z) for z in zt])
    saved = 2.0 * cross - sq
    # the noise: the residual left by the most saving point's signature at its fitted gain
    # (what the signature's shape does not explain is not counted as the effect's noise)
    first = int(np.argmax(saved))
    e1 = r0 - (cross[first] / sq[first] if sq[first] > 0.0 else 0.0) * zt[first]
    g = np.stack([np.bincount(bl, z * e1, nb) for z in zt], axis=1)  # block sums of z·e
    cov = 4.0 * (g.T @ g)
    sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    # each point's noise widened by its scores' correlation between blocks
    factors = [long_run_factor(g[:, k : k + 1]) for k in range(g.shape[1])]
    kappa = np.array([f for f, _ in factors])
    dof = min((d for _, d in factors if d is not None), default=None)
    # studentised: each point's saving over its own noise (a long dead time has a large
    # signature and a large noise projection; it must not set the scale of the others)
    stat = saved / (sd * np.sqrt(kappa))
    t_obs = float(np.max(stat))
    evals, evecs = np.linalg.eigh(cov)
    root = evecs * np.sqrt(np.clip(evals, 0.0, None))
    # H0: the effect at its own size saves nothing at any point (T_k <= 0); at its boundary
    # the saving's error 2·z̃·e is normal with the block sums' covariance
    draws = (rng.standard_normal((replicates, len(zt))) @ root.T) / sd
    t_null = np.max(draws, axis=1) * np.sqrt(_variance_draws(dof, replicates, rng))
    p_emp = (1.0 + float(np.sum(t_null >= t_obs))) / (1.0 + replicates)
    # beyond the replicates: the normal tail of the best point, Bonferroni over the scan
    p_tail = float(stats.norm.sf(t_obs) if dof is None else stats.t.sf(t_obs, dof))
    p = min(1.0, p_tail * len(zt)) if p_emp <= 1.5 / (1.0 + replicates) else p_emp
    z = float(stats.norm.isf(max(min(p, 1.0), 1e-300))) if p < 1.0 else -math.inf
    best = first
    gain = cross[best] / sq[best] if sq[best] > 0.0 else 0.0
    return ScanResult(
        statistic=t_obs,
        best=best,
        p=p,
        p_bootstrap=p_emp,
        p_tail=p_tail,
        z=z,
        n_blocks=nb,
        replicates=replicates,
        coefficients=np.array([gain]),
        residual=r0,
    )

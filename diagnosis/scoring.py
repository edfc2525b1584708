"""Held-out scoring of fitted models: the training/held-out blocks, the signal weights, the
held-out cost and the improvement test of the decision rule."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from .fit import FitResult, Objective, robust
from .metrics import (
    autocorrelation_time,
    effective_samples,
    fit_percent,
    improvement_test,
    information_criterion,
    nrmse,
)
from .replay import ReplayInput
from .results import COMPARED, Score, SignalFit


class Scorer:
    """Held-out scores: the odd blocks of the recording, or one or more second recordings
    (``val_objs``; their samples are concatenated, blocks numbered on)."""

    def __init__(
        self, obj: Objective, val_objs: Sequence[Objective], blocks: np.ndarray, lags: int = 5
    ) -> None:
        self.obj = obj
        self.val_objs = list(val_objs)
        #: block number of every held-out sample
        self.blocks = blocks
        #: Newey-West lags of the held-out tests: twice the autocorrelation time of the
        #: re-fitted nominal model's held-out residual (set by the engine)
        self.lags = lags

    @property
    def signals(self) -> tuple[str, ...]:
        objs = self.val_objs or [self.obj]
        return tuple(s for s in self.obj.signals if all(s in o.signals for o in objs))

    def test(self, small: np.ndarray, big: np.ndarray) -> tuple[float, float]:
        """z and one-sided p that the held-out residuals ``big`` are the smaller ones
        (:func:`~diagnosis.metrics.improvement_test`)."""
        lags = min(self.lags, max(1, small.shape[1] // 10))
        return improvement_test(small, big, lags)

    def test_without_best_block(self, small: np.ndarray, big: np.ndarray) -> float:
        """p of :meth:`test` without the held-out block that gains most: an effect must show
        in more than one place, not only where one event of another error sits."""
        gains = np.bincount(self.blocks, np.sum(small**2 - big**2, axis=0))
        keep = self.blocks != int(np.argmax(gains))
        if keep.sum() < 10:
            return 1.0
        return self.test(small[:, keep], big[:, keep])[1]

    def _held(
        self, result: FitResult
    ) -> list[tuple[Objective, Mapping[str, np.ndarray], np.ndarray]]:
        if not self.val_objs:
            return [(self.obj, result.residuals, ~self.obj.train)]
        return [
            (v, v.residuals(result.axis, result.options), np.ones(v.inp.n_samples, dtype=bool))
            for v in self.val_objs
        ]

    def score(self, result: FitResult, n_free: int) -> tuple[Score, np.ndarray]:
        """Held-out score and the held-out scaled residuals (rows: signals)."""
        held = self._held(result)
        signals = self.signals
        res = {s: np.concatenate([r[s][m] for _, r, m in held]) for s in signals}
        y = {s: np.concatenate([o.inp.compared(s)[m] for o, _, m in held]) for s in signals}
        n = len(res[signals[0]])
        rob = {s: robust(res[s]) for s in signals}
        per = {s: float(np.mean(rob[s] ** 2)) for s in signals}
        cost = sum(per.values())
        total = cost or 1.0
        tau = sum(per[s] / total * autocorrelation_time(rob[s]) for s in signals)
        n_eff = effective_samples(n, tau)
        fits = {}
        for s in signals:
            yh = y[s] - res[s] * held[0][0].scales[s]  # residual is (y - ŷ)/scale
            fits[s] = SignalFit(nrmse(y[s], yh), fit_percent(y[s], yh), COMPARED[s])
        bic = information_criterion(cost, n_eff, n_free)
        loss = np.array([rob[s] for s in signals]) / math.sqrt(n)
        return Score(cost, n, n_eff, n_free, bic, fits), loss


def validation_objectives(
    val_inps: Sequence[ReplayInput],
    weights: Mapping[str, float],
    previous: Sequence[Objective],
    retired: list[Objective],
) -> list[Objective]:
    """Held-out objectives of the second recordings under new signal weights (the previous
    ones are retired: their simulation counts still add up)."""
    retired.extend(previous)
    return [Objective(v, np.ones(v.n_samples, dtype=bool), weights) for v in val_inps]


def heldout_blocks(
    time_s: np.ndarray, train: np.ndarray, val_inps: Sequence[ReplayInput], block_s: float
) -> np.ndarray:
    """Block number of every held-out sample: the odd blocks of the recording, or the blocks
    of the second recordings numbered on from one recording to the next."""
    if not val_inps:
        return block_index(time_s, block_s)[~train]
    out, offset = [], 0
    for v in val_inps:
        b = block_index(v.time_s, block_s) + offset
        out.append(b)
        offset = int(b.max()) + 1
    return np.concatenate(out)


def block_index(time_s: np.ndarray, block_s: float) -> np.ndarray:
    """Block number of every sample: an even number of blocks of about ``block_s``."""
    span = float(time_s[-1] - time_s[0])
    n_blocks = max(2, 2 * round(span / (2.0 * block_s)))
    return np.minimum((time_s - time_s[0]) / span * n_blocks, n_blocks - 1).astype(int)


def training_blocks(time_s: np.ndarray, block_s: float) -> np.ndarray:
    """Training mask: the even blocks (at least one of each)."""
    return block_index(time_s, block_s) % 2 == 0


def signal_weights(obj: Objective, result: FitResult) -> dict[str, float]:
    """RMS residual per signal on the training samples, in the signal's unit."""
    out = {}
    for s in obj.signals:
        r = result.residuals[s][obj.train] * obj.scales[s]
        rms = float(np.sqrt(np.mean(r**2)))
        out[s] = rms if rms > 0.0 and math.isfinite(rms) else obj.scales[s]
    return out

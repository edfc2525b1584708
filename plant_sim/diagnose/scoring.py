"""Held-out scoring of fitted models: the training/held-out blocks, the signal weights, the
held-out cost and the improvement test of the decision rule."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

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
    """Held-out scores: the odd blocks of the recording, or a second recording."""

    def __init__(
        self, obj: Objective, val_obj: Objective | None, blocks: np.ndarray, lags: int = 5
    ) -> None:
        self.obj = obj
        self.val_obj = val_obj
        #: block number of every held-out sample
        self.blocks = blocks
        #: Newey-West lags of the held-out tests: twice the autocorrelation time of the
        #: re-fitted nominal model's held-out residual (set by the engine)
        self.lags = lags

    def test(self, small: np.ndarray, big: np.ndarray) -> tuple[float, float]:
        """z and one-sided p that the held-out residuals ``big`` are the smaller ones
        (:func:`~plant_sim.diagnose.metrics.improvement_test`)."""
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

    def score(self, result: FitResult, n_free: int) -> tuple[Score, np.ndarray]:
        """Held-out score and the held-out scaled residuals (rows: signals)."""
        if self.val_obj is None:
            res = result.residuals
            mask = ~self.obj.train
            obj = self.obj
            inp = self.obj.inp
        else:
            res = self.val_obj.residuals(result.axis, result.options)
            mask = np.ones(self.val_obj.inp.n_samples, dtype=bool)
            obj = self.val_obj
            inp = self.val_obj.inp
        cost = obj.cost(res, mask)
        per = {s: float(np.mean(robust(res[s][mask]) ** 2)) for s in obj.signals}
        total = sum(per.values()) or 1.0
        tau = sum(per[s] / total * autocorrelation_time(robust(res[s][mask])) for s in obj.signals)
        n = int(mask.sum())
        n_eff = effective_samples(n, tau)
        fits = {}
        for s in obj.signals:
            y = inp.compared(s)[mask]
            # residual is (y - ŷ)/scale
            yh = y - res[s][mask] * obj.scales[s]
            fits[s] = SignalFit(nrmse(y, yh), fit_percent(y, yh), COMPARED[s])
        bic = information_criterion(cost, n_eff, n_free)
        loss = np.array([robust(res[s][mask]) for s in obj.signals]) / math.sqrt(n)
        return Score(cost, n, n_eff, n_free, bic, fits), loss


def validation_objective(
    val_inp: ReplayInput | None,
    weights: Mapping[str, float],
    previous: Objective | None,
    retired: list[Objective],
) -> Objective | None:
    if val_inp is None:
        return None
    if previous is not None:
        retired.append(previous)
    return Objective(val_inp, np.ones(val_inp.n_samples, dtype=bool), weights)


def rescaled(result: FitResult, old: Objective, new: Objective) -> FitResult:
    """``result`` with its residuals and cost in ``new``'s signal scales (no simulation)."""
    res = {s: result.residuals[s] * old.scales[s] / new.scales[s] for s in new.signals}
    return replace(result, residuals=res, cost=new.cost(res))


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

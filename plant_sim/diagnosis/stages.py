"""The state the diagnosis's stages pass on (:mod:`.engine`, :mod:`.selection`): the inputs
and bookkeeping (:class:`Context`), the base model every effect is compared with
(:class:`Base`), and where its residual sits (:class:`Located`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from .evidence import DataScales
from .fit import PERIODIC_COS, PERIODIC_SIN, FitResult, FitSpec, Objective
from .mismatch import Kinematics, ResidualTests
from .parameters import Suspect
from .replay import ReplayInput
from .results import DiagnosisOptions, ProgressBar, Score
from .scoring import Scorer


@dataclass
class Context:
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
class Base:
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
    hold: list[str]  # keys held within their uncertainty when effects are compared
    decision: str


@dataclass
class Located:
    kin: Kinematics
    labels: np.ndarray
    residuals: dict[str, np.ndarray]
    tests: list[ResidualTests]
    simulated: Trace


def axis_values(values: Mapping[str, float]) -> dict[str, float]:
    """Fitted values keyed by axis keys (the periodic pseudo-keys become amplitude/phase)."""
    out = {k: float(v) for k, v in values.items() if k not in (PERIODIC_COS, PERIODIC_SIN)}
    if PERIODIC_COS in values or PERIODIC_SIN in values:
        c, s = values.get(PERIODIC_COS, 0.0), values.get(PERIODIC_SIN, 0.0)
        out["disturbance.periodic_amplitude"] = math.hypot(c, s)
        out["disturbance.periodic_phase"] = math.atan2(s, c)
    return out

"""The state the diagnosis's stages pass on (:mod:`.engine`, :mod:`.closed_loop`): the
inputs, the options and the bookkeeping (:class:`Context`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from .evidence import DataScales
from .fit import Objective
from .replay import ReplayInput
from .results import DiagnosisOptions, ProgressBar


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

"""What :func:`.engine.diagnose` returns (``report.py`` writes it, ``explain.py`` reads it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from .closed_loop import ClosedLoop
from .effects import Effect
from .mismatch import MismatchWindow, ResidualTests
from .results import Adequacy, Ambiguity, DiagnosisOptions, Score, SignalFit
from .screen import Screening
from .unexplained import Where


@dataclass(frozen=True)
class DatasheetVerdict:
    """A parameter of the nominal: its data-sheet value and uncertainty box, what the
    evidence estimates (± a block-robust standard error), whether that says the data sheet
    is wrong (beyond three standard errors outside the box), and where the closed-loop fit put
    it (within the box, or around the evidence's value where the sheet is wrong)."""

    key: str
    nominal: float | None
    box: tuple[float, float] | None
    evidence: float
    standard_error: float
    datasheet_wrong: bool
    fitted: float | None
    unit: str


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found (``report.py`` writes it)."""

    left_out: list[Effect]
    evidence: Screening  # stage 2: the tests, estimates and data-sheet verdicts
    closed_loop: ClosedLoop  # stage 3: the models fitted in closed loop, held-out scores
    ambiguous: list[Ambiguity]
    mismatch: list[MismatchWindow]
    mismatch_by_condition: dict[str, float]
    tests_final: list[ResidualTests]
    fit_before: dict[str, SignalFit]
    fit_refit: dict[str, SignalFit]
    fit_after: dict[str, SignalFit]
    heldout_nominal: Score
    heldout_refit: Score
    heldout_final: Score
    nominal: AxisConfig
    refit: AxisConfig  # the nominal within its data sheet, fitted in closed loop
    fitted: AxisConfig  # with the named effects
    fitted_values: dict[str, tuple[float, float]]  # key -> (nominal or NaN, fitted)
    datasheet: list[DatasheetVerdict]
    adequacy: Adequacy
    unexplained: list[Where]  # where the residual stays above the noise (empty: nowhere)
    notes: list[str]
    explanation: str
    simulated_before: Trace
    simulated_refit: Trace
    simulated_after: Trace
    recording: Trace
    validation: str  # "interleaved blocks" or "N second recording(s)"
    timings_s: dict[str, float] = field(default_factory=dict)
    n_simulations: int = 0
    options: DiagnosisOptions = field(default_factory=DiagnosisOptions)

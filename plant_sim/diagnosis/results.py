"""What :func:`~plant_sim.diagnosis.engine.diagnose` returns, its options and the per-signal
fit of a simulation (report.json is written from these)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from .effects import Effect
from .errors import DiagnosisOptionError
from .metrics import fit_percent, nrmse
from .mismatch import MismatchWindow, ResidualTests
from .parameters import Suspect
from .replay import ReplayInput, compared_quantity

DECISION_RULE = (
    "Every candidate is fitted on the training blocks only and scored on the held-out ones. "
    "Held-out cost C: sum over signals of the mean squared simulation error, each signal "
    "scaled by the re-fitted nominal model's RMS residual. An effect is named when the "
    "held-out improvement C0 - C1 is significant against the noise: with delta the change of "
    "the simulation that the effect makes and r1 the residual with it, "
    "z = (C0 - C1) / sd(2 sum delta r1) (Newey-West, lags = twice the residual's "
    "autocorrelation time) has one-sided p < {alpha:g}, and C falls by at least "
    "{min_improvement:g} %, and without the held-out block that gains most p stays below "
    "0.1 (the effect must show in more than one place). Parameters are paid for on the "
    "held-out data: a parameter that only fits training noise makes C1 larger than C0 on "
    "average. Forward selection: the best such "
    "effect is added, the next round starts from the model with it, until none qualifies. "
    "Effects that the best one does not beat by the same test at the same level explain "
    "the data equally well and are reported as ambiguous with an experiment that tells them "
    "apart; of them the one with fewest parameters is named, unless the best one beats it "
    "by the same test at p < {choice_alpha:g} with a held-out cost at least "
    "{min_improvement:g} % lower (a choice between explanations of an effect already "
    "shown). The "
    "nested F test and BIC with n_eff = held-out samples / autocorrelation time are reported "
    "for comparison."
)


@dataclass(frozen=True)
class DiagnosisOptions:
    """Settings of :func:`diagnose` (defaults: the documented decision rule)."""

    alpha: float = 1e-3  # significance level of the held-out (Diebold-Mariano) test
    #: level at which an ambiguous candidate with more parameters is named over one with fewer
    choice_alpha: float = 0.05
    min_improvement: float = 0.005  # least relative held-out cost reduction to name an effect
    block_s: float = 1.0  # length of the interleaved fit / held-out blocks, s
    max_effects: int = 3  # rounds of forward selection
    max_nfev: int = 20  # least-squares iterations per start
    n_starts: int = 2  # least-squares starts per fit
    n_global_nominal: int = 8  # Sobol points of the nominal re-fit's global stage
    n_global_candidate: int = 4  # ... of each candidate's
    jobs: int = 2  # candidate fits in parallel (threads; the kernel releases the GIL)
    seed: int = 0
    effects: tuple[Effect, ...] = tuple(Effect)  # effects that may be tried

    def __post_init__(self) -> None:
        checks = [
            ("alpha", self.alpha, 0.0 < self.alpha < 1.0, "(0, 1)"),
            (
                "choice_alpha",
                self.choice_alpha,
                self.alpha <= self.choice_alpha < 1.0,
                f"[alpha = {self.alpha:g}, 1)",
            ),
            ("min_improvement", self.min_improvement, 0.0 <= self.min_improvement < 1.0, "[0, 1)"),
            ("block_s", self.block_s, 0.05 <= self.block_s <= 1e4, "[0.05, 10000] s"),
            (
                "max_effects",
                self.max_effects,
                0 <= self.max_effects <= len(Effect),
                f"[0, {len(Effect)}]",
            ),
            ("max_nfev", self.max_nfev, 1 <= self.max_nfev <= 10_000, "[1, 10000]"),
            ("n_starts", self.n_starts, 1 <= self.n_starts <= 20, "[1, 20]"),
            (
                "n_global_nominal",
                self.n_global_nominal,
                0 <= self.n_global_nominal <= 4096,
                "[0, 4096]",
            ),
            (
                "n_global_candidate",
                self.n_global_candidate,
                0 <= self.n_global_candidate <= 4096,
                "[0, 4096]",
            ),
            ("jobs", self.jobs, 1 <= self.jobs <= 64, "[1, 64]"),
        ]
        for name, value, ok, allowed in checks:
            if not ok:
                raise DiagnosisOptionError(f"{name} = {value!r}: allowed {allowed}")


class ProgressBar:
    """What :func:`diagnose` reports progress to (a ``tqdm`` bar fits): counts simulations."""

    def update(self, n: int = 1) -> object:  # pragma: no cover - interface
        return None

    def set_description(self, desc: str) -> object:  # pragma: no cover - interface
        return None


@dataclass(frozen=True)
class SignalFit:
    """Fit of the simulation to one recorded signal (over all samples of a recording)."""

    nrmse: float
    fit_percent: float
    compared: str


@dataclass(frozen=True)
class Score:
    """Held-out score of a fitted model."""

    cost: float
    n_samples: int
    n_eff: float
    n_free: int
    bic: float
    fits: dict[str, SignalFit]


@dataclass(frozen=True)
class CandidateResult:
    effect: Effect
    round: int
    parameters: dict[str, float]  # fitted values of the effect's keys and the refitted ones
    heldout: Score
    improvement_percent: float  # held-out cost reduction against the model of its round
    training_improvement_percent: float  # the same on the data it was fitted to
    z_statistic: float  # z of that reduction against the noise (the decision)
    p_value: float  # its one-sided p-value
    p_without_best_block: float  # the same without the held-out block that gains most
    f_statistic: float  # nested F test with n_eff (reported for comparison)
    f_p_value: float
    significant: bool
    accepted: bool
    notes: list[str]
    n_simulations: int
    seconds: float


@dataclass(frozen=True)
class Ambiguity:
    named: Effect
    alternative: Effect
    cost_ratio: float  # held-out cost of the alternative / of the named one
    p_value: float  # p that the one with the lower held-out cost is better (>= alpha: not shown)
    experiment: str


@dataclass(frozen=True)
class Adequacy:
    """Whether the best model explains the recording: per signal the RMS residual over the
    white-noise level (``noise_ratio``), where the unexplained part sits (share of its mean
    square per operating condition), its dominant frequency, and the regressors it correlates
    with; ``hints``: the kinds of physics that pattern points to."""

    adequate: bool
    noise_ratio: dict[str, float]
    fit_percent: dict[str, float]
    by_condition: dict[str, float]
    frequency_hz: dict[str, float]
    correlated_with: dict[str, list[str]]
    hints: list[str]


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found (``report.py`` writes it)."""

    left_out: list[Effect]
    candidates: list[CandidateResult]
    ambiguous: list[Ambiguity]
    mismatch: list[MismatchWindow]
    mismatch_by_condition: dict[str, float]
    tests_refit: list[ResidualTests]
    tests_final: list[ResidualTests]
    fit_before: dict[str, SignalFit]
    fit_refit: dict[str, SignalFit]
    fit_after: dict[str, SignalFit]
    heldout_refit: Score
    heldout_final: Score
    nominal: AxisConfig
    refit: AxisConfig
    fitted: AxisConfig
    refit_values: dict[str, tuple[float, float]]  # key -> (nominal, refitted)
    fitted_values: dict[str, tuple[float, float]]  # key -> (nominal, in axis_fitted.toml)
    #: re-fitted parameters that ended on a bound or moved beyond their data-sheet
    #: uncertainty (signs of missing physics; held within it when effects are compared)
    suspects: list[Suspect]
    refit_decision: str  # which re-fit was kept and why (held-out costs)
    heldout_nominal: Score  # held-out score of the nominal as given (final weights)
    adequacy: Adequacy  # does the model class explain the recording (explain.py)
    notes: list[str]
    explanation: str
    simulated_before: Trace
    simulated_refit: Trace
    simulated_after: Trace
    recording: Trace
    validation: str  # "interleaved blocks" or "N second recording(s)"
    timings_s: dict[str, float] = field(default_factory=dict)
    n_simulations: int = 0
    options: DiagnosisOptions = DiagnosisOptions()


COMPARED = {
    "motor_position": "following error k_r*position_reference - motor_position (rad)",
    "load_position": "following error position_reference - load_position (load units)",
    "motor_speed": "motor_speed (rad/s)",
    "motor_torque": "motor_torque (N m)",
}


def signal_fits(
    inp: ReplayInput, simulated: Trace, mask: np.ndarray | None = None
) -> dict[str, SignalFit]:
    out = {}
    for s in inp.signals:
        y = inp.compared(s)
        yh = compared_quantity(inp, s, simulated[s])
        if mask is not None:
            y, yh = y[mask], yh[mask]
        e = nrmse(y, yh)
        out[s] = SignalFit(e, fit_percent(y, yh), COMPARED[s])
    return out

"""What :func:`~diagnosis.engine.diagnose` returns, its options and the per-signal
fit of a simulation (report.json is written from these)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from virtual_bus.formats.trace import Trace

from .effects import Effect
from .errors import DiagnosisOptionError
from .metrics import fit_percent, nrmse
from .replay import ReplayInput, compared_quantity

DECISION_RULE = (
    "Evidence first. Every effect of the axis-file table the model lacks is tested where it "
    "acts, by regressors linear in its parameters: the torque balance from the measured "
    "motion (inverse dynamic model, least squares), the deflection between two measuring "
    "systems, and, for a dead time, a torque limit and free play with one measuring system, "
    "its signature in the closed-loop replay (a scan of its value, linear in its gain). Each "
    "relation is fitted on the recording and on replays of the current model carrying the "
    "recording's measurement noise, with one pre-whitening filter; H0: the recording's "
    "coefficients equal the replays' (what the estimator gives where the effect is absent). "
    "Statistic: the residual reduction, the largest over a scan; null distribution: a wild "
    "bootstrap of the recording's own residual in blocks of its correlation length (Gaussian "
    "multipliers), widened by the scores' correlation between blocks over a 16th of the "
    "recording (a residual that wanders for seconds). An effect is named when "
    "p < {alpha:g} / (effects tested) (Bonferroni: "
    "{alpha:g} is the false-alarm rate per recording and round), its estimate is physical and "
    "above the effect's absent value, and (closed loop) the effect at its own size explains "
    "the signature (gain 0.5..2). Forward selection: the largest z is named unless another "
    "significant effect of the same relation explains it; two that explain each other are "
    "ambiguous (the one with fewer parameters named). Then the named effects are modelled and "
    "the whole model re-fitted in closed loop, nominal parameters within their data-sheet "
    "uncertainty unless the evidence puts them beyond it, and scored on the held-out data (odd "
    "blocks or --validate): in naming order an effect stays named only when the model with it "
    "predicts them better than the model without it (both fitted alike) by at least "
    "{min_improvement:g} % (otherwise: evidence without a model gain), and of two ambiguous "
    "explanations the other is named when it fits them better at p < {choice_alpha:g} by at "
    "least {min_improvement:g} %."
)


@dataclass(frozen=True)
class DiagnosisOptions:
    """Settings of :func:`diagnose` (defaults: the documented decision rule)."""

    #: false-alarm rate per recording and round of the evidence stage (Bonferroni over the
    #: effects tested)
    alpha: float = 0.01
    #: level at which the held-out data name an ambiguous alternative over the evidence's
    choice_alpha: float = 0.05
    #: least held-out cost reduction for an effect to stay named (the held-out gate) and for
    #: an ambiguous alternative to be named instead
    min_improvement: float = 0.005
    block_s: float = 1.0  # length of the interleaved fit / held-out blocks, s
    max_effects: int = 3  # rounds of forward selection
    max_nfev: int = 4  # least-squares iterations of each closed-loop fit
    jobs: int = 2  # simulations in parallel (threads; the kernel releases the GIL)
    seed: int = 0
    effects: tuple[Effect, ...] = tuple(Effect)  # effects that may be tried

    def __post_init__(self) -> None:
        checks = [
            ("alpha", self.alpha, 0.0 < self.alpha < 1.0, "(0, 1)"),
            (
                "choice_alpha",
                self.choice_alpha,
                0.0 < self.choice_alpha < 1.0,
                "(0, 1)",
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

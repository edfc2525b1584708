"""The search for beta_T (section VIII: "starting from small values for stability, and it is
increased to improve the response"), with its margin and its confirmation."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..errors import RegulatorConfigError, TuningError, require_positive
from ..units import length
from .judge import Limits, Record, TrialResult, Verdict, judge, measure
from .ladder import Ladder, Rung
from .motion import MotionProfile


class Outcome(Enum):
    FOUND = "found"
    NEVER_STABLE = "never stable"  # no beta_T below the first vibrating one is quiet and exact
    NOT_CONFIRMED = "result not confirmed"
    STOPPED = "axis stopped"


def _require(cond: bool, message: str, field_name: str, value: object) -> None:
    if not cond:
        raise RegulatorConfigError(message, field=field_name, value=value)


#: Without a given start, the schedule starts this factor below the limit cycle's beta (the
#: detector's level in the provoking reference trial) ...
START_BELOW_BETA = 64.0
#: ... and ends this factor above it (lambda = exp(-1/16) = 0.94 at the limit cycle's beta:
#: the regulator hardly acts).
END_ABOVE_BETA = 16.0


#: Where the ordinary control itself stops less exactly than the standstill limit asks, the
#: trials are held to its standstill error times this.
ORDINARY_ACCURACY_MARGIN = 1.25


@dataclass(frozen=True)
class SearchConfig:
    """start_rad_s: first beta_T (None: the limit cycle's beta / :data:`START_BELOW_BETA`);
    factor: ratio between trials (> 1); max_rad_s: the largest tried (None: the limit cycle's
    beta x :data:`END_ABOVE_BETA`); margin: the result is the largest stable beta_T divided by
    it (>= 1), or less where a smaller one would not be exact; vibration_fraction: a trial
    vibrates when its band amplitude exceeds this share of the reference trial's (the ordinary
    control's limit cycle); limit_cycle_floor: a reference limit-cycles above this many times
    the standstill limit."""

    start_rad_s: float | None = None
    factor: float = 2.0
    max_rad_s: float | None = None
    margin: float = 2.0
    vibration_fraction: float = 0.1
    limit_cycle_floor: float = 10.0

    def __post_init__(self) -> None:
        if self.start_rad_s is not None:
            require_positive("start_rad_s", self.start_rad_s, "rad/s")
        if self.max_rad_s is not None:
            require_positive("max_rad_s", self.max_rad_s, "rad/s")
        _require(
            isinstance(self.factor, int | float) and self.factor > 1.0,
            f"factor = {self.factor!r}: must be > 1",
            "factor",
            self.factor,
        )
        _require(
            self.start_rad_s is None
            or self.max_rad_s is None
            or self.max_rad_s >= self.start_rad_s,
            f"max_rad_s = {self.max_rad_s!r}: must be >= start_rad_s = {self.start_rad_s!r}",
            "max_rad_s",
            self.max_rad_s,
        )
        _require(
            isinstance(self.margin, int | float) and self.margin >= 1.0,
            f"margin = {self.margin!r}: must be >= 1",
            "margin",
            self.margin,
        )
        _require(
            isinstance(self.vibration_fraction, int | float)
            and 0.0 < self.vibration_fraction < 1.0,
            f"vibration_fraction = {self.vibration_fraction!r}: must be in (0, 1)",
            "vibration_fraction",
            self.vibration_fraction,
        )
        require_positive("limit_cycle_floor", self.limit_cycle_floor, "")

    def schedule(self, beta_ref_rad_s: float) -> list[float]:
        """The beta_T of the raising trials, in order (``beta_ref_rad_s``: the limit cycle's
        beta, for the defaults)."""
        start = self.start_rad_s or _round(beta_ref_rad_s / START_BELOW_BETA)
        end = self.max_rad_s or beta_ref_rad_s * END_ABOVE_BETA
        out, beta = [], start
        while beta <= end * (1.0 + 1e-9) or not out:
            out.append(beta)
            beta *= self.factor
        return out


def _round(value: float) -> float:
    """``value`` to 2 significant digits (a schedule a person reads)."""
    if value <= 0.0 or not math.isfinite(value):
        raise TuningError(f"the limit cycle's beta {value!r} rad/s gives no schedule")
    return float(f"{value:.2g}")


@dataclass(frozen=True)
class Tried:
    """A rung of the ladder and what its reference trial showed (``vibration`` load units;
    None: skipped, ``skipped`` says why)."""

    name: str
    description: str
    vibration: float | None
    skipped: str | None = None


@dataclass(frozen=True)
class SearchResult:
    """Outcome of :func:`search`: ``beta_t_rad_s`` only when FOUND. ``margin``: the factor
    actually backed off (at most the configured one); ``tried``: the ladder's rungs up to the
    one that provoked the limit cycle."""

    outcome: Outcome
    beta_t_rad_s: float | None
    last_stable_rad_s: float | None
    first_vibrating_rad_s: float | None
    reference: TrialResult
    trials: tuple[TrialResult, ...]
    confirmation: TrialResult | None
    limits: Limits
    reason: str
    tried: tuple[Tried, ...] = ()
    margin: float = math.nan
    unit: str = "m"
    profile: MotionProfile | None = None  # the motion of the trials
    kv: float = math.nan
    velocity_feedforward: float = 0.0

    def expected_error(self, record: Record, cycle_s: float) -> np.ndarray:
        """Eq. 1's following error (1 - k_vff) v / k_v along ``record``'s reference."""
        v = np.append(np.diff(record.position_reference), 0.0) / cycle_s
        return (1.0 - self.velocity_feedforward) * v / self.kv

    @property
    def cost(self) -> str:
        """What the result costs (the paper: "stability with the cost of some following
        error"): the confirmation's deviation from eq. 1 while moving and its wait for the
        standstill accuracy."""
        c = self.confirmation
        if c is None or c.metrics is None:
            return ""
        m = c.metrics
        wait = (
            "" if math.isnan(m.settle_s) else f"; exact at rest {m.settle_s:.2f} s into the dwell"
        )
        return (
            f"costs {length(m.following_deviation, self.unit)} of following error against "
            f"eq. 1 while moving{wait}; lambda at rest {m.lambda_at_rest:.2f}"
        )


#: What a runner does: play ``profile`` from where the axis stands with the regulator at
#: ``beta_t`` (None: off) and return what it recorded.
Runner = Callable[[MotionProfile, float | None], Record]


def describe_tried(tried: list[Tried], unit: str) -> str:
    parts = []
    for t in tried:
        what = f"{t.name} ({t.description})" if t.description else t.name
        if t.vibration is None:
            parts.append(f"{what}: skipped, {t.skipped}")
        else:
            parts.append(f"{what}: {length(t.vibration, unit)}")
    return "; ".join(parts)


def provoke(
    run: Runner,
    ladder: Ladder,
    floor: float,
    cycle_s: float,
    kv: float,
    velocity_feedforward: float,
    notify: Callable[[TrialResult], None],
    unit: str,
) -> tuple[Rung, TrialResult, list[Tried]]:
    """Play the ladder's rungs with the regulator off until one limit-cycles (band amplitude
    above ``floor``); TuningError naming every rung when none does."""
    tried: list[Tried] = []
    for rung in ladder.rungs():
        if rung.profile is None:
            tried.append(Tried(rung.name, rung.description, None, rung.skipped))
            continue
        record = run(rung.profile, None)
        if record.stopped is not None:
            notify(TrialResult(None, Verdict.STOPPED, None, record.stopped, record, rung.name))
            raise TuningError(
                f"the reference trial ({rung.name}, regulator off) stopped: {record.stopped}"
            )
        m = measure(record, rung.profile, cycle_s, kv, velocity_feedforward)
        tried.append(Tried(rung.name, rung.description, m.vibration))
        if rung.name == "deceleration":
            ladder.calibration = (record, rung.profile)
        verdict = Verdict.VIBRATING if m.vibration > floor else Verdict.STABLE
        what = "limit cycle" if verdict is Verdict.VIBRATING else "no limit cycle"
        ref = TrialResult(None, verdict, m, f"reference ({rung.name}): {what}", record, rung.name)
        notify(ref)
        if verdict is Verdict.VIBRATING:
            return rung, ref, tried
    raise TuningError(
        "no test motion excites a limit cycle under ordinary control (band amplitude above "
        f"{length(floor, unit)}): tried {describe_tried(tried, unit)}; there is nothing for "
        "beta_T to suppress -- or play the motion that makes the axis shake with --motion FILE"
    )


def search(
    run: Runner,
    ladder: Ladder,
    config: SearchConfig,
    cycle_s: float,
    kv: float,
    standstill_limit: float,
    velocity_feedforward: float = 0.0,
    on_trial: Callable[[TrialResult], None] | None = None,
    unit: str = "m",
) -> SearchResult:
    """The whole procedure (:mod:`regulator.tuning`). ``standstill_limit``: the standstill
    error a result must reach within the dwell (load units)."""
    require_positive("standstill_limit", standstill_limit, "load units")
    notify = on_trial or (lambda _r: None)
    floor = config.limit_cycle_floor * standstill_limit
    rung, ref, tried = provoke(run, ladder, floor, cycle_s, kv, velocity_feedforward, notify, unit)
    profile = rung.profile
    assert profile is not None and ref.metrics is not None
    # the standstill accuracy: the one asked, or the ordinary control's own if that is worse
    # (the regulator cannot make an axis more exact than its position loop)
    accuracy = max(standstill_limit, ORDINARY_ACCURACY_MARGIN * ref.metrics.standstill_error)
    limits = Limits(config.vibration_fraction * ref.metrics.vibration, accuracy)
    beta_ref = _limit_cycle_beta(ref.record, profile)
    trials: list[TrialResult] = []

    def trial(beta: float) -> TrialResult:
        result = judge(
            run(profile, beta), profile, limits, cycle_s, kv, beta, velocity_feedforward, unit
        )
        trials.append(result)
        notify(result)
        return result

    def finish(
        outcome: Outcome,
        beta: float | None,
        reason: str,
        confirm: TrialResult | None = None,
        margin: float = math.nan,
    ) -> SearchResult:
        stable = [t.beta_t_rad_s for t in trials if t.verdict is Verdict.STABLE]
        vibrating = [t.beta_t_rad_s for t in trials if t.verdict is Verdict.VIBRATING]
        return SearchResult(
            outcome,
            beta,
            max(stable, default=None),  # type: ignore[type-var]
            min(vibrating, default=None),  # type: ignore[type-var]
            ref,
            tuple(t for t in trials if t is not confirm),
            confirm,
            limits,
            reason,
            tuple(tried),
            margin,
            unit,
            profile,
            kv,
            velocity_feedforward,
        )

    first_vibrating: float | None = None
    for beta in config.schedule(beta_ref):
        result = trial(beta)
        if result.verdict is Verdict.STOPPED:
            return finish(Outcome.STOPPED, None, f"beta_T {beta:.4g}: {result.reason}")
        if result.verdict is Verdict.VIBRATING:
            first_vibrating = beta
            break
    quiet = [t for t in trials if t.verdict in (Verdict.STABLE, Verdict.INEXACT)]
    if first_vibrating is not None and quiet and quiet[-1].verdict is Verdict.INEXACT:
        # between the last quiet-but-inexact trial and the first vibrating one: refine
        low = quiet[-1].beta_t_rad_s
        assert low is not None
        for _ in range(2):
            mid = math.sqrt(low * first_vibrating)
            result = trial(mid)
            if result.verdict is Verdict.STOPPED:
                return finish(Outcome.STOPPED, None, f"beta_T {mid:.4g}: {result.reason}")
            if result.verdict is Verdict.VIBRATING:
                first_vibrating = mid
            elif result.verdict is Verdict.INEXACT:
                low = mid
            else:
                break
    stable = sorted(
        t.beta_t_rad_s
        for t in trials
        if t.verdict is Verdict.STABLE
        and t.beta_t_rad_s is not None
        and (first_vibrating is None or t.beta_t_rad_s < first_vibrating)
    )
    if not stable:
        return finish(
            Outcome.NEVER_STABLE,
            None,
            "no beta_T below the first vibrating one "
            f"({'none' if first_vibrating is None else f'{first_vibrating:.4g} rad/s'}) keeps "
            f"the axis quiet and exact at rest: {trials[0].reason}; check k_v and the "
            "detector's n, T_v, or lengthen the dwell (--dwell-s)",
        )
    last_stable = stable[-1]
    # the margin may not take the result below the quiet-and-exact range it was found in
    exact_floor = last_stable
    for t in sorted(
        (t for t in trials if t.beta_t_rad_s is not None and t.verdict is not Verdict.STOPPED),
        key=lambda t: -(t.beta_t_rad_s or 0.0),
    ):
        if t.beta_t_rad_s > last_stable:  # type: ignore[operator]
            continue
        if t.verdict is not Verdict.STABLE:
            break
        exact_floor = t.beta_t_rad_s  # type: ignore[assignment]
    candidate = max(last_stable / config.margin, exact_floor)
    above = (
        f"first vibrating {first_vibrating:.4g} rad/s"
        if first_vibrating is not None
        else f"no vibration up to {trials[-1].beta_t_rad_s:.4g} rad/s"
    )
    for _ in range(3):
        confirm = trial(candidate)
        margin = last_stable / candidate
        if confirm.verdict is Verdict.STOPPED:
            return finish(Outcome.STOPPED, None, f"confirmation: {confirm.reason}", confirm)
        if confirm.verdict is Verdict.STABLE:
            note = (
                ""
                if margin >= config.margin * (1 - 1e-9)
                else f" (margin {margin:.3g} instead of {config.margin:g}: below "
                f"{exact_floor:.4g} rad/s the axis was not exact within the dwell)"
            )
            return finish(
                Outcome.FOUND,
                candidate,
                f"largest stable beta_T {last_stable:.4g} rad/s, {above}; result "
                f"{candidate:.4g} rad/s{note}, confirmed quiet and exact",
                confirm,
                margin,
            )
        if confirm.verdict is Verdict.VIBRATING or candidate >= last_stable:
            break
        candidate = min(last_stable, candidate * math.sqrt(config.factor))
    return finish(
        Outcome.NOT_CONFIRMED,
        None,
        f"beta_T = {candidate:.4g} rad/s (largest stable {last_stable:.4g}) is "
        f"{confirm.verdict.value}: {confirm.reason}",
        confirm,
    )


def _limit_cycle_beta(record: Record, profile: MotionProfile) -> float:
    """The detector's level in the reference's watch windows (its 90th percentile over them):
    what the regulator sees of the limit cycle."""
    parts = [record.beta[a:b] for a, b in profile.watch]
    values = np.concatenate(parts) if parts else record.beta
    level = float(np.percentile(values, 90))
    return level if level > 0.0 else float(np.max(record.beta))

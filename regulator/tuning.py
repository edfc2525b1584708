"""The paper's beta_T procedure, automated (section VIII): pure, shared by every runner.

"This threshold should be defined experimentally by starting from small values for stability,
and it is increased to improve the response." Here, for any runner that can play a test
motion and record it (the simulated axis offline, the bridge over the bus):

1. a **test motion** (:class:`TuningMotion`) that provokes the limit cycle of eq. 12-13 and
   comes back to where it started: in each direction a ramp to ``feed``, a ramp down to
   ``low_feed`` -- the deceleration throws the load into the backlash gap, after which the
   position loop on the load scale sustains the limit cycle at the lower speed -- a watch window
   at ``low_feed``, a ramp to standstill and a dwell;
2. a **reference trial** with the regulator off (ordinary control, Fig. 1): the limit cycle to
   cut; a motion that does not excite one is refused (nothing to tune);
3. **trials** from a small beta_T upwards by a factor (:class:`BetaTSearch`), each judged by
   :func:`judge` from what the bridge itself measures:

   * *following error*: the oscillation of x_ref - x_l in a band around eq. 13's
     k_v/4..k_v (half an octave wider each side), as half its peak-to-peak in each watch window
     after the transient and in each dwell after the transient (a limit cycle at standstill);
     above ``vibration_fraction`` of the reference trial's it VIBRATES;
   * *detector*: lambda (eq. 15) back above 0.9 at the end of each dwell -- the regulator has
     given the load scale back to the position loop;
   * *standstill error*: the mean |x_ref - x_l| over the dwell's last 0.1 s;
   * reported, not judged: the mean following error against eq. 1 (v / k_v, with feed-forward
     (1 - k_vff) v / k_v) -- what a small beta_T costs while moving ("stability with the cost
     of some following error", section VIII);

   a trial is STOPPED when the axis stopped (any stop reason, the same safety limits
   everywhere: :func:`safety_stop`), VIBRATING, INEXACT (no vibration, but the detector has
   not given the scale back at rest or the standstill error is too large: a small beta_T fades
   the load scale out on every transient) or STABLE;
4. the search **stops at the first sign of vibration** and backs off by ``margin``: the
   result is the largest beta_T that kept the axis stable divided by the margin (default 2,
   a factor like a 6 dB gain margin), confirmed by one more trial that must be STABLE.

It never stores anything itself: the runner writes the result (2002h, 1010h) only when the
outcome is FOUND, and stops the axis with the reason otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from scipy.signal import butter, sosfiltfilt

from .errors import RegulatorConfigError, RegulatorError, require_positive

#: The watch window's first ``SETTLE_TIMES_KV / kv`` seconds are the position loop's transient
#: (e^-10 of the speed step's following error).
SETTLE_TIMES_KV = 10.0
#: lambda the detector must have come back to at the end of a dwell.
LAMBDA_RECOVERED = 0.9
#: Standstill error is averaged over the dwell's last this many seconds.
STANDSTILL_AVERAGE_S = 0.1
#: A window judged for oscillation lasts at least this many periods of eq. 13's lowest
#: frequency k_v / 4 (20 / k_v seconds: eq. 14's T_v), so the band-pass has settled in it.
MIN_WINDOW_PERIODS = 5.0


class TuningError(RegulatorError, ValueError):
    """A tuning run cannot start or cannot find beta_T; nothing is stored."""


class Verdict(Enum):
    STABLE = "stable"
    INEXACT = "inexact"
    VIBRATING = "vibrating"
    STOPPED = "stopped"


class Outcome(Enum):
    FOUND = "found"
    NEVER_STABLE = "never stable"  # the smallest beta_T already vibrates
    NO_VIBRATION = "no vibration up to the largest beta_T"
    NOT_CONFIRMED = "result not confirmed"
    STOPPED = "axis stopped"


def _require(cond: bool, message: str, field_name: str, value: object) -> None:
    if not cond:
        raise RegulatorConfigError(message, field=field_name, value=value)


@dataclass(frozen=True)
class TuningMotion:
    """The repeated motion (load units, s). See the module docstring."""

    feed: float = 0.05
    low_feed: float = 0.02
    accel: float = 0.1
    high_s: float = 0.5
    low_s: float = 1.5
    dwell_s: float = 1.5

    def __post_init__(self) -> None:
        for name in ("feed", "low_feed", "accel", "high_s", "low_s", "dwell_s"):
            require_positive(name, getattr(self, name), "")
        _require(
            self.low_feed < self.feed,
            f"low_feed = {self.low_feed!r}: must be below feed = {self.feed!r} (the deceleration "
            "between them provokes the limit cycle)",
            "low_feed",
            self.low_feed,
        )
        _require(
            self.dwell_s > STANDSTILL_AVERAGE_S,
            f"dwell_s = {self.dwell_s!r}: must exceed {STANDSTILL_AVERAGE_S} s",
            "dwell_s",
            self.dwell_s,
        )

    def profile(self, cycle_s: float, kv: float, start: float = 0.0) -> MotionProfile:
        """Samples of one run (positive direction, then back), one per cycle."""
        require_positive("cycle_s", cycle_s, "s")
        require_positive("kv", kv, "1/s")
        speeds: list[np.ndarray] = []
        watch: list[tuple[int, int]] = []
        standstill: list[tuple[int, int]] = []
        rest: list[tuple[int, int]] = []
        n = 0
        settle = round(SETTLE_TIMES_KV / kv / cycle_s)
        shortest = math.ceil(MIN_WINDOW_PERIODS * 4.0 / kv / cycle_s)
        for sign in (1.0, -1.0):
            level = 0.0
            for target, hold_s, kind in (
                (self.feed, self.high_s, ""),
                (self.low_feed, self.low_s, "watch"),
                (0.0, self.dwell_s, "dwell"),
            ):
                steps = max(1, math.ceil(abs(target - level) / self.accel / cycle_s))
                ramp = level + (target - level) * np.arange(1, steps + 1) / steps
                hold = round(hold_s / cycle_s)
                speeds += [sign * ramp, np.full(hold, sign * target)]
                n += steps
                if kind == "watch":
                    if hold < settle + shortest:
                        raise TuningError(
                            f"low_s = {self.low_s:g} s: the watch window must outlast the "
                            f"transient of {settle * cycle_s:g} s (10 / k_v) by "
                            f"{shortest * cycle_s:g} s (5 periods of k_v / 4)"
                        )
                    watch.append((n + settle, n + hold))
                elif kind == "dwell":
                    last = round(STANDSTILL_AVERAGE_S / cycle_s)
                    standstill.append((n + hold - last, n + hold))
                    if hold >= settle + shortest:  # else too short to judge oscillation
                        rest.append((n + settle, n + hold))
                n += hold
                level = target
        speed = np.concatenate(speeds)
        # forward difference convention of the interpolator: x[k+1] = x[k] + v[k] cycle
        position = start + np.concatenate([[0.0], np.cumsum(speed[:-1]) * cycle_s])
        return MotionProfile(position, speed, tuple(watch), tuple(standstill), tuple(rest), self)

    def travel(self, cycle_s: float, kv: float) -> float:
        """Largest excursion from the start, load units."""
        p = self.profile(cycle_s, kv)
        return float(np.max(np.abs(p.position - p.position[0])))


@dataclass(frozen=True)
class MotionProfile:
    """One run of a :class:`TuningMotion`: reference position and speed per cycle, the watch
    windows (index ranges at low_feed after the transient), the standstill windows (a dwell's
    last 0.1 s) and the rest windows (a dwell after the transient)."""

    position: np.ndarray
    speed: np.ndarray
    watch: tuple[tuple[int, int], ...]
    standstill: tuple[tuple[int, int], ...]
    rest: tuple[tuple[int, int], ...]
    motion: TuningMotion

    def repeated(self, times: int) -> MotionProfile:
        """The run ``times`` times back to back (it ends where it started)."""
        if times < 1:
            raise TuningError(f"repeats = {times}: at least 1")
        n = self.position.size
        shift = lambda ranges, k: tuple((a + k * n, b + k * n) for a, b in ranges)  # noqa: E731
        return MotionProfile(
            np.tile(self.position, times),
            np.tile(self.speed, times),
            tuple(w for k in range(times) for w in shift(self.watch, k)),
            tuple(w for k in range(times) for w in shift(self.standstill, k)),
            tuple(w for k in range(times) for w in shift(self.rest, k)),
            self.motion,
        )


@dataclass(frozen=True)
class Record:
    """What a runner recorded of one trial, one value per cycle: reference and load position
    (load units), the detector's beta (rad/s) and lambda; ``stopped``: the stop reason's
    message if the axis stopped (the arrays then end there)."""

    position_reference: np.ndarray
    load_position: np.ndarray
    beta: np.ndarray
    switching_factor: np.ndarray
    stopped: str | None = None
    torque: np.ndarray | None = None


@dataclass(frozen=True)
class SafetyLimits:
    """The limits every runner applies (the bridge's 2008h, 2014h, and a torque limit)."""

    following_error: float
    position_min: float
    position_max: float
    torque_nm: float = math.inf


def safety_stop(record: Record, limits: SafetyLimits) -> str | None:
    """The first limit ``record`` breaks (the message the bridge would stop with), or None.
    For runners without a supervisor of their own (the offline simulation)."""
    e = record.position_reference - record.load_position
    checks = [
        (np.abs(e) > limits.following_error, "following error", e, limits.following_error),
        (
            (record.load_position < limits.position_min)
            | (record.load_position > limits.position_max),
            "load position outside 2014h",
            record.load_position,
            (limits.position_min, limits.position_max),
        ),
    ]
    if record.torque is not None:
        checks.append(
            (np.abs(record.torque) > limits.torque_nm, "torque", record.torque, limits.torque_nm)
        )
    first: tuple[int, str] | None = None
    for broken, what, values, limit in checks:
        idx = np.nonzero(broken)[0]
        if idx.size and (first is None or idx[0] < first[0]):
            first = (int(idx[0]), f"{what} {values[idx[0]]:.6g} beyond the limit {limit}")
    return None if first is None else f"cycle {first[0]}: {first[1]}"


def _band_amplitude(signal: np.ndarray, cycle_s: float, kv: float) -> float:
    """The oscillation of ``signal`` in eq. 13's band k_v/4..k_v Hz widened by half an
    octave each side: the median height of its half-waves (between zero crossings of the
    band-passed signal, 8th-order Butterworth, zero phase, after a cubic trend is removed), the
    window's first and last tenth left out (the filter's edges).

    The median of half-waves, like the paper's detector taking the smaller of two half-waves
    (Fig. 5, docs/regulator.md D5), counts what alternates for most of the window: a limit
    cycle, not the one or two half-waves a monotone transient (a faded-out load scale coming
    back) leaves in the band."""
    nyquist = 0.5 / cycle_s
    widen = math.sqrt(2.0)
    high = min(kv * widen, 0.9 * nyquist)
    sos = butter(4, [kv / 4.0 / widen, high], btype="band", fs=1.0 / cycle_s, output="sos")
    if signal.size < 60:
        raise TuningError(f"watch window of {signal.size} cycles is too short to judge")
    t = np.linspace(-1.0, 1.0, signal.size)
    x = signal - np.polyval(np.polyfit(t, signal, 3), t)
    edge = x.size // 10
    y = sosfiltfilt(sos, x, padlen=x.size - 1)[edge : x.size - edge]
    crossings = np.nonzero(np.signbit(y[1:]) != np.signbit(y[:-1]))[0] + 1
    if crossings.size < 2:
        return 0.0
    peaks = [float(np.max(np.abs(seg))) for seg in np.split(y, crossings)[1:-1]]
    return float(np.median(peaks)) if peaks else 0.0


@dataclass(frozen=True)
class Metrics:
    """What :func:`judge` measured in one trial (load units, rad/s, 1)."""

    vibration: float  # worst band amplitude of the following error in a watch or rest window
    following_deviation: float  # worst |mean following error - eq. 1| in a watch window
    standstill_error: float  # worst |mean following error| at the end of a dwell
    lambda_at_rest: float  # smallest lambda at the end of a dwell
    beta_max: float  # largest beta of the trial (detector)


@dataclass(frozen=True)
class Limits:
    """Verdict limits, load units. vibration: the band amplitude that counts as vibration."""

    vibration: float
    standstill_error: float

    def __post_init__(self) -> None:
        for name in ("vibration", "standstill_error"):
            require_positive(name, getattr(self, name), "load units")


@dataclass(frozen=True)
class TrialResult:
    beta_t_rad_s: float | None  # None: the reference trial (regulator off)
    verdict: Verdict
    metrics: Metrics | None
    reason: str
    record: Record = field(repr=False)


def measure(
    record: Record, profile: MotionProfile, cycle_s: float, kv: float, velocity_feedforward: float
) -> Metrics:
    """The metrics of a complete record of ``profile`` (see the module docstring)."""
    e = record.position_reference - record.load_position
    vibration = deviation = 0.0
    for a, b in profile.rest:
        vibration = max(vibration, _band_amplitude(e[a:b], cycle_s, kv))
    for a, b in profile.watch:
        vibration = max(vibration, _band_amplitude(e[a:b], cycle_s, kv))
        v = float(profile.speed[(a + b) // 2])
        expected = (1.0 - velocity_feedforward) * v / kv  # eq. 1
        deviation = max(deviation, abs(float(np.mean(e[a:b])) - expected))
    standstill = max(abs(float(np.mean(e[a:b]))) for a, b in profile.standstill)
    lam = min(float(record.switching_factor[b - 1]) for _, b in profile.standstill)
    return Metrics(vibration, deviation, standstill, lam, float(np.max(record.beta)))


def judge(
    record: Record,
    profile: MotionProfile,
    limits: Limits,
    cycle_s: float,
    kv: float,
    beta_t_rad_s: float | None,
    velocity_feedforward: float = 0.0,
) -> TrialResult:
    """The verdict of one trial (module docstring, step 3)."""
    if record.stopped is not None:
        return TrialResult(beta_t_rad_s, Verdict.STOPPED, None, record.stopped, record)
    if record.load_position.size < profile.position.size:
        raise TuningError(
            f"record of {record.load_position.size} cycles for a motion of "
            f"{profile.position.size}: incomplete without a stop reason"
        )
    m = measure(record, profile, cycle_s, kv, velocity_feedforward)
    if m.vibration > limits.vibration:
        return TrialResult(
            beta_t_rad_s,
            Verdict.VIBRATING,
            m,
            f"following error oscillates by {m.vibration:.3g} in eq. 13's band, above "
            f"{limits.vibration:.3g}",
            record,
        )
    faults = []
    if m.lambda_at_rest < LAMBDA_RECOVERED:
        faults.append(f"lambda {m.lambda_at_rest:.3g} at rest (< {LAMBDA_RECOVERED})")
    if m.standstill_error > limits.standstill_error:
        faults.append(f"standstill error {m.standstill_error:.3g} > {limits.standstill_error:.3g}")
    if faults:
        return TrialResult(beta_t_rad_s, Verdict.INEXACT, m, "; ".join(faults), record)
    return TrialResult(beta_t_rad_s, Verdict.STABLE, m, "stable and exact", record)


@dataclass(frozen=True)
class SearchConfig:
    """start_rad_s: first beta_T; factor: ratio between trials (> 1); max_rad_s: the largest
    tried; margin: the result is the largest stable beta_T divided by it (>= 1);
    vibration_fraction: a trial vibrates when its band amplitude exceeds this share of the
    reference trial's (the ordinary control's limit cycle)."""

    start_rad_s: float = 0.01
    factor: float = 2.0
    max_rad_s: float = 100.0
    margin: float = 2.0
    vibration_fraction: float = 0.1

    def __post_init__(self) -> None:
        require_positive("start_rad_s", self.start_rad_s, "rad/s")
        _require(
            isinstance(self.factor, int | float) and self.factor > 1.0,
            f"factor = {self.factor!r}: must be > 1",
            "factor",
            self.factor,
        )
        _require(
            isinstance(self.max_rad_s, int | float) and self.max_rad_s >= self.start_rad_s,
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

    def schedule(self) -> list[float]:
        """The beta_T of the raising trials, in order."""
        out, beta = [], self.start_rad_s
        while beta <= self.max_rad_s * (1.0 + 1e-9):
            out.append(beta)
            beta *= self.factor
        return out


@dataclass(frozen=True)
class SearchResult:
    """Outcome of :func:`search`: ``beta_t_rad_s`` only when FOUND."""

    outcome: Outcome
    beta_t_rad_s: float | None
    last_stable_rad_s: float | None
    first_vibrating_rad_s: float | None
    reference: TrialResult
    trials: tuple[TrialResult, ...]
    confirmation: TrialResult | None
    limits: Limits
    reason: str


Runner = Callable[[float | None], Record]


def search(
    run: Runner,
    profile: MotionProfile,
    config: SearchConfig,
    cycle_s: float,
    kv: float,
    standstill_limit: float,
    velocity_feedforward: float = 0.0,
    on_trial: Callable[[TrialResult], None] | None = None,
) -> SearchResult:
    """The whole procedure (module docstring). ``run(beta_t)`` plays ``profile`` once with
    the regulator at beta_t (None: off) from the same start and returns its record.
    ``standstill_limit``: the standstill error a result must keep (load units)."""
    require_positive("standstill_limit", standstill_limit, "load units")
    notify = on_trial or (lambda _r: None)
    ref_record = run(None)
    # the reference is judged with a limit of its own band amplitude (it is the scale)
    if ref_record.stopped is not None:
        ref = TrialResult(None, Verdict.STOPPED, None, ref_record.stopped, ref_record)
        notify(ref)
        raise TuningError(f"the reference trial (regulator off) stopped: {ref_record.stopped}")
    ref_metrics = measure(ref_record, profile, cycle_s, kv, velocity_feedforward)
    ref = TrialResult(
        None, Verdict.VIBRATING, ref_metrics, "reference: ordinary control", ref_record
    )
    notify(ref)
    floor = 10.0 * standstill_limit
    if ref_metrics.vibration <= floor:
        raise TuningError(
            f"the test motion excites no limit cycle under ordinary control (band amplitude "
            f"{ref_metrics.vibration:.3g} load units, not above {floor:.3g}): there is nothing "
            "for beta_T to suppress; a larger feed step or a disturbance provokes it"
        )
    limits = Limits(
        vibration=config.vibration_fraction * ref_metrics.vibration,
        standstill_error=standstill_limit,
    )
    trials: list[TrialResult] = []
    last_stable: float | None = None
    first_vibrating: float | None = None

    def finish(
        outcome: Outcome, beta: float | None, reason: str, confirm: TrialResult | None = None
    ) -> SearchResult:
        return SearchResult(
            outcome,
            beta,
            last_stable,
            first_vibrating,
            ref,
            tuple(trials),
            confirm,
            limits,
            reason,
        )

    for beta in config.schedule():
        result = judge(
            run(beta), profile, limits, cycle_s, kv, beta, velocity_feedforward=velocity_feedforward
        )
        trials.append(result)
        notify(result)
        if result.verdict is Verdict.STOPPED:
            return finish(Outcome.STOPPED, None, f"beta_T {beta:.4g}: {result.reason}")
        if result.verdict is Verdict.VIBRATING:
            first_vibrating = beta
            break
        last_stable = beta
    if first_vibrating is None:
        return finish(
            Outcome.NO_VIBRATION,
            None,
            f"no sign of vibration up to beta_T = {config.max_rad_s:g} rad/s: the first sign "
            "is what sets beta_T; raise max_rad_s or provoke more",
        )
    if last_stable is None:
        return finish(
            Outcome.NEVER_STABLE,
            None,
            f"the axis vibrates already at the smallest beta_T = {config.start_rad_s:g} rad/s "
            f"({trials[0].reason}): the regulator does not stabilise this axis; lower "
            "start_rad_s or check k_v and the detector's n, T_v",
        )
    candidate = last_stable / config.margin
    confirm = judge(
        run(candidate),
        profile,
        limits,
        cycle_s,
        kv,
        candidate,
        velocity_feedforward=velocity_feedforward,
    )
    notify(confirm)
    if confirm.verdict is Verdict.STOPPED:
        return finish(Outcome.STOPPED, None, f"confirmation: {confirm.reason}", confirm)
    if confirm.verdict is not Verdict.STABLE:
        return finish(
            Outcome.NOT_CONFIRMED,
            None,
            f"beta_T = {candidate:.4g} rad/s (largest stable {last_stable:.4g} / margin "
            f"{config.margin:g}) is {confirm.verdict.value}: {confirm.reason}",
            confirm,
        )
    return finish(
        Outcome.FOUND,
        candidate,
        f"largest stable beta_T {last_stable:.4g} rad/s, first vibrating {first_vibrating:.4g}; "
        f"result {candidate:.4g} rad/s (margin {config.margin:g}), confirmed stable",
        confirm,
    )

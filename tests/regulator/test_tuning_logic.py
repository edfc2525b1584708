"""The beta_T procedure's logic (regulator.tuning) on synthetic trials whose oscillation,
drift and lambda are set by hand: the verdicts measure what was put in, the search stops at
the first vibration and backs off by the margin, and every way of failing is named."""

from __future__ import annotations

import math

import numpy as np
import pytest

from regulator.tuning import (
    Ladder,
    MotionProfile,
    Outcome,
    Record,
    SafetyLimits,
    SearchConfig,
    TuningError,
    TuningMotion,
    Verdict,
    judge,
    measure,
    safety_stop,
    search,
)

CYCLE_S, KV = 0.001, 25.0
MOTION = TuningMotion(feed=0.05, low_feed=0.02, accel=0.1, high_s=0.3, low_s=1.3, dwell_s=1.3)
PROFILE = MOTION.profile(CYCLE_S, KV).repeated(2)


def synthetic(
    profile: MotionProfile,
    amplitude: float,
    frequency_hz: float = 12.0,
    drift: float = 0.0,
    lam_at_rest: float = 1.0,
    stopped: str | None = None,
) -> Record:
    """A record: the following error of eq. 1 (v / k_v) plus a sinusoid of ``amplitude``
    while moving slowly and at rest, a slow drift, lambda as given at the dwells."""
    n = profile.position.size
    t = np.arange(n) * CYCLE_S
    e = profile.speed / KV + amplitude * np.sin(2 * math.pi * frequency_hz * t)
    e += drift * (1 - np.exp(-t / 0.8))
    lam = np.ones(n)
    for a, b in profile.standstill:
        lam[a:b] = lam_at_rest
    beta = np.full(n, 0.01)
    return Record(profile.position, profile.position - e, beta, lam, stopped)


def test_the_motion_comes_back_and_its_windows_are_where_they_say() -> None:
    p = MOTION.profile(CYCLE_S, KV)  # from 0: the runner adds where the axis stands
    assert len(p.watch) == len(p.rest) == len(p.standstill) == 2
    assert p.position[0] == 0.0 and p.position[-1] == pytest.approx(0.0, abs=1e-12)
    for a, b in p.watch:
        assert np.all(np.abs(p.speed[a:b]) == pytest.approx(0.02))
        assert a - np.nonzero(np.abs(p.speed[:a]) != 0.02)[0][-1] - 1 == 10 / KV / CYCLE_S
    for a, b in p.standstill:
        assert np.all(p.speed[a:b] == 0.0) and b - a == 100
    assert MOTION.travel(CYCLE_S, KV) == pytest.approx(float(np.max(np.abs(p.position))))


@pytest.mark.parametrize("frequency_hz", [6.25, 12.0, 25.0])  # eq. 13's band at k_v = 25
def test_the_oscillation_in_eq13s_band_is_measured(frequency_hz: float) -> None:
    m = measure(synthetic(PROFILE, 40e-6, frequency_hz), PROFILE, CYCLE_S, KV, 0.0)
    assert m.vibration == pytest.approx(40e-6, rel=0.05)
    # the mean is eq. 1's v / k_v, up to a part of a period of the sinusoid
    assert m.following_deviation < 0.1 * 40e-6


def test_a_slow_drift_and_a_single_transient_are_no_vibration() -> None:
    drifting = synthetic(PROFILE, 0.0, drift=2e-3)
    assert measure(drifting, PROFILE, CYCLE_S, KV, 0.0).vibration < 0.5e-6
    e = PROFILE.speed / KV
    a, _ = PROFILE.watch[0]
    e = e.copy()
    e[a + 50 : a + 90] += 50e-6 * np.sin(np.linspace(0, math.pi, 40))  # one half-wave
    rec = Record(PROFILE.position, PROFILE.position - e, np.zeros(e.size), np.ones(e.size))
    assert measure(rec, PROFILE, CYCLE_S, KV, 0.0).vibration < 1e-6


def test_out_of_band_oscillation_is_not_the_limit_cycle() -> None:
    m = measure(synthetic(PROFILE, 40e-6, 150.0), PROFILE, CYCLE_S, KV, 0.0)
    assert m.vibration < 4e-6


#: A standstill error far above what the ordinary control leaves at the end of its dwells (its
#: 60 µm limit cycle's mean over a dwell): the regulated axis is not exact.
INEXACT_M = 1e-3
#: The schedule fixed (its default follows the limit cycle's beta, tested below): 0.01 rad/s
#: doubled up to 10 rad/s.
CONFIG = SearchConfig(start_rad_s=0.01, max_rad_s=10.0)


def _ladder(**kwargs: object) -> Ladder:
    """The ladder of MOTION (twice, as PROFILE), 100 N m torque limit, no travel limit."""
    return Ladder(MOTION, CYCLE_S, KV, 2, 100.0, **kwargs)  # type: ignore[arg-type]


def _runner(
    vibrating_above: float,
    ordinary: float = 60e-6,
    inexact_below: float = 0.0,
    provoked_by: str | None = None,
):
    """Trials on the profile each is given: the ordinary control vibrates by ``ordinary``
    (only on the rung ``provoked_by`` where that is named); with the regulator, beta_T up to
    ``vibrating_above`` is quiet, and below ``inexact_below`` it leaves INEXACT_M of standstill
    error at the end of the dwells (the axis not exact). Calls: (rung, beta) in order."""
    calls: list[tuple[str, float | None]] = []

    def run(profile: MotionProfile, beta: float | None) -> Record:
        calls.append((profile.name, beta))
        if beta is None:
            vibrates = provoked_by is None or profile.name == provoked_by
            return synthetic(profile, ordinary if vibrates else 0.0)
        amp = 30e-6 if beta > vibrating_above else 0.2e-6
        return synthetic(profile, amp, drift=INEXACT_M if beta < inexact_below else 0.0)

    return run, calls


def test_search_stops_at_the_first_vibration_and_backs_off_by_the_margin() -> None:
    run, calls = _runner(vibrating_above=1.0)
    result = search(run, _ladder(), CONFIG, CYCLE_S, KV, 1e-6)
    assert result.outcome is Outcome.FOUND, result.reason
    assert result.first_vibrating_rad_s == 1.28 and result.last_stable_rad_s == 0.64
    assert result.beta_t_rad_s == pytest.approx(0.32)
    # the default motion's reference, 0.01 ... 1.28, the confirmation at 0.32: nothing tried
    # beyond the vibration, every trial on the rung that provoked the limit cycle
    betas = [beta for _, beta in calls]
    assert betas == [None, *(0.01 * 2**k for k in range(8)), pytest.approx(0.32)]
    assert {name for name, _ in calls} == {"deceleration"}
    assert [t.verdict for t in result.trials[:7]] == [Verdict.STABLE] * 7
    assert result.limits.vibration == pytest.approx(6e-6, rel=0.05)


def test_never_stable_no_vibration_not_confirmed_and_nothing_to_suppress() -> None:
    run, _ = _runner(vibrating_above=0.001)
    assert search(run, _ladder(), CONFIG, CYCLE_S, KV, 1e-6).outcome is (Outcome.NEVER_STABLE)
    # nothing vibrates up to the schedule's end: the largest tried, backed off by the margin
    run, _ = _runner(vibrating_above=1e9)
    result = search(run, _ladder(), CONFIG, CYCLE_S, KV, 1e-6)
    assert result.outcome is Outcome.FOUND and result.first_vibrating_rad_s is None
    assert result.beta_t_rad_s == pytest.approx(result.last_stable_rad_s / 2.0)
    # quiet from 0.01 to 0.64, but below 0.5 rad/s not exact at rest: the margin may not take
    # the result below the exact range, so it is the last stable one, 0.64 (margin 1)
    run, calls = _runner(vibrating_above=1.0, inexact_below=0.5)
    result = search(run, _ladder(), CONFIG, CYCLE_S, KV, 1e-6)
    assert result.outcome is Outcome.FOUND and result.beta_t_rad_s == pytest.approx(0.64)
    assert [t.verdict for t in result.trials[:6]] == [Verdict.INEXACT] * 6
    # an axis that vibrates when the result is confirmed (it changed meanwhile): no result
    plain, calls = _runner(vibrating_above=1.0)

    def changing(profile: MotionProfile, beta: float | None) -> Record:
        if beta is not None and len(calls) >= 9:  # reference + 8 raising trials, then confirm
            calls.append((profile.name, beta))
            return synthetic(profile, 30e-6)
        return plain(profile, beta)

    result = search(changing, _ladder(), CONFIG, CYCLE_S, KV, 1e-6)
    assert result.outcome is Outcome.NOT_CONFIRMED and result.beta_t_rad_s is None


def test_the_ladder_escalates_until_the_limit_cycle_shows_and_names_what_it_tried() -> None:
    """Ordinary control quiet on the default motion: the search goes up the ladder in its
    documented order and tunes on the first rung that limit-cycles; where none does, the
    refusal names every rung (played, or skipped with why)."""
    run, calls = _runner(vibrating_above=1.0, provoked_by="load pulse")
    result = search(run, _ladder(pulse=True), CONFIG, CYCLE_S, KV, 1e-6)
    refs = [name for name, beta in calls if beta is None]
    assert refs[0] == "deceleration" and refs[-1] == "load pulse", refs
    assert all(name == "load pulse" for name, beta in calls if beta is not None)
    assert result.outcome is Outcome.FOUND and result.beta_t_rad_s == pytest.approx(0.32)
    run, calls = _runner(vibrating_above=1.0, provoked_by="nowhere")
    with pytest.raises(TuningError) as info:
        search(run, _ladder(), CONFIG, CYCLE_S, KV, 1e-6)
    said = str(info.value)
    for rung in ("deceleration", "sharp deceleration", "reversal", "load pulse"):
        assert rung in said, said
    assert "torque offset" in said  # the pulse rungs: skipped, and why


def test_a_stopped_trial_ends_the_search_with_its_reason() -> None:
    def run(profile: MotionProfile, beta: float | None) -> Record:
        if beta is not None and beta > 0.1:
            return synthetic(profile, 0.0, stopped="FOLLOWING_ERROR: 0.002 > 2008h")
        return synthetic(profile, 60e-6 if beta is None else 0.0)

    result = search(run, _ladder(), CONFIG, CYCLE_S, KV, 1e-6)
    assert result.outcome is Outcome.STOPPED and "FOLLOWING_ERROR" in result.reason
    assert result.beta_t_rad_s is None


def test_safety_stop_names_the_first_limit_broken() -> None:
    rec = synthetic(PROFILE, 0.0)
    limits = SafetyLimits(following_error=1.9e-3, position_min=-1.0, position_max=1.0)
    assert safety_stop(rec, limits) is not None and "following error" in safety_stop(rec, limits)
    assert safety_stop(rec, SafetyLimits(3e-3, -1.0, 1.0)) is None
    narrow = SafetyLimits(3e-3, -1.0, 0.01)
    assert "outside 2014h" in (safety_stop(rec, narrow) or "")


def test_judge_refuses_an_incomplete_record_without_a_stop() -> None:
    rec = synthetic(PROFILE, 0.0)
    short = Record(rec.position_reference[:100], rec.load_position[:100], rec.beta, rec.beta)
    with pytest.raises(TuningError, match="incomplete"):
        judge(short, PROFILE, SearchConfig and _limits(), CYCLE_S, KV, 0.1)


def _limits():
    from regulator.tuning import Limits

    return Limits(vibration=5e-6, standstill_error=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"low_feed": 0.06}, "must be below feed"),
        ({"dwell_s": 0.05}, "must exceed"),
        ({"accel": 0.0}, "accel"),
    ],
)
def test_bad_motions_are_refused(kwargs: dict[str, float], needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        TuningMotion(**kwargs)


def test_a_watch_window_too_short_to_judge_is_refused() -> None:
    with pytest.raises(TuningError, match="5 periods of k_v / 4"):
        TuningMotion(low_s=0.8).profile(CYCLE_S, KV)


def test_the_default_schedule_follows_the_limit_cycles_beta() -> None:
    """Without a start, the trials run from the limit cycle's beta / 64 to x 16, doubling: a
    fixed start would waste trials on a strong limit cycle and miss a weak one."""
    for beta_ref in (0.64, 6.4, 64.0):
        betas = SearchConfig().schedule(beta_ref)
        assert betas[0] == pytest.approx(beta_ref / 64, rel=0.5)
        assert betas[-1] <= beta_ref * 16 * (1 + 1e-9) < betas[-1] * 2
        assert np.allclose(np.diff(np.log2(betas)), 1.0)

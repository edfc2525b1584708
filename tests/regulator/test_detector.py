"""Vibration detector (Fig. 5, section VII) against an independent vectorised implementation
and against the behaviour the paper asks for (detect in-band vibration, no false alarms)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view
from scipy.signal import lfilter

from regulator import (
    DetectorConfig,
    RegulatorConfigError,
    RegulatorError,
    RegulatorInputError,
    VibrationDetector,
    core,
)

KV = 25.0  # 1/s, the paper's axis
TV = 20.0 / KV  # eq. 14 with f = kv / 4
TF = 0.05
BETA_T = 0.2
CYCLES = [0.001, 0.0025]


def reference_detector(
    u: np.ndarray, n: int, cycle_s: float, tv_s: float, tf_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Second implementation, vectorised over the whole record: (beta, holder output)."""
    u = np.asarray(u, dtype=np.float64)
    size, m = u.size, n + 1
    crossing = np.zeros(size, dtype=bool)
    if size >= m:
        windows = sliding_window_view(u, m)  # windows[j] ends at sample j + n
        sum_abs = np.abs(windows).sum(axis=1)
        crossing[n:] = sum_abs - np.abs(windows.sum(axis=1)) > 1e-12 * sum_abs
    events = np.flatnonzero(crossing & ~np.concatenate(([False], crossing[:-1])))
    y = np.zeros(size)
    if events.size:
        # peak |u| of each half-wave finished at an event: samples [previous event, event)
        finished = np.maximum.reduceat(np.abs(u), np.concatenate(([0], events)))[: events.size]
        held = np.minimum(finished, np.concatenate(([0.0], finished[:-1])))
        k = np.arange(size)
        segment = np.searchsorted(events, k, side="right") - 1
        valid = segment >= 0
        since = k[valid] - events[segment[valid]]
        y[valid] = held[segment[valid]] * np.exp(-since * cycle_s / tv_s)
    a = 1.0 - math.exp(-cycle_s / tf_s)
    beta = lfilter([a], [1.0, -(1.0 - a)], y)
    return beta, y


def run(detector: VibrationDetector, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    beta = np.empty(u.size)
    holder = np.empty(u.size)
    for i, x in enumerate(u):
        beta[i] = detector.step(float(x))
        holder[i] = detector.holder_output
    return beta, holder


def make(cycle_s: float, n: int = 4) -> VibrationDetector:
    return VibrationDetector(DetectorConfig(n=n, cycle_s=cycle_s, tv_s=TV, tf_s=TF))


@pytest.mark.parametrize("cycle_s", CYCLES)
@pytest.mark.parametrize("n", [2, 4])
def test_matches_independent_vectorised_implementation(cycle_s: float, n: int) -> None:
    rng = np.random.default_rng(11 + n)
    t = np.arange(int(4.0 / cycle_s)) * cycle_s
    gate = (t > 0.5) & (t < 1.7) | (t > 2.6) & (t < 3.1)
    u = (
        gate * (0.8 + 0.5 * t) * np.sin(2 * np.pi * 9.0 * t)
        + 0.2 * (t > 1.9)
        + rng.normal(0.0, 0.02, t.size)
    )
    beta, holder = run(make(cycle_s, n), u)
    beta_ref, holder_ref = reference_detector(u, n, cycle_s, TV, TF)
    assert np.max(beta_ref) > 1.0  # the record does contain detections
    np.testing.assert_allclose(holder, holder_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(beta, beta_ref, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("n", [2, 4])
def test_bit_identical_to_the_compiled_core_the_simulator_runs(n: int) -> None:
    """The class steps ``core.detector_step`` uncompiled on its own state; the simulator's
    kernel runs the same function compiled by numba (LLVM) on a float64 array. Both are IEEE
    binary64 arithmetic in the same order: beta and the holder output must be equal to the
    bit, whatever the class keeps its state in."""
    compiled = numba.njit(core.detector_step)
    cycle_s = 0.001
    rng = np.random.default_rng(5 + n)
    t = np.arange(3000) * cycle_s
    u = (t > 0.4) * np.sin(2 * np.pi * 9.0 * t) + rng.normal(0.0, 0.02, t.size)
    u[1500:1600] = 0.0  # exact zeros: no crossing, the holder decays
    state = np.zeros(core.detector_state_size(n))
    expected = np.array([compiled(state, n, cycle_s, TV, TF, x) for x in u])
    detector = make(cycle_s, n)
    beta, holder = run(detector, u)
    assert expected.max() > 0.5
    np.testing.assert_array_equal(beta, expected)
    assert holder[-1] == core.detector_holder_output(state)


@pytest.mark.parametrize("cycle_s", CYCLES)
@pytest.mark.parametrize("profile", ["step", "ramp"])
def test_no_false_alarm_on_a_vibration_free_move(cycle_s: float, profile: str) -> None:
    """Standstill with noise, then a speed change that omega_c follows without overshoot.

    u = omega_s - omega_c rises to the step height (50 rad/s) and decays monotonically; once
    it reaches the noise level the noise makes crossings. The monotone transient must not be
    held as a vibration half-wave.
    """
    rng = np.random.default_rng(5)
    t = np.arange(int(5.0 / cycle_s)) * cycle_s
    if profile == "step":
        omega_s = np.where(t >= 1.0, 50.0, 0.0)
    else:
        omega_s = np.clip((t - 1.0) / 0.4, 0.0, 1.0) * 50.0
    # position loop with ideal speed control: omega_c is omega_s through a first-order lag
    # 1/kv (eq. 8), discretised exactly -- monotone, no overshoot
    c = math.exp(-KV * cycle_s)
    omega_c = lfilter([1.0 - c], [1.0, -c], omega_s)
    u = omega_s - omega_c + rng.normal(0.0, 0.002, t.size)
    assert np.count_nonzero(np.diff(np.sign(u[t > 3.0]))) > 100  # noise does cross
    beta, _ = run(make(cycle_s), u)
    lam = np.exp(-beta / BETA_T)
    assert lam.min() > 0.9


@pytest.mark.parametrize("cycle_s", CYCLES)
@pytest.mark.parametrize("f_rel", [0.25 * 1.05, 0.5, 0.95])
def test_detects_in_band_vibration_within_three_periods(cycle_s: float, f_rel: float) -> None:
    f_hz = f_rel * KV  # inside eq. 13's band kv/4 .. kv
    amplitude = 5.0 * BETA_T
    t = np.arange(int(2.0 / cycle_s)) * cycle_s
    u = amplitude * np.sin(2 * np.pi * f_hz * t + 0.3)
    beta, _ = run(make(cycle_s), u)
    lam = np.exp(-beta / BETA_T)
    first = int(np.argmax(lam < 0.1))
    assert lam[first] < 0.1
    assert t[first] <= 3.0 / f_hz
    assert np.all(lam[first:] < 0.1)  # and it stays detected while the vibration lasts


@pytest.mark.parametrize("cycle_s", CYCLES)
def test_calm_again_beta_decays_with_tv(cycle_s: float) -> None:
    t = np.arange(int(6.0 / cycle_s)) * cycle_s
    u = np.where(t < 1.0, 1.0 * np.sin(2 * np.pi * 10.0 * t), 0.05)  # then calm, offset only
    beta, holder = run(make(cycle_s), u)
    lam = np.exp(-beta / BETA_T)
    assert lam[t < 1.0].min() < 0.01
    # holder: y = h exp(-(t - t_p) / T_v) from the last crossing on
    last = int(np.flatnonzero(np.diff(holder) > 0)[-1]) + 1
    assert t[last] < 1.01
    k = np.arange(last, t.size)
    np.testing.assert_allclose(
        holder[k], holder[last] * np.exp(-(k - last) * cycle_s / TV), rtol=1e-12
    )
    # beta: once the low pass (T_f) has settled, it decays like exp(-t / T_v)
    i0, i1 = np.searchsorted(t, [2.0, 2.5])
    assert beta[i1] / beta[i0] == pytest.approx(math.exp(-(t[i1] - t[i0]) / TV), rel=1e-3)
    assert lam[-1] > 0.95  # lambda -> 1
    assert np.all(np.diff(lam[t > 1.5]) > 0)


def test_holder_takes_the_smaller_half_wave_of_an_asymmetric_oscillation() -> None:
    cycle_s, a, offset = 0.001, 1.0, 0.3
    t = np.arange(2000) * cycle_s
    u = offset + a * np.sin(2 * np.pi * 10.0 * t)  # half-waves of height 1.3 and 0.7
    _, holder = run(make(cycle_s), u)
    assert holder[t > 0.5].max() == pytest.approx(a - offset, rel=1e-3)


def test_no_detection_before_the_window_is_full() -> None:
    detector = make(0.001, n=4)
    for x in [1.0, -1.0, 1.0, -1.0]:  # n samples with crossings: window not full yet
        assert detector.step(x) == 0.0
        assert detector.holder_output == 0.0


def test_one_event_per_crossing() -> None:
    """A square wave of half-period 20 samples: one event per sign change, no more."""
    cycle_s = 0.001
    u = np.tile(np.r_[np.full(20, 1.0), np.full(20, -0.5)], 10)
    _, holder = run(make(cycle_s), u)
    events = np.flatnonzero(np.diff(holder) > 0) + 1
    crossings = np.flatnonzero(np.diff(np.sign(u)) != 0) + 1
    # the first crossing has no finished neighbour half-wave yet (held 0): no visible jump
    np.testing.assert_array_equal(events, crossings[1:])
    assert holder[events[-1]] == 0.5


def test_vibration_faster_than_the_sampling_rule_is_not_seen() -> None:
    """Section VII: the cycle must be below period / (2 (n + 1)); at a half-period of fewer
    than n + 1 samples every window holds a crossing, so there is no rising edge."""
    cycle_s = 0.0025
    f_hz = 1.0 / (2 * 4 * cycle_s)  # half-period = 4 samples < n + 1 = 5
    t = np.arange(2000) * cycle_s
    beta, _ = run(make(cycle_s), np.sin(2 * np.pi * f_hz * t + 0.1))
    assert np.all(beta == 0.0)


def test_reset_returns_to_the_initial_state() -> None:
    t = np.arange(1000) * 0.001
    u = np.sin(2 * np.pi * 10.0 * t)
    detector = make(0.001)
    run(detector, u)
    assert detector.vibration_level > 0.1
    detector.reset()
    assert detector.vibration_level == 0.0
    np.testing.assert_array_equal(run(detector, u)[0], run(make(0.001), u)[0])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "1.0", None])
def test_non_finite_input_is_refused_and_changes_nothing(bad: object) -> None:
    detector = make(0.001)
    u = np.sin(2 * np.pi * 10.0 * np.arange(300) * 0.001)
    run(detector, u[:150])
    before = detector.vibration_level
    with pytest.raises(RegulatorInputError, match="u_rad_s") as info:
        detector.step(bad)  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError) and isinstance(info.value, RegulatorError)
    assert detector.vibration_level == before
    reference = make(0.001)
    run(reference, u[:150])
    np.testing.assert_array_equal(run(detector, u[150:])[0], run(reference, u[150:])[0])


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"n": 0}, r"n = 0: must be an integer >= 1"),
        ({"n": 2.0}, r"n = 2.0: must be an integer >= 1"),
        ({"n": True}, r"n = True: must be an integer >= 1"),
        ({"cycle_s": 0.0}, r"cycle_s = 0.0: must be a finite number > 0 s"),
        ({"cycle_s": math.nan}, r"cycle_s = nan: must be a finite number > 0 s"),
        ({"tv_s": -1.0}, r"tv_s = -1.0: must be a finite number > 0 s"),
        ({"tf_s": math.inf}, r"tf_s = inf: must be a finite number > 0 s"),
    ],
)
def test_config_validation_messages(kwargs: dict[str, object], pattern: str) -> None:
    args: dict[str, object] = {"n": 4, "cycle_s": 0.001, "tv_s": TV, "tf_s": TF, **kwargs}
    with pytest.raises(RegulatorConfigError, match=pattern) as info:
        DetectorConfig(**args)  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError)
    assert info.value.field == next(iter(kwargs))

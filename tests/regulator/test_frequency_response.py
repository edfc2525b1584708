"""The frequency-response arithmetic (regulator.frequency_response) and the two-mass model
(regulator.twomass) against references the project did not write: scipy's ``lfilter`` and
``freqz`` (a known discrete system), and the paper's own formulas written out literally."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from regulator.errors import RegulatorError
from regulator.frequency_response import Multisine, antiresonance, bandwidth, estimate
from regulator.twomass import TwoMass

CYCLE_S = 0.001


def _notch_filter(f0_hz: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """A discrete system with zeros r e^(+-j w0 T) (a notch at f0) and two damped poles."""
    w = 2 * math.pi * f0_hz * CYCLE_S
    b = np.array([1.0, -2 * r * math.cos(w), r * r])
    a = np.array([1.0, -1.2, 0.5])
    return b, a


def test_multisine_is_periodic_zero_mean_with_its_peak_and_lines() -> None:
    ms = Multisine(CYCLE_S, 512, 2.0, 200.0, 1.5, corner_hz=20.0)
    x = ms.period()
    assert np.max(np.abs(x)) == pytest.approx(1.5)
    assert abs(float(np.mean(x))) < 1e-12
    spectrum = np.abs(np.fft.rfft(x))
    excited = set(ms.lines.tolist())
    assert excited == set(range(2, 103))  # 2..200 Hz on the 1.953 Hz grid
    quiet = [k for k in range(spectrum.size) if k not in excited]
    assert np.max(spectrum[quiet]) < 1e-9 * np.max(spectrum)
    # above the corner each line falls as 1/f (constant torque per line)
    lines = ms.lines
    ratio = spectrum[lines[-1]] / spectrum[lines[20]]
    assert ratio == pytest.approx(ms.frequencies_hz[20] / ms.frequencies_hz[-1], rel=1e-9)
    assert np.array_equal(ms.signal(3), np.tile(x, 3))
    assert not np.allclose(ms.realization(1).period(), ms.realization(2).period())


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"f_max_hz": 600.0}, "Nyquist"),
        ({"f_min_hz": 0.1}, "resolution"),
        ({"period_samples": 8}, ">= 16"),
        ({"amplitude": -1.0}, "amplitude"),
    ],
)
def test_multisine_refuses_what_it_cannot_be(kwargs: dict[str, float], needle: str) -> None:
    base = {"cycle_s": CYCLE_S, "period_samples": 512, "f_min_hz": 2.0, "f_max_hz": 200.0}
    base |= {"amplitude": 1.0} | kwargs
    with pytest.raises(RegulatorError, match=needle):
        Multisine(**base)  # type: ignore[arg-type]


@pytest.mark.parametrize("realizations", [1, 6])
def test_estimate_equals_freqz_within_its_stated_deviation(realizations: int) -> None:
    """A known discrete filter with output noise: the estimate at every line is within 4
    standard deviations of scipy's freqz, and the deviations are honest (normalised errors
    of about unit spread)."""
    b, a = _notch_filter(60.0, 0.97)
    ms = Multisine(CYCLE_S, 512, 2.0, 400.0, 1.0)
    rng = np.random.default_rng(3)
    periods = 5
    blocks_u, blocks_y = [], []
    for m in range(realizations):
        exc = ms if realizations == 1 else ms.realization(m)
        u = exc.signal(periods)
        y = signal.lfilter(b, a, u) + 0.002 * rng.standard_normal(u.size)
        blocks_u.append(u)
        blocks_y.append(y)
    frf = estimate(ms, np.concatenate(blocks_u), np.concatenate(blocks_y), 1, realizations)
    _, truth = signal.freqz(b, a, worN=frf.frequency_hz, fs=1.0 / CYCLE_S)
    z = np.abs(frf.response - truth) / frf.std
    assert np.max(z) < 4.5
    assert 0.4 < float(np.sqrt(np.mean(z**2))) < 2.0


def test_the_notch_of_a_known_zero_pair_is_found_within_its_uncertainty() -> None:
    b, a = _notch_filter(93.3, 0.985)
    ms = Multisine(CYCLE_S, 1024, 1.0, 400.0, 1.0)
    rng = np.random.default_rng(5)
    u = np.concatenate([ms.realization(m).signal(3) for m in range(8)])
    y = signal.lfilter(b, a, u) + 0.001 * rng.standard_normal(u.size)
    frf = estimate(ms, u, y, 1, 8)
    notch = antiresonance(frf, 10.0, 400.0)
    truth = 2 * math.pi * 93.3
    assert notch.resolved and notch.contains(truth), (notch.rad_s, notch.uncertainty_rad_s)
    # the interval is not vacuous: well under a line of resolution (0.98 Hz) each side
    assert notch.uncertainty_rad_s < 2 * math.pi * 1.0


def test_a_response_without_a_notch_is_not_resolved() -> None:
    b, a = signal.butter(2, 80.0, fs=1.0 / CYCLE_S)
    ms = Multisine(CYCLE_S, 1024, 1.0, 400.0, 1.0)
    u = np.concatenate([ms.realization(m).signal(3) for m in range(4)])
    frf = estimate(ms, u, signal.lfilter(b, a, u), 1, 4)
    assert not antiresonance(frf, 5.0, 300.0).resolved


def test_bandwidth_of_a_first_order_loop_is_its_corner() -> None:
    """H = 1 / (1 + s / (2 pi 40 Hz)), discretised bilinearly (scipy): -3 dB where the
    bilinear transform maps 40 Hz."""
    pole = 2 * math.pi * 40.0
    bz, az = signal.zpk2tf(*signal.bilinear_zpk([], [-pole], pole, 1.0 / CYCLE_S))
    ms = Multisine(CYCLE_S, 2048, 1.0, 300.0, 1.0)
    u = ms.signal(4)
    frf = estimate(ms, u, signal.lfilter(bz, az, u))
    # bilinear transform maps 40 Hz to tan-warped 39.6 Hz without prewarping
    expected = 1000.0 / math.pi * math.atan(math.pi * 40.0 / 1000.0)
    assert bandwidth(frf).frequency_hz == pytest.approx(expected, rel=0.01)


# --- the two-mass model against the paper's formulas, written out -----------------------------
AXIS = TwoMass(0.1409, 0.0664, 600.0, 0.04)  # the paper's axis: J1, M / k_r^2, omega_a, xi


def test_eq4_resonance_ratio() -> None:
    assert AXIS.resonance_rad_s / AXIS.antiresonance_rad_s == pytest.approx(
        math.sqrt(1 + AXIS.load_inertia_kgm2 / AXIS.motor_inertia_kgm2)
    )


def test_eq2_eq3_and_eq6a_as_printed() -> None:
    """W_m, W_l against the mechanics written from k_s and c_s (J_l omega_a^2 = k_s,
    xi = c_s omega / (2 k_s)); G_sm against eq. 6a as printed with the PI written
    k_sp (T_si s + 1) / (T_si s) -- the printed ``k_sp T_si s + 1`` leaves k_sp off the
    integral term (it is not dimensionally a torque); the simulator and the independent plant
    integrate with k_sp / T_si, docs/regulator.md."""
    f = np.geomspace(1.0, 500.0, 200)
    s = 2j * np.pi * f
    jm, jl, wa, xa = (
        AXIS.motor_inertia_kgm2,
        AXIS.load_inertia_kgm2,
        AXIS.antiresonance_rad_s,
        AXIS.damping_ratio,
    )
    ks = jl * wa**2
    cs = 2 * xa * ks / wa
    # the mechanics directly: J_m s w_m = t - (k_s/s + c_s)(w_m - w_l), J_l s w_l = (...)
    spring = ks / s + cs
    wm_direct = (jl * s + spring) / (jm * s * (jl * s + spring) + jl * s * spring)
    wl_direct = spring / (jm * s * (jl * s + spring) + jl * s * spring)
    assert np.allclose(AXIS.motor_admittance(f), wm_direct, rtol=1e-9)
    assert np.allclose(AXIS.load_admittance(f), wl_direct, rtol=1e-9)
    ksp, tsi = 52.0, 0.0075
    wr = AXIS.resonance_rad_s
    xr = cs * wr / (2 * ks)
    p = 1 + 2 * xa * s / wa + (s / wa) ** 2
    q = 1 + 2 * xr * s / wr + (s / wr) ** 2
    pi = ksp * (tsi * s + 1)
    g6a = pi * p / (tsi * (jm + jl) * s**2 * q + pi * p)
    assert np.allclose(AXIS.speed_loop(f, ksp, tsi), g6a, rtol=1e-9)


def test_the_motor_admittance_vanishes_at_the_antiresonance_without_damping() -> None:
    undamped = TwoMass(0.1409, 0.0664, 600.0, 0.0)
    assert abs(undamped.motor_admittance(np.array([600.0 / (2 * math.pi)]))[0]) < 1e-12

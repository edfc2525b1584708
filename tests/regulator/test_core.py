"""regulator.core: numba nopython compatibility (bit-identical) and the closed-form pieces."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from regulator import core

KV = 25.0
TV = 20.0 / KV
TF = 0.05


def _random_signal(seed: int, size: int, cycle_s: float) -> np.ndarray:
    """In-band vibration bursts, offsets and noise: many crossings and calm stretches."""
    rng = np.random.default_rng(seed)
    t = np.arange(size) * cycle_s
    burst = (np.sin(2 * np.pi * 0.7 * t) > 0.2).astype(float)
    return (
        1.5 * burst * np.sin(2 * np.pi * 11.0 * t)
        + 0.3 * np.sign(np.sin(2 * np.pi * 0.37 * t))
        + rng.normal(0.0, 0.05, size)
    )


def _run_python(u: np.ndarray, n: int, cycle_s: float) -> tuple[np.ndarray, np.ndarray]:
    state = np.zeros(core.detector_state_size(n))
    core.detector_reset(state)
    beta = np.array([core.detector_step(state, n, cycle_s, TV, TF, float(x)) for x in u])
    return beta, state


@pytest.mark.parametrize("cycle_s", [0.001, 0.0025])
@pytest.mark.parametrize("n", [1, 4])
def test_detector_step_compiles_in_nopython_mode_and_is_bit_identical(
    cycle_s: float, n: int
) -> None:
    u = _random_signal(7 + n, 3000, cycle_s)
    size_jit = numba.njit(core.detector_state_size)
    reset_jit = numba.njit(core.detector_reset)
    step_jit = numba.njit(core.detector_step)
    beta_jit = numba.njit(core.detector_beta)
    holder_jit = numba.njit(core.detector_holder_output)

    @numba.njit
    def kernel(state: np.ndarray, signal: np.ndarray, out: np.ndarray) -> None:
        # called from compiled code, as the simulator's kernel does
        reset_jit(state)
        for i in range(signal.shape[0]):
            out[i] = step_jit(state, n, cycle_s, TV, TF, signal[i])

    assert size_jit(n) == core.detector_state_size(n) == 10 + n
    state_jit = np.full(size_jit(n), 123.0)  # garbage: reset must clear it
    beta_compiled = np.empty(u.size)
    kernel(state_jit, u, beta_compiled)

    beta_python, state_python = _run_python(u, n, cycle_s)
    assert np.max(beta_python) > 0.5  # the signal does trigger the detector
    assert np.array_equal(beta_compiled, beta_python)  # bit-identical
    assert np.array_equal(state_jit, state_python)
    assert beta_jit(state_jit) == core.detector_beta(state_python) == beta_python[-1]
    assert holder_jit(state_jit) == core.detector_holder_output(state_python)


def test_scalar_functions_compile_and_are_bit_identical() -> None:
    rng = np.random.default_rng(3)
    lam_jit = numba.njit(core.switching_factor)
    reg_jit = numba.njit(core.regulated_speed)
    pos_jit = numba.njit(core.position_command)
    for beta, beta_t, ws, wc, x_ref, x_fb in rng.uniform(0.01, 3.0, size=(200, 6)):
        lam = core.switching_factor(beta, beta_t)
        assert lam_jit(beta, beta_t) == lam
        assert reg_jit(ws, wc, lam) == core.regulated_speed(ws, wc, lam)
        assert pos_jit(x_ref, x_fb, KV, 100 * math.pi) == core.position_command(
            x_ref, x_fb, KV, 100 * math.pi
        )


def test_detector_reset_zeroes_everything() -> None:
    state = np.arange(core.detector_state_size(4), dtype=np.float64) + 1.0
    core.detector_reset(state)
    assert np.all(state == 0.0)


def test_switching_factor_eq15() -> None:
    assert core.switching_factor(0.0, 0.2) == 1.0
    assert core.switching_factor(0.2, 0.2) == pytest.approx(math.e**-1, rel=1e-15)
    assert core.switching_factor(0.2 * math.log(10.0), 0.2) == pytest.approx(0.1, rel=1e-14)
    assert core.switching_factor(1e3, 0.2) == 0.0  # underflows to exactly 0


@pytest.mark.parametrize("lam", [0.0, 0.25, 0.5, 1.0])
def test_regulated_speed_eq15(lam: float) -> None:
    ws, wc = 10.3, -2.7
    # eq. 15 as printed
    assert core.regulated_speed(ws, wc, lam) == pytest.approx(ws - lam * (ws - wc), rel=1e-15)
    if lam == 1.0:
        assert core.regulated_speed(ws, wc, lam) == wc  # exactly the position control
    if lam == 0.0:
        assert core.regulated_speed(ws, wc, lam) == ws  # exactly the interpolator speed


def test_position_command_eq7_units() -> None:
    # 1 mm following error, kv = 25 1/s, 20 mm pitch (k_r = 100 pi rad/m):
    # load speed 25 mm/s = 1.25 rev/s of the screw = 2.5 pi rad/s at the motor
    omega_c = core.position_command(0.101, 0.100, 25.0, 100.0 * math.pi)
    assert omega_c == pytest.approx(2.5 * math.pi, rel=1e-12)
    assert core.position_command(0.1, 0.1, 25.0, 100.0 * math.pi) == 0.0
    assert core.position_command(0.0, 0.001, 25.0, 1.0) == pytest.approx(-0.025, rel=1e-12)


def test_defaults_are_the_paper_values() -> None:
    assert core.DEFAULT_N == 4  # section VII: "in this paper n is 4"
    # eq. 14 at the lower band end of eq. 13: T_v = 5 / (kv / 4)
    assert math.isclose(core.DEFAULT_TV_TIMES_KV / KV, 5.0 / (KV / 4.0), rel_tol=1e-15)

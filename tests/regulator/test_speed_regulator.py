"""BacklashRegulator (Fig. 6, eq. 15), its configuration, and the P position controller (eq. 7)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import regulator
from regulator import (
    BacklashRegulator,
    PositionController,
    RegulatorConfig,
    RegulatorConfigError,
    RegulatorError,
    RegulatorInputError,
    following_error,
    min_decay_time_s,
)

KV = 25.0
CYCLES = [0.001, 0.0025]


def drive(
    reg: BacklashRegulator, omega_s: np.ndarray, omega_c: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    out = np.empty((3, omega_s.size))
    for i, (ws, wc) in enumerate(zip(omega_s, omega_c, strict=True)):
        out[0, i] = reg.step(float(ws), float(wc))
        out[1, i] = reg.vibration_level
        out[2, i] = reg.switching_factor
    return out[0], out[1], out[2]


def vibration_then_calm(cycle_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant interpolator speed; omega_c oscillates (12 Hz, 1 rad/s) for 1.5 s, then sits
    calmly 0.05 rad/s below omega_s."""
    t = np.arange(int(6.0 / cycle_s)) * cycle_s
    omega_s = np.full(t.size, 30.0)
    omega_c = np.where(t < 1.5, 30.0 + 1.0 * np.sin(2 * np.pi * 12.0 * t), 29.95)
    return t, omega_s, omega_c


@pytest.mark.parametrize("cycle_s", CYCLES)
def test_lambda_goes_to_zero_under_vibration_and_back_to_one_when_calm(cycle_s: float) -> None:
    t, omega_s, omega_c = vibration_then_calm(cycle_s)
    reg = BacklashRegulator(kv=KV, cycle_s=cycle_s)
    omega_r, beta, lam = drive(reg, omega_s, omega_c)
    # eq. 15, recomputed from the reported beta
    np.testing.assert_allclose(lam, np.exp(-beta / regulator.DEFAULT_BETA_T_RAD_S), rtol=1e-15)
    np.testing.assert_allclose(omega_r, omega_s - lam * (omega_s - omega_c), rtol=1e-14)
    vibrating = (t > 0.5) & (t < 1.5)
    assert lam[vibrating].max() < 0.01
    # lambda -> 0: the oscillating omega_c is cut off, omega_r ~ omega_s
    assert np.max(np.abs(omega_r[vibrating] - omega_s[vibrating])) < 0.01
    assert np.max(np.abs(omega_c[vibrating] - omega_s[vibrating])) > 0.99
    # calm again: lambda -> 1 (holder decays with T_v = 20 / kv = 0.8 s), omega_r -> omega_c
    assert lam[-1] > 0.95
    assert abs(omega_r[-1] - omega_c[-1]) < 0.05 * 0.05
    assert np.all(np.diff(lam[t > 2.0]) > 0)


@pytest.mark.parametrize("cycle_s", CYCLES)
def test_calm_axis_gets_exactly_the_position_control(cycle_s: float) -> None:
    # omega_c approaches omega_s from below without crossing: beta = 0, lambda = 1 exactly
    t = np.arange(int(1.0 / cycle_s)) * cycle_s
    omega_s = np.full(t.size, 12.0)
    omega_c = 12.0 - 3.0 * np.exp(-KV * t)
    reg = BacklashRegulator(kv=KV, cycle_s=cycle_s)
    omega_r, beta, lam = drive(reg, omega_s, omega_c)
    assert np.all(beta == 0.0) and np.all(lam == 1.0)
    np.testing.assert_array_equal(omega_r, omega_c)


@pytest.mark.parametrize("cycle_s", CYCLES)
def test_disabled_passes_omega_c_but_still_measures(cycle_s: float) -> None:
    _, omega_s, omega_c = vibration_then_calm(cycle_s)
    enabled = BacklashRegulator(kv=KV, cycle_s=cycle_s)
    disabled = BacklashRegulator(kv=KV, cycle_s=cycle_s, enabled=False)
    _, beta_on, _ = drive(enabled, omega_s, omega_c)
    omega_r, beta_off, lam = drive(disabled, omega_s, omega_c)
    np.testing.assert_array_equal(omega_r, omega_c)
    assert np.all(lam == 1.0)
    np.testing.assert_array_equal(beta_off, beta_on)
    assert beta_off.max() > 0.5


def test_reset_and_from_config() -> None:
    _, omega_s, omega_c = vibration_then_calm(0.001)
    cfg = RegulatorConfig(kv=KV, cycle_s=0.001, beta_t_rad_s=0.3, tf_s=0.02, tv_s=1.0)
    reg = BacklashRegulator.from_config(cfg)
    assert reg.config is cfg
    first = drive(reg, omega_s[:1400], omega_c[:1400])
    assert reg.switching_factor < 0.1
    reg.reset()
    assert (reg.vibration_level, reg.switching_factor) == (0.0, 1.0)
    np.testing.assert_array_equal(drive(reg, omega_s[:1400], omega_c[:1400])[0], first[0])
    same = BacklashRegulator(kv=KV, cycle_s=0.001, beta_t_rad_s=0.3, tf_s=0.02, tv_s=1.0)
    assert same.config == cfg
    np.testing.assert_array_equal(drive(same, omega_s[:1400], omega_c[:1400])[0], first[0])


def test_defaults() -> None:
    reg = BacklashRegulator(kv=KV, cycle_s=0.001)
    cfg = reg.config
    assert (cfg.n, cfg.beta_t_rad_s, cfg.tv_s, cfg.tf_s, cfg.enabled) == (
        regulator.DEFAULT_N,
        regulator.DEFAULT_BETA_T_RAD_S,
        None,
        regulator.DEFAULT_TF_S,
        True,
    )
    assert (cfg.n, cfg.beta_t_rad_s, cfg.tf_s) == (4, 0.2, 0.05)
    # eq. 14 with eq. 13's lower band end
    assert cfg.effective_tv_s == pytest.approx(min_decay_time_s(KV), rel=1e-15)
    assert cfg.effective_tv_s == pytest.approx(0.8, rel=1e-15)
    assert cfg.detector_config().tv_s == cfg.effective_tv_s
    # kv changed with dataclasses.replace: T_v follows
    assert dataclasses.replace(cfg, kv=50.0).effective_tv_s == pytest.approx(0.4, rel=1e-15)
    assert (reg.vibration_level, reg.switching_factor) == (0.0, 1.0)


@pytest.mark.parametrize(
    ("kwargs", "field", "pattern"),
    [
        ({"kv": 0.0}, "kv", r"kv = 0.0: must be a finite number > 0 1/s"),
        ({"kv": math.nan}, "kv", r"kv = nan: must be a finite number > 0 1/s"),
        ({"cycle_s": -0.001}, "cycle_s", r"cycle_s = -0.001: must be a finite number > 0 s"),
        ({"n": 0}, "n", r"n = 0: must be an integer >= 1"),
        ({"beta_t_rad_s": 0.0}, "beta_t_rad_s", r"beta_t_rad_s = 0.0: .* > 0 rad/s"),
        ({"tf_s": -1.0}, "tf_s", r"tf_s = -1.0: must be a finite number > 0 s"),
        ({"tv_s": 0.0}, "tv_s", r"tv_s = 0.0: must be a finite number > 0 s"),
        ({"tv_s": 0.5}, "tv_s", r"tv_s = 0.5: must be >= 0.8 s, eq. 14"),
        ({"enabled": 1}, "enabled", r"enabled = 1: must be True or False"),
        # sampling rule: cycle < (1 / kv) / (2 (n + 1)) = 0.004 s for kv = 25, n = 4
        ({"cycle_s": 0.004}, "cycle_s", r"cycle_s = 0.004: must be < 0.004 s.*section VII"),
        ({"cycle_s": 0.005}, "cycle_s", r"cycle_s = 0.005: must be < 0.004 s.*section VII"),
        ({"cycle_s": 0.0025, "n": 8}, "cycle_s", r"must be < 0.00222222 s.*n = 8"),
    ],
)
def test_config_validation_messages(kwargs: dict[str, object], field: str, pattern: str) -> None:
    args: dict[str, object] = {"kv": KV, "cycle_s": 0.001, **kwargs}
    with pytest.raises(RegulatorConfigError, match=pattern) as info:
        BacklashRegulator(**args)  # type: ignore[arg-type]
    assert info.value.field == field
    assert isinstance(info.value, ValueError) and isinstance(info.value, RegulatorError)
    with pytest.raises(RegulatorConfigError, match=pattern):
        RegulatorConfig(**args)  # type: ignore[arg-type]


def test_sampling_rule_accepts_just_below_the_limit() -> None:
    assert BacklashRegulator(kv=KV, cycle_s=0.0039).config.cycle_s == 0.0039
    assert regulator.max_cycle_s(KV, 4) == pytest.approx(0.004, rel=1e-15)


@pytest.mark.parametrize(
    ("omega_s", "omega_c", "argument"),
    [(math.nan, 1.0, "omega_s"), (1.0, math.inf, "omega_c"), (1.0, "2", "omega_c")],
)
def test_non_finite_input_is_refused_and_changes_nothing(
    omega_s: object, omega_c: object, argument: str
) -> None:
    _, ws, wc = vibration_then_calm(0.001)
    reg = BacklashRegulator(kv=KV, cycle_s=0.001)
    twin = BacklashRegulator(kv=KV, cycle_s=0.001)
    drive(reg, ws[:700], wc[:700])
    drive(twin, ws[:700], wc[:700])
    before = (reg.vibration_level, reg.switching_factor)
    with pytest.raises(RegulatorInputError, match=rf"{argument} = .*finite") as info:
        reg.step(omega_s, omega_c)  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError)
    assert (reg.vibration_level, reg.switching_factor) == before
    np.testing.assert_array_equal(
        drive(reg, ws[700:900], wc[700:900])[0], drive(twin, ws[700:900], wc[700:900])[0]
    )


def test_from_config_refuses_other_objects() -> None:
    with pytest.raises(RegulatorConfigError, match="must be a RegulatorConfig"):
        BacklashRegulator.from_config({"kv": KV, "cycle_s": 0.001})  # type: ignore[arg-type]


# --- position controller (eq. 7) -------------------------------------------------------------


def test_position_controller_eq7() -> None:
    pc = PositionController(kv_per_s=25.0, transmission_ratio=100.0 * math.pi)
    omega_c = pc.step(0.201, 0.200)  # 1 mm following error
    assert omega_c == pytest.approx(100.0 * math.pi * 25.0 * 0.001, rel=1e-9)
    assert pc.last_error == pytest.approx(0.001, rel=1e-9)
    assert pc.last_output_rad_s == omega_c
    pc.reset()
    assert (pc.last_error, pc.last_output_rad_s) == (0.0, 0.0)
    assert PositionController.from_config(pc.config).step(0.201, 0.200) == omega_c


@pytest.mark.parametrize("cycle_s", CYCLES)
def test_position_loop_following_error_is_speed_over_kv(cycle_s: float) -> None:
    """Eqs. 1 and 8: with an ideal speed loop, a ramp reference is followed with a constant
    lag speed / kv. Simulated: load moves by omega_c / k_r per second."""
    ratio, speed = 100.0 * math.pi, 0.05  # rad/m, m/s
    pc = PositionController(kv_per_s=KV, transmission_ratio=ratio)
    x = 0.0
    steps = int(1.0 / cycle_s)
    for k in range(steps):
        omega_c = pc.step(speed * k * cycle_s, x)
        x += omega_c / ratio * cycle_s
    # discrete loop: e[k+1] = (1 - kv cycle) e[k] + speed cycle, fixed point speed / kv
    assert pc.last_error == pytest.approx(following_error(speed, KV), rel=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"kv_per_s": 0.0}, r"kv_per_s = 0.0: must be a finite number > 0 1/s"),
        ({"transmission_ratio": -1.0}, r"transmission_ratio = -1.0: .* > 0 motor rad per load"),
    ],
)
def test_position_controller_validation(kwargs: dict[str, float], pattern: str) -> None:
    args = {"kv_per_s": KV, "transmission_ratio": 1.0, **kwargs}
    with pytest.raises(RegulatorConfigError, match=pattern):
        PositionController(**args)


def test_position_controller_refuses_non_finite() -> None:
    pc = PositionController(kv_per_s=KV, transmission_ratio=1.0)
    pc.step(1.0, 0.5)
    with pytest.raises(RegulatorInputError, match="x_fb"):
        pc.step(1.0, math.nan)
    assert pc.last_error == 0.5

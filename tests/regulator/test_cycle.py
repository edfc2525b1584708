"""regulator.cycle: the one composition of a position cycle, against the paper's equations
written out here (eq. 7 with the velocity feed-forward, eq. 15), the limits' decisions, and
numba's compiled function against Python's, bit for bit."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from regulator import compiled, core, cycle

KR, KV, CYCLE_S = 100 * math.pi, 25.0, 0.001


def fresh(**kw: float | bool) -> tuple[list[float], list[float]]:
    return cycle.block(KR, KV, CYCLE_S, tv_s=0.8, **kw), [0.0] * core.detector_state_size(4)  # type: ignore[arg-type]


def test_eq_7_with_the_velocity_feed_forward_and_the_regulator_off() -> None:
    c, det = fresh(velocity_feedforward=0.5)
    code = cycle.position_cycle(c, det, 0.010, 0.05, 0.008, 0.0, True)
    assert code == cycle.OK
    omega_s = KR * 0.05
    assert c[cycle.Y_OMEGA_S] == omega_s
    assert c[cycle.Y_OMEGA_C] == pytest.approx(KR * KV * 0.002 + 0.5 * omega_s, rel=1e-15)
    assert c[cycle.Y_OMEGA_R] == c[cycle.Y_OMEGA_C]  # off: exactly omega_c
    assert c[cycle.Y_LAMBDA] == 1.0
    assert c[cycle.Y_ERROR] == pytest.approx(0.002)


def test_eq_15_with_the_regulator_on() -> None:
    c, det = fresh(regulator_on=True, beta_t_rad_s=0.2)
    rng = np.random.default_rng(3)
    for k in range(400):  # a vibrating feedback: beta rises
        x_fb = 1e-4 * math.sin(2 * math.pi * 12 * k * CYCLE_S) + 1e-6 * rng.normal()
        assert cycle.position_cycle(c, det, 0.0, 0.0, x_fb, 0.0, True) == cycle.OK
    beta = c[cycle.Y_BETA]
    assert beta > 0.0 and beta == core.detector_beta(det)
    lam = math.exp(-beta / 0.2)
    assert c[cycle.Y_LAMBDA] == pytest.approx(lam, rel=1e-15)
    omega_s, omega_c = c[cycle.Y_OMEGA_S], c[cycle.Y_OMEGA_C]
    assert c[cycle.Y_OMEGA_R] == pytest.approx(omega_s - lam * (omega_s - omega_c), abs=1e-12)


def test_the_clamp_2007h() -> None:
    c, det = fresh(speed_limit_rad_s=3.0)
    assert cycle.position_cycle(c, det, 1.0, 0.0, 0.0, 0.0, True) == cycle.OK
    assert c[cycle.Y_OMEGA_R] == 3.0
    assert cycle.position_cycle(c, det, -1.0, 0.0, 0.0, 0.0, True) == cycle.OK
    assert c[cycle.Y_OMEGA_R] == -3.0


@pytest.mark.parametrize(
    ("x_ref", "speed", "x_fb", "difference", "code"),
    [
        (0.02, 0.0, 0.0, 0.0, cycle.FOLLOWING_ERROR),  # |e| 20 mm > 10 mm
        (0.0, 0.0, 0.0, 0.006, cycle.DISCREPANCY),  # 6 mm > 5 mm
        (0.5, 0.1, 0.5, 0.0, cycle.POSITION_LIMIT),  # beyond +0.4, heading on
        (0.5, -0.1, 0.5, 0.0, cycle.OK),  # beyond, heading back: allowed
        (math.nan, 0.0, 0.0, 0.0, cycle.NOT_FINITE),
        (0.0, math.inf, 0.0, 0.0, cycle.NOT_FINITE),
    ],
)
def test_the_supervision_decisions(
    x_ref: float, speed: float, x_fb: float, difference: float, code: int
) -> None:
    limits = dict(following_error_limit=0.01, discrepancy_limit=0.005, position_max=0.4)
    c, det = fresh(**limits)  # type: ignore[arg-type]
    before = list(det)
    assert cycle.position_cycle(c, det, x_ref, speed, x_fb, difference, True) == code
    if code != cycle.OK:
        assert det == before  # the detector is not fed on a stop
    # limits are checked on measured cycles only
    if code in (cycle.FOLLOWING_ERROR, cycle.DISCREPANCY, cycle.POSITION_LIMIT):
        c, det = fresh(**limits)  # type: ignore[arg-type]
        assert cycle.position_cycle(c, det, x_ref, speed, x_fb, difference, False) == cycle.OK


def _vibrating_inputs(k: int, rng: np.random.Generator) -> tuple[float, float, float]:
    x_ref = 1e-3 * math.sin(k / 50)
    x_fb = x_ref - 1e-4 * math.sin(2 * math.pi * 11 * k * CYCLE_S) + 1e-7 * rng.normal()
    return x_ref, 0.02 * math.cos(k / 50), x_fb


@pytest.mark.parametrize("regulator_on", [False, True])
def test_numba_compiles_it_to_the_same_bits(regulator_on: bool) -> None:
    """Compiled without fastmath as the bridge's core compiles it (regulator.compiled's
    cycle_copy: position_cycle calling measure and apply, inlined): every code, result and the
    detector state equal Python's over a vibrating run with the feed-forward, the clamp, the
    following-error stop and a non-finite feedback."""
    numba = pytest.importorskip("numba")
    jit = numba.njit(cache=False)
    inline = numba.njit(cache=False, inline="always")
    compiled_core = types.ModuleType("regulator.core (compiled)")
    for name in compiled.CORE_FUNCTIONS:
        setattr(compiled_core, name, jit(getattr(core, name)))
    f = compiled.cycle_copy(jit, inline, compiled_core, prefix="test_").position_cycle
    kw = dict(regulator_on=regulator_on, velocity_feedforward=0.3, speed_limit_rad_s=50.0)
    kw |= dict(following_error_limit=0.99e-4)  # the peaks of the shake stop it
    c_py, det_py = fresh(**kw)  # type: ignore[arg-type]
    c_nb, det_nb = np.array(c_py), np.array(det_py)
    rng = np.random.default_rng(7)
    codes = set()
    for k in range(3000):
        x_ref, speed, x_fb = _vibrating_inputs(k, rng)
        x_fb = math.nan if k == 2000 else x_fb
        a = cycle.position_cycle(c_py, det_py, x_ref, speed, x_fb, 0.0, True)
        b = f(c_nb, det_nb, x_ref, speed, x_fb, 0.0, True)
        codes.add(a)
        assert a == b
        assert c_py == c_nb.tolist() and det_py == det_nb.tolist()
    assert codes == {cycle.OK, cycle.FOLLOWING_ERROR, cycle.NOT_FINITE}  # stops too


def test_a_shared_lambda_is_the_smallest_and_makes_the_axes_alike() -> None:
    """Two axes, one vibrating: with the shared lambda both set points follow eq. 15 with the
    shaking axis's lambda (written out here), so the quiet axis fades its load scale out just
    as much (eq. 1: the same dynamics on every contour axis)."""
    (cx, dx), (cy, dy) = fresh(regulator_on=True), fresh(regulator_on=True)
    rng = np.random.default_rng(5)
    faded = 0
    for k in range(600):
        shake = 1e-4 * math.sin(2 * math.pi * 12 * k * CYCLE_S) + 1e-6 * rng.normal()
        assert cycle.measure(cx, dx, 0.0, 0.0, shake, 0.0, True) == cycle.OK
        assert cycle.measure(cy, dy, 1e-5, 0.0, 0.0, 0.0, True) == cycle.OK
        own_x, own_y = cx[cycle.Y_LAMBDA], cy[cycle.Y_LAMBDA]
        lam = cycle.shared_lambda((cx, cy))
        assert lam == min(own_x, own_y)
        for c in (cx, cy):
            cycle.apply(c, lam)
            ws, wc = c[cycle.Y_OMEGA_S], c[cycle.Y_OMEGA_C]
            assert c[cycle.Y_OMEGA_R] == pytest.approx(ws - lam * (ws - wc), abs=1e-12)
            assert c[cycle.Y_LAMBDA] == lam
        faded += lam < 0.5
    assert own_y == 1.0 and faded > 100  # y never shook; it faded with x all the same

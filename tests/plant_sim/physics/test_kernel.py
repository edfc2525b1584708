"""Physics of the compiled kernel against analytic results (paper section III, eq. 2-4)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from plant_sim.physics import kernel as K
from plant_sim.physics.model import AxisPlant, KernelOptions, build_params, initial_state
from plant_sim.physics.simulate import References, simulate
from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisConfig, load_axis

PAPER = CONFIG / "paper_axis.toml"


@pytest.fixture(scope="module")
def paper() -> AxisConfig:
    return load_axis(PAPER)


def _frictionless(axis: AxisConfig, **values: float | None) -> AxisConfig:
    base = {
        "friction.coulomb": None,
        "friction.viscous": None,
        "mechanics.damping_ratio": None,
        "mechanics.backlash": None,
    }
    base.update({k.replace("__", "."): v for k, v in values.items()})
    return axis.with_values(base)


def _free_run(axis: AxisConfig, dt: float, n: int, deflection: float, tau: float = 0.0):
    p = build_params(axis)
    st = initial_state(axis)
    st[K.S_X] = -deflection  # motor at 0, load behind: the spring is deflected
    out = np.empty((n, 4))
    K.run_mechanics(p, st, tau, 0.0, dt, out)
    return out


def _frequency_from_crossings(signal: np.ndarray, dt: float) -> float:
    s = signal - signal.mean()
    idx = np.nonzero(np.diff(np.sign(s)) != 0)[0]
    # linear interpolation of the crossing instants
    t = (idx + s[idx] / (s[idx] - s[idx + 1])) * dt
    period = 2.0 * (t[-1] - t[0]) / (len(t) - 1)
    return 2.0 * math.pi / period


def test_free_oscillation_at_resonance(paper: AxisConfig) -> None:
    """Motor free, no torque: the two masses oscillate at ω_r = ω_a·sqrt(1 + R) (eq. 2-4)."""
    axis = _frictionless(paper)
    dt = 1e-5
    out = _free_run(axis, dt, 20_000, 1e-5)
    deflection = out[:, 0] / axis.transmission_ratio - out[:, 2]
    assert _frequency_from_crossings(deflection, dt) == pytest.approx(axis.resonance, rel=0.01)


def test_oscillation_with_motor_held_is_antiresonance(paper: AxisConfig) -> None:
    """Motor held (infinite motor inertia): the load oscillates at ω_a = sqrt(k_s/J_l)."""
    axis = _frictionless(paper, mechanics__motor_inertia=1e12)
    dt = 1e-5
    out = _free_run(axis, dt, 20_000, 1e-5)
    assert abs(out[:, 0]).max() < 1e-9  # the motor really is held
    assert _frequency_from_crossings(out[:, 2], dt) == pytest.approx(600.0, rel=0.01)


@pytest.mark.parametrize("backlash", [None, 1e-4])
def test_energy_is_conserved_without_damping_and_friction(
    paper: AxisConfig, backlash: float | None
) -> None:
    """Kinetic + spring energy stays constant, also through the dead-zone impacts."""
    axis = _frictionless(paper, mechanics__backlash=backlash)
    dt = 2e-6
    p = build_params(axis)
    st = initial_state(axis)
    st[K.S_V] = 0.01  # load flying towards the flank at 10 mm/s
    out = np.empty((200_000, 4))
    K.run_mechanics(p, st, 0.0, 0.0, dt, out)
    th, om, x, v = out.T
    # leapfrog velocities live at half steps: average them to the position instants
    om_n = 0.5 * (om[1:] + om[:-1])
    v_n = 0.5 * (v[1:] + v[:-1])
    d = th[:-1] / axis.transmission_ratio - x[:-1]
    half = 0.5 * (backlash or 0.0)
    dz = np.where(d > half, d - half, np.where(d < -half, d + half, 0.0))
    energy = (
        0.5 * axis.motor_side_inertia * om_n**2
        + 0.5 * axis.mechanics.load_mass * v_n**2
        + 0.5 * axis.stiffness * dz**2
    )
    if backlash:
        assert np.count_nonzero(np.diff((np.abs(d) > half).astype(int)) == 1) >= 5  # impacts
    assert np.ptp(energy) / energy.mean() < 2e-3


@pytest.mark.parametrize("rigid", [True, False])
def test_rigid_limit_acceleration_is_torque_over_total_inertia(
    paper: AxisConfig, rigid: bool
) -> None:
    """δ = 0, very stiff (or rigid): acceleration = torque / total inertia."""
    if rigid:
        axis = _frictionless(paper, mechanics__antiresonance=None)
        dt = 1e-4
    else:
        axis = _frictionless(paper, mechanics__antiresonance=20_000.0)
        dt = 2e-6
    tau = 10.0
    n = round(0.1 / dt)
    out = _free_run(axis, dt, n, 0.0, tau=tau)
    t = n * dt
    expected = tau / axis.total_inertia * t
    # compare the load's speed, reflected to the motor (the masses move together)
    assert out[-1, 3] * axis.transmission_ratio == pytest.approx(expected, rel=0.01)


def _constant_speed_refs(axis: AxisConfig, feed: float, seconds: float) -> References:
    cycle = axis.control.position_cycle
    n = round(seconds / cycle)
    speed = np.full(n, feed)
    position = np.arange(n) * cycle * feed
    return References(position, speed, np.zeros(n))


@pytest.mark.parametrize("feedback", ["load", "motor"])
@pytest.mark.parametrize("cycle", [0.001, 0.0025])
def test_following_error_is_speed_over_kv(paper: AxisConfig, feedback: str, cycle: float) -> None:
    """Eq. 1: at constant speed the following error is speed / k_v (within 1 %)."""
    from virtual_bus.formats.axis import PositionFeedback

    axis = paper.with_values({"control.position_cycle": cycle})
    control = dataclasses.replace(axis.control, position_feedback=PositionFeedback(feedback))
    axis = dataclasses.replace(axis, control=control)
    feed = 0.05
    trace = simulate(axis, _constant_speed_refs(axis, feed, 2.0))
    x_fb = (
        trace["load_position"]
        if feedback == "load"
        else trace["motor_position"] / axis.transmission_ratio
    )
    e = trace["position_reference"] - x_fb
    steady = trace.time > 1.5
    assert e[steady].mean() == pytest.approx(feed / axis.control.kv, rel=0.01)


def test_motor_load_offset_is_the_backlash_after_a_reversal(paper: AxisConfig) -> None:
    """Driving forwards the motor leads the load by δ/2 on the one flank, backwards it trails
    by δ/2 on the other: the motor-load difference changes by δ (plus the tiny spring
    deflection from friction, k = 2.4e9 N/m)."""
    axis = paper
    cycle = axis.control.position_cycle
    n = round(3.0 / cycle)
    t = np.arange(n) * cycle
    speed = np.where(t < 1.5, 0.02, -0.02)
    position = np.concatenate([[0.0], np.cumsum(speed[:-1]) * cycle])
    trace = simulate(axis, References(position, speed, np.zeros(n)))
    diff = trace["motor_position"] / axis.transmission_ratio - trace["load_position"]
    forward = diff[(t > 1.0) & (t < 1.5)].mean()
    backward = diff[t > 2.5].mean()
    assert forward - backward == pytest.approx(axis.mechanics.backlash, rel=0.02)


def test_coulomb_friction_holds_the_load_below_breakaway(paper: AxisConfig) -> None:
    """Rigid axis, torque below the Coulomb level: the axis stays exactly at rest; above it,
    acceleration = (torque - coulomb) / total inertia."""
    axis = paper.with_values(
        {
            "mechanics.antiresonance": None,
            "mechanics.damping_ratio": None,
            "mechanics.backlash": None,
            "friction.viscous": None,
        }
    )
    out = _free_run(axis, 1e-4, 1000, 0.0, tau=1.0)  # coulomb = 1.2 N m
    assert np.all(out[:, 3] == 0.0)
    out = _free_run(axis, 1e-4, 1000, 0.0, tau=3.0)
    expected = (3.0 - 1.2) / axis.total_inertia * 0.1
    assert out[-1, 1] == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize("dt", [1e-4, 1e-5])
def test_creeping_friction_law_creeps_below_breakaway_and_slides_above(
    paper: AxisConfig, dt: float
) -> None:
    """``friction.creep_speed`` (regularised law): a torque below the Coulomb level makes the
    rigid axis creep at the steady speed where the linear zone balances it,
    v = v_c·tau/(coulomb + viscous·v_c) (analytic); above it the axis accelerates at
    (torque − coulomb − viscous·v)/J like the set-valued law. Implicit friction: the zone's
    slope (here coulomb/v_c ~ 1e5 times J/dt) is stable at either step."""
    vc = 1e-5
    axis = paper.with_values(
        {
            "mechanics.antiresonance": None,
            "mechanics.damping_ratio": None,
            "mechanics.backlash": None,
            "friction.creep_speed": vc,
        }
    )
    coulomb, viscous = axis.friction.coulomb, axis.friction.viscous
    n = round(0.1 / dt)
    out = _free_run(axis, dt, n, 0.0, tau=0.6)  # half the Coulomb level
    creep = vc * 0.6 / (coulomb + viscous * vc)
    assert out[-1, 3] == pytest.approx(creep, rel=1e-6)
    assert out[-1, 2] == pytest.approx(creep * 0.1, rel=0.02)
    out = _free_run(axis, dt, n, 0.0, tau=3.0)
    v = out[-1, 3]
    accel = (3.0 - coulomb - viscous * v) / axis.total_inertia / axis.transmission_ratio
    v_prev = out[-2, 3]
    assert (v - v_prev) / dt == pytest.approx(accel, rel=1e-2)


def test_current_loop_is_a_first_order_lag(paper: AxisConfig) -> None:
    """advance_torque with a torque step: τ(t) = τ_cmd·(1 − exp(−t/T_c)) at every sample."""
    plant = AxisPlant(paper)
    lag = paper.control.current_lag
    assert lag is not None
    values = []
    for _ in range(3):
        plant.advance_torque(10.0)
        values.append(plant.motor_torque_nm)
    t = np.arange(1, 4) * paper.control.position_cycle
    assert np.allclose(values, 10.0 * (1.0 - np.exp(-t / lag)), rtol=1e-9)


def test_dead_time_delays_the_torque_by_whole_speed_cycles(paper: AxisConfig) -> None:
    delay_cycles = 12
    axis = paper.with_values(
        {"control.delay": delay_cycles * paper.control.speed_cycle, "control.current_lag": None}
    )
    p = build_params(axis)
    st = initial_state(axis)
    seen = []
    for _ in range(20):
        K.speed_cycle(p, st, 1.0, 0.0)
        seen.append(st[K.S_TAU])
    first = next(i for i, v in enumerate(seen) if v != 0.0)
    assert first == delay_cycles


def test_anti_windup_stops_integrating_at_the_torque_limit(paper: AxisConfig) -> None:
    """A set point far beyond reach: the torque sits at the limit and the integral does not
    grow while it does (clamping anti-windup), so the torque leaves the limit as soon as the
    speed error changes sign — a wound-up integral would hold it there."""
    lim = 20.0
    axis = paper.with_values({"control.torque_limit": lim, "control.current_lag": None})
    p = build_params(axis)
    st = initial_state(axis)
    integrals = []
    for _ in range(400):  # 50 ms at a set point the axis cannot reach in that time
        K.speed_cycle(p, st, 200.0, 0.0)
        assert st[K.S_TAU] == pytest.approx(lim)
        integrals.append(st[K.S_INT])
    assert max(integrals) <= lim + 1e-9
    assert np.all(np.diff(integrals) <= 1e-12)
    # the error turns negative: the torque drops below the limit in the next cycle
    K.speed_cycle(p, st, st[K.S_OM_MEAS] - 1.0, 0.0)
    assert st[K.S_TAU] < lim


def test_kernel_options_are_validated() -> None:
    from plant_sim.errors import ScenarioError

    with pytest.raises(ScenarioError, match="substeps = 0"):
        KernelOptions(substeps=0)
    with pytest.raises(ScenarioError, match="setpoint_delay_cycles = 2"):
        KernelOptions(setpoint_delay_cycles=2)

"""The drive's speed-measurement filter (``control.speed_filter``) in the kernel, against the
continuous first-order filter's analytic step response, solve_ivp (plant_sim/physics/reference.py)
and the independent plant (reference_plants/independent), which implements its own filter."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis.synthetic import FAMILIES, reference_profile, slide_axis
from plant_sim.physics import kernel as K
from plant_sim.physics.model import KernelOptions, build_params, initial_state
from plant_sim.physics.reference import simulate_reference
from plant_sim.physics.simulate import References, simulate
from reference_plants.independent import PlantOptions
from reference_plants.independent import simulate as independent_simulate
from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisConfig, load_axis

PAPER = CONFIG / "paper_axis.toml"


def _coasting(axis: AxisConfig, speed: float, position_cycles: int) -> np.ndarray:
    """Measured motor speed after each position cycle of a frictionless rigid axis coasting
    at ``speed`` (load units/s), the filter starting from 0."""
    p = build_params(axis)
    st = initial_state(axis)
    st[K.S_V] = speed
    out = np.empty(position_cycles)
    for i in range(position_cycles):
        K.advance_torque(p, st, 0.0, 0.0)
        out[i] = st[K.S_OM_MEAS]
    return out


@pytest.mark.parametrize("speed_cycle", [125e-6, 62.5e-6, 250e-6])
@pytest.mark.parametrize("filter_s", [50e-6, 1e-3])
def test_step_response_is_the_continuous_filters_at_every_sample(
    speed_cycle: float, filter_s: float
) -> None:
    """A constant encoder speed ω0 from t = 0: ω_meas(t_k) = ω0·(1 − exp(−t_k/T_f)) at every
    speed sample t_k, for any speed cycle (the discretisation is exact, not Euler's). The
    speed is measured at the start of each speed cycle, so after position cycle i (two speed
    cycles each) the latest sample is at t = (2i − 1)·T_sc."""
    axis = slide_axis().with_values(
        {
            "friction.coulomb": None,
            "friction.viscous": None,
            "control.speed_cycle": speed_cycle,
            "control.position_cycle": 2 * speed_cycle,
            "control.speed_filter": filter_s,
        }
    )
    speed = 0.05
    measured = _coasting(axis, speed, 12)
    t = speed_cycle * (2 * np.arange(1, 13) - 1)
    omega0 = axis.transmission_ratio * speed
    np.testing.assert_allclose(measured, omega0 * (1.0 - np.exp(-t / filter_s)), rtol=1e-9)


@pytest.mark.parametrize("setting", [None, 0.0])
def test_no_filter_is_the_encoder_difference(setting: float | None) -> None:
    """Absent or 0: the measured speed is the encoder difference at once (the step)."""
    axis = slide_axis().with_values(
        {"friction.coulomb": None, "friction.viscous": None, "control.speed_filter": setting}
    )
    measured = _coasting(axis, 0.05, 3)
    assert np.all(measured == pytest.approx(axis.transmission_ratio * 0.05, rel=1e-12))


def test_absent_and_zero_simulate_bit_for_bit_alike() -> None:
    fam = FAMILIES["mill"]
    x = reference_profile(fam.excitation, 1.0, 0.001, np.random.default_rng(4))
    refs = References.from_position(x, 0.001)
    a = simulate(fam.truth, refs)
    b = simulate(fam.truth.with_values({"control.speed_filter": 0.0}), refs)
    for name in ("motor_position", "load_position", "motor_speed", "motor_torque"):
        np.testing.assert_array_equal(a[name], b[name])


def test_closed_loop_with_filter_converges_to_solve_ivp() -> None:
    """The paper axis (smooth: no backlash, no Coulomb friction) through its speed step with a
    0.2 ms speed filter: the kernel's error against solve_ivp (which integrates the filter's
    ODE) halves with the substep, and is far below the filter's own effect."""
    axis = (
        load_axis(PAPER)
        .with_values({"friction.viscous": 5.0, "mechanics.backlash": 0.0, "friction.coulomb": 0.0})
        .with_values({"control.speed_filter": 2e-4})
    )
    from plant_sim.paper.scenarios import SectionX

    refs = SectionX().references(axis)
    n = round(0.3 / axis.control.position_cycle)
    refs = References(refs.position[:n], refs.speed[:n], refs.disturbance_nm[:n])
    reference = simulate_reference(axis, refs)
    errors = []
    for sub in (1, 2, 4):
        trace = simulate(axis, refs, options=KernelOptions(substeps=sub))
        errors.append(float(np.abs(trace["motor_speed"] - reference["motor_speed"]).max()))
    unfiltered = simulate(axis.with_values({"control.speed_filter": None}), refs)
    effect = float(np.abs(unfiltered["motor_speed"] - reference["motor_speed"]).max())
    assert errors[2] < 0.6 * errors[1] < 0.36 * errors[0]
    assert errors[0] < 0.05 * effect and errors[2] < 0.02 * effect


@pytest.mark.parametrize("family", ["mill", "slide"])
def test_kernel_with_the_filter_follows_the_independent_plants_filter(family: str) -> None:
    """The independent plant has its own speed filter. With the modelling choices that the
    filter does not concern made alike (no friction, ideal current loop, exact sensors), the
    kernel's recorded speed follows that plant's far closer with the same filter stated in
    the axis file than without it."""
    fam = FAMILIES[family]
    x = reference_profile(fam.excitation, 2.0, 0.001, np.random.default_rng(8))
    refs = References.from_position(x, 0.001)
    options = PlantOptions(speed_filter_s=2e-4, motor_counts_per_rev=0, load_resolution=0.0)
    plain = fam.truth.with_values(
        {"friction.coulomb": None, "friction.viscous": None, "control.current_lag": None}
    )
    indep = independent_simulate(plain, refs.position, refs.speed, options=options)
    scale = float(np.std(indep["motor_speed"]))

    def distance(axis: AxisConfig) -> float:
        tr = simulate(axis, refs)
        return float(np.sqrt(np.mean((tr["motor_speed"] - indep["motor_speed"]) ** 2))) / scale

    with_filter = distance(plain.with_values({"control.speed_filter": 2e-4}))
    without = distance(plain)
    assert with_filter < 0.01 * without, (with_filter, without)

"""The kernel against itself (step halving) and against an independent implementation
(scipy's solve_ivp, plant_sim/physics/reference.py)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from plant_sim.paper.scenarios import SectionX, run_section_x
from plant_sim.physics.model import KernelOptions
from plant_sim.physics.reference import simulate_reference
from plant_sim.physics.simulate import References, simulate
from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisConfig, load_axis

PAPER = CONFIG / "paper_axis.toml"


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(PAPER).with_values({"friction.viscous": 5.0})


def _start(axis: AxisConfig, seconds: float) -> References:
    refs = SectionX().references(axis)
    n = round(seconds / axis.control.position_cycle)
    return References(refs.position[:n], refs.speed[:n], refs.disturbance_nm[:n])


def test_step_halving_converges_on_the_section_x_run(axis: AxisConfig) -> None:
    """Halving the substep again and again: the whole section X trace (impacts, limit cycle,
    friction) changes less each time, and the changes shrink at least ~linearly."""
    runs = [
        run_section_x(axis, with_regulator=False, options=KernelOptions(substeps=n))
        for n in (1, 2, 4, 8)
    ]
    window = runs[0].time < 4.0  # start, speed step, both flank changes of the disturbance
    e = [(r["position_reference"] - r["load_position"])[window] for r in runs]
    diffs = [float(np.abs(e[i + 1] - e[i]).max()) for i in range(3)]
    assert diffs[0] > diffs[1] > diffs[2]
    assert diffs[2] < 0.35 * diffs[0]  # first order would give 1/4 over two halvings
    assert diffs[0] < 5e-6  # default step already within 5 µm of the next one (δ = 100 µm)


def test_kernel_converges_to_the_solve_ivp_reference(axis: AxisConfig) -> None:
    """Smooth configuration (no backlash, no Coulomb friction) through the speed step: the
    kernel's error against solve_ivp halves with every halving of its substep."""
    smooth = axis.with_values({"mechanics.backlash": 0.0, "friction.coulomb": 0.0})
    refs = _start(smooth, 0.3)
    reference = simulate_reference(smooth, refs)
    errors = []
    for n in (1, 2, 4):
        trace = simulate(smooth, refs, options=KernelOptions(substeps=n))
        errors.append(float(np.abs(trace["load_position"] - reference["load_position"]).max()))
    assert errors[0] < 1e-6  # < 1 µm in a 6 mm move at the default step
    for coarse, fine in itertools.pairwise(errors):
        assert fine == pytest.approx(coarse / 2, rel=0.15)


def test_kernel_matches_reference_with_backlash_and_friction_in_motion(axis: AxisConfig) -> None:
    """With the dead zone and Coulomb friction the two agree once the load moves (the start
    differs by design: stiction vs sign(v)). The disturbance at 2 s throws the load onto the
    other flank: the impact's torque spike converges to the reference as the substep shrinks."""
    refs = _start(axis, 2.4)
    reference = simulate_reference(axis, refs)
    moving = reference.time > 0.4
    dx, dtau = [], []
    for n in (1, 4, 16):
        trace = simulate(axis, refs, options=KernelOptions(substeps=n))
        dx.append(float(np.abs(trace["load_position"] - reference["load_position"])[moving].max()))
        dtau.append(float(np.abs(trace["motor_torque"] - reference["motor_torque"])[moving].max()))
    assert dx[0] < 2.5e-6  # µm-level through the flank change at the default step, δ = 100 µm
    assert dx[2] < dx[1] < dx[0]
    assert dtau[2] < dtau[1] < dtau[0]
    assert dtau[2] < 0.1 * dtau[0]  # 16x finer: the impact spike within 1/10

"""The third test plant (reference_plants/third) against physics and against the kernel where the
two model the same thing: where its extra modelling choices are switched off, its closed
loop agrees with plant_sim's kernel on the axis file it writes for itself; its LuGre friction
settles on the Stribeck curve; its torque limit clips; its test set is what the matrix
needs. No diagnosis runs here: the third plant's results are reported once, after the
design was frozen (docs/diagnosis.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis.effects import MODELS, effects_in
from diagnosis.metrics import nrmse
from diagnosis.testsets import third as third_cases
from diagnosis.testsets.third import FAMILIES
from plant_sim.physics.model import KernelOptions, default_substeps
from plant_sim.physics.simulate import References, simulate
from reference_plants.third import plant
from virtual_bus.formats.trace import MOTION_COLUMNS


def _refs(family: str, seconds: float, seed: int) -> References:
    fam = FAMILIES[family]
    pos = third_cases.program(fam.motion, seconds, 0.001, np.random.default_rng(seed))
    return References.from_position(pos, 0.001)


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_agrees_with_the_kernel_where_the_physics_is_the_same(family: str) -> None:
    """No encoder error, quantisation or trace filter, LuGre without bristle damping: the
    remaining differences (the coupling's torsion, the bristles' pre-sliding, the PI current
    loop with back-EMF) leave the torque within 5 % and the following error within 1 %."""
    ph = FAMILIES[family].base.with_(
        bristle_damping=0.0,
        encoder_error=0.0,
        encoder_quantum=0.0,
        scale_quantum=0.0,
        trace_filter=0.0,
    )
    refs = _refs(family, 8.0, 3)
    ours = plant.simulate(ph, refs.position, refs.speed, refs.disturbance_nm)
    axis = plant.axis_of(ph)
    kernel = simulate(axis, refs, None, KernelOptions(substeps=4 * default_substeps(axis)))
    assert nrmse(kernel["motor_torque"], ours["motor_torque"]) < 0.05
    fe = {n: t["position_reference"] - t["load_position"] for n, t in (("k", kernel), ("o", ours))}
    assert nrmse(fe["k"], fe["o"]) < 0.01


def test_lugre_friction_settles_on_the_stribeck_curve() -> None:
    """Constant-speed moves: the torque the motor holds is the LuGre law's steady state
    g(v) + σ2·v (plus the load force), reflected by k_r: below the Stribeck speed the
    static level shows, far above it Coulomb + viscous."""
    fam = FAMILIES["vertical"]
    ph = fam.base.with_(static_pos=110.0, static_neg=110.0, trace_filter=0.0)
    kr = ph.transmission_ratio
    for v in (0.002, 0.05):
        n = 6000
        t = np.arange(n) * 0.001
        ramp = np.clip(t / 0.2, 0.0, 1.0)
        x = 0.02 + np.cumsum(v * ramp) * 0.001
        refs = References.from_position(x, 0.001)
        sim = plant.simulate(ph, refs.position, refs.speed, refs.disturbance_nm)
        settled = float(np.mean(sim["motor_torque"][-2000:]))
        g = ph.coulomb_pos + (ph.static_pos - ph.coulomb_pos) * math.exp(
            -((v / ph.stribeck_speed) ** 2)
        )
        expected = (g + ph.viscous_pos * v + ph.load_force) / kr
        assert settled == pytest.approx(expected, rel=0.02), v


def test_the_torque_limit_clips_the_traced_torque() -> None:
    fam = FAMILIES["rotary"]
    refs = _refs("rotary", 6.0, 5)
    free = plant.simulate(
        fam.base.with_(trace_filter=0.0), refs.position, refs.speed, refs.disturbance_nm
    )
    peak = float(np.max(np.abs(free["motor_torque"])))
    limited = fam.base.with_(torque_limit=0.8 * peak, trace_filter=0.0)
    sim = plant.simulate(limited, refs.position, refs.speed, refs.disturbance_nm)
    # the current follows its clipped reference through the current loop's lag
    assert float(np.max(np.abs(sim["motor_torque"]))) < 0.85 * peak
    assert float(np.max(np.abs(sim["motor_torque"]))) > 0.75 * peak


def test_test_set_conceals_one_effect_each_in_a_recording_of_its_own() -> None:
    cases = third_cases.test_set(seed=1, duration_s=4.0)
    assert len(cases) == 26
    assert {c.family for c in cases} == set(FAMILIES)
    for case in (cases[0], cases[7], cases[12], cases[20]):
        gen = third_cases.generate(case)
        rec = gen.recording
        assert set(rec.names) >= set(MOTION_COLUMNS)
        assert float(np.median(np.diff(rec.time))) == pytest.approx(0.001)
        left = effects_in(gen.truth) - effects_in(gen.nominal)
        if case.effect is None:
            assert left == frozenset()
        else:
            assert case.effect in left
            assert not MODELS[case.effect].present(gen.nominal)
        again = third_cases.generate(case)
        assert np.array_equal(again.recording["motor_torque"], rec["motor_torque"])

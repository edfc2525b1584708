"""The independent test plant (reference_plants/independent) against analytic results, and the
compiled kernel against it: two implementations with different integrators, friction and
contact laws, sensors and current loops must agree where the physics is the same."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis.effects import Effect
from diagnosis.matrix import load_plant, run_case
from diagnosis.synthetic import FAMILIES, Case, reference_profile, slide_axis
from diagnosis.testsets.independent import generate
from plant_sim.physics.simulate import References
from plant_sim.physics.simulate import simulate as kernel_simulate
from reference_plants.independent import PlantOptions, simulate

CYCLE_S = 0.001


def _nrmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.std(b))


@pytest.mark.parametrize("feedforward", [False, True], ids=["plain", "feedforward"])
@pytest.mark.parametrize("family", ["mill", "slide"])
def test_kernel_agrees_with_the_independent_plant(family: str, feedforward: bool) -> None:
    """Same axis, same references: torque and following error agree within a few per cent
    (the rest is the modelling choices: smooth vs set-valued friction, PI vs exact current
    loop, quantised sensors) -- also with full velocity and acceleration feed-forward."""
    fam = FAMILIES[family]
    axis = fam.truth
    if feedforward:
        axis = axis.with_values(
            {
                "control.velocity_feedforward": 1.0,
                "control.acceleration_feedforward": axis.total_inertia,
            }
        )
    x = reference_profile(fam.excitation, 8.0, CYCLE_S, np.random.default_rng(11))
    refs = References.from_position(x, CYCLE_S)
    kernel = kernel_simulate(axis, refs)
    indep = simulate(axis, refs.position, refs.speed, options=PlantOptions())
    assert _nrmse(indep["motor_torque"], kernel["motor_torque"]) < 0.1
    kr = axis.transmission_ratio
    e_k = refs.position - kernel["motor_position"] / kr
    e_i = refs.position - indep["motor_position"] / kr
    # scale: the following error without feed-forward (with it, e is nearly 0 on both)
    plain = kernel_simulate(fam.truth, refs)
    scale = float(np.std(refs.position - plain["motor_position"] / kr))
    assert float(np.sqrt(np.mean((e_i - e_k) ** 2))) < 0.05 * scale
    if feedforward:
        assert float(np.std(e_k)) < 0.5 * scale and float(np.std(e_i)) < 0.5 * scale


@pytest.mark.parametrize("gain", [0.0, 1.0])
def test_velocity_feedforward_on_the_independent_plant(gain: float) -> None:
    """Steady ramp: following error (1 − k_vff)·v/k_v, as on the kernel."""
    axis = slide_axis().with_values(
        {"friction.coulomb": None, "friction.viscous": None, "control.velocity_feedforward": gain}
    )
    speed = 0.05
    t = np.arange(1500) * CYCLE_S
    x = speed * np.clip(t - 0.2, 0.0, None)
    refs = References.from_position(x, CYCLE_S)
    tr = simulate(axis, refs.position, refs.speed)
    e = refs.position - tr["motor_position"] / axis.transmission_ratio
    expected = (1.0 - gain) * speed / axis.control.kv
    # encoder quantum 6 µrad = 1 nm of load travel: far below the tolerance
    assert float(np.mean(e[-200:])) == pytest.approx(expected, abs=0.01 * speed / axis.control.kv)


def test_sensor_time_offset_on_the_independent_plant() -> None:
    """The load reading is the load position offset seconds earlier."""
    axis = slide_axis()
    shifted = axis.with_values({"control.sensor_time_offset": 0.004})
    fam = FAMILIES["slide"]
    x = reference_profile(fam.excitation, 3.0, CYCLE_S, np.random.default_rng(2))
    refs = References.from_position(x, CYCLE_S)
    a = simulate(axis, refs.position, refs.speed)
    b = simulate(shifted, refs.position, refs.speed)
    np.testing.assert_array_equal(a["motor_position"], b["motor_position"])
    t = a["time"]
    valid = t > 0.01
    expected = np.interp(t - 0.004, t, a["load_position"])
    assert np.max(np.abs(b["load_position"][valid] - expected[valid])) < 2e-8  # 4 scale counts


def test_generated_case_follows_the_axis_file_rule() -> None:
    """The nominal lacks exactly the concealed effect's keys and keeps every other key."""
    gen = generate(Case("slide-none", "slide", None, 3, duration_s=4.0))
    assert gen.nominal.friction.viscous is not None and len(gen.recording) == 2000

    gen = generate(Case("mill-visc", "mill", Effect.VISCOUS_FRICTION, 3, duration_s=4.0))
    assert gen.nominal.friction.viscous is None
    assert gen.nominal.friction.coulomb is not None
    assert gen.truth.friction.viscous is not None


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "family", "effect", "seed"),
    [
        ("slide-none-1", "slide", None, 5022),
        ("mill-coulomb_friction", "mill", "coulomb_friction", 5002),
    ],
)
def test_matrix_subset_on_the_independent_plant(
    name: str, family: str, effect: str | None, seed: int
) -> None:
    """Two cases of the concealed-effect matrix recorded on the independent plant: the
    diagnosis (which simulates with the kernel) names exactly what was left out."""
    case = Case(name, family, Effect(effect) if effect else None, seed, duration_s=12.0)
    result = run_case(case, plant=load_plant("independent"))
    assert result.exact, result


def test_matrix_command_refuses_an_unknown_plant(capsys: pytest.CaptureFixture[str]) -> None:
    from diagnosis.__main__ import main
    from tests.command_line import exit_status

    assert exit_status(main, ["matrix", "--plant", "bogus"]) == 2
    err = capsys.readouterr().err
    assert "--plant" in err and "'bogus'" in err and "independent" in err and "kernel" in err
    assert err.count("\n") == 1


def _dominant_hz(signal: np.ndarray, dt: float) -> float:
    s = (signal - signal.mean()) * np.hanning(len(signal))
    amp = np.abs(np.fft.rfft(s))
    return float(np.fft.rfftfreq(len(s), dt)[1 + int(np.argmax(amp[1:]))])


def test_section_x_limit_cycle_on_both_plants() -> None:
    """The paper's section X (backlash 0.1 mm, disturbance step, ordinary control): both
    plants shake after the disturbance with the same peak-to-peak following error and
    frequency, although their contact and friction laws differ."""
    from plant_sim.paper.outputs import LIMIT_CYCLE_VISCOUS
    from plant_sim.paper.scenarios import P2P_START_S, SectionX, run_section_x
    from virtual_bus.formats.axis import load_axis

    axis = load_axis("config/paper_axis.toml").with_values(
        {"friction.viscous": LIMIT_CYCLE_VISCOUS}
    )
    scenario = SectionX()
    refs = scenario.references(axis)
    kernel = run_section_x(axis, False)
    indep = simulate(axis, refs.position, refs.speed, refs.disturbance_nm)
    t = kernel["time"]
    window = (t >= P2P_START_S) & (t < scenario.stop_s)
    errors = {
        name: (tr["position_reference"] - tr["load_position"])[window]
        for name, tr in (("kernel", kernel), ("independent", indep))
    }
    p2p = {name: float(np.ptp(e)) for name, e in errors.items()}
    assert p2p["kernel"] > 5e-5  # it does shake (half the free play and more)
    assert p2p["independent"] == pytest.approx(p2p["kernel"], rel=0.15)
    freq = {name: _dominant_hz(e, CYCLE_S) for name, e in errors.items()}
    assert freq["independent"] == pytest.approx(freq["kernel"], rel=0.15)

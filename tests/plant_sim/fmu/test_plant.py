"""An FMU stepped as a plant (:class:`plant_sim.fmu.FmuPlant`), checked against things this
project did not write: FMPy's own API stepping the same FMU (as the family's README does it),
the family's data sheet (the steady friction torque of a clean axis), unit factors of a
declared unit, and the FMU's own failure messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from plant_sim.errors import FmuError, FmuStepError
from plant_sim.fmu import FmuPlant, FmuSpec, load_fmu, nominal_axis
from tests.plant_sim.fmu.fmus import edited_copy, family_fmu, tiny_fmu, unit_of

OUTPUTS = ("motor_position", "load_position", "motor_speed", "motor_torque")


def readings(plant: FmuPlant) -> tuple[float, ...]:
    return (
        plant.motor_position_rad,
        plant.load_position,
        plant.motor_speed_rad_s,
        plant.motor_torque_nm,
    )


def test_the_same_steps_as_fmpys_own_api() -> None:
    """The family README's loop through FMPy's FMU2Slave, and FmuPlant: bit for bit."""
    import fmpy
    from fmpy.fmi2 import FMU2Slave

    path = family_fmu()
    model = load_fmu(FmuSpec.from_text(path, "seed=7,family=1"))
    axis = nominal_axis(model)
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(
        guid=md.guid,
        unzipDirectory=fmpy.extract(str(path)),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="reference",
    )
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.setInteger([vr["seed"], vr["family"]], [7, 1])
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    kr = axis.transmission_ratio
    rng = np.random.default_rng(1)
    speeds = rng.normal(0.0, 20.0, 400)
    disturbances = rng.normal(0.0, 2.0, 400)  # N·m at the motor
    with FmuPlant(model, axis) as plant:
        t = 0.0
        for w, d in zip(speeds, disturbances, strict=True):
            ref = slave.getReal([vr[n] for n in OUTPUTS])
            assert readings(plant) == tuple(ref)
            slave.setReal([vr["speed_setpoint"], vr["disturbance_force"]], [w, d * kr])
            slave.doStep(currentCommunicationPoint=t, communicationStepSize=0.001)
            t += 0.001
            plant.advance(w, d)
    slave.terminate()
    slave.freeInstance()


def test_two_plants_of_one_seed_are_the_same_plant() -> None:
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=12,family=3"))
    axis = nominal_axis(model)
    with FmuPlant(model, axis) as a, FmuPlant(model, axis) as b:
        for k in range(300):
            a.advance(5.0 * math.sin(k / 30))
            b.advance(5.0 * math.sin(k / 30))
        assert readings(a) == readings(b)
        assert a.time_s == pytest.approx(0.3)


@pytest.mark.parametrize("seed", [0, 5, 9])
def test_a_clean_axis_at_constant_speed_carries_its_data_sheets_friction(seed: int) -> None:
    """Family 0 without noise: the steady torque is coulomb + viscous * v of the data sheet
    (N·m at the motor, v the load speed): the mapping's units and the nominal keys mean what
    the axis file says they mean."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), f"seed={seed},family=0,noise=0"))
    axis = nominal_axis(model)
    kr = axis.transmission_ratio
    with FmuPlant(model, axis) as plant:
        for v in (0.01, 0.03):
            for _ in range(3000):
                plant.advance(v * kr)
            torque = np.mean([plant.advance(v * kr) or plant.motor_torque_nm for _ in range(500)])
            law = axis.friction.coulomb + axis.friction.viscous * v
            assert torque == pytest.approx(law, rel=1e-6)
            assert plant.motor_speed_rad_s / kr == pytest.approx(v, rel=1e-9)


def test_a_declared_unit_is_converted(tmp_path: Path) -> None:
    """The same binary with motor_speed declared in rpm: the plant's reading is the raw value
    times 2*pi/60, and the set point in (rad/s) reaches the FMU as rpm."""
    rpm = edited_copy(tmp_path, "rpm.fmu", unit_of("motor_speed", "rpm"))
    plain = load_fmu(FmuSpec.from_text(family_fmu(), "seed=2"))
    scaled = load_fmu(FmuSpec.from_text(rpm, "seed=2"))
    axis = nominal_axis(plain)
    with FmuPlant(plain, axis) as a, FmuPlant(scaled, axis) as b:
        for _ in range(200):
            a.advance(3.0)
            b.advance(3.0)
        assert b.motor_speed_rad_s == pytest.approx(a.motor_speed_rad_s * 2 * math.pi / 60)
        assert b.motor_position_rad == a.motor_position_rad


def test_the_disturbance_torque_is_a_force_on_the_carriage() -> None:
    """A disturbance of tau N·m at the motor is tau * k_r N on the carriage: at rest under the
    loop's hold, the motor torque that holds it is tau (data-sheet friction aside)."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=0,family=0,noise=0"))
    axis = nominal_axis(model)
    with FmuPlant(model, axis) as plant:
        for _ in range(3000):  # hold the position against 10 N·m pushing towards +x
            plant.advance(-axis.control.kv * plant.load_position * axis.transmission_ratio, 10.0)
        assert plant.motor_torque_nm == pytest.approx(-10.0, abs=0.05)


def test_power_stage_off_holds_speed_zero() -> None:
    """It cannot coast (speed input only): advance_torque(0) is advance(0) (docs/fmu.md)."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=4"))
    axis = nominal_axis(model)
    with FmuPlant(model, axis) as a, FmuPlant(model, axis) as b:
        for _ in range(100):
            a.advance(8.0)
            b.advance(8.0)
        for _ in range(100):
            a.advance_torque(0.0)
            b.advance(0.0)
        assert readings(a) == readings(b)
        assert not a.coasts and not a.limits_torque
        with pytest.raises(FmuStepError, match="no torque input"):
            a.advance_torque(1.0)


def test_a_step_the_fmu_refuses_stops_the_plant() -> None:
    """A non-finite set point: the FMU's own message, and no step after it."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=1"))
    with FmuPlant(model, nominal_axis(model)) as plant:
        plant.advance(1.0)
        before = readings(plant)
        with pytest.raises(FmuStepError, match="input not finite") as info:
            plant.advance(math.nan)
        assert info.value.call == "fmi2DoStep" and plant.failure is info.value
        plant.advance(1.0)  # nothing more happens
        assert readings(plant) == before


def test_the_tiny_fmu_fails_where_it_is_told(tmp_path: Path) -> None:
    model = load_fmu(FmuSpec.from_text(tiny_fmu(tmp_path), "fail_after=5"))
    axis = nominal_axis_of_tiny(model)
    with FmuPlant(model, axis) as plant:
        for _ in range(5):
            plant.advance(2.0)
        assert plant.motor_position_rad == pytest.approx(5 * 2.0 * 0.001)
        with pytest.raises(FmuStepError, match="fails here on purpose"):
            plant.advance(2.0)


def nominal_axis_of_tiny(model):  # type: ignore[no-untyped-def]
    """The tiny FMU has no data sheet beyond k_r: the paper's axis file configures it."""
    from virtual_bus.formats.axis import load_axis
    from virtual_bus.shipped import PAPER_AXIS

    with pytest.raises(FmuError, match="no data-sheet value"):
        nominal_axis(model)
    return load_axis(PAPER_AXIS)

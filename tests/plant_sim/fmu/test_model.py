"""Loading an FMU as an axis: what is checked before anything runs, and what a user is told.

The shared feed-axis family (``shared/plants``, written apart from this project) loads; every
bad FMU a user may be handed is refused with one message naming the FMU and what is wrong:
a renamed file that is no zip, a model-exchange-only FMU, no binary for this platform, a
variable the mapping names that is missing, of the wrong causality or unit, a parameter it
does not have or of the wrong type, and a parameter value the FMU itself refuses (its own
log message quoted)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from plant_sim.errors import FmuError
from plant_sim.fmu import FmuSpec, load_fmu, nominal_axis
from plant_sim.fmu.units import Quantity
from tests.plant_sim.fmu.fmus import (
    edited_copy,
    family_fmu,
    model_exchange_only,
    renamed,
    unit_of,
)


def spec(path: Path, params: str = "", mapping: str = "") -> FmuSpec:
    return FmuSpec.from_text(path, params, mapping)


def test_the_family_loads_with_its_data_sheet() -> None:
    model = load_fmu(spec(family_fmu(), "seed=0,family=0"))
    assert model.set_point.quantity is Quantity.ANGULAR_SPEED
    assert model.disturbance is not None and model.disturbance.quantity is Quantity.FORCE
    # seed 0 is the paper's axis (the family's README; the paper's section IX)
    axis = nominal_axis(model)
    assert axis.transmission_ratio == pytest.approx(100 * math.pi)
    assert axis.mechanics.load_mass == pytest.approx(6554.2)
    assert axis.mechanics.antiresonance == pytest.approx(600.0)
    assert (axis.control.kv, axis.control.ksp, axis.control.tsi) == pytest.approx((25, 52, 0.0075))
    assert axis.mechanics.backlash is None  # a data sheet knows no hidden free play
    assert axis.control.speed_cycles_per_position_cycle == 8


def test_a_loaded_fmu_is_kept_per_spec() -> None:
    a = load_fmu(spec(family_fmu(), "seed=3"))
    assert load_fmu(spec(family_fmu(), "seed=3")) is a
    assert load_fmu(spec(family_fmu(), "seed=4")) is not a


def test_another_seed_is_another_axis() -> None:
    a = nominal_axis(load_fmu(spec(family_fmu(), "seed=1")))
    b = nominal_axis(load_fmu(spec(family_fmu(), "seed=2")))
    assert a != b


def refused(path: Path, params: str = "", mapping: str = "") -> str:
    with pytest.raises(FmuError) as info:
        load_fmu(spec(path, params, mapping))
    message = str(info.value)
    assert "\n" not in message
    return message


def test_a_renamed_file_is_not_an_fmu(tmp_path: Path) -> None:
    fake = tmp_path / "axis.fmu"
    fake.write_text("[axis]\nkind = 'linear'\n")
    assert "not an FMU" in refused(fake)


def test_a_model_exchange_fmu_is_refused(tmp_path: Path) -> None:
    fmu = edited_copy(tmp_path, "me.fmu", model_exchange_only)
    assert "model exchange only" in refused(fmu)


def test_no_binary_for_this_platform(tmp_path: Path) -> None:
    fmu = edited_copy(tmp_path, "nobin.fmu", drop="binaries/")
    message = refused(fmu)
    assert "no binary for this platform" in message and "source only" in message


def test_a_mapped_variable_that_is_missing(tmp_path: Path) -> None:
    fmu = edited_copy(tmp_path, "renamed.fmu", renamed("motor_speed", "speed_actual"))
    message = refused(fmu)
    assert "'motor_speed': no such variable" in message and "speed_actual" in message
    # mapped by name, the same FMU loads
    load_fmu(spec(fmu, mapping="motor_speed=speed_actual"))


def test_wrong_causality_and_unit_are_named() -> None:
    assert "must be an output" in refused(family_fmu(), mapping="motor_speed=speed_setpoint")
    message = refused(family_fmu(), mapping="motor_speed=motor_position")
    assert "unit 'rad'" in message and "rad/s" in message


def test_a_unit_the_table_does_not_know(tmp_path: Path) -> None:
    fmu = edited_copy(tmp_path, "furlong.fmu", unit_of("load_position", "furlong"))
    assert "unit 'furlong'" in refused(fmu)


def test_parameters_are_checked_by_the_fmus_own_types() -> None:
    fmu = family_fmu()
    assert "not an integer" in refused(fmu, "seed=1.5")
    assert "no such parameter" in refused(fmu, "sede=1")
    assert "not a parameter a user sets" in refused(fmu, "truth_backlash=0")


def test_a_value_the_fmu_refuses_is_named_with_its_own_message() -> None:
    message = refused(family_fmu(), "family=50")
    assert "fmi2ExitInitializationMode failed" in message and "invalid parameter" in message

"""Axis files (docs/axis-file.md): derived values (eq. 2-4) and refusals."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisKind, dump_axis, load_axis
from virtual_bus.formats.errors import AxisFileError, FormatError

PAPER_TEXT = (CONFIG / "paper_axis.toml").read_text()


def test_paper_axis_derived_values_follow_eq_2_to_4() -> None:
    axis = load_axis(CONFIG / "paper_axis.toml")
    kr = 100 * math.pi
    jl = 6554.2 / kr**2  # reflected load inertia J_l'
    j1 = 0.0625 + 0.0784
    assert axis.load_inertia_reflected == pytest.approx(jl)
    assert axis.inertia_ratio == pytest.approx(jl / j1)
    # eq. 2: omega_a = sqrt(k_s'/J_l') with k_s' the reflected stiffness
    assert math.sqrt(axis.stiffness_reflected / jl) == pytest.approx(600.0)
    # eq. 2: omega_r = sqrt(k_s'(1/J_m + 1/J_l')) and eq. 4: H = omega_r/omega_a = sqrt(1 + R)
    assert axis.resonance == pytest.approx(math.sqrt(axis.stiffness_reflected * (1 / j1 + 1 / jl)))
    assert axis.resonance / 600.0 == pytest.approx(math.sqrt(1 + axis.inertia_ratio))
    # xi_a = c_s omega_a / (2 k_s)
    assert axis.damping_coefficient * 600.0 / (2 * axis.stiffness) == pytest.approx(0.04)


def test_dump_and_load_round_trip(tmp_path: Path) -> None:
    axis = load_axis(CONFIG / "paper_axis.toml").with_values(
        {
            "friction.stribeck": 0.5,
            "friction.stribeck_speed": 0.002,
            "control.delay": 0.0005,
            "control.speed_filter": 5e-5,
        }
    )
    path = tmp_path / "a.toml"
    path.write_text(dump_axis(axis, "fitted"))
    assert load_axis(path) == axis


def test_dump_writes_numpy_scalars_as_toml_numbers(tmp_path: Path) -> None:
    import numpy as np

    axis = load_axis(CONFIG / "paper_axis.toml").with_values({"friction.coulomb": np.float64(1.5)})
    path = tmp_path / "np.toml"
    path.write_text(dump_axis(axis))
    assert load_axis(path).friction.coulomb == 1.5


def test_rotary_axis_uses_load_inertia(tmp_path: Path) -> None:
    text = PAPER_TEXT.replace('kind = "linear"', 'kind = "rotary"').replace(
        "load_mass = 6554.2", "load_inertia = 12.0"
    )
    path = tmp_path / "rotary.toml"
    path.write_text(text)
    axis = load_axis(path)
    assert axis.kind is AxisKind.ROTARY and axis.load_unit == "rad"
    assert axis.mechanics.load_mass == 12.0
    assert "load_inertia = 12.0" in dump_axis(axis)


BAD = [
    # (replace this, with this, the message must contain)
    ("[friction]", "[frictions]", "frictions"),
    ("coulomb = 1.2", "coulumb = 1.2", "friction.coulumb"),
    ("load_mass = 6554.2", "", "missing required key mechanics.load_mass"),
    ("kv = 25.0", "", "missing required key control.kv"),
    ("kv = 25.0", 'kv = "25"', "control.kv"),
    ("kv = 25.0", "kv = true", "must be a number"),
    ("kv = 25.0", "kv = 0.0", "control.kv = 0.0"),
    ("load_mass = 6554.2", "load_mass = -1.0", "allowed range (0, inf)"),
    ("backlash = 0.0001", "backlash = -0.0001", "mechanics.backlash"),
    ("damping_ratio = 0.04       #", "damping_ratio = 1.5 #", "allowed range [0, 1]"),
    ("position_cycle = 0.001", "position_cycle = 0.0011", "whole multiple"),
    ('position_feedback = "load"', 'position_feedback = "scale"', "one of ['load', 'motor']"),
    ('kind = "linear"', 'kind = "planar"', "one of ['linear', 'rotary']"),
    ("load_mass = 6554.2", "load_inertia = 1.0", "a linear axis gives mechanics.load_mass"),
    ("antiresonance = 600.0", "", "needs mechanics.antiresonance"),
    ("coulomb = 1.2", "coulomb = 1.2\nstribeck = 0.3", "go together"),
    ("viscous = 57.3", "viscous = nan", "friction.viscous"),
    (
        "kv = 25.0",
        "kv = 25.0\nspeed_filter = -5e-5",
        "control.speed_filter = -5e-05: allowed range [0, 0.1]",
    ),
    (
        "kv = 25.0",
        "kv = 25.0\nspeed_filter = 0.2",
        "control.speed_filter = 0.2: allowed range [0, 0.1]",
    ),
    ("[axis]", "[axis\n", "not valid TOML"),
]


@pytest.mark.parametrize(("old", "new", "message"), BAD, ids=[b[2][:30] for b in BAD])
def test_bad_axis_files_are_refused_with_key_and_range(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    assert old in PAPER_TEXT
    path = tmp_path / "bad.toml"
    path.write_text(PAPER_TEXT.replace(old, new, 1))
    with pytest.raises(AxisFileError) as info:
        load_axis(path)
    assert message in str(info.value)
    assert str(path) in str(info.value)
    assert isinstance(info.value, FormatError) and isinstance(info.value, ValueError)


def test_missing_file_is_an_axis_file_error(tmp_path: Path) -> None:
    with pytest.raises(AxisFileError, match="no such axis file"):
        load_axis(tmp_path / "nope.toml")

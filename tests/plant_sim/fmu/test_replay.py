"""A recording replayed through an FMU (``diagnosis simulate --fmu``, the diagnosis's replay
with an FMU as the plant): the FMU's own recording, replayed through the same FMU, comes back
as it was -- the replay and the recording share the loop (regulator.loop) and the FMU is the
same plant, bit for bit; a kernel replay of it does not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from diagnosis.__main__ import main
from plant_sim.__main__ import main as plant_sim_main
from plant_sim.fmu import FmuPlant, FmuSpec, load_fmu, nominal_axis
from plant_sim.physics.simulate import References, simulate_plant
from tests.plant_sim.fmu.fmus import family_fmu
from virtual_bus.formats.trace import Trace, read_trace

PARAMS = "seed=3,family=0"


def recording(path: Path) -> None:
    """A move out and back on the FMU's axis, its data-sheet loop, recorded as a trace."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), PARAMS))
    axis = nominal_axis(model)
    t = np.arange(3000) * axis.control.position_cycle
    position = 0.01 * np.clip(np.minimum(t - 0.2, 2.2 - t), 0.0, 0.5)
    refs = References.from_position(position, axis.control.position_cycle)
    with FmuPlant(model, axis) as plant:
        trace = simulate_plant(plant, axis, refs)
    columns = ("time", "position_reference", "motor_position", "load_position")
    Trace({c: trace[c] for c in (*columns, "motor_speed", "motor_torque")}).to_csv(path)


def test_the_fmus_recording_replayed_through_it_comes_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec, sim = tmp_path / "rec.csv", tmp_path / "sim.csv"
    recording(rec)
    fmu = ["--fmu", str(family_fmu()), "--fmu-param", PARAMS]
    assert main(["simulate", *fmu, "--like", str(rec), "--out", str(sim)]) == 0
    assert "load_position 100.0 %" in capsys.readouterr().out
    a, b = read_trace(rec), read_trace(sim)
    for column in ("motor_position", "load_position", "motor_speed", "motor_torque"):
        np.testing.assert_array_equal(a[column], b[column])
    # the kernel's model of the same data sheet is a model, not the machine
    kernel = tmp_path / "kernel.csv"
    axis_file = tmp_path / "axis.toml"
    assert plant_sim_main(["fmu-axis", *fmu, "--out", str(axis_file)]) == 0
    argv = ["simulate", "--axis", str(axis_file), "--like", str(rec), "--out", str(kernel)]
    assert main(argv) == 0
    assert not np.array_equal(read_trace(kernel)["motor_torque"], a["motor_torque"])

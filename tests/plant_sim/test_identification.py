"""Section IX identification (plant_sim.identification, ``python -m plant_sim identify``).

Independent reference: the parameters that generated the synthetic trace (the paper's
M_l = 6554.2 kg, tau_f = 1.2 sign(v) + 57.3 v), recovered from starts 20-30 % off.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from plant_sim.__main__ import main
from plant_sim.errors import ScenarioError
from plant_sim.identification import (
    SECTION_IX_CYCLE_S,
    SECTION_IX_PARAMETERS,
    SECTION_IX_POINTS,
    IdentifyOptions,
    bench_identify,
    identify,
    section_ix_axis,
    section_ix_trace,
)
from plant_sim.physics.model import KernelOptions
from tests.command_line import exit_status
from virtual_bus.formats.axis import AxisConfig, load_axis
from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import Trace
from virtual_bus.shipped import PAPER_AXIS

TRUTH = {"mechanics.load_mass": 6554.2, "friction.coulomb": 1.2, "friction.viscous": 57.3}
TOLERANCE = 0.02
#: Data and model at the kernel's default step (the same for both).
OPTIONS = IdentifyOptions(kernel=KernelOptions())


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return section_ix_axis(PAPER_AXIS)


@pytest.fixture(scope="module")
def trace(axis: AxisConfig) -> Trace:
    return section_ix_trace(axis, noise=0.005, seed=1)


def test_section_ix_trace_is_the_papers_setting(axis: AxisConfig, trace: Trace) -> None:
    assert len(trace) == SECTION_IX_POINTS
    assert trace.time[1] - trace.time[0] == pytest.approx(SECTION_IX_CYCLE_S)
    assert {k: axis.value(k) for k in TRUTH} == TRUTH
    assert axis.mechanics.antiresonance == 600.0 and axis.mechanics.backlash is None


@pytest.mark.parametrize(
    "factors",
    [(1.25, 0.75, 0.75), (0.8, 1.3, 1.2), (0.7, 1.2, 1.3)],
    ids=["mass_high", "mass_low", "mass_low_friction_high"],
)
def test_recovers_mass_and_friction_within_2_percent(
    axis: AxisConfig, trace: Trace, factors: tuple[float, float, float]
) -> None:
    start = {k: f * TRUTH[k] for k, f in zip(SECTION_IX_PARAMETERS, factors, strict=True)}
    result = identify(trace, axis, start, OPTIONS)
    for key, true in TRUTH.items():
        assert result.values[key] == pytest.approx(true, rel=TOLERANCE), key
        assert abs(result.start[key] / true - 1.0) >= 0.2 - 1e-9  # really 20-30 % off
    assert result.cost < 0.01 * result.cost_start
    assert result.axis.value("mechanics.load_mass") == result.values["mechanics.load_mass"]


def test_identify_refuses_bad_input(axis: AxisConfig, trace: Trace) -> None:
    no_coulomb = axis.with_values({"friction.coulomb": None})
    with pytest.raises(ScenarioError, match=r"--start friction\.coulomb=VALUE"):
        identify(trace, no_coulomb, None, OPTIONS)
    with pytest.raises(ScenarioError, match="not identified"):
        identify(trace, axis, {"friction.stribeck": 1.0}, OPTIONS)
    with pytest.raises(AxisFileError, match=r"mechanics\.mass"):
        identify(trace, axis, None, IdentifyOptions(parameters=("mechanics.mass",)))
    with pytest.raises(ScenarioError, match=r"sampled every 0\.0025 s"):
        identify(trace, axis.with_values({"control.position_cycle": 0.001}), None, OPTIONS)
    with pytest.raises(ScenarioError, match="xatol"):
        IdentifyOptions(xatol=0.0)


def test_bench_reports_injected_clock_and_accuracy() -> None:
    ticks = iter([10.0, 12.5])
    bench = bench_identify(PAPER_AXIS, clock=lambda: next(ticks))
    assert bench.elapsed_s == 2.5
    assert bench.seconds_per_simulation == pytest.approx(2.5 / bench.evaluations)
    assert all(abs(e) < TOLERANCE for e in bench.relative_errors.values())


def test_cli_writes_identified_axis_and_summary(
    tmp_path: Path, trace: Trace, capsys: pytest.CaptureFixture[str]
) -> None:
    recording, fitted, summary = tmp_path / "ix.csv", tmp_path / "fit.toml", tmp_path / "s.json"
    trace.to_csv(recording)
    argv = ["identify", str(recording), "--axis", str(PAPER_AXIS), "--position-cycle", "0.0025"]
    argv += ["--drop", "mechanics.backlash", "--substeps", "1"]
    argv += ["--start", "mechanics.load_mass=8000", "--start", "friction.coulomb=0.9"]
    argv += ["--out", str(fitted), "--json", str(summary)]
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads(summary.read_text())
    identified = load_axis(fitted)
    for key, true in TRUTH.items():
        assert identified.value(key) == pytest.approx(true, rel=TOLERANCE)
        assert printed["parameters"][key]["identified"] == identified.value(key)
    assert identified.mechanics.backlash is None


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--start", "friction.coulomb"], "expected KEY=VALUE"),
        (["--start", "friction.stribeck=1"], "not identified"),
        (["--drop", "mechanics.mass"], "unknown axis key"),
        (["--substeps", "0"], "allowed 1..10000"),
    ],
)
def test_cli_bad_arguments_exit_2(
    tmp_path: Path,
    trace: Trace,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    recording = tmp_path / "ix.csv"
    trace.to_csv(recording)
    argv = ["identify", str(recording), "--axis", str(PAPER_AXIS), "--position-cycle", "0.0025"]
    assert exit_status(main, [*argv, *extra]) == 2
    err = capsys.readouterr().err  # a progress line may come first (stderr, not a terminal)
    assert message in err and "Traceback" not in err


def test_signed_key_crosses_zero(axis: AxisConfig) -> None:
    """disturbance.constant_torque may take either sign: from a start of the wrong sign the
    search still finds the load torque that generated the trace."""
    loaded = axis.with_values({"disturbance.constant_torque": 2.0})
    trace = section_ix_trace(loaded, noise=0.005, seed=2)
    options = IdentifyOptions(parameters=("disturbance.constant_torque",), kernel=KernelOptions())
    result = identify(trace, loaded, {"disturbance.constant_torque": -1.0}, options)
    assert result.values["disturbance.constant_torque"] == pytest.approx(2.0, rel=TOLERANCE)
    with pytest.raises(ScenarioError, match="start != 0"):
        identify(trace, loaded, {"disturbance.constant_torque": 0.0}, options)

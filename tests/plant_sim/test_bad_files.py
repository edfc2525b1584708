"""Mutated axis files, traces and drive profiles (``tests/mutations/``) through what the
simulator builds from them and through its command line (issue 20, bad files).

An accepted axis file must give an :class:`AxisPlant` whose outputs stay finite, a
:class:`SimulatedDrive` and a replay input (``prepare_replay``), or be refused by them with the
package's own error in one line; the fleet monitor's streaming reader must refuse what
``read_trace`` refuses, except where docs/trace-file.md says it differs; a sample through
``python -m diagnosis simulate/identify/diagnose/force_error/drive`` ends in one error line.
"""

from __future__ import annotations

import math
import random
import uuid
import warnings
from pathlib import Path

import can
import pytest

from bridge.errors import BridgeError
from diagnosis.__main__ import main as diagnosis_main
from diagnosis.errors import DiagnosisError
from diagnosis.replay import prepare_replay
from fleet.candump import layout_for
from fleet.errors import FleetError
from fleet.readers import OPTIONAL, read_trace_chunks
from plant_sim.__main__ import main as plant_sim_main
from plant_sim.drive import DriveConfig, SimulatedDrive
from plant_sim.errors import PlantSimError
from plant_sim.physics.model import AxisPlant
from tests import mutations
from virtual_bus.formats.axis import AxisConfig, AxisKind, load_axis
from virtual_bus.formats.drive_profile import load_profile
from virtual_bus.formats.errors import DriveProfileError, FormatError
from virtual_bus.formats.trace import REQUIRED_COLUMNS, read_trace
from virtual_bus.shipped import PAPER_AXIS

ERRORS = (FormatError, PlantSimError, DiagnosisError, FleetError, BridgeError)
#: where a command line takes the mutated file
X = object()


def _assert_clean(findings: mutations.Findings) -> None:
    problems = findings.problems()
    assert not problems, f"{findings.summary()}:\n" + "\n".join(problems)


def _plant_outputs(axis: AxisConfig) -> tuple[float, float, float]:
    """Motor position, motor speed and load position after 20 cycles at 10 rad/s."""
    plant = AxisPlant(axis)
    for _ in range(20):
        plant.advance(speed_setpoint_rad_s=10.0)
    return plant.motor_position_rad, plant.motor_speed_rad_s, plant.load_position


def _drive(axis: AxisConfig) -> None:
    bus = can.Bus(interface="virtual", channel=f"bad-{uuid.uuid4().hex[:8]}")
    try:
        SimulatedDrive(bus, 2, axis, DriveConfig())
    finally:
        bus.shutdown()


@pytest.fixture(scope="module")
def traces(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return mutations.trace_seeds(tmp_path_factory.mktemp("seeds"))


def test_accepted_axis_files_build_a_plant_a_drive_and_a_replay(
    tmp_path: Path, traces: list[Path]
) -> None:
    findings = mutations.load_each(
        mutations.axis_mutants(), tmp_path, ".toml", load_axis, (FormatError,)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recording = read_trace(traces[0])
    for m, axis in findings.accepted.items():
        uses = {
            "plant": _plant_outputs,
            "drive": _drive,
            "replay": lambda a: prepare_replay(recording, a, source=traces[0].name),
        }
        for what, use in uses.items():
            label = f"{m.label} ({what})"
            ok, result = mutations.attempt(findings, label, lambda u=use, a=axis: u(a), ERRORS)
            if ok and what == "plant" and not all(math.isfinite(v) for v in result):
                findings.accepted_invalid.append(f"{label}: the simulated axis gives {result}")
    _assert_clean(findings)
    assert len(findings.accepted) > 100


def _monitor_may_differ(m: mutations.Mutant) -> bool:
    """Where docs/trace-file.md lets the fleet monitor's reader differ from read_trace: an
    empty/NaN/inf cell of an optional column it reads is a missing sample, columns it does
    not read are not looked at, and it refuses a time step that cannot be seconds (read_trace
    warns)."""
    read = {*REQUIRED_COLUMNS, *OPTIONAL}
    if m.what.startswith("time in") or m.what == "latin-1 byte in a cell":
        return True
    if m.names and not read & set(m.names):
        return True
    missing = ("empty cell", "nan cell", "inf cell", "-inf cell")
    return set(m.names) <= set(OPTIONAL) and (
        m.what.startswith(missing) or m.what.endswith("cell in the last row empty")
    )


def test_trace_mutants_through_the_replay_and_the_monitors_reader(
    tmp_path: Path, traces: list[Path]
) -> None:
    mutants = mutations.mutants_of(traces, mutations.trace_mutants, 200)
    paper = load_axis(PAPER_AXIS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        findings = mutations.load_each(mutants, tmp_path, ".csv", read_trace, (FormatError,))
        monitor = mutations.load_each(
            mutants, tmp_path, ".csv", lambda p: sum(len(c) for c in read_trace_chunks(p)), ERRORS
        )
        for m, trace in findings.accepted.items():
            mutations.attempt(findings, m.label, lambda t=trace: prepare_replay(t, paper), ERRORS)
    _assert_clean(findings)
    assert not monitor.tracebacks and not monitor.bad_messages
    differ = [
        f"{m.label}: read_trace {'accepts' if m in findings.accepted else 'refuses'}, "
        f"the monitor {'accepts' if m in monitor.accepted else 'refuses'}"
        for m in mutants
        if (m in findings.accepted) != (m in monitor.accepted) and not _monitor_may_differ(m)
    ]
    assert not differ, "\n".join(differ)


def test_profile_mutants_give_the_monitor_a_scaling_or_one_line(tmp_path: Path) -> None:
    mutants = mutations.profile_mutants()
    loaded = mutations.load_each(mutants, tmp_path, ".toml", load_profile, (DriveProfileError,))
    layouts = mutations.load_each(
        mutants, tmp_path, ".toml", lambda p: layout_for(AxisKind.LINEAR, p), ERRORS
    )
    _assert_clean(loaded)
    _assert_clean(layouts)
    assert loaded.accepted.keys() == layouts.accepted.keys()
    for layout in layouts.accepted.values():
        assert math.isfinite(layout.rad_per_increment) and layout.rad_per_increment > 0
        assert math.isfinite(layout.rad_s_per_velocity_unit)


def _sample(mutants: list[mutations.Mutant], k: int, seed: int) -> list[mutations.Mutant]:
    return random.Random(seed).sample(mutants, min(k, len(mutants)))


def main(argv: list[str]) -> int:
    """The command line a user types: the diagnosis's commands (simulate, diagnose) are
    ``python -m diagnosis``'s, the others the simulator's."""
    package = diagnosis_main if argv[0] in ("simulate", "diagnose") else plant_sim_main
    return package(argv)


def test_a_sample_through_the_command_line(tmp_path: Path, traces: list[Path]) -> None:
    """Refused files: one error line naming the file, exit 2, from every command that reads
    them; accepted ones through the quick commands (simulate, force_error)."""
    findings = mutations.Findings()
    axes = mutations.load_each(
        mutations.axis_mutants(), tmp_path, ".toml", load_axis, (FormatError,)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recordings = mutations.load_each(
            mutations.mutants_of(traces, mutations.trace_mutants, 200),
            tmp_path,
            ".csv",
            read_trace,
            (FormatError,),
        )
    sine, paper, out = str(traces[0]), str(PAPER_AXIS), str(tmp_path / "sim.csv")
    diag = str(tmp_path / "diagnosis")
    # (mutants of, only where the reader refused: a good file would run long, argv); X: the file
    commands = [
        ("axis", False, ["simulate", "--axis", X, "--like", sine, "--out", out]),
        ("axis", False, ["force_error", sine, "--axis", X]),
        ("axis", True, ["identify", sine, "--axis", X]),
        ("axis", True, ["diagnose", sine, "--axis", X, "--out", diag]),
        ("axis", True, ["drive", "--interface", "virtual", "--channel", "x", "--axis", X]),
        ("trace", False, ["simulate", "--axis", paper, "--like", X, "--out", out]),
        ("trace", False, ["force_error", X, "--axis", paper]),
        ("trace", True, ["identify", X, "--axis", paper]),
        ("trace", True, ["diagnose", X, "--axis", paper, "--out", diag]),
    ]
    runs = []
    for kind, found, suffix, refused, accepted in (
        ("axis", axes, ".toml", 20, 6),
        ("trace", recordings, ".csv", 24, 6),
    ):
        chosen = _sample(list(found.refused), refused, 1)
        for m in chosen + _sample(list(found.accepted), accepted, 2):
            path = m.write(tmp_path, suffix)
            bad = path.name if m in found.refused else ""
            runs += [
                (m, bad, [str(path) if a is X else a for a in argv])
                for of, slow, argv in commands
                if of == kind and (bad or not slow)
            ]
    for m, bad, argv in runs:
        code = mutations.run_cli(findings, m.label, main, [*argv, "--quiet"], bad)
        assert code in (0, 2, None) and (code == 2 or not bad), (m.label, argv)
    _assert_clean(findings)

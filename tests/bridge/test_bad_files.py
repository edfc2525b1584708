"""Mutated drive profiles, DCF files and axis files (``tests/mutations/``) through the
bridge's readers and command line (issue 20, bad files).

``load_profile`` and ``read_dcf`` accept each mutant or refuse it with their errors
(:class:`DriveProfileError`, :class:`BridgeError`)
in one line naming the file and the key or section; never a builtin error; what
docs/commissioning.md and CiA 306 call invalid is refused. The DCF files are the ones
``python -m bridge config dump`` writes of the bridge and of the simulated drive. Accepted axis
files give :meth:`BridgeParams.for_axis` parameters or its ParameterError; a sample through
``python -m bridge busload/run/config load`` ends in one error line, exit 2, nothing sent.
"""

from __future__ import annotations

import random
from pathlib import Path

import canopen
import pytest

from bridge import od as objdict
from bridge.__main__ import main
from bridge.commission.dcf import read_dcf
from bridge.errors import BridgeError
from bridge.params import BridgeParams
from plant_sim.drive.od import DEFAULT_EDS_PATH as DRIVE_EDS
from regulator.errors import RegulatorError
from tests import mutations
from tests.bridge.test_config_command import Nodes, nodes, run, writable_snapshot
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.drive_profile import load_profile
from virtual_bus.formats.errors import DriveProfileError, FormatError
from virtual_bus.shipped import PAPER_AXIS

__all__ = ["nodes"]  # the fixture: a bridge and a simulated drive on one bus

EDS = {1: objdict.DEFAULT_EDS_PATH, 2: DRIVE_EDS}


def _assert_clean(findings: mutations.Findings) -> None:
    problems = findings.problems()
    assert not problems, f"{findings.summary()}:\n" + "\n".join(problems)


def _sample(mutants: list[mutations.Mutant], k: int, seed: int) -> list[mutations.Mutant]:
    return random.Random(seed).sample(mutants, min(k, len(mutants)))


def test_drive_profile_mutants_are_accepted_or_refused_in_one_line(tmp_path: Path) -> None:
    mutants = mutations.profile_mutants()
    assert len(mutants) > 400
    findings = mutations.load_each(mutants, tmp_path, ".toml", load_profile, (DriveProfileError,))
    _assert_clean(findings)


def test_accepted_axis_files_give_bridge_parameters_or_one_line(tmp_path: Path) -> None:
    findings = mutations.load_each(
        mutations.axis_mutants(), tmp_path, ".toml", load_axis, (FormatError,)
    )
    for m, axis in findings.accepted.items():
        # the regulator's own rules (section VII) refuse with its error, as RegulatorConfig
        errors = (BridgeError, RegulatorError)
        mutations.attempt(findings, m.label, lambda a=axis: BridgeParams.for_axis(a), errors)
    _assert_clean(findings)


def test_dcf_mutants_are_accepted_or_refused_and_load_sends_nothing(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    mutants: list[mutations.Mutant] = []
    for node_id in (1, 2):
        dcf = tmp_path / f"node{node_id}.dcf"
        assert run(nodes.argv("dump", node_id, "--out", str(dcf)), capsys)[0] == 0
        mutants += mutations.dcf_mutants(dcf.name, dcf.read_text(), 300 + node_id)
    assert len(mutants) > 300
    ods = {n: canopen.import_od(str(EDS[n]), n) for n in EDS}

    def load(path: Path) -> object:
        node_id = int(path.name[len("node")])
        return read_dcf(path, ods[node_id], node_id)

    findings = mutations.load_each(mutants, tmp_path, ".dcf", load, (BridgeError,))
    _assert_clean(findings)
    cli = mutations.Findings()
    before = {n: writable_snapshot(nodes.node(n)) for n in EDS}
    for m in _sample(list(findings.refused), 16, 5):
        path = m.write(tmp_path, ".dcf")
        node_id = int(path.name[len("node")])
        argv = nodes.argv("load", node_id, "--eds", str(EDS[node_id]), str(path))
        assert mutations.run_cli(cli, m.label, main, argv, path.name) in (2, None), m.label
    _assert_clean(cli)
    assert {n: writable_snapshot(nodes.node(n)) for n in EDS} == before


def test_a_sample_of_axis_files_and_profiles_through_the_command_line(tmp_path: Path) -> None:
    findings = mutations.Findings()
    axes = mutations.load_each(
        mutations.axis_mutants(), tmp_path, ".toml", load_axis, (FormatError,)
    )
    profiles = mutations.load_each(
        mutations.profile_mutants(), tmp_path, ".toml", load_profile, (DriveProfileError,)
    )
    run_args = ["run", "--interface", "virtual", "--channel", "nobody", "--seconds", "0.01"]
    for m in _sample(list(axes.refused), 20, 6) + _sample(list(axes.accepted), 6, 7):
        path = str(m.write(tmp_path, ".toml"))
        bad = Path(path).name if m in axes.refused else ""
        code = mutations.run_cli(findings, m.label, main, ["busload", "--axis", path], bad)
        assert code in (0, 2, None) and (code == 2) == bool(bad), m.label
        if bad:
            code = mutations.run_cli(findings, m.label, main, [*run_args, "--axis", path], bad)
            assert code in (2, None), m.label
    paper = str(PAPER_AXIS)
    for m in _sample(list(profiles.refused), 20, 8):
        path = m.write(tmp_path, ".toml")
        argv = [*run_args, "--axis", paper, "--drive-profile", str(path)]
        assert mutations.run_cli(findings, m.label, main, argv, path.name) in (2, None), m.label
    _assert_clean(findings)


# --- a file given as an EDS that is not one ---------------------------------------------------
def _not_eds_files(tmp_path: Path) -> dict[str, Path]:
    """Files a user may give as ``--eds`` by mistake: a drive profile (TOML) renamed, an INI
    file of another kind, an EDS cut before its objects, a binary file, an empty file."""
    drive_eds = DRIVE_EDS.read_text(encoding="ascii")
    files = {
        "toml": Path("config/drives/simdrive.toml").read_text(encoding="utf-8"),
        "other ini": "[drive]\nname = x\n[pdo]\ntpdos = 1\n",
        "no objects": drive_eds[: drive_eds.index("[1000]")],
        "no [FileInfo]": drive_eds.replace("[FileInfo]", "[Info]"),
        "empty": "",
    }
    out = {what: tmp_path / f"{what.replace(' ', '_')}.eds" for what in files}
    for what, text in files.items():
        out[what].write_text(text, encoding="utf-8")
    binary = tmp_path / "binary.eds"
    binary.write_bytes(bytes(range(256)))
    return {**out, "binary": binary}


@pytest.mark.parametrize("command", ["probe", "config"])
def test_a_file_that_is_not_an_eds_is_refused_before_any_bus_opens(
    command: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``bridge probe --eds`` / ``bridge config --eds`` with a file that is not an EDS: one
    line naming the file and what an EDS has, exit 2, and no bus opened (python canopen's
    import_od reads such files into an empty dictionary: a probe then blamed the drive)."""
    from bridge import probe as probe_module
    from bridge.commission import command as config_module
    from tests.command_line import refused_in_one_line

    def no_bus(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("a bus was opened for a file that is not an EDS")

    monkeypatch.setattr(probe_module, "open_bus", no_bus)
    monkeypatch.setattr(config_module, "open_bus", no_bus)
    bus = ["--interface", "virtual", "--channel", "bad-eds"]
    for what, path in _not_eds_files(tmp_path).items():
        if command == "probe":
            argv = ["probe", *bus, "--drive-id", "2", "--eds", str(path)]
        else:
            argv = ["config", "get", *bus, "--node-id", "2", "--eds", str(path), "6041h"]
        line = refused_in_one_line(main, argv, capsys)
        assert f"{path}: not an EDS: " in line, (what, line)
        assert "an EDS (CiA 306) has [FileInfo], [DeviceInfo], [MandatoryObjects]" in line


def test_vendor_and_project_eds_files_pass_the_check() -> None:
    """Every EDS the project reads is one: its own, the vendor files (CRLF, lower-case hex,
    EDSVersion 4), CANopenNode's demo (where built)."""
    from tests.adapt_helpers import VENDOR_EDS
    from virtual_bus.formats.eds import check_eds_file

    files = [objdict.DEFAULT_EDS_PATH, DRIVE_EDS, Path("tests/data/cia406_encoder.eds")]
    files += sorted(VENDOR_EDS.glob("*.eds"))
    for path in files:
        check_eds_file(path)

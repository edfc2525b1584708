"""``python -m diagnosis diagnose``: report files, and bad input -> one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from diagnosis.__main__ import main
from diagnosis.effects import Effect
from diagnosis.synthetic import Case, generate, write_case
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import read_trace


@pytest.fixture(scope="module")
def case_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A short recording of the slide hiding a constant load torque, its nominal axis file,
    and a second recording of the same hidden axis (other excitation) to validate on."""
    d = tmp_path_factory.mktemp("diag")
    gen = generate(Case("slide-load", "slide", Effect.CONSTANT_LOAD_TORQUE, 1016, 10.0))
    csv, toml = write_case(gen, d)
    second = generate(Case("slide-load-2", "slide", Effect.CONSTANT_LOAD_TORQUE, 1017, 10.0))
    second.recording.to_csv(d / "second.csv")
    third = generate(Case("slide-load-3", "slide", Effect.CONSTANT_LOAD_TORQUE, 1018, 6.0))
    third.recording.to_csv(d / "third.csv")
    return csv, toml, d / "second.csv"


def _diagnose(csv: Path, toml: Path, out: Path, *options: str) -> int:
    """``diagnosis diagnose CSV --axis TOML --out OUT --no-progress OPTIONS``."""
    files = [str(csv), "--axis", str(toml), "--out", str(out)]
    return main(["diagnose", *files, "--no-progress", *options])


@pytest.fixture(scope="module")
def report_dir(
    case_files: tuple[Path, Path, Path], tmp_path_factory: pytest.TempPathFactory
) -> Path:
    csv, toml, _ = case_files
    out = tmp_path_factory.mktemp("out") / "report"
    effects = ("constant_load_torque", "asymmetric_friction", "backlash")
    assert _diagnose(csv, toml, out, "--effects", *effects) == 0
    return out


@pytest.mark.slow
def test_report_files(report_dir: Path, case_files: tuple[Path, Path, Path]) -> None:
    csv, _, _ = case_files
    for name in (
        "report.html",
        "report.json",
        "axis_fitted.toml",
        "fit_before.csv",
        "fit_after.csv",
        "report.png",
    ):
        assert (report_dir / name).stat().st_size > 0, name
    report = json.loads((report_dir / "report.json").read_text())
    assert report["left_out"] == ["constant_load_torque"]
    for key in (
        "evidence",
        "closed_loop",
        "datasheet",
        "mismatch",
        "fit_before",
        "fit_after",
        "unexplained",
        "explanation",
        "decision_rule",
    ):
        assert key in report
    tried = {t["effect"] for t in report["evidence"]["tests"]}
    assert tried == {"constant_load_torque", "asymmetric_friction", "backlash"}
    named = [t for t in report["evidence"]["tests"] if t["named"]]
    assert named[0]["estimate"]["disturbance.constant_torque"] > 0
    assert named[0]["p_value"] < report["evidence"]["alpha_per_test"]
    final = report["closed_loop"]["final"]
    assert final["effects"] == ["constant_load_torque"]
    assert final["heldout_cost"] < report["closed_loop"]["within_datasheet"]["heldout_cost"]
    for sig, fit in report["fit_after"].items():
        assert set(fit) >= {"nrmse", "fit_percent"}, sig
    assert (
        report["fit_after"]["motor_torque"]["fit_percent"]
        > (report["fit_before"]["motor_torque"]["fit_percent"])
    )
    assert "constant_load_torque" in report["explanation"]
    fitted = load_axis(report_dir / "axis_fitted.toml")
    assert fitted.disturbance.constant_torque is not None
    recording = read_trace(csv)
    for name in ("fit_before.csv", "fit_after.csv"):
        sim = read_trace(report_dir / name)
        assert set(sim.names) == set(recording.names)
        np.testing.assert_array_equal(sim.time, recording.time)


@pytest.mark.slow
def test_fitted_model_checked_on_a_second_recording(
    report_dir: Path,
    case_files: tuple[Path, Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The fitted axis simulates a second recording of the same hidden axis better than the
    nominal one (``simulate --like``, independent of the fit's own data)."""
    _, toml, second = case_files
    fits = {}
    for label, axis in (("nominal", toml), ("fitted", report_dir / "axis_fitted.toml")):
        out = tmp_path / f"{label}.csv"
        assert (
            main(["simulate", "--axis", str(axis), "--like", str(second), "--out", str(out)]) == 0
        )
        line = capsys.readouterr().out
        fits[label] = float(line.split("motor_torque ")[1].split(" %")[0])
    assert fits["fitted"] > fits["nominal"]


@pytest.mark.slow
def test_validate_with_a_second_recording(
    case_files: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    csv, toml, second = case_files
    out = tmp_path / "rep"
    validate = (str(second), str(second.parent / "third.csv"))
    effects = ("constant_load_torque", "backlash")
    code = _diagnose(csv, toml, out, "--validate", *validate, "--effects", *effects)
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert report["recording"]["validation"] == "2 second recording(s)"
    # the fitted models were scored on the second recordings: the named load torque fits
    # them better than the nominal within its data sheet
    loop = report["closed_loop"]
    assert loop["final"]["heldout_cost"] < loop["within_datasheet"]["heldout_cost"]
    assert report["left_out"] == ["constant_load_torque"]


def test_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as err:
        main(["diagnose", "--help"])
    assert err.value.code == 0
    assert "--validate" in capsys.readouterr().out


def _one_line_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str], *needles: str) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:  # refused by the argument parser (e.g. --out is a file)
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for needle in needles:
        assert needle in err[0]


@pytest.mark.parametrize(
    ("flags", "needles"),
    [
        (["--alpha", "3"], ["alpha = 3"]),
        (["--choice-alpha", "1.5"], ["choice_alpha = 1.5", "(0, 1)"]),
    ],
    ids=["alpha", "choice-alpha"],
)
def test_bad_alpha_exit_2_and_nothing_written(
    case_files: tuple[Path, Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    flags: list[str],
    needles: list[str],
) -> None:
    csv, toml, _ = case_files
    out = tmp_path / "never"
    _one_line_exit_2(
        ["diagnose", str(csv), "--axis", str(toml), "--out", str(out), *flags],
        capsys,
        *needles,
    )
    assert not out.exists()


def test_missing_column_exit_2(
    case_files: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv, toml, _ = case_files
    rec = read_trace(csv)
    bad = tmp_path / "no_torque.csv"
    from virtual_bus.formats.trace import Trace

    Trace({k: v for k, v in rec.columns.items() if k != "motor_torque"}).to_csv(bad)
    out = tmp_path / "never"
    _one_line_exit_2(
        ["diagnose", str(bad), "--axis", str(toml), "--out", str(out)], capsys, "motor_torque"
    )
    assert not out.exists()


def test_axis_and_recording_do_not_fit_exit_2(
    case_files: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The slide closes its loop on the motor; an axis file that says "load" needs a
    load_position column the recording does not have."""
    csv, toml, _ = case_files
    rec = read_trace(csv)
    from virtual_bus.formats.trace import Trace

    no_scale = tmp_path / "no_scale.csv"
    Trace({k: v for k, v in rec.columns.items() if k != "load_position"}).to_csv(no_scale)
    load_fb = tmp_path / "load_fb.toml"
    load_fb.write_text(
        toml.read_text().replace('position_feedback = "motor"', 'position_feedback = "load"')
    )
    out = tmp_path / "never"
    _one_line_exit_2(
        ["diagnose", str(no_scale), "--axis", str(load_fb), "--out", str(out)],
        capsys,
        "load_position",
        "position_feedback",
    )
    assert not out.exists()


def test_out_is_a_file_exit_2(
    case_files: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv, toml, _ = case_files
    out = tmp_path / "file"
    out.write_text("x")
    _one_line_exit_2(
        ["diagnose", str(csv), "--axis", str(toml), "--out", str(out)], capsys, "not a directory"
    )


def test_implausible_units_warn(
    case_files: tuple[Path, Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A motor_speed column in rpm is used as it is but warned about (one line, once); the
    run goes on (here stopped early by a bad option on purpose would hide it, so run it
    short). The recording is checked against the axis file once: the command's check is the
    one the diagnosis goes on from."""
    from diagnosis import engine

    calls: list[str] = []
    real = engine.prepare_replay

    def counted(*args: object, **kwargs: object) -> object:
        calls.append(str(args[2] if len(args) > 2 else kwargs.get("source")))
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(engine, "prepare_replay", counted)
    csv, toml, _ = case_files
    rec = read_trace(csv)
    rpm = tmp_path / "rpm.csv"
    rec.with_columns({"motor_speed": rec["motor_speed"] * 60 / (2 * np.pi)}).to_csv(rpm)
    out = tmp_path / "rep"
    code = main(
        [
            "diagnose",
            str(rpm),
            "--axis",
            str(toml),
            "--out",
            str(out),
            "--no-progress",
            "--max-effects",
            "0",
        ]
    )
    assert code == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "rpm" in err
    assert err.count("warning:") == 1, err
    assert calls == [str(rpm)]

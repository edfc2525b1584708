"""``python -m plant_sim`` (and the replays of ``python -m diagnosis``): outputs of the paper
command; bad input -> one line, exit 2.

Every "one line" below is counted: stderr holds exactly one line (no usage dump, no
traceback, no Python warning with its source line).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from diagnosis.synthetic import slide_axis
from plant_sim.physics.model import KernelOptions
from plant_sim.physics.simulate import References, simulate
from tests.paths import ROOT
from virtual_bus.formats.axis import AxisConfig, dump_axis
from virtual_bus.formats.trace import Trace, read_trace

#: The commands of the diagnosis's package (python -m diagnosis), beside the simulator's.
DIAGNOSIS_COMMANDS = ("simulate", "diagnose", "matrix")


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    package = "diagnosis" if args and args[0] in DIAGNOSIS_COMMANDS else "plant_sim"
    return subprocess.run(
        [sys.executable, "-m", package, *args], cwd=ROOT, capture_output=True, text=True
    )


def _one_line_exit_2(done: subprocess.CompletedProcess[str], *needles: str) -> str:
    lines = done.stderr.splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1, lines
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def paper_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("paper")
    done = _run("paper", "--out", str(out), "--quiet")
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # --quiet: no progress
    return out, done.stdout


def test_paper_writes_figures_summary_and_traces(paper_dir: tuple[Path, str]) -> None:
    out, _ = paper_dir
    for name in ("fig8.png", "fig9.png", "summary.json", "ordinary.csv", "regulated.csv"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["band_hz"] == [6.25, 25.0]
    assert summary["p2p_reduction"] >= 0.9
    ordinary = summary["runs"]["ordinary"]
    assert 6.25 <= ordinary["dominant_frequency_hz"] <= 25.0
    assert summary["as_given"]["ordinary"]["dominant_frequency_hz"] is None
    for run in summary["runs"].values():
        assert {"p2p_following_error", "final_standstill_error"} <= run.keys()


def test_paper_lists_every_file_it_wrote(paper_dir: tuple[Path, str]) -> None:
    """The last stdout line and summary.json name exactly the files in the directory."""
    out, stdout = paper_dir
    on_disk = sorted(p.name for p in out.iterdir())
    assert json.loads((out / "summary.json").read_text())["files"] == on_disk
    assert stdout.splitlines()[-1] == f"wrote {out}/: " + ", ".join(on_disk)


def test_paper_says_what_differs_from_the_paper(paper_dir: tuple[Path, str]) -> None:
    out, stdout = paper_dir
    summary = json.loads((out / "summary.json").read_text())
    assert summary["figures_axis_changes"] == {"friction.viscous": 5.0}
    assert stdout.startswith("note: ") and "friction.viscous = 5.0" in stdout.splitlines()[0]


def test_paper_as_given_runs_are_one_file_because_they_are_identical(
    paper_dir: tuple[Path, str],
) -> None:
    """Without vibration β never reaches β_T: the regulated run of the axis as given is the
    ordinary one (compared here by simulating both again)."""
    from plant_sim.paper.scenarios import run_section_x
    from virtual_bus.formats.axis import load_axis

    out, _ = paper_dir
    axis = load_axis(ROOT / "config" / "paper_axis.toml")
    a, b = run_section_x(axis, False), run_section_x(axis, True)
    assert all(np.array_equal(a[c], b[c]) for c in a.names)
    assert (out / "as_given.csv").exists()
    assert not (out / "as_given_regulated.csv").exists()
    np.testing.assert_array_equal(read_trace(out / "as_given.csv")["lambda"], 1.0)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("paper",), "the following arguments are required: --out"),
        (("paper", "--out", "README.md"), "README.md: exists and is not a directory"),
        (("paper", "--out", "x", "--position-cycle", "-1"), "must be a finite number > 0"),
        (("paper", "--out", "x", "--position-cycle", "nan"), "must be a finite number > 0"),
        (("paper", "--out", "x", "--axis", "nope.toml"), "no such axis file"),
        (("sweep", "--out", "x", "--kv", "25,abc"), "comma-separated numbers"),
        (("sweep", "--out", "x", "--kv", "20", "-30"), "every value must be a finite number > 0"),
        (("bench", "--repeat", "0"), "must be >= 1"),
        (("matrix", "--duration", "1"), "allowed 5..600"),
        (("matrix", "--validate", "4"), "allowed 0..3"),
        (("frobnicate",), "invalid choice"),
        ((), "required: COMMAND"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(args: tuple[str, ...], message: str) -> None:
    _one_line_exit_2(_run(*args), message)


def test_sweep_takes_k_v_with_commas_or_spaces() -> None:
    from cmdline import cli
    from plant_sim.__main__ import COMMANDS

    parser = cli.build_parser("p", "d", cli.load_commands("plant_sim", COMMANDS))
    for argv in (["--kv", "20,30"], ["--kv", "20", "30"]):
        args = parser.parse_args(["sweep", "--out", "x", *argv, "--backlash-mm", "0.1", "0.2"])
        assert args.kv == (20.0, 30.0) and args.backlash_mm == (0.1, 0.2)


def test_bad_axis_file_exits_2_naming_the_key(tmp_path: Path) -> None:
    text = (ROOT / "config" / "paper_axis.toml").read_text().replace("kv = 25.0", "kv = -3.0")
    (tmp_path / "bad.toml").write_text(text)
    done = _run("paper", "--out", str(tmp_path / "o"), "--axis", str(tmp_path / "bad.toml"))
    _one_line_exit_2(done, "control.kv = -3.0")


# --- bad recordings ----------------------------------------------------------------------------
def _axis() -> AxisConfig:
    return slide_axis()


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Trace]:
    d = tmp_path_factory.mktemp("rec")
    ax = _axis()
    cycle = ax.control.position_cycle
    t = np.arange(1500) * cycle
    x = 0.02 * (1 - np.cos(2 * np.pi * t / 1.5))
    sim = simulate(ax, References.from_position(x, cycle), options=KernelOptions())
    cols = ("time", "position_reference", "motor_position", "motor_speed", "motor_torque")
    (d / "axis.toml").write_text(dump_axis(ax))
    return d / "axis.toml", Trace({c: sim[c] for c in cols})


def _commands(axis: Path, rec: Path, out: Path) -> dict[str, tuple[str, ...]]:
    return {
        "simulate": ("simulate", "--axis", str(axis), "--like", str(rec), "--out", str(out)),
        "diagnose": ("diagnose", str(rec), "--axis", str(axis), "--out", str(out.parent / "d")),
        "identify": ("identify", str(rec), "--axis", str(axis)),
        "force_error": ("force_error", str(rec), "--axis", str(axis)),
    }


@pytest.mark.parametrize("command", ["simulate", "diagnose", "identify", "force_error"])
def test_time_in_nanoseconds_is_refused_by_every_replay(
    recording: tuple[Path, Trace], tmp_path: Path, command: str
) -> None:
    """One shared check (trace.check_time_base) instead of a 10 TiB allocation."""
    axis, trace = recording
    rec = tmp_path / "ns.csv"
    trace.with_columns({"time": trace.time * 1e9}).to_csv(rec)
    done = _run(*_commands(axis, rec, tmp_path / "sim.csv")[command])
    line = _one_line_exit_2(done, "time must be in s", "ns?")
    assert "warning" not in line


@pytest.mark.parametrize("command", ["simulate", "identify"])
def test_overflowing_value_is_refused(
    recording: tuple[Path, Trace], tmp_path: Path, command: str
) -> None:
    axis, trace = recording
    torque = trace["motor_torque"].copy()
    torque[5] = 1.7e308
    rec = tmp_path / "huge.csv"
    trace.with_columns({"motor_torque": torque}).to_csv(rec)
    done = _run(*_commands(axis, rec, tmp_path / "sim.csv")[command])
    _one_line_exit_2(done, "line 7, column 'motor_torque': 1.7e+308 is beyond ±1e+150")
    assert not (tmp_path / "sim.csv").exists()


def test_byte_order_mark_is_accepted(recording: tuple[Path, Trace], tmp_path: Path) -> None:
    axis, trace = recording
    rec = tmp_path / "bom.csv"
    trace.to_csv(rec)
    rec.write_bytes(b"\xef\xbb\xbf" + rec.read_bytes())
    np.testing.assert_array_equal(read_trace(rec).time, trace.time)
    done = _run(*_commands(axis, rec, tmp_path / "sim.csv")["simulate"])
    assert done.returncode == 0, done.stderr


def test_numbers_in_messages_are_plain(recording: tuple[Path, Trace], tmp_path: Path) -> None:
    axis, trace = recording
    rec = tmp_path / "back.csv"
    trace.to_csv(rec)
    lines = rec.read_text().splitlines()
    lines[10] = lines[9]  # time repeats on line 11
    rec.write_text("\n".join(lines) + "\n")
    line = _one_line_exit_2(_run(*_commands(axis, rec, tmp_path / "s.csv")["simulate"]))
    assert "line 11, column 'time'" in line and "np.float64" not in line


def test_unit_warning_is_one_plain_line(recording: tuple[Path, Trace], tmp_path: Path) -> None:
    """identify prints the trace's unit warning as ``warning: ...``, not Python's
    ``file:line: TraceWarning`` with the source line; then the one-line error."""
    axis, trace = recording
    rec = tmp_path / "mm.csv"
    trace.with_columns({"motor_torque": trace["motor_torque"] + 2e6}).to_csv(rec)
    done = _run("identify", str(rec), "--axis", str(axis), "--start", "friction.x=1", "-q")
    lines = done.stderr.splitlines()
    assert done.returncode == 2
    assert len(lines) == 2, lines
    assert lines[0].startswith("warning: ") and "motor_torque" in lines[0]
    assert "TraceWarning" not in done.stderr and ".py:" not in done.stderr
    assert lines[1].startswith("python -m plant_sim identify: error: ")


def test_sweep_progress_in_a_log_has_no_bar(tmp_path: Path) -> None:
    """Not on a terminal: one plain line per stage on stderr, no carriage returns."""
    done = _run("sweep", "--out", str(tmp_path), "--kv", "25", "--backlash-mm", "0.1")
    assert done.returncode == 0, done.stderr
    assert "\r" not in done.stderr
    assert done.stderr.splitlines() == [
        line for line in done.stderr.splitlines() if "] plant_sim sweep: " in line
    ]
    assert done.stdout.splitlines()[-1] == (
        f"wrote {tmp_path}/: sweep.csv, sweep.json, sweep.md, sweep.png"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "sweep.csv",
        "sweep.json",
        "sweep.md",
        "sweep.png",
    ]

"""``python -m diagnosis simulate --axis A --like REC --out SIM``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from diagnosis.__main__ import main
from diagnosis.synthetic import slide_axis
from plant_sim.physics.model import KernelOptions
from plant_sim.physics.simulate import References, simulate
from tests.command_line import refused_in_one_line
from virtual_bus.formats.axis import AxisConfig, dump_axis
from virtual_bus.formats.trace import Trace, read_trace


def axis() -> AxisConfig:
    return slide_axis()


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    ax = axis()
    cycle = ax.control.position_cycle
    t = np.arange(3000) * cycle
    x = 0.05 * np.sin(2 * np.pi * t / 1.5) * (1 - np.cos(2 * np.pi * t / 3.0))
    n = len(t)
    dist = np.where(t >= 1.5, 0.05, 0.0)  # steps on a recorded sample
    sim = simulate(
        ax, References(x, References.from_position(x, cycle).speed, dist), options=KernelOptions()
    )
    cols = {
        c: sim[c][::2]
        for c in (
            "time",
            "position_reference",
            "motor_position",
            "motor_speed",
            "motor_torque",
            "disturbance",
        )
    }
    cols["note"] = np.arange(n)[::2].astype(float)
    rec = tmp_path / "rec.csv"
    Trace(cols).to_csv(rec)
    toml = tmp_path / "axis.toml"
    toml.write_text(dump_axis(ax))
    return toml, rec


def test_simulate_like_reproduces_a_recording_of_the_same_axis(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The recording was made by the simulator with this axis (1 ms cycle, kept every 2nd):
    the replay on its time base gives it back; extra columns are kept."""
    toml, rec = files
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--axis", str(toml), "--like", str(rec), "--out", str(out)]) == 0
    assert "motor_torque 100.0 %" in capsys.readouterr().out
    a, b = read_trace(rec), read_trace(out)
    assert a.names == b.names
    np.testing.assert_array_equal(a.time, b.time)
    np.testing.assert_array_equal(a["note"], b["note"])
    for col in ("motor_position", "motor_speed", "motor_torque"):
        np.testing.assert_allclose(b[col], a[col], atol=1e-6 * np.ptp(a[col]))


def test_the_disturbance_column_matters(files: tuple[Path, Path], tmp_path: Path) -> None:
    toml, rec = files
    r = read_trace(rec)
    no_dist = tmp_path / "nodist.csv"
    Trace({k: v for k, v in r.columns.items() if k != "disturbance"}).to_csv(no_dist)
    out1, out2 = tmp_path / "a.csv", tmp_path / "b.csv"
    assert main(["simulate", "--axis", str(toml), "--like", str(rec), "--out", str(out1)]) == 0
    assert main(["simulate", "--axis", str(toml), "--like", str(no_dist), "--out", str(out2)]) == 0
    diff = read_trace(out1)["motor_torque"] - read_trace(out2)["motor_torque"]
    assert np.max(np.abs(diff)) > 0.03  # the 0.05 N m push is held by the motor


def test_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as err:
        main(["simulate", "--help"])
    assert err.value.code == 0
    assert "--like" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        ("no_reference", "position_reference"),
        ("short", "at least 100"),
        ("nan", "NaN"),
        ("load_feedback", "load_position"),
        ("bad_dir", "does not exist"),
    ],
)
def test_bad_input_exit_2(
    files: tuple[Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    mutate: str,
    needle: str,
) -> None:
    toml, rec = files
    r = read_trace(rec)
    like = tmp_path / "like.csv"
    out = tmp_path / "sim.csv"
    cols = dict(r.columns)
    if mutate == "no_reference":
        del cols["position_reference"]
    elif mutate == "short":
        cols = {k: v[:50] for k, v in cols.items()}
    elif mutate == "nan":
        cols["motor_torque"] = cols["motor_torque"].copy()
        cols["motor_torque"][7] = np.nan
    elif mutate == "load_feedback":
        toml.write_text(toml.read_text().replace('"motor"', '"load"'))
    elif mutate == "bad_dir":
        out = tmp_path / "missing" / "sim.csv"
    Trace(cols).to_csv(like)
    argv = ["simulate", "--axis", str(toml), "--like", str(like), "--out", str(out)]
    assert needle in refused_in_one_line(main, argv, capsys)
    assert not out.exists()

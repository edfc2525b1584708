"""``python -m hil plot``: the panels' units and data ranges against the trace's own numbers
and an analytic sine (its spectrum peak), the HTML self-contained, a non-trace refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil.__main__ import main
from hil.plot import PlotSetup, panels
from virtual_bus.formats.trace import Trace, read_trace

KR = 314.1592653589793  # config/paper_axis.toml's k_r
AMP_M, F_HZ = 5e-6, 10.0


def _trace(path: Path) -> Path:
    t = np.arange(2000) * 1e-3
    ref = 0.01 * t
    load = ref - AMP_M * np.sin(2 * np.pi * F_HZ * t)
    Trace(
        {
            "time": t,
            "position_reference": ref,
            "motor_position": (load + 1e-6) * KR,
            "load_position": load,
            "motor_speed": np.full_like(t, 3.14),
            "motor_torque": np.sin(t),
            "beta": np.abs(np.sin(t)),
            "lambda": np.ones_like(t),
        }
    ).to_csv(path)
    return path


def test_units_ranges_and_band(tmp_path: Path) -> None:
    trace = read_trace(_trace(tmp_path / "t.csv"))
    plots = {p.ylabel: p for p in panels(trace, PlotSetup("m", KR, 50.0))}
    err = plots["following error, µm"].curves[0].values
    assert np.max(err) == pytest.approx(AMP_M * 1e6, rel=1e-3)
    defl = plots["motor / k_r − load, µm"].curves[0].values
    assert np.allclose(defl, 1.0, atol=1e-6)  # the 1 µm offset put between the two systems
    pos = plots["position, mm"].curves[0].values
    assert pos.max() == pytest.approx(trace.columns["position_reference"].max() * 1e3)
    spec = plots["amplitude, µm"]
    peak = int(np.argmax(spec.curves[0].values))
    assert spec.x[peak] == pytest.approx(F_HZ, abs=0.5)  # the sine's frequency
    assert spec.curves[0].values[peak] == pytest.approx(AMP_M * 1e6, rel=0.05)
    assert spec.band_hz == (12.5, 50.0)  # eq. 13: k_v/4..k_v
    for p in plots.values():
        assert any(u in p.ylabel for u in ("µm", "mm", "N m", "rad/s", "1")), p.ylabel


def test_command_writes_self_contained_html(tmp_path: Path, capsys) -> None:
    path = _trace(tmp_path / "t.csv")
    assert main(["plot", str(path), "--axis", "config/paper_axis.toml"]) == 0
    page = (tmp_path / "t.html").read_text(encoding="utf-8")
    assert "http" not in page and "data:image/png;base64," in page
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_not_a_trace_is_one_line_exit_2(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("hi\n")
    assert main(["plot", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "time" in err
    assert not (tmp_path / "bad.png").exists()


def test_emps_dataset_trace(tmp_path: Path) -> None:
    """A dataset's trace (EMPS, no load_position): positions and following error against the
    trace's own columns, the band from the axis file's k_v."""
    from plant_sim.datasets.emps import import_emps
    from virtual_bus.formats.axis import load_axis
    from virtual_bus.shipped import SHARED_DIR

    mat = SHARED_DIR / "data" / "emps" / "DATA_EMPS.mat"
    if not mat.exists():
        pytest.skip(f"EMPS data not found at {mat}")
    import_emps([mat], tmp_path)
    csv = tmp_path / "DATA_EMPS.csv"
    axis_path = Path(__file__).parents[2] / "config" / "emps_nominal.toml"
    axis = load_axis(axis_path)
    trace = read_trace(csv)
    cols = trace.columns
    plots = {
        p.ylabel: p for p in panels(trace, PlotSetup("m", axis.transmission_ratio, axis.control.kv))
    }
    expect = (cols["position_reference"] - cols["motor_position"] / axis.transmission_ratio) * 1e6
    assert np.allclose(plots["following error, µm"].curves[0].values, expect)
    assert plots["amplitude, µm"].band_hz == (axis.control.kv / 4, axis.control.kv)
    assert "motor / k_r − load, µm" not in plots  # no load column: no empty panel
    assert main(["plot", str(csv), "--axis", str(axis_path)]) == 0
    assert "http" not in (tmp_path / "DATA_EMPS.html").read_text(encoding="utf-8")

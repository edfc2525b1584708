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


def test_xl330_dataset_trace(tmp_path: Path) -> None:
    """BAM's XL330 (a rotary axis, no load scale, k_r = 1): positions in rad, the following
    error in mrad from the trace's own columns, the band from the imported axis file."""
    from plant_sim.datasets.xl330 import import_xl330
    from virtual_bus.formats.axis import load_axis
    from virtual_bus.shipped import SHARED_DIR

    logs = sorted((SHARED_DIR / "data" / "bam_xl330").glob("*.json"))
    if not logs:
        pytest.skip(f"XL330 data not found at {SHARED_DIR / 'data' / 'bam_xl330'}")
    done = import_xl330(logs[:1], tmp_path)
    csv = done.traces[0].target
    axis_path = next(p for p in done.axis_files if p.name.endswith("_nominal.toml"))
    axis = load_axis(axis_path)
    trace = read_trace(csv)
    cols = trace.columns
    setup = PlotSetup("rad", axis.transmission_ratio, axis.control.kv)
    plots = {p.ylabel: p for p in panels(trace, setup)}
    expect = (cols["position_reference"] - cols["motor_position"] / axis.transmission_ratio) * 1e3
    assert np.allclose(plots["following error, mrad"].curves[0].values, expect)
    assert "position, rad" in plots and "torque, N m" in plots
    assert plots["amplitude, mrad"].band_hz == (axis.control.kv / 4, axis.control.kv)
    assert main(["plot", str(csv), "--axis", str(axis_path)]) == 0
    assert "http" not in csv.with_suffix(".html").read_text(encoding="utf-8")


def test_a_bridge_trace(tmp_path: Path, capsys) -> None:
    """``bridge run --trace`` against the simulated drive (lockstep, virtual bus): the
    following error on the load scale and the deflection between the measuring systems are
    the trace's own columns in µm; the run's eq. 7 error v / k_v is what the panel peaks at."""
    import uuid

    from bridge.__main__ import main as bridge_main
    from plant_sim.drive import DriveConfig, SimulatedDrive
    from virtual_bus import BusConfig, Interface, open_bus
    from virtual_bus.formats.axis import load_axis

    axis_path = Path(__file__).parents[2] / "config" / "paper_axis.toml"
    axis = load_axis(axis_path)
    channel = f"plot-{uuid.uuid4().hex[:10]}"
    bus = open_bus(BusConfig(interface=Interface.VIRTUAL, channel=channel))
    drive = SimulatedDrive(bus, 2, axis, DriveConfig())
    drive.start()
    csv = tmp_path / "bridge.csv"
    feed = 0.02
    try:
        argv = ["run", "--interface", "virtual", "--channel", channel, "--axis", str(axis_path)]
        argv += ["--move", f"target=0.01,feed={feed}", "--hold", "0.3", "--clock", "lockstep"]
        assert bridge_main([*argv, "--trace", str(csv)]) == 0
    finally:
        drive.stop()
        bus.shutdown()
    capsys.readouterr()
    trace = read_trace(csv)
    cols = trace.columns
    plots = {
        p.ylabel: p for p in panels(trace, PlotSetup("m", axis.transmission_ratio, axis.control.kv))
    }
    error = plots["following error, µm"].curves[0].values
    assert np.allclose(error, (cols["position_reference"] - cols["load_position"]) * 1e6)
    deflection = plots["motor / k_r − load, µm"].curves[0].values
    expect = (cols["motor_position"] / axis.transmission_ratio - cols["load_position"]) * 1e6
    assert np.allclose(deflection, expect)
    assert np.max(error) == pytest.approx(feed / axis.control.kv * 1e6, rel=0.05)  # eq. 7
    assert {"β, rad/s", "λ, 1", "torque, N m"} <= set(plots)
    assert main(["plot", str(csv), "--axis", str(axis_path)]) == 0
    assert (tmp_path / "bridge.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

"""Fleet monitor (fleet): episodes, verdicts, lost motion, streaming, Dask, CLI.

Independent references: analytic signals (a sinusoidal following error of known frequency,
an ideal dead-zone backlash of known width), python-can's own candump log reader,
can-utils' ``log2asc`` where installed, and the demo fleet's known truth.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import can
import numpy as np
import pyarrow.parquet as pq
import pytest

from fleet import candump, readers
from fleet.analyse import analyse
from fleet.demo_fleet import FleetSpec, generate, simulate_recording, write_candump
from fleet.episodes import Verdict
from fleet.sources import RecordingKind, Source, discover, load_axis_map
from tests.paths import ROOT
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import Trace
from virtual_bus.shipped import PAPER_AXIS

KV = 25.0  # paper axis
KR = 100 * math.pi


def _source(path: Path, kind: RecordingKind = RecordingKind.TRACE) -> Source:
    return Source(path, kind, "M", "X", None, PAPER_AXIS)


def _write(path: Path, cols: dict[str, np.ndarray]) -> Path:
    Trace(cols).to_csv(path)
    return path


def _steady_move(n: int, dt: float, speed: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * dt
    return t, speed * t


def _rigid_recording(path: Path, t: np.ndarray, x_ref: np.ndarray, load: np.ndarray) -> Path:
    """A trace of the paper axis moving rigidly (motor = k_r · load) with no torque."""
    cols = {
        "time": t,
        "position_reference": x_ref,
        "motor_position": load * KR,
        "load_position": load,
        "motor_torque": np.zeros_like(t),
    }
    return _write(path, cols)


# --- episodes against an analytic vibration ---------------------------------------------------
@pytest.mark.parametrize(
    ("freq_hz", "verdict"), [(12.0, Verdict.IN_BAND), (60.0, Verdict.OUTSIDE_BAND)]
)
def test_sinusoidal_following_error_is_found_at_its_frequency(tmp_path, freq_hz, verdict):
    dt = 0.001
    t, x_ref = _steady_move(10_000, dt, 0.02)
    amp = 20e-6  # m of following error oscillation
    vib = np.where(t > 3.0, amp * np.sin(2 * np.pi * freq_hz * t), 0.0)
    load = x_ref - 0.02 / KV - vib  # steady following error v/kv (eq. 1) plus the vibration
    r = analyse(_source(_rigid_recording(tmp_path / "v.csv", t, x_ref, load)))
    assert r.ok, r.error
    assert r.verdict is verdict
    (ep,) = r.episodes
    assert ep.frequency_hz == pytest.approx(freq_hz, rel=0.01)
    assert ep.amplitude == pytest.approx(amp, rel=0.1)  # eq. 7: u = k_r k_v e
    assert 2.9 < ep.start_s < 3.4 and ep.end_s > 9.0
    assert (ep.band_low_hz, ep.band_high_hz) == (KV / 4, KV)


def test_calm_axis_has_no_episode(tmp_path):
    dt = 0.001
    t, x_ref = _steady_move(5000, dt, 0.02)
    rng = np.random.default_rng(0)
    load = x_ref - 0.02 / KV + rng.normal(0, 1e-8, t.size)
    r = analyse(_source(_rigid_recording(tmp_path / "c.csv", t, x_ref, load)))
    assert r.ok and r.verdict is Verdict.NONE and r.episodes == ()


# --- lost motion against an ideal dead zone ---------------------------------------------------
def test_lost_motion_of_an_ideal_dead_zone(tmp_path):
    """Motor leads the load by δ/2 in the direction of motion: lost motion δ at each reversal."""
    dt, delta = 0.001, 37e-6
    t = np.arange(20_000) * dt
    v = 0.02 * np.sign(np.sin(2 * np.pi * t / 5.0 + 0.3))  # four reversals, steady between
    x_ref = np.cumsum(v) * dt
    load = x_ref - v / KV
    motor = (load + 0.5 * delta * np.sign(v)) * KR
    rng = np.random.default_rng(1)
    cols = {
        "time": t,
        "position_reference": x_ref,
        "motor_position": motor,
        "load_position": load + rng.normal(0, 2e-8, t.size),
        "motor_torque": 2.0 * np.sign(v),
    }
    rigid = tmp_path / "rigid.toml"
    text = PAPER_AXIS.read_text()
    rigid.write_text(
        "\n".join(
            line
            for line in text.splitlines()
            if not line.startswith(("antiresonance", "damping_ratio", "backlash"))
        )
    )
    r = analyse(
        Source(_write(tmp_path / "lm.csv", cols), RecordingKind.TRACE, "M", "X", None, rigid)
    )
    assert r.ok, r.error
    assert r.reversals == 7
    assert abs(r.lost_motion - delta) < max(4 * r.lost_motion_uncertainty, 1e-8)
    assert math.isnan(r.backlash)  # rigid axis file: no elastic wind-up to take off


def test_backlash_of_the_simulated_axis_matches_its_truth(tmp_path):
    """Kernel simulation of the paper's axis with δ = 40 µm: lost motion less wind-up ≈ δ."""
    axis = load_axis(PAPER_AXIS).with_values({"mechanics.backlash": 40e-6})
    trace = simulate_recording(axis, np.random.default_rng(2))
    r = analyse(_source(_write(tmp_path / "sim.csv", {c: trace[c] for c in trace.names})))
    assert r.ok, r.error
    assert r.reversals == 3
    assert r.lost_motion > r.backlash  # the wind-up of a compliant axis adds to the free play
    assert r.backlash == pytest.approx(40e-6, abs=0.3e-6)


# --- streaming: chunk boundaries change nothing -----------------------------------------------
def test_results_do_not_depend_on_the_chunk_size(tmp_path, monkeypatch):
    axis = load_axis(PAPER_AXIS).with_values(
        {"mechanics.backlash": 100e-6, "friction.viscous": 5.0}
    )
    trace = simulate_recording(axis, np.random.default_rng(3))
    path = _write(tmp_path / "s.csv", {c: trace[c] for c in trace.names})
    whole = analyse(_source(path))
    monkeypatch.setattr(readers, "CHUNK_ROWS", 997)
    monkeypatch.setattr(readers, "CSV_BLOCK_BYTES", 1 << 16)
    chunked = analyse(_source(path))
    (ep,) = whole.episodes  # section X's limit cycle after the load pulse: 12.7 Hz (README)
    assert ep.frequency_hz == pytest.approx(12.7, abs=0.3) and 4.0 < ep.start_s < 4.3
    assert whole.verdict is Verdict.IN_BAND  # the paper's limit cycle with viscous 5
    assert len(chunked.episodes) == len(whole.episodes)
    for a, b in zip(chunked.episodes, whole.episodes, strict=True):
        assert a.verdict is b.verdict
        for name in ("start_s", "end_s", "frequency_hz", "amplitude", "speed", "position_min"):
            assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-9), name
    assert chunked.lost_motion == pytest.approx(whole.lost_motion, rel=1e-9)


# --- candump logs -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("log")
    axis = load_axis(PAPER_AXIS).with_values({"mechanics.backlash": 30e-6})
    trace = simulate_recording(axis, np.random.default_rng(4))
    import datetime as dt

    log = tmp / "can0.log"
    write_candump(trace, log, dt.datetime(2026, 6, 1, 8, 0))
    return trace, log


def test_python_can_reads_the_log_and_decoding_matches_the_trace(logged):
    trace, log = logged
    frames = list(can.LogReader(str(log)))
    assert sum(f.arbitration_id == 0x080 for f in frames) == len(trace)
    tpdo1 = [f for f in frames if f.arbitration_id == 0x182]
    mpos = np.array([int.from_bytes(f.data[:4], "little", signed=True) for f in tpdo1])
    chunks = list(candump.read_candump_chunks(log))
    decoded = np.concatenate([c.motor_position_rad for c in chunks])
    assert decoded.size == len(trace)
    np.testing.assert_allclose(decoded, mpos * 2 * np.pi / (1 << 20), atol=1e-12)
    np.testing.assert_allclose(decoded, trace["motor_position"], atol=2 * np.pi / (1 << 20))
    assert chunks[0].torque_unit == "N·m"  # 6076h found in the start-up SDO exchange
    r = analyse(_source(log, RecordingKind.CANDUMP))
    assert r.ok, r.error
    assert r.backlash == pytest.approx(30e-6, abs=0.3e-6)


@pytest.mark.skipif(shutil.which("log2asc") is None, reason="can-utils' log2asc not installed")
def test_can_utils_converts_the_log(logged, tmp_path):
    trace, log = logged
    out = subprocess.run(
        ["log2asc", "-I", str(log), "can0"], capture_output=True, text=True, check=True
    ).stdout
    data_lines = [ln for ln in out.splitlines() if ln.strip() and ln.strip()[0].isdigit()]
    assert len(data_lines) == 4 * len(trace) + 2


# --- bad input ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"hello, world\n1,2\n", "missing required column"),
        (b"\x00\xff\xfe binary", "not a trace file"),
        (
            b"time,motor_position,motor_torque\n"
            + b"".join(f"{i * 1_000_000},0,0\n".encode() for i in range(200)),
            "must be in seconds",
        ),
        (
            b"time,position_reference,motor_position,motor_torque\n"
            + b"".join(f"{i * 0.001},0,0,0\n".encode() for i in range(50)),
            "at least 100",
        ),
        (
            b"time,motor_position,motor_torque\n"
            + b"".join(f"{i * 0.001},0,0\n".encode() for i in range(150)),
            "position_reference",
        ),
    ],
)
def test_bad_trace_files_give_one_line(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_bytes(content)
    r = analyse(_source(path))
    assert not r.ok and message in r.error and "\n" not in r.error


def test_non_finite_optional_samples_are_missing_measurements(tmp_path):
    path = tmp_path / "gaps.csv"
    rows = [f"{i * 0.001},{i * 0.1},0,{i * 1e-6}" for i in range(150)]
    rows[10] = "0.010,1.0,0,inf"
    rows[11] = "0.011,1.1,0,-inf"
    rows[12] = "0.012,1.2,0,"
    path.write_text("time,motor_position,motor_torque,load_position\n" + "\n".join(rows) + "\n")
    (chunk,) = readers.read_trace_chunks(path)
    assert chunk.load_position is not None
    assert np.isnan(chunk.load_position[10:13]).all()
    assert np.isfinite(np.delete(chunk.load_position, [10, 11, 12])).all()


def test_bad_log_gives_one_line(tmp_path):
    path = tmp_path / "bad.log"
    path.write_text("(1.0) can0 123#00\n(1.1) can0 080#\n")
    r = analyse(_source(path, RecordingKind.CANDUMP))
    assert not r.ok and "without TPDOs" in r.error


def test_axis_map_that_names_no_file(tmp_path):
    (tmp_path / "M1" / "X").mkdir(parents=True)
    (tmp_path / "M1" / "X" / "2026-01-02.csv").write_text("x")
    m = tmp_path / "map.toml"
    m.write_text('[[axis]]\nmachine = "M1"\naxis = "X"\n')
    found = discover([tmp_path], axis_map=load_axis_map(m))
    (src,) = found.sources
    assert src.axis_file is None and src.machine == "M1" and src.date.day == 2
    assert "no axis file for M1/X" in analyse(src).error


# --- the whole job, as a user runs it ---------------------------------------------------------
def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fleet", "monitor", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    out = tmp_path_factory.mktemp("fleet")
    generate(out, FleetSpec(machines=2, axes_per_machine=3, recordings_per_axis=4, seed=5))
    return out


@pytest.mark.slow
def test_demo_fleet_on_local_dask_processes_finds_exactly_the_truth(fleet, tmp_path):
    res = _cli(
        str(fleet),
        "--axes",
        str(fleet / "axes.toml"),
        "--out",
        str(tmp_path / "a"),
        "--workers",
        "2",
        "--quiet",
    )
    assert res.returncode == 0, res.stderr
    serial = _cli(
        str(fleet),
        "--axes",
        str(fleet / "axes.toml"),
        "--out",
        str(tmp_path / "b"),
        "--workers",
        "0",
        "--quiet",
        "--no-figures",
    )
    assert serial.returncode == 0, serial.stderr
    # identical tables from Dask processes and from this process
    for name in ("recordings.csv", "episodes.csv", "axes.csv"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text()
    rows = {r["axis_id"]: r for r in csv.DictReader((tmp_path / "a" / "axes.csv").open())}
    truth = json.loads((fleet / "truth.json").read_text())
    for axis_id, entry in truth.items():
        row = rows[axis_id]
        assert (row["growth_warning"] == "True") == (entry["condition"] == "growing"), axis_id
        assert (row["vibrating"] == "True") == (entry["condition"] == "vibrating"), axis_id
        assert (int(row["bad_files"]) > 0) == (entry["condition"] == "corrupt"), axis_id
    assert "skipped" in res.stderr or res.stderr == ""  # --quiet: only the bad-file lines
    assert (tmp_path / "a" / "index.html").read_text().count("<tr") == len(truth) + 1
    assert pq.read_table(tmp_path / "a" / "recordings.parquet").num_rows == 24


@pytest.mark.slow
def test_same_results_on_an_existing_dask_cluster(fleet, tmp_path):
    """A LocalCluster started apart (as a cluster would be) gives the local run's tables."""
    script = textwrap.dedent(
        """
        import sys
        from distributed import LocalCluster
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                               dashboard_address=None, scheduler_port=0)
        print(cluster.scheduler_address, flush=True)
        sys.stdin.read()
        cluster.close()
        """
    )
    env_path = str(ROOT)
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=env_path,
    )
    try:
        address = proc.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        remote = _cli(
            str(fleet),
            "--axes",
            str(fleet / "axes.toml"),
            "--out",
            str(tmp_path / "r"),
            "--scheduler",
            address,
            "--quiet",
            "--no-figures",
        )
        assert remote.returncode == 0, remote.stderr
    finally:
        proc.stdin.close()
        proc.wait(timeout=60)
    local = _cli(
        str(fleet),
        "--axes",
        str(fleet / "axes.toml"),
        "--out",
        str(tmp_path / "l"),
        "--workers",
        "0",
        "--quiet",
        "--no-figures",
    )
    assert local.returncode == 0
    assert (tmp_path / "r" / "axes.csv").read_text() == (tmp_path / "l" / "axes.csv").read_text()


def test_cli_bad_arguments_and_unreachable_scheduler(tmp_path):
    res = _cli("--out", str(tmp_path / "o"))
    assert res.returncode == 2 and "no PATH given" in res.stderr
    res = _cli(str(tmp_path), "--out", str(tmp_path / "o"), "--workers", "-1")
    assert res.returncode == 2 and "--workers" in res.stderr.splitlines()[-1]
    bad_map = tmp_path / "m.toml"
    bad_map.write_text("[[axis]]\nmachine = 3\n")
    res = _cli(str(tmp_path), "--axes", str(bad_map), "--out", str(tmp_path / "o"))
    assert res.returncode == 2 and "'machine' must be a non-empty string" in res.stderr
    (tmp_path / "only.csv").write_text("not,a\ntrace,file\n")
    only = [str(tmp_path / "only.csv"), "--axis", str(PAPER_AXIS), "--out", str(tmp_path / "o")]
    res = _cli(*only, "--workers", "0", "--no-figures")
    assert res.returncode == 1 and "0 recordings analysed, 1 skipped" in res.stdout
    res = _cli(*only, "--scheduler", "tcp://127.0.0.1:9", "--no-figures")
    assert res.returncode == 1 and "cannot connect" in res.stderr
    assert res.stderr.strip().count("\n") <= 1

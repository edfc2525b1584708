"""Every legal axis file is diagnosable (issue 17 item 4): random axis files within the
format's rules — rigid and elastic, lumped (motor_inertia and screw_inertia 0), motor or
load feedback, linear and rotary, every optional key — each with a recording of itself,
through ``diagnose``: it returns, or refuses with the package's own error (one line in the
CLI), never another exception. And bad input gets one line and exit 2."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from diagnosis import DiagnosisOptions, diagnose
from diagnosis.__main__ import main as diagnosis_main
from diagnosis.errors import DiagnosisError
from plant_sim.errors import PlantSimError
from plant_sim.physics.model import KernelOptions
from plant_sim.physics.simulate import References, simulate
from virtual_bus.formats.axis import AxisConfig, AxisKind, axis_from_mapping, dump_axis
from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import MOTION_COLUMNS, Trace

#: Axis files drawn (``DIAG_FUZZ_AXES`` for a longer run: docs/diagnosis.md used 150).
N_AXES = int(os.environ.get("DIAG_FUZZ_AXES", "24"))


def _maybe(rng: np.random.Generator, p: float, value: float) -> float | None:
    return value if rng.random() < p else None


def random_axis(rng: np.random.Generator) -> AxisConfig:
    """A random axis file within the format's rules and a stable loop (speed-loop bandwidth
    a few times k_v, below the speed cycle's Nyquist rate), read by the format's own loader
    from the mapping a TOML file gives."""
    kind = "rotary" if rng.random() < 0.4 else "linear"
    kr = float(np.exp(rng.uniform(0.0, math.log(800.0))))
    lumped = rng.random() < 0.25
    jm = 0.0 if lumped else float(np.exp(rng.uniform(math.log(1e-5), math.log(1e-2))))
    js = 0.0 if lumped or rng.random() < 0.5 else float(jm * rng.uniform(0.1, 2.0))
    j_load = float(np.exp(rng.uniform(math.log(0.01), math.log(2000.0))))
    if kind == "linear":
        j_load = max(j_load, 1e-3)
    elastic = not lumped and rng.random() < 0.5
    wa = float(rng.uniform(150.0, 2000.0)) if elastic else None
    mech = {
        "motor_inertia": jm,
        "screw_inertia": js,
        "load_inertia" if kind == "rotary" else "load_mass": j_load,
        "antiresonance": wa,
        "damping_ratio": float(rng.uniform(0.02, 0.3)) if elastic else None,
        "backlash": _maybe(rng, 0.3, float(rng.uniform(1e-6, 1e-4))) if elastic else None,
    }
    speed_cycle = float(rng.choice([1.25e-4, 2.5e-4, 5e-4, 1e-3]))
    position_cycle = speed_cycle * int(rng.choice([1, 2, 4, 8]))
    position_cycle = min(position_cycle, 0.004)
    position_cycle = speed_cycle * max(1, round(position_cycle / speed_cycle))
    j_total = jm + js + j_load / kr**2
    kv = float(rng.uniform(5.0, 40.0))
    bandwidth = min(float(rng.uniform(4.0, 10.0)) * kv, 0.15 / speed_cycle)
    torque_scale = j_total * bandwidth
    coulomb = _maybe(rng, 0.7, float(rng.uniform(0.001, 0.05)) * torque_scale * 100.0)
    friction = {
        "coulomb": coulomb,
        "viscous": _maybe(rng, 0.7, float(rng.uniform(0.0, 0.5)) * torque_scale * kr),
        "coulomb_negative": _maybe(rng, 0.2, (coulomb or 0.0) * 1.2),
        "creep_speed": _maybe(rng, 0.2, 1e-4),
    }
    if rng.random() < 0.2:
        friction |= {"stribeck": 0.5 * (coulomb or 0.01), "stribeck_speed": 0.01}
    constant = _maybe(rng, 0.3, float(rng.uniform(-1.0, 1.0)) * 0.02 * torque_scale * 100.0)
    disturbance: dict[str, float | None] = {"constant_torque": constant}
    if rng.random() < 0.2:
        disturbance |= {
            "periodic_amplitude": 0.01 * torque_scale * 100.0,
            "periodic_period": 0.05 if kind == "linear" else 0.5,
            "periodic_phase": 0.3,
        }
    feedback = "load" if rng.random() < 0.4 else "motor"
    control = {
        "kv": kv,
        "ksp": bandwidth * j_total,
        "position_feedback": feedback,
        "tsi": _maybe(rng, 0.6, 4.0 / bandwidth),
        "torque_limit": _maybe(rng, 0.3, 50.0 * torque_scale),
        "current_lag": _maybe(rng, 0.5, 0.2 * speed_cycle),
        "delay": _maybe(rng, 0.15, speed_cycle),
        "position_cycle": position_cycle,
        "speed_cycle": speed_cycle,
        "velocity_feedforward": _maybe(rng, 0.2, 0.5),
        "speed_filter": _maybe(rng, 0.3, 0.3 * speed_cycle),
        "sensor_time_offset": _maybe(rng, 0.1, 0.5 * position_cycle),
    }
    doc = {
        "axis": {"kind": kind, "transmission_ratio": kr},
        "mechanics": mech,
        "friction": friction,
        "disturbance": disturbance,
        "control": control,
    }
    # a key without a value is left out of the file
    return axis_from_mapping(
        {name: {k: v for k, v in table.items() if v is not None} for name, table in doc.items()}
    )


def recording_of(axis: AxisConfig, rng: np.random.Generator, seconds: float = 5.0) -> Trace | None:
    """The axis's own closed loop on back-and-forth moves, noise added, every position
    cycle recorded; None when the loop is unstable (no recording a drive would make)."""
    cycle = axis.control.position_cycle
    t = np.arange(round(seconds / cycle)) * cycle
    span = 0.05 if axis.kind is AxisKind.LINEAR else 0.5
    x = span * (0.5 * np.sin(2 * np.pi * t / 1.7) + 0.2 * np.sin(2 * np.pi * t / 0.45 + 1.0))
    x[t < 0.2] = x[t < 0.2][0]
    refs = References.from_position(x, cycle)
    try:
        sim = simulate(axis, refs, None, KernelOptions())
    except PlantSimError:
        return None
    cols = {c: sim[c] for c in MOTION_COLUMNS}
    if not all(np.all(np.isfinite(v)) and np.max(np.abs(v)) < 1e12 for v in cols.values()):
        return None
    tau = cols["motor_torque"]
    cols["motor_torque"] = tau + 0.01 * (float(np.std(tau)) + 1e-9) * rng.standard_normal(len(t))
    return Trace(cols)


@pytest.mark.slow
def test_random_axis_files_are_diagnosed_without_a_traceback() -> None:
    rng = np.random.default_rng(17)
    done = refused = 0
    tried = 0
    while done + refused < N_AXES and tried < 10 * N_AXES:
        tried += 1
        try:
            axis = random_axis(rng)
        except AxisFileError:
            continue  # a combination the format refuses is no legal axis file
        rec = recording_of(axis, rng)
        if rec is None:
            continue
        nominal = axis.with_values({"friction.coulomb": None}) if axis.friction.coulomb else axis
        try:
            d = diagnose(rec, nominal, options=DiagnosisOptions(max_effects=2))
        except (DiagnosisError, PlantSimError) as exc:  # refused with one line: allowed
            assert "\n" not in str(exc)
            refused += 1
            continue
        done += 1
        assert d.explanation
        assert d.fitted.kind is axis.kind
    assert done + refused == N_AXES, (done, refused, tried)
    assert done >= N_AXES // 2, (done, refused)


def _write(tmp: Path, axis: AxisConfig, rec: Trace) -> tuple[Path, Path]:
    a, r = tmp / "axis.toml", tmp / "rec.csv"
    a.write_text(dump_axis(axis), encoding="utf-8")
    rec.to_csv(r)
    return a, r


def _lumped_rigid() -> AxisConfig:
    """The EMPS authors' model as a user writes it: all inertia in the load."""
    return axis_from_mapping(
        {
            "axis": {"kind": "linear", "transmission_ratio": 1.0},
            "mechanics": {"motor_inertia": 0.0, "screw_inertia": 0.0, "load_mass": 95.0},
            "control": {
                "kv": 160.0,
                "ksp": 8557.0,
                "position_feedback": "motor",
                "torque_limit": 351.5,
                "position_cycle": 0.001,
                "speed_cycle": 0.001,
            },
            "friction": {"coulomb": 20.0, "viscous": 200.0},
            "disturbance": {"constant_torque": -3.0},
        }
    )


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = diagnosis_main(["diagnose", *args, "--quiet"])
    err = capsys.readouterr().err
    return code, err


def test_a_lumped_rigid_axis_is_diagnosed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """motor_inertia = screw_inertia = 0 (issue 17: a ZeroDivisionError before)."""
    axis = _lumped_rigid()
    rec = recording_of(axis, np.random.default_rng(0), 6.0)
    assert rec is not None
    a, r = _write(tmp_path, axis, rec)
    code, err = _run([str(r), "--axis", str(a), "--out", str(tmp_path / "out")], capsys)
    assert code == 0, err
    assert (tmp_path / "out" / "axis_fitted.toml").exists()


@pytest.mark.parametrize("problem", ["too short", "nan", "zero mass", "never moves"])
def test_bad_input_gets_one_line_and_exit_2(
    problem: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    axis = _lumped_rigid()
    rec = recording_of(axis, np.random.default_rng(1), 6.0)
    assert rec is not None
    a, r = _write(tmp_path, axis, rec)
    if problem == "too short":
        Trace({k: v[:150] for k, v in rec.columns.items()}).to_csv(r)
    elif problem == "nan":
        text = r.read_text().splitlines()
        cells = text[50].split(",")
        cells[2] = "nan"
        text[50] = ",".join(cells)
        r.write_text("\n".join(text) + "\n")
    elif problem == "zero mass":
        a.write_text(a.read_text().replace("load_mass = 95.0", "load_mass = 0.0"))
    else:
        cols = dict(rec.columns)
        cols["position_reference"] = np.full(len(rec), cols["position_reference"][0])
        Trace(cols).to_csv(r)
    out = tmp_path / "out"
    code, err = _run([str(r), "--axis", str(a), "--out", str(out)], capsys)
    errors = [ln for ln in err.splitlines() if "error:" in ln]
    assert code == 2, err
    assert len(errors) == 1 and "Traceback" not in err, err
    assert not out.exists() or not any(out.iterdir())


def test_extreme_evidence_gives_valid_bounds() -> None:
    """Found by the reported matrices (docs/diagnosis.md, "Protocol"): an evidence estimate
    of a damping ratio below the usual floor, a negative mass, a negative viscous friction
    gave invalid bounds or an invalid axis. A damping ratio keeps its own factor 5; a
    non-physical estimate never says the data sheet is wrong."""
    from types import SimpleNamespace

    from diagnosis.parameters import parameter_for, physical

    axis = _lumped_rigid()
    scales = SimpleNamespace(torque_peak=100.0, speed_max=1.0)
    p = parameter_for("mechanics.damping_ratio", 1.7e-4, scales, axis, axis)  # type: ignore[arg-type]
    assert p.low < 1.7e-4 < p.high
    assert not physical("mechanics.load_mass", -1.8)
    assert not physical("friction.viscous", -0.14)
    assert physical("friction.viscous", 0.0)
    assert physical("disturbance.constant_torque", -3.0)


@pytest.mark.parametrize("seconds", [1.2, 2.0, 3.0])
def test_a_short_recording_is_diagnosed_on_shorter_blocks(
    seconds: float, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Any recording of 1 s and more is diagnosed (issue 30: the demo's 2 s cut raised): the
    first ``seconds`` of a 6 s recording, exit 0, the blocks cut to a quarter of it and the
    report says so; a recording below 1 s is refused in one line (above)."""
    axis = _lumped_rigid()
    rec = recording_of(axis, np.random.default_rng(2), 6.0)
    assert rec is not None
    a, r = _write(tmp_path, axis, rec)
    n = int(np.searchsorted(rec["time"], rec["time"][0] + seconds))
    Trace({k: v[:n] for k, v in rec.columns.items()}).to_csv(r)
    out = tmp_path / "out"
    code, err = _run([str(r), "--axis", str(a), "--out", str(out)], capsys)
    assert code == 0 and "Traceback" not in err, err
    report = (out / "report.json").read_text(encoding="utf-8")
    assert "a short recording" in report

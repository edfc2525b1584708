"""BAM XL330 importer (plant_sim.datasets.xl330) against what the data set documents about itself.

Independent references: the trajectories' formulas (BAM's bam/trajectory.py), the
controller's stated scaling (bam/xl330/actuator.py: KP divisor 256, "manual mentions 128";
PWM limit 885), the recorder's units (Present Velocity in rad/s), the log headers (0.49 kg at
0.1 m, 7.4 V) and a second simulation of BAM's model m1 written here from BAM's documented
equations (explicit stepping with set-valued friction), against the project's closed-loop
replay of the axis file the importer writes. The data are third-party and not in the
repository: tests that need them skip without them (``XL330_DATA``, docs/xl330.md).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from diagnosis.replay import simulate_like
from plant_sim.__main__ import main
from plant_sim.datasets.xl330 import (
    BAM_M1,
    DATA_DIR,
    MANUAL_KP_DIVISOR,
    PWM_LIMIT,
    G,
    TorqueOffError,
    Xl330FileError,
    Xl330Recording,
    control_law_residual,
    import_xl330,
    read_xl330_log,
)
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import read_trace

LOGS = sorted(DATA_DIR.glob("*.json")) if DATA_DIR.is_dir() else []
needs_data = pytest.mark.skipif(
    not LOGS, reason=f"BAM XL330 logs not found in {DATA_DIR} (set XL330_DATA; docs/xl330.md)"
)

#: bam/trajectory.py at commit af226046: the goal of each trajectory as a function of time.
TRAJECTORIES = {
    "sin_time_square": lambda t: np.sin(t**2),
    "sin_sin": lambda t: np.sin(t) * np.pi / 2 + np.sin(5.0 * t) * 0.5 * np.sin(2.0 * t),
}


def _recordings() -> list[Xl330Recording]:
    out = []
    for path in LOGS:
        try:
            out.append(read_xl330_log(path))
        except TorqueOffError:
            continue
    return out


@pytest.fixture(scope="module")
def recordings() -> list[Xl330Recording]:
    return _recordings()


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("xl330")
    import_xl330([rec.source for rec in _recordings()], out)
    return out


# --- against the data set's documentation ------------------------------------------------------
@needs_data
def test_headers_are_the_documented_bench(recordings: list[Xl330Recording]) -> None:
    """16 logs, 12 with the torque on throughout; 0.49 kg at 0.1 m, 7.4 V, kp 100..800, 6 s
    each (every trajectory of bam/trajectory.py lasts 6.0 s)."""
    assert len(LOGS) == 16
    assert len(recordings) == 12
    assert {r.kp_register for r in recordings} == {100, 200, 400, 800}
    for r in recordings:
        assert (r.mass_kg, r.length_m, r.vin_nominal_v) == (0.49, 0.1, 7.4)
        assert r.time_s[-1] - r.time_s[0] == pytest.approx(6.0, abs=0.02)


@needs_data
def test_lift_and_drop_is_refused_where_the_trajectory_releases_the_torque() -> None:
    """bam/trajectory.py: LiftAndDrop enables the torque for t < 2.0 s only."""
    drops = [p for p in LOGS if json.loads(p.read_text())["trajectory"] == "lift_and_drop"]
    assert len(drops) == 4
    for path in drops:
        with pytest.raises(TorqueOffError) as err:
            read_xl330_log(path)
        t_off = json.loads(path.read_text())["entries"][err.value.sample]["timestamp"]
        assert 2.0 <= t_off < 2.01


@needs_data
@pytest.mark.parametrize("trajectory", sorted(TRAJECTORIES))
def test_goal_column_is_the_documented_trajectory(
    recordings: list[Xl330Recording], trajectory: str
) -> None:
    """The imported position_reference is BAM's formula at the sample time, less the ~2 ms
    between computing the goal and the middle of the register reads."""
    for rec in (r for r in recordings if r.trajectory == trajectory):
        lag_s = np.linspace(0.0, 0.005, 51)
        rms = [np.sqrt(np.mean((rec.goal_rad - TRAJECTORIES[trajectory](rec.time_s - lag)) ** 2))
               for lag in lag_s]  # fmt: skip
        best = int(np.argmin(rms))
        assert 0.0005 < lag_s[best] < 0.004
        assert rms[best] < 1e-3  # rad, against a ±1.57 rad trajectory


@needs_data
def test_pwm_follows_the_documented_divisor_not_the_manuals(
    recordings: list[Xl330Recording],
) -> None:
    """duty = kp*e*4096/(2 pi)/(256*885) (bam/xl330/actuator.py, 'manual mentions 128'): the
    recorded PWM of the unsaturated gains matches the stated divisor to 2 % and misses the
    manual's by ~50 %."""
    for rec in (r for r in recordings if r.kp_register <= 200):
        assert control_law_residual(rec) < 0.02
        assert control_law_residual(rec, MANUAL_KP_DIVISOR) > 0.4


@needs_data
def test_pwm_stays_within_the_documented_limit(recordings: list[Xl330Recording]) -> None:
    """PWM_LIMIT = 885 counts (bam/xl330/actuator.py): never exceeded, reached at kp = 800."""
    assert max(np.abs(r.pwm_counts).max() for r in recordings) == PWM_LIMIT
    for rec in recordings:
        assert (rec.saturated_share > 0.2) == (
            rec.kp_register == 800 and rec.trajectory != "sin_time_square"
        )


@needs_data
def test_speed_column_is_the_derivative_of_position_in_rad_s(imported: Path) -> None:
    """The recorder converts Present Velocity to rad/s (0.229 rpm per count): the imported
    motor_speed is the position's time derivative (a central difference over ±5 samples,
    ~50 ms, above the encoder's 1.5 mrad quantum) within 10 % (rpm would be 9.5 times)."""
    w = 5
    for path in sorted(imported.glob("kp*.csv")):
        trace = read_trace(path)
        q, t = trace["motor_position"], trace.time
        derivative = (q[2 * w :] - q[: -2 * w]) / (t[2 * w :] - t[: -2 * w])
        speed = trace["motor_speed"][w:-w]
        slope = float(derivative @ speed) / float(derivative @ derivative)
        assert slope == pytest.approx(1.0, abs=0.1), path.name


def _bam_m1_rollout(rec: Xl330Recording, dt: float = 1e-4) -> np.ndarray:
    """BAM's model m1 of the bench, simulated here from BAM's documented equations: duty =
    kp*e*4096/(2 pi)/(256*885), torque = kt/R*(vin*duty - kt*dq), gravity -m*g*l*sin(q +
    q_offset), friction as a torque that stops the motion when it can (set-valued), inertia
    armature + m*l^2; the goal linearly interpolated. Positions at the recording's times."""
    kt, r = BAM_M1["kt"], BAM_M1["R"]
    inertia = BAM_M1["armature"] + rec.mass_kg * rec.length_m**2
    duty_per_rad = rec.kp_register * 4096 / (2 * math.pi) / (256 * 885)
    t = np.arange(rec.time_s[0], rec.time_s[-1], dt)
    goal = np.interp(t, rec.time_s, rec.goal_rad)
    q, dq = float(rec.position_rad[0]), 0.0
    out = np.empty(len(t))
    for i in range(len(t)):
        duty = min(max(duty_per_rad * (goal[i] - q), -1.0), 1.0)
        torque = kt / r * (rec.vin_nominal_v * duty - kt * dq)
        torque -= rec.mass_kg * G * rec.length_m * math.sin(q + BAM_M1["q_offset"])
        stop = inertia / dt * dq + torque  # the torque that would stop the motion in dt
        friction = BAM_M1["friction_base"] + BAM_M1["friction_viscous"] * abs(dq)
        torque -= math.copysign(min(abs(stop), friction), stop)
        dq += torque / inertia * dt
        q += dq * dt
        out[i] = q
    return np.interp(rec.time_s, t, out)


@needs_data
@pytest.mark.parametrize("trajectory", ["sin_sin", "up_and_down"])
def test_reference_axis_file_replays_like_bams_model(
    recordings: list[Xl330Recording], imported: Path, trajectory: str
) -> None:
    """The axis file written for BAM's m1 (cascade kv/ksp, gravity as a 2 pi-periodic
    torque) replayed by the project follows the recording like the second simulation above:
    positions agree within 5 % of the following error's RMS."""
    rec = next(r for r in recordings if r.kp_register == 200 and r.trajectory == trajectory)
    axis = load_axis(imported / "xl330_kp200_reference.toml")
    trace = read_trace(imported / f"kp200_{trajectory}.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ours = simulate_like(axis, trace)["motor_position"]
    theirs = _bam_m1_rollout(rec)
    following = rec.goal_rad - rec.position_rad
    assert np.sqrt(np.mean((ours - theirs) ** 2)) < 0.05 * np.sqrt(np.mean(following**2))


@needs_data
def test_command_imports_the_data_directory(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["xl330", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert err.count("skipped:") == 4 and "lift_and_drop" in err
    assert len(list(tmp_path.glob("kp*.csv"))) == 12
    assert len(list(tmp_path.glob("xl330_kp*_*.toml"))) == 8
    nominal = load_axis(tmp_path / "xl330_kp200_nominal.toml")
    assert nominal.friction.coulomb is None and nominal.disturbance.periodic_phase is None


# --- bad input (no data needed) ----------------------------------------------------------------
def _log(tmp_path: Path, name: str = "log.json", **changes: object) -> Path:
    n = 150
    t = 0.005 * np.arange(1, n + 1)
    entries = [
        {
            "position": 0.1 * math.sin(x),
            "speed": 0.1 * math.cos(x),
            "load": 10,
            "input_volts": 7.4,
            "temp": 30.0,
            "timestamp": float(x),
            "goal_position": 0.12 * math.sin(x),
            "torque_enable": True,
        }
        for x in t
    ]
    doc: dict[str, object] = {
        "mass": 0.49,
        "length": 0.1,
        "kp": 200,
        "vin": 7.4,
        "motor": "xl330",
        "trajectory": "sin_sin",
        "entries": entries,
    }
    for key, value in changes.items():
        if key.startswith("entry_"):
            index, field = key[len("entry_") :].split("_", 1)
            entries[int(index)][field] = value
        else:
            doc[key] = value
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def test_a_wellformed_log_imports(tmp_path: Path) -> None:
    result = import_xl330([_log(tmp_path)], tmp_path / "out")
    assert [item.rows for item in result.traces] == [150]
    assert read_trace(result.traces[0].target)["pwm_duty"][0] == pytest.approx(10 / PWM_LIMIT)


@pytest.mark.parametrize(
    ("changes", "key", "text"),
    [
        ({"motor": "mx64"}, "motor", "only 'xl330'"),
        ({"kp": 2.5}, "kp", "integer 1..16383"),
        ({"mass": -1.0}, "mass", "expected > 0"),
        ({"entry_7_load": 900}, "load", "allowed ±885"),
        ({"entry_7_load": 1.5}, "load", "raw Present PWM"),
        ({"entry_7_timestamp": 0.0}, "timestamp", "does not increase"),
        ({"entry_7_position": "x"}, "position", "expected a number"),
        ({"entry_7_torque_enable": False}, "torque_enable", "torque off"),
    ],
)
def test_bad_logs_are_refused_naming_key_and_entry(
    tmp_path: Path, changes: dict[str, object], key: str, text: str
) -> None:
    with pytest.raises(Xl330FileError, match=text) as err:
        read_xl330_log(_log(tmp_path, **changes))
    assert err.value.key == key


def test_missing_key_and_too_few_entries_are_refused(tmp_path: Path) -> None:
    path = _log(tmp_path)
    doc = json.loads(path.read_text())
    del doc["vin"]
    path.write_text(json.dumps(doc))
    with pytest.raises(Xl330FileError, match="missing key") as err:
        read_xl330_log(path)
    assert err.value.key == "vin"
    doc["vin"] = 7.4
    doc["entries"] = doc["entries"][:50]
    path.write_text(json.dumps(doc))
    with pytest.raises(Xl330FileError, match="at least 100"):
        read_xl330_log(path)


def test_cli_refuses_a_bad_log_with_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    good = _log(tmp_path, "good.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    out = tmp_path / "out"
    assert main(["xl330", str(good), str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.json" in err[0] and "JSON" in err[0]
    assert not out.exists()

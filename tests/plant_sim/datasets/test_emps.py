"""EMPS importer, axis files and the relative force error (plant_sim.datasets.emps, force_error).

Independent references: the README's control law (rebuilt from the imported columns), a
second implementation of the recording's closed loop written here from the README's
equations with an exact exponential integrator, and the README's published figures.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from plant_sim.__main__ import main
from plant_sim.datasets.emps import (
    DATA_DIR,
    DROPPED_SAMPLES,
    ESTIMATION_FILE,
    VALIDATION_FILE,
    EmpsFileError,
    import_emps,
    read_emps_mat,
)
from plant_sim.datasets.force_error import compare_force, relative_force_error, replay
from plant_sim.errors import ScenarioError
from tests.paths import ROOT
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.trace import Trace, read_trace

REFERENCE = ROOT / "config" / "emps_reference.toml"
NOMINAL = ROOT / "config" / "emps_nominal.toml"

#: README: the reference model's relative force error (authors' simulation).
README_PERCENT = {ESTIMATION_FILE: 5.85, VALIDATION_FILE: 8.94}
#: Stated tolerance: our simulation of the reference model scores between 70 % of the README's
#: figure and 0.3 points above it (measured 4.47 and 6.55; docs/emps.md explains the gap:
#: the recording's two-tap speed filter and the authors' own simulation set-up).
README_LOW_FACTOR = 0.70
README_HIGH_POINTS = 0.3


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Trace]:
    out = tmp_path_factory.mktemp("emps")
    done = import_emps([DATA_DIR / ESTIMATION_FILE, DATA_DIR / VALIDATION_FILE], out)
    return {item.recording.source.name: read_trace(item.target) for item in done}


# --- importer ----------------------------------------------------------------------------------
def _write_mat(path: Path, **variables: np.ndarray) -> Path:
    scipy.io.savemat(path, variables)
    return path


def test_importer_refuses_mat_without_needed_variables(tmp_path: Path) -> None:
    t = np.arange(200) * 1e-3
    bad = _write_mat(tmp_path / "partial.mat", t=t[:, None], qm=np.zeros((200, 1)))
    with pytest.raises(EmpsFileError) as info:
        read_emps_mat(bad)
    message = str(info.value)
    for name in ("qg", "vir", "gtau", "kp", "kv"):
        assert name in message
    assert "partial.mat" in message and info.value.variable == "qg"


def test_importer_cli_bad_file_exits_2_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _write_mat(tmp_path / "nothing.mat", x=np.zeros((5, 1)))
    out = tmp_path / "out"
    assert main(["emps", str(DATA_DIR / ESTIMATION_FILE), str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing variable(s)" in err
    assert not out.exists()  # every file is checked before anything is written


def test_importer_refuses_mismatched_lengths(tmp_path: Path) -> None:
    n = 300
    col = np.zeros((n, 1))
    one = np.ones((1, 1))
    bad = _write_mat(
        tmp_path / "short.mat",
        t=(np.arange(n) * 1e-3)[:, None],
        qm=col,
        qg=col[:-1],
        vir=col,
        gtau=one,
        kp=one,
        kv=one,
    )
    with pytest.raises(EmpsFileError, match="'qg' has 299 samples, 't' has 300"):
        read_emps_mat(bad)


def test_cli_help_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["emps", "--help"])
    assert info.value.code == 0 and "--out" in capsys.readouterr().out


@pytest.mark.parametrize("name", [ESTIMATION_FILE, VALIDATION_FILE])
def test_imported_trace_reads_back_and_obeys_the_readme_control_law(
    imported: dict[str, Trace], name: str
) -> None:
    trace = imported[name]
    rec = read_emps_mat(DATA_DIR / name)
    assert len(trace) == len(rec.time_s) - DROPPED_SAMPLES
    # row k: torque of the cycle ending at t_k, computed at t_(k-1) from qg, qm and the
    # speed actual value of that instant (README: vir - pulses = kp kv (qg - qm) - kv dqm)
    law = rec.gtau_n_per_v * (
        rec.kp_per_s
        * rec.kv_v_s_per_m
        * (trace["position_reference"][:-1] - trace["motor_position"][:-1])
        - rec.kv_v_s_per_m * trace["motor_speed"][1:]
    )
    residual = trace["motor_torque"][1:] - law
    rms = float(np.sqrt(np.mean(trace["motor_torque"] ** 2)))
    assert float(np.sqrt(np.mean(residual**2))) < 0.04 * rms
    # the known external force: gtau * pulses_N, 0 or 5 V
    levels = np.unique(np.round(trace["disturbance"] / rec.gtau_n_per_v, 9))
    assert set(levels) <= {0.0, 5.0} and (len(levels) == 2) == rec.has_pulses


# --- axis files ----------------------------------------------------------------------------------
def test_nominal_is_reference_without_coulomb_and_offset() -> None:
    ref, nom = load_axis(REFERENCE), load_axis(NOMINAL)
    assert nom.friction.coulomb is None and nom.disturbance.constant_torque is None
    assert ref.with_values({"friction.coulomb": None, "disturbance.constant_torque": None}) == nom
    gtau = read_emps_mat(DATA_DIR / ESTIMATION_FILE).gtau_n_per_v
    assert ref.control.ksp == pytest.approx(gtau * 243.45, rel=1e-12)
    assert ref.control.torque_limit == pytest.approx(gtau * 10.0, rel=1e-12)
    assert ref.total_inertia == pytest.approx(95.1089, rel=1e-7)


# --- force error ---------------------------------------------------------------------------------
def _replica_force_error(trace: Trace, gtau: float, rows: int, settle: int) -> float:
    """The recording's loop with the reference model, from the README's equations: one-step
    backward-difference speed (the simulator's measurement), |u| <= 10 V, force
    gtau*(u + pulses) on M*ddq = F - Fv*dq - Fc*sign(dq) - offset, integrated exactly
    (exponential solution per sub-interval, stiction at rest)."""
    m, fv, fc, off = 95.1089, 203.5034, 20.3935, -3.1648
    kp, kv, cycle, nsub = 160.18, 243.45, 1e-3, 20
    qg, dist = trace["position_reference"], trace["disturbance"]
    x = float(trace["motor_position"][0])
    x_prev, v = x, 0.0
    applied = np.empty(rows)
    h = cycle / nsub
    decay = math.exp(-fv / m * h)
    for k in range(rows):
        u = kp * kv * (qg[k] - x) - kv * (x - x_prev) / cycle
        u = min(10.0, max(-10.0, u))
        force = gtau * u + dist[k]
        applied[k] = force
        x_prev = x
        for _ in range(nsub):
            net = force - off
            if v == 0.0 and abs(net) <= fc:
                continue
            s = math.copysign(1.0, v if v != 0.0 else net)
            v_inf = (net - s * fc) / fv
            v_new = v_inf + (v - v_inf) * decay
            if v_new * s < 0.0:  # friction stops the carriage inside this step
                v_new = 0.0
            x += v_inf * h + (v - v_inf) * (1.0 - decay) * m / fv
            v = v_new
    # measured force over the cycle ending at row k+1 = motor_torque[k+1] + disturbance[k]
    measured = trace["motor_torque"][1 : rows + 1] + dist[:rows]
    err = (measured - applied)[settle:]
    return 100.0 * float(np.linalg.norm(err) / np.linalg.norm(measured[settle:]))


@pytest.mark.parametrize("name", [ESTIMATION_FILE, VALIDATION_FILE])
def test_force_error_matches_an_independent_replica(imported: dict[str, Trace], name: str) -> None:
    rows = 4000  # 4 s: speed steps, reversals and (validation) four force pulses
    full = imported[name]
    trace = Trace({c: v[: rows + 1] for c, v in full.columns.items()})
    gtau = read_emps_mat(DATA_DIR / name).gtau_n_per_v
    ours = relative_force_error(load_axis(REFERENCE), trace).percent
    replica = _replica_force_error(trace, gtau, rows, settle=49)
    assert ours == pytest.approx(replica, abs=0.1)


@pytest.mark.parametrize("name", [ESTIMATION_FILE, VALIDATION_FILE])
def test_reference_model_force_error_near_readme(imported: dict[str, Trace], name: str) -> None:
    percent = relative_force_error(load_axis(REFERENCE), imported[name]).percent
    assert README_LOW_FACTOR * README_PERCENT[name] <= percent
    assert percent <= README_PERCENT[name] + README_HIGH_POINTS


def test_offset_sign_rule(imported: dict[str, Trace]) -> None:
    """constant_torque = offset (the force the motor must supply at rest); the opposite sign
    or no offset at all must fit the estimation recording worse."""
    ref = load_axis(REFERENCE)
    trace = imported[ESTIMATION_FILE]
    right = relative_force_error(ref, trace).percent
    flipped = ref.with_values({"disturbance.constant_torque": 3.1648})
    none = ref.with_values({"disturbance.constant_torque": None})
    assert relative_force_error(none, trace).percent > right + 1.0
    assert relative_force_error(flipped, trace).percent > relative_force_error(none, trace).percent


def test_replay_refuses_other_sample_time(imported: dict[str, Trace]) -> None:
    axis = load_axis(REFERENCE).with_values({"control.position_cycle": 0.002})
    with pytest.raises(ScenarioError, match=r"sampled every 0\.001 s"):
        replay(axis, imported[ESTIMATION_FILE])


def test_compare_force_of_a_trace_with_itself_is_zero(imported: dict[str, Trace]) -> None:
    assert compare_force(imported[VALIDATION_FILE], imported[VALIDATION_FILE]).percent == 0.0
    trace = imported[ESTIMATION_FILE]  # no external force: force = motor torque
    scaled = trace.with_columns({"motor_torque": 1.1 * trace["motor_torque"]})
    assert compare_force(trace, scaled).percent == pytest.approx(10.0, rel=1e-12)

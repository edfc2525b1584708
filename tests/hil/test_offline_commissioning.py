"""Offline commissioning on the simulated axis (python -m hil tune / freqresp): the frequency
response against the analytic response of the linearised two-mass model (eq. 2, 6a) and the
axis file's known antiresonance; the beta_T procedure on section X's axis; bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from bridge.commission.freqresp import ExcitationPlan
from hil.__main__ import main
from hil.offline import analytic_loop, frequency_response
from plant_sim.paper.outputs import LIMIT_CYCLE_VISCOUS
from plant_sim.physics.model import AxisPlant
from regulator.frequency_response import Multisine
from regulator.tuning import TuningError
from tests.paths import CONFIG
from virtual_bus.formats.axis import dump_axis, load_axis

PAPER = load_axis(CONFIG / "paper_axis.toml")
LINEAR = PAPER.with_values({"mechanics.backlash": 0.0, "friction.coulomb": 0.0})
PLAN = ExcitationPlan(
    Multisine(0.001, 1024, 1.0, 450.0, 1.0, corner_hz=20.0),
    periods=3,
    realizations=2,
    torque_limit=150.0,
)


def test_linearised_axis_against_eq_6a_and_its_antiresonance() -> None:
    """Backlash 0 and no Coulomb friction: the measured omega_m / omega_r equals eq. 6a with
    the current lag and the sampled loop's delays within 0.5 dB and 10 degrees up to 200 Hz
    (the drive's 8 kHz speed loop and the 1 ms hold are not in eq. 6a: measured 0.34 dB and
    8.6 degrees); the notch holds omega_a = 600 rad/s; the bandwidth is eq. 6a's."""
    fr = frequency_response(AxisPlant(LINEAR), PLAN, LINEAR.transmission_ratio, 25.0)
    f = fr.loop.frequency_hz
    analytic = analytic_loop(LINEAR, f)
    assert analytic is not None
    ratio = fr.loop.response / analytic
    low = f <= 200.0
    assert np.max(np.abs(20 * np.log10(np.abs(ratio[low])))) < 0.5
    assert np.max(np.abs(np.degrees(np.angle(ratio[low])))) < 10.0
    assert fr.antiresonance.resolved and fr.antiresonance.contains(600.0)
    crossing = f[np.argmax(np.abs(analytic) < 1 / math.sqrt(2))]
    assert fr.bandwidth.frequency_hz == pytest.approx(crossing, abs=fr.plan.multisine.resolution_hz)


def test_an_open_gap_at_standstill_shows_no_antiresonance_a_closed_one_does() -> None:
    """The paper's axis (backlash 0.1 mm) at standstill: the motor rattles in the gap, the
    load is decoupled -- no notch is claimed. With a 20 N m load torque closing the gap and a
    slow feed (no reversal), the notch holds 600 rad/s."""
    standstill = frequency_response(AxisPlant(PAPER), PLAN, PAPER.transmission_ratio, 25.0)
    assert not standstill.antiresonance.resolved
    assert "no antiresonance resolved" in standstill.describe()
    preloaded = PAPER.with_values({"disturbance.constant_torque": 20.0})
    plan = ExcitationPlan(PLAN.multisine, 3, 2, offset_speed=0.006, torque_limit=150.0)
    fr = frequency_response(AxisPlant(preloaded), plan, PAPER.transmission_ratio, 25.0)
    assert fr.antiresonance.resolved and fr.antiresonance.contains(600.0)


def test_an_excitation_beyond_the_torque_limit_is_refused() -> None:
    plan = ExcitationPlan(PLAN.multisine, 3, 1, torque_limit=5.0)
    with pytest.raises(TuningError, match="beyond the test's limit 5"):
        frequency_response(AxisPlant(LINEAR), plan, LINEAR.transmission_ratio, 25.0)


@pytest.fixture
def limit_cycle_axis(tmp_path: Path) -> Path:
    path = tmp_path / "limit_cycle.toml"
    variant = PAPER.with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
    path.write_text(dump_axis(variant, "paper axis, section X's figures"), encoding="utf-8")
    return path


def test_hil_tune_finds_beta_t_and_reports_every_trial(
    limit_cycle_axis: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "tune"
    argv = ["tune", "--axis", str(limit_cycle_axis), "--out", str(out)]
    code = main([*argv, "--torque-limit", "150"])
    text = capsys.readouterr().out
    assert code == 0, text
    report = json.loads((out / "tune.json").read_text())
    assert report["outcome"] == "found"
    beta = report["beta_t_rad_s"]
    assert beta == pytest.approx(report["last_stable_rad_s"] / 2)  # the margin
    assert report["first_vibrating_rad_s"] == pytest.approx(2 * report["last_stable_rad_s"])
    assert report["reference"]["metrics"]["vibration"] > 30e-6  # the limit cycle to cut
    assert report["confirmation"]["verdict"] == "stable"
    assert (out / "trials.png").stat().st_size > 10_000
    assert f"beta_T = {beta:.4g} rad/s" in text
    assert text.count("trial beta_T") == len(report["trials"]) + 1


def test_hil_tune_on_an_axis_without_limit_cycle_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The paper's own friction (57.3 N m s/m) damps the limit cycle out (README): nothing to
    tune, exit 1 with the reason."""
    argv = ["tune", "--axis", str(CONFIG / "paper_axis.toml"), "--out", str(tmp_path / "t")]
    code = main([*argv, "--torque-limit", "150"])
    err = capsys.readouterr().err
    assert code == 1 and "excites a limit cycle under ordinary control" in err
    for rung in ("tried deceleration", "sharp deceleration", "reversal", "load pulse"):
        assert rung in err, err  # the refusal names what was tried
    assert err.count("\n") == 1


def test_hil_tune_stops_on_a_safety_limit(
    limit_cycle_axis: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A following-error limit below what the user's feed needs (eq. 1: 0.05 / 25 = 2 mm; the
    default motion would choose its feed from the limit) stops the first trial with the
    reason, in the bridge's words (the loop is the bridge's cycle with its 2008h)."""
    argv = ["tune", "--axis", str(limit_cycle_axis), "--out", str(tmp_path / "t")]
    argv += ["--feed", "0.05", "--low-feed", "0.02"]
    code = main([*argv, "--torque-limit", "150", "--following-error-limit", "0.001"])
    err = capsys.readouterr().err
    assert code == 1 and "following error" in err and "exceeds 2008h = 0.001 load units" in err


def test_hil_freqresp_writes_the_bode_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    axis = tmp_path / "linear.toml"
    axis.write_text(dump_axis(LINEAR, "paper axis, linearised"), encoding="utf-8")
    out = tmp_path / "fr"
    argv = ["freqresp", "--axis", str(axis), "--out", str(out), "--torque-limit", "150"]
    code = main([*argv, "--realizations", "2"])
    text = capsys.readouterr().out
    assert code == 0, text
    summary = json.loads((out / "freqresp.json").read_text())
    assert summary["antiresonance_resolved"]
    assert abs(summary["antiresonance_rad_s"] - 600.0) <= summary["antiresonance_uncertainty_rad_s"]
    table = np.loadtxt(out / "freqresp.csv", delimiter=",")
    assert table.shape == (PLAN.multisine.lines.size, 6)
    assert (out / "bode.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--f-max", "700"], "Nyquist"),
        (["--torque-limit", "-1"], "--torque-limit"),
        (["--notch-band", "300,100"], "--notch-band"),
    ],
)
def test_hil_freqresp_bad_arguments_are_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], needle: str
) -> None:
    argv = ["freqresp", "--axis", str(CONFIG / "paper_axis.toml"), "--out", str(tmp_path / "x")]
    if "--torque-limit" not in extra:
        argv += ["--torque-limit", "100"]
    try:
        code = main([*argv, *extra])
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "x").exists()

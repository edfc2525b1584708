"""``python -m hil``: help, one-line errors with exit 2, and the demo (section X over the
bus) against the offline simulation."""

from __future__ import annotations

import json
from pathlib import Path

import can
import numpy as np
import pytest

from hil.__main__ import main
from tests.command_line import refused_in_one_line
from virtual_bus import Interface
from virtual_bus.contract import SYNC_COB_ID
from virtual_bus.formats.trace import read_trace


@pytest.mark.parametrize("command", [[], ["demo"], ["bench"]])
def test_help(command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main([*command, "--help"])
    assert info.value.code == 0
    assert "usage: python -m hil" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        ([], "required: COMMAND"),
        (["fly"], "invalid choice"),
        (["demo"], "--out"),
        (["demo", "--out", "README.md"], "exists and is not a directory"),
        (["bench", "--skip-lockstep", "--skip-realtime"], "nothing to run"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert fragment in refused_in_one_line(main, argv, capsys)


@pytest.mark.slow
def test_demo_writes_the_paper_outputs_and_reproduces_the_offline_run(
    bus_mode: Interface, tmp_path: Path
) -> None:
    """The 6 s section X over the bus: summary.json and figures as `plant_sim paper`, traces,
    bus logs; the loop matches the offline simulation within the stated tolerances."""
    bus = "virtual" if bus_mode is Interface.VIRTUAL else "socketcan"
    assert main(["demo", "--out", str(tmp_path), "--bus", bus]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    for name in ("fig8.png", "fig9.png", "ordinary.csv", "regulated.csv", "bus_ordinary.log"):
        assert (tmp_path / name).stat().st_size > 1000, name
    runs = summary["bridge"]["runs"]
    ordinary, regulated = (runs[n]["offline_comparison"] for n in ("ordinary", "regulated"))
    # regulated: nm; ordinary (a chaotic limit cycle): µm of a 118 µm oscillation
    assert regulated["max_following_error_difference"] < 50e-9
    assert regulated["max_beta_difference_rad_s"] < 2e-5
    assert regulated["max_lambda_difference"] < 2e-5
    assert ordinary["max_following_error_difference"] < 30e-6
    assert ordinary["max_beta_difference_rad_s"] < 0.05 * ordinary["max_beta_rad_s"]
    assert ordinary["max_lambda_difference"] == 0.0
    for name in runs:
        assert runs[name]["pdo_counters"]["missed"] == 0
    # the paper's result: the regulator removes the limit cycle
    assert summary["runs"]["ordinary"]["dominant_frequency_hz"] is not None
    assert summary["runs"]["regulated"]["dominant_frequency_hz"] is None
    assert summary["p2p_reduction"] > 0.9
    trace = read_trace(tmp_path / "regulated.csv")
    assert len(trace) == 7000 and np.all(np.diff(trace.time) > 0)
    syncs = sum(
        1
        for f in can.CanutilsLogReader(str(tmp_path / "bus_regulated.log"))
        if f.arbitration_id == SYNC_COB_ID
    )
    assert syncs == 7000

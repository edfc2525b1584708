"""``python -m plant_sim``: outputs of the paper command, exit code 2 on bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "plant_sim", *args], cwd=ROOT, capture_output=True, text=True
    )


def test_paper_writes_figures_summary_and_traces(tmp_path: Path) -> None:
    done = _run("paper", "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    for name in ("fig8.png", "fig9.png", "summary.json", "ordinary.csv", "regulated.csv"):
        assert (tmp_path / name).stat().st_size > 0, name
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["band_hz"] == [6.25, 25.0]
    assert summary["p2p_reduction"] >= 0.9
    ordinary = summary["runs"]["ordinary"]
    assert 6.25 <= ordinary["dominant_frequency_hz"] <= 25.0
    assert summary["as_given"]["ordinary"]["dominant_frequency_hz"] is None
    for run in summary["runs"].values():
        assert {"p2p_following_error", "final_standstill_error"} <= run.keys()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("paper",), "--out"),
        (("paper", "--out", "x", "--position-cycle", "-1"), "must be a finite number > 0"),
        (("paper", "--out", "x", "--axis", "nope.toml"), "no such axis file"),
        (("sweep", "--out", "x", "--kv", "25,abc"), "comma-separated numbers"),
        (("frobnicate",), "invalid choice"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(args: tuple[str, ...], message: str) -> None:
    done = _run(*args)
    assert done.returncode == 2
    assert message in done.stderr
    assert "Traceback" not in done.stderr


def test_bad_axis_file_exits_2_naming_the_key(tmp_path: Path) -> None:
    text = (ROOT / "config" / "paper_axis.toml").read_text().replace("kv = 25.0", "kv = -3.0")
    (tmp_path / "bad.toml").write_text(text)
    done = _run("paper", "--out", str(tmp_path / "o"), "--axis", str(tmp_path / "bad.toml"))
    assert done.returncode == 2
    assert "control.kv = -3.0" in done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr

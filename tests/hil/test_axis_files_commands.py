"""Every shipped axis file, and axis files with extreme values, through every bridge command
and the standalone drive that take one: each runs, or is refused in one line naming why
(exit 2); never a traceback."""

from __future__ import annotations

import re
import threading
import uuid
from pathlib import Path

import can
import pytest

from bridge.__main__ import main as bridge_main
from hil.__main__ import main as hil_main
from plant_sim.__main__ import main as plant_sim_main
from plant_sim.drive.process import DriveProcessConfig, serve
from plant_sim.errors import PlantSimError
from tests.command_line import exit_status
from tests.paths import ROOT
from virtual_bus.formats import FormatError
from virtual_bus.formats.axis import load_axis

SHIPPED = sorted((ROOT / "config").glob("*.toml"))
PAPER = ROOT / "config" / "paper_axis.toml"
#: (name, key, value): paper_axis.toml with one value pushed to an extreme
EXTREMES = [
    ("torque_limit_1e308", "torque_limit", "1e308"),
    ("transmission_ratio_1e-12", "transmission_ratio", "1e-12"),
    ("transmission_ratio_1e12", "transmission_ratio", "1e12"),
    ("transmission_ratio_1e300", "transmission_ratio", "1e300"),
]


def _variant(tmp_path: Path, key: str, value: str) -> Path:
    text = PAPER.read_text()
    changed = re.sub(rf"(?m)^{key}\s*=.*$", f"{key} = {value}", text)
    assert changed != text
    path = tmp_path / f"{key}.toml"
    path.write_text(changed)
    return path


@pytest.fixture(
    params=[pytest.param(p, id=p.name) for p in SHIPPED]
    + [pytest.param(e, id=e[0]) for e in EXTREMES]
)
def axis_file(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    if isinstance(request.param, Path):
        return request.param
    _, key, value = request.param
    return _variant(tmp_path, key, value)


def _call(main: object, argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = exit_status(main, argv)  # type: ignore[arg-type]
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    if code == 2:
        assert err.count("\n") == 1, err  # refused: one line naming why
    return code, err


def test_bridge_commands_run_or_refuse_in_one_line(
    axis_file: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    axis = ["--axis", str(axis_file)]
    code, _ = _call(bridge_main, ["busload", *axis], capsys)
    assert code in (0, 2)
    code, _ = _call(hil_main, ["bench", *axis, "--cycles", "20", "--skip-realtime"], capsys)
    assert code in (0, 2)
    refused = code == 2
    # no drive on this channel: start-up fails (1) or the file is refused (2), in one line
    channel = f"nobody-{uuid.uuid4().hex[:8]}"
    argv = ["run", "--interface", "virtual", "--channel", channel, *axis, "--seconds", "0.01"]
    code, err = _call(bridge_main, argv, capsys)
    assert code in (1, 2)
    assert err.splitlines()[-1].startswith("python -m bridge run: ")
    if refused:  # the demo only where it is refused quickly (a full demo is a slow test)
        code, _ = _call(hil_main, ["demo", *axis, "--out", str(tmp_path / "demo")], capsys)
        assert code == 2 and not (tmp_path / "demo").exists()


def test_standalone_drive_serves_or_refuses_in_one_line(
    axis_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        config = DriveProcessConfig(load_axis(axis_file))
        bus = can.Bus(interface="virtual", channel=f"axis-{uuid.uuid4().hex[:8]}")
        stop = threading.Event()
        stop.set()  # boot-up, then leave the bus
        try:
            result = serve(config, bus, stop)
        finally:
            bus.shutdown()
    except (PlantSimError, FormatError):
        # refused: the command says it in one line, exit 2
        argv = ["drive", "--interface", "virtual", "--channel", "x", "--axis", str(axis_file)]
        code, err = _call(plant_sim_main, argv, capsys)
        assert (code == 2 and str(axis_file.name) in err) or "resonance" in err
    else:
        assert result.sync_count == 0


@pytest.mark.parametrize("command", [["paper", "--out", "unused-dir"], ["bench"]])
@pytest.mark.parametrize(
    "axis_path", [p for p in SHIPPED if "emps" in p.name], ids=lambda p: p.name
)
def test_plant_sim_refuses_an_axis_the_regulator_cannot_run(
    command: list[str], axis_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The EMPS files' 1 ms position cycle is above section VII's sampling limit for their
    kv = 160/s (cycle < 1 / (10 kv) = 0.62 ms): refused in one line naming the rule."""
    code, err = _call(plant_sim_main, [*command, "--axis", str(axis_path)], capsys)
    assert code == 2 and "sampling rule of section VII" in err and axis_path.name in err

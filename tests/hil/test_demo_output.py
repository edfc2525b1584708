"""What ``hil demo`` prints and draws (issue 31 item 3): a summary in µm/mm with units on
stdout, summary.json's content behind ``--json``, a first stage that says it loads or compiles
the compiled functions and how long it took, and one peak-to-peak window for summary.json and
the figures' zoom.

The figures are checked against the traces the demo wrote, recomputed here with numpy over
the window summary.json states."""

from __future__ import annotations

import contextlib
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fleet.analyse import analyse
from fleet.episodes import Verdict
from fleet.sources import RecordingKind, Source
from hil.__main__ import main
from plant_sim.paper import outputs
from virtual_bus.formats.trace import read_trace
from virtual_bus.shipped import PAPER_AXIS

#: A number with its unit (a range "6.25–25 Hz" carries it once, at its end).
WITH_UNIT = re.compile(
    r"[−-]?\d[\d,]*(?:\.\d+)?(?:e[+-]?\d+)?(?:–[\d.]+)?\s"
    r"(?:µm|mm|nm|Hz|rad/s|1/s|%|s\b|cycles/s|cycles)"
)
#: What may carry a number without a unit: names of figures and equations, λ (1), TPDO counts.
NAMES = re.compile(r"Fig\. \d+|eq\. \d+|λ (?:min|within) [\d.e+-]+|missed TPDOs \d+")


@dataclass(frozen=True)
class Demo:
    out: Path
    stdout: str
    stderr: str
    titles: list[str]


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Demo:
    out = tmp_path_factory.mktemp("demo")
    titles: list[str] = []
    original = outputs.plot_section_x

    def kept(*args: object, **kwargs: object) -> str:
        titles.append(original(*args, **kwargs))  # type: ignore[arg-type]
        return titles[-1]

    stdout, stderr = io.StringIO(), io.StringIO()
    with (
        pytest.MonkeyPatch.context() as mp,
        contextlib.redirect_stdout(stdout),
        contextlib.redirect_stderr(stderr),
    ):
        mp.setattr(outputs, "plot_section_x", kept)
        assert main(["demo", "--out", str(out)]) == 0
    return Demo(out, stdout.getvalue(), stderr.getvalue(), titles)


def test_the_summary_gives_every_number_a_unit(demo: Demo) -> None:
    results = [ln for ln in demo.stdout.splitlines() if not ln.startswith(("note:", "wrote "))]
    assert len(results) == 5, demo.stdout
    for line in results:
        bare = WITH_UNIT.sub("", NAMES.sub("", line))
        assert not re.search(r"\d", bare), (line, bare)
    assert not any(ch in demo.stdout for ch in "{}"), "no JSON on stdout without --json"


def test_the_summary_says_what_summary_json_says_in_micrometres(demo: Demo) -> None:
    summary = json.loads((demo.out / "summary.json").read_text())
    ordinary = summary["runs"]["ordinary"]
    (line,) = [ln for ln in demo.stdout.splitlines() if "ordinary control (Fig. 8)" in ln]
    p2p_um = ordinary["p2p_following_error"] * 1e6
    assert f"following error {p2p_um:.3g} µm peak to peak" in line
    assert f"vibrates at {ordinary['dominant_frequency_hz']:.3g} Hz (in the band)" in line
    (line,) = [ln for ln in demo.stdout.splitlines() if "with the regulator (Fig. 9)" in ln]
    reduction = 100 * summary["p2p_reduction"]
    assert f"(−{reduction:.1f} %)" in line and "no vibration" in line


def test_figures_and_summary_json_use_one_window(demo: Demo) -> None:
    summary = json.loads((demo.out / "summary.json").read_text())
    start, end = summary["p2p_window_s"]
    assert len(demo.titles) == 2
    for name, title in zip(("ordinary", "regulated"), demo.titles, strict=True):
        trace = read_trace(demo.out / f"{name}.csv")
        keep = (trace.time >= start) & (trace.time < end)
        e = trace["position_reference"][keep] - trace["load_position"][keep]
        p2p = float(np.ptp(e))
        assert summary["runs"][name]["p2p_following_error"] == pytest.approx(p2p, rel=1e-12)
        assert f"zoom on {start:g}–{end:g} s" in title
        assert f"peak-to-peak {p2p * 1e6:.3g} µm" in title


def test_the_first_stage_says_whether_it_compiled_and_how_long(demo: Demo) -> None:
    stages = [ln for ln in demo.stderr.splitlines() if "hil demo:" in ln]
    assert "a first run compiles them" in stages[0]
    assert re.search(
        r"(compiled \(numba, first run\) in \d+ s|from numba's cache in [\d.]+ s)", stages[1]
    ), stages[1]


def test_json_prints_summary_json(demo: Demo, tmp_path: Path) -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(["demo", "--out", str(tmp_path), "--json", "--quiet"]) == 0
    printed = json.loads(out.getvalue())
    assert printed == json.loads((tmp_path / "summary.json").read_text())


def test_the_monitor_judges_the_demos_bus_log_as_its_trace(demo: Demo) -> None:
    """The fleet monitor on the candump log of the ordinary run (a lockstep log, stamped
    far less than the 1 ms cycle apart) gives the verdict and frequency the trace of the same
    run gives, and says it timed the log by its SYNC count (issue 31 item 4)."""
    axis = demo.out / "axis_limit_cycle.toml"
    if not axis.exists():  # the axis as given limit-cycles
        axis = PAPER_AXIS
    log, trace = (
        analyse(Source(demo.out / name, kind, "", "", None, axis))
        for name, kind in (
            ("bus_ordinary.log", RecordingKind.CANDUMP),
            ("ordinary.csv", RecordingKind.TRACE),
        )
    )
    assert log.ok and trace.ok, (log.error, trace.error)
    assert trace.verdict is Verdict.IN_BAND  # Fig. 8's limit cycle
    assert log.verdict is trace.verdict
    assert log.dominant_frequency_hz == pytest.approx(trace.dominant_frequency_hz, rel=0.02)
    assert log.duration_s == pytest.approx(trace.duration_s, abs=2e-3)
    assert "SYNC count times 1 ms" in log.warning


def test_plot_draws_the_demos_trace(demo: Demo) -> None:
    """``hil plot`` on the demo's ordinary run: the following error on the load scale is the
    trace's own, its spectrum peaks at the limit cycle summary.json names, inside the band it
    shades (eq. 13), which is summary.json's (issue 31 item 2)."""
    from hil.plot import PlotSetup, panels
    from virtual_bus.formats.axis import load_axis

    axis_path = demo.out / "axis_limit_cycle.toml"
    if not axis_path.exists():  # the axis as given limit-cycles
        axis_path = PAPER_AXIS
    axis = load_axis(axis_path)
    summary = json.loads((demo.out / "summary.json").read_text())
    trace = read_trace(demo.out / "ordinary.csv")
    cols = trace.columns
    setup = PlotSetup("m", axis.transmission_ratio, axis.control.kv)
    plots = {p.ylabel: p for p in panels(trace, setup)}
    error = plots["following error, µm"].curves[0].values
    assert np.allclose(error, (cols["position_reference"] - cols["load_position"]) * 1e6)
    spectrum = plots["amplitude, µm"]
    assert spectrum.band_hz == pytest.approx(tuple(summary["band_hz"]))
    # below the band the move's own error (eq. 7) dominates; inside it, the limit cycle
    low, high = spectrum.band_hz
    inside = (spectrum.x >= low) & (spectrum.x <= high)
    peak = spectrum.x[inside][int(np.argmax(spectrum.curves[0].values[inside]))]
    found = summary["runs"]["ordinary"]["dominant_frequency_hz"]
    assert peak == pytest.approx(found, abs=0.5)  # the whole run's FFT, the late window's
    with contextlib.redirect_stdout(io.StringIO()) as said:
        assert main(["plot", str(demo.out / "ordinary.csv"), "--axis", str(axis_path)]) == 0
    assert "following error" in said.getvalue() and "µm" in said.getvalue()
    assert (demo.out / "ordinary.png").is_file() and (demo.out / "ordinary.html").is_file()

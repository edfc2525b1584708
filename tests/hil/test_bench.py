"""``python -m hil bench``: real-time options refused in one line, and the real-time run
with the drive in its own process (no timing checked: timings are the bench's output)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.paths import ROOT
from virtual_bus.realtime import RealTimeOptions


# --- command line ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["bench", "--rt-priority", "0"], "SCHED_FIFO priority is 1..99"),
        (["bench", "--rt-priority", "high"], "not an integer"),
        (["bench", "--cpu", "-1"], "CPU number is >= 0"),
        (["bench", "--rate-hz", "3000"], "invalid choice"),
        (["bench", "--drive", "elsewhere"], "invalid choice"),
    ],
)
def test_bad_real_time_arguments_exit_2_with_one_line(
    argv: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from hil.__main__ import main

    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1


def test_a_refused_real_time_option_exits_1_with_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    import os

    from hil.__main__ import main

    cpu = max(os.sched_getaffinity(0)) + 64
    argv = ["bench", "--skip-lockstep", "--drive", "thread", "--seconds", "0.01", "--cpu", str(cpu)]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert f"--cpu {cpu}" in err and "refused" in err and err.count("\n") == 1


def test_bench_with_the_drive_in_its_own_process(tmp_path: Path) -> None:
    """The real-time bench runs the drive as a second process (python -m plant_sim drive) on
    udp_multicast in a namespace of its own, and removes that namespace; no timing checked."""
    from virtual_bus.netns import netns_problem

    if (problem := netns_problem()) is not None:
        pytest.skip(problem)
    from hil.__main__ import main

    out = tmp_path / "bench.json"
    argv = ["bench", "--skip-lockstep", "--drive", "process", "--seconds", "0.3", "--json"]
    assert main([*argv, str(out)]) == 0
    r = json.loads(out.read_text())["realtime"]
    netns = r["bus"].rsplit(" ", 1)[1]
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert netns.startswith("vbus-") and netns not in listed  # the bench removed it
    assert r["drive"] == "process" and r["cycles"] > 0
    assert r["cycles"] + r["skipped_syncs"] >= 300  # every slot of 0.3 s: run or skipped
    assert r["missed_tpdo_cycles"] < r["cycles"]  # the drive process answered
    assert sum(r["latency_histogram_us"].values()) == r["cycles"]
    assert r["drive_cpu_percent_of_one_core"] > 0.0
    assert not r["stopped"], r["stop_message"]


def test_cyclictest_first_leaves_the_axis_running(tmp_path: Path) -> None:
    """With cyclictest before the loop (the README's real-time rows), the drive watches the
    bridge's heartbeat all along (1016h, 250 ms): the loop timed after it drives a running
    axis, not one the drive stopped (EMCY 8130h) while cyclictest ran."""
    import shutil

    from virtual_bus.netns import netns_problem

    if (problem := netns_problem()) is not None:
        pytest.skip(problem)
    if shutil.which("cyclictest") is None:
        pytest.skip("cyclictest (rt-tests) is not installed")
    out = tmp_path / "bench.json"
    argv = [sys.executable, "-m", "hil", "bench", "--skip-lockstep", "--drive", "process"]
    argv += ["--seconds", "0.5", "--rt-priority", "10", "--cpu", "1", "--json", str(out)]
    # a process of its own: the real-time options (CPU affinity) stay with it
    done = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, check=False)
    assert done.returncode == 0, done.stderr
    r = json.loads(out.read_text())["realtime"]
    assert "host_latency" in r  # cyclictest measured the host first
    assert not r["stopped"], r["stop_message"]


def test_the_drive_process_gets_the_loops_real_time_options_one_priority_lower() -> None:
    """bench: the drive process runs with the bridge's options, read back by the drive
    command's own parser (plant_sim drive), on its own CPU, one SCHED_FIFO priority lower."""
    import argparse

    from hil.bench_realtime import drive_options
    from virtual_bus.realtime import add_realtime_options, realtime_options

    rt = RealTimeOptions(rt_priority=50, cpu=1, lock_memory=True, freeze_gc=True, busy_poll=True)
    parser = argparse.ArgumentParser()
    add_realtime_options(parser)
    got = realtime_options(parser.parse_args(drive_options(rt, drive_cpu=0)))
    assert got == RealTimeOptions(
        rt_priority=49, cpu=0, lock_memory=True, freeze_gc=True, busy_poll=True
    )
    assert drive_options(RealTimeOptions(rt_priority=1), None) == ["--rt-priority", "1"]
    assert drive_options(RealTimeOptions(), None) == []

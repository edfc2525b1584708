"""The host latency floor (bridge/host_latency.py) read from cyclictest (rt-tests), a tool
this project did not write: its real ``--json`` output (stored, and live where it is
installed and may run SCHED_FIFO), and constructed results whose figures are known."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

import pytest

from bridge.__main__ import main
from bridge.host_latency import (
    HostLatencyError,
    cyclictest_args,
    measure,
    parse_cyclictest_json,
)
from tests.paths import DATA

#: A real run on this project's development VM: ``cyclictest --mlockall --priority=50
#: --interval=1000 --loops=2000 --threads=1 --affinity=1 --quiet --histogram=10000 ...``;
#: one wake-up came 3,178 µs late (hypervisor steal), the next latest 218 µs.
STORED = DATA / "cyclictest_1khz.json"


def _doc(histogram: dict[int, int], cycles: int, max_us: int, realtime: int = 0) -> str:
    return json.dumps(
        {
            "sysinfo": {
                "release": "6.1.0-rt",
                "version": "#1 SMP PREEMPT_RT",
                "realtime": realtime,
            },
            "thread": {
                "0": {
                    "histogram": {str(k): v for k, v in histogram.items()},
                    "cycles": cycles,
                    "max": max_us,
                }
            },
        }
    )


def test_stored_real_run_is_read_as_cyclictest_reported_it() -> None:
    raw = json.loads(STORED.read_text())
    result = parse_cyclictest_json(STORED.read_text(), cycle_us=1000)
    assert result.cycles == raw["thread"]["0"]["cycles"] == 2000
    assert result.max_us == raw["thread"]["0"]["max"] == 3178
    assert result.late_cycles == 1  # the 3,178 µs wake-up: three deadlines behind, one late
    assert result.over_500us == 1
    assert 10 <= result.median_us <= result.p99_us < 500
    assert not result.preempt_rt


def test_quantiles_and_late_counts_of_a_known_histogram() -> None:
    # 90 at 10 µs, 9 at 600 µs, 1 at 1000 µs (exactly one cycle: late)
    result = parse_cyclictest_json(_doc({10: 90, 600: 9, 1000: 1}, 100, 1000, 1), 1000)
    assert result.median_us == 10
    assert result.p99_us == 600  # rank 0.99 * 99 = 98.01 -> the 99th sample
    assert result.late_cycles == 1
    assert result.over_500us == 10
    assert result.preempt_rt


def test_overflow_beyond_the_histogram_counts_as_late_and_infinite_quantile() -> None:
    # 100 cycles, 95 in the histogram: 5 beyond its reach (the maximum says how far)
    result = parse_cyclictest_json(_doc({20: 95}, 100, 15_000), 500)
    assert result.late_cycles == 5
    assert result.over_500us == 5
    assert result.median_us == 20
    assert math.isinf(result.p99_us)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("not json", "cannot be read"),
        (json.dumps({"thread": {}}), "0 threads"),
        (json.dumps({"thread": {"0": {"cycles": 3}}}), "cannot be read"),
        (_doc({10: 5}, 3, 10), "more than its 3 cycles"),
        (_doc({}, 0, 0), "no cycles"),
    ],
)
def test_unreadable_results_are_refused_with_the_reason(text: str, needle: str) -> None:
    with pytest.raises(HostLatencyError, match=needle):
        parse_cyclictest_json(text, 1000)


def test_the_command_line_asks_for_the_bench_settings(tmp_path: Path) -> None:
    args = cyclictest_args("cyclictest", 2000.0, 60.0, 1, 50, tmp_path / "r.json")
    assert "--interval=500" in args
    assert "--loops=120000" in args
    assert "--priority=50" in args and "--affinity=1" in args and "--mlockall" in args
    assert "--histogram=5000" in args


def test_a_failing_cyclictest_says_why() -> None:
    def refuse(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
        return subprocess.CompletedProcess(args, 255, "", "unable to change scheduling policy!")

    with pytest.raises(HostLatencyError, match=r"exit 255\): unable to change scheduling policy"):
        measure(1000.0, 1.0, 0, 50, executable="cyclictest", runner=refuse)


def test_missing_cyclictest_is_one_line_and_exit_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(shutil, "which", lambda _name: None)
    assert main(["host-latency", "--seconds", "0.01", "--cpu", "0"]) == 1
    err = capsys.readouterr().err
    assert "apt install rt-tests" in err and len(err.strip().splitlines()) == 1


def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["host-latency", "--rt-priority", "0"])
    assert info.value.code == 2
    assert "allowed 1..99" in capsys.readouterr().err


def _can_run_cyclictest() -> str | None:
    if shutil.which("cyclictest") is None:
        return "cyclictest (rt-tests) is not installed"
    if os.geteuid() != 0:
        return "cyclictest needs root for SCHED_FIFO"
    return None


@pytest.mark.skipif(_can_run_cyclictest() is not None, reason=str(_can_run_cyclictest()))
def test_live_run_through_the_command(tmp_path: Path) -> None:
    out = tmp_path / "host.json"
    cpu = min(os.sched_getaffinity(0))
    assert main(["host-latency", "--seconds", "0.2", "--cpu", str(cpu), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())["host_latency"]
    assert doc["cycles"] == 200
    assert 0 < doc["latency_us_median"] <= doc["latency_us_max"]
    assert isinstance(doc["host_steal_ms"], dict)

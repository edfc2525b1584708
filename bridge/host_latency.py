"""The wake-up latency this host gives any real-time loop, measured by ``cyclictest``.

A 1 kHz loop (the bridge sending SYNC, the drive answering it) can only be as punctual as
the operating system wakes it. ``cyclictest`` (rt-tests, the Linux real-time community's
standard tool, written in C; ``apt install rt-tests``) measures exactly that: one thread at
SCHED_FIFO, memory locked, pinned to a CPU, sleeps to absolute deadlines one cycle apart on
CLOCK_MONOTONIC and records how late each wake-up came. Nothing of this project runs in it,
so its figures are the floor under the bridge's: a wake-up at least one cycle late is a
deadline that *any* loop at that rate misses on this host (the bench counts it as a skipped
SYNC), and its maximum bounds from below the largest SYNC-to-set-point latency.

:func:`measure` runs it (the runner is injectable) and :func:`parse_cyclictest_json` reads
its ``--json`` file; the hypervisor's steal time over the run comes from ``/proc/stat``
(:func:`virtual_bus.realtime.steal_s`).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from .errors import BridgeError

#: How far the histogram reaches, in cycles; later wake-ups count as overflows (their
#: number is still known: cycles minus the histogram's total).
HISTOGRAM_CYCLES = 10


class HostLatencyError(BridgeError, RuntimeError):
    """``cyclictest`` is missing, refused to run, or wrote a result that cannot be read."""


@dataclass(frozen=True)
class HostLatency:
    """One ``cyclictest`` run: wake-up latencies of a SCHED_FIFO thread, µs.

    ``late_cycles``: wake-ups at least one cycle (``cycle_us``) late, each a deadline any
    loop at that rate misses; ``over_500us``: wake-ups later than 500 µs (the TPDO window
    of a 1 ms cycle); ``over_slack``: wake-ups at least ``slack_us`` late (a loop that may
    send its SYNC that late after waking, e.g. the bridge's spin before the SYNC plus the
    lateness its pacer allows, misses a slot for each); ``preempt_rt``: the kernel is a
    PREEMPT_RT kernel (cyclictest's ``sysinfo.realtime``)."""

    cycle_us: int
    cycles: int
    median_us: float
    p99_us: float
    max_us: int
    late_cycles: int
    over_500us: int
    preempt_rt: bool
    kernel: str
    slack_us: int = 0
    over_slack: int = 0

    def as_dict(self) -> dict[str, float | int | bool | str]:
        return {
            "cycle_us": self.cycle_us,
            "cycles": self.cycles,
            "latency_us_median": self.median_us,
            "latency_us_p99": self.p99_us,
            "latency_us_max": self.max_us,
            "late_cycles": self.late_cycles,
            "over_500us": self.over_500us,
            "preempt_rt": self.preempt_rt,
            "kernel": self.kernel,
            "slack_us": self.slack_us,
            "over_slack": self.over_slack,
        }


def json_doc(result: HostLatency, steal_ms: dict[str, float]) -> dict[str, object]:
    """What ``python -m bridge host-latency --json`` writes (read by ``dev.py bench``)."""
    return {"host_latency": {**result.as_dict(), "host_steal_ms": steal_ms}}


def _quantile_us(histogram: dict[int, int], overflow: int, total: int, q: float) -> float:
    """The ``q`` quantile of the latencies, µs, from a 1-µs histogram whose ``overflow``
    samples lie beyond its last bucket (returned as inf when the quantile falls there)."""
    rank = q * (total - 1)
    seen = 0
    for latency_us in sorted(histogram):
        seen += histogram[latency_us]
        if seen > rank:
            return float(latency_us)
    return float("inf") if overflow else float(max(histogram, default=0))


def parse_cyclictest_json(text: str, cycle_us: int, slack_us: int | None = None) -> HostLatency:
    """Read the ``--json`` file of a one-thread ``cyclictest -h N`` run (``slack_us``: count
    the wake-ups at least that late too; default one cycle)."""
    try:
        doc = json.loads(text)
        threads = doc["thread"]
        if len(threads) != 1:
            raise HostLatencyError(f"cyclictest result has {len(threads)} threads, expected 1")
        (thread,) = threads.values()
        histogram = {int(k): int(v) for k, v in thread["histogram"].items()}
        cycles = int(thread["cycles"])
        max_us = int(thread["max"])
        sysinfo = doc.get("sysinfo", {})
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise HostLatencyError(f"cyclictest result cannot be read: {exc!r}") from exc
    if cycles <= 0:
        raise HostLatencyError("cyclictest result has no cycles")
    in_histogram = sum(histogram.values())
    overflow = cycles - in_histogram
    if overflow < 0:
        raise HostLatencyError(
            f"cyclictest histogram holds {in_histogram} samples, more than its {cycles} cycles"
        )
    slack = cycle_us if slack_us is None else slack_us
    return HostLatency(
        cycle_us=cycle_us,
        cycles=cycles,
        median_us=_quantile_us(histogram, overflow, cycles, 0.5),
        p99_us=_quantile_us(histogram, overflow, cycles, 0.99),
        max_us=max_us,
        late_cycles=overflow + sum(n for us, n in histogram.items() if us >= cycle_us),
        over_500us=overflow + sum(n for us, n in histogram.items() if us > 500),
        preempt_rt=bool(sysinfo.get("realtime", 0)),
        kernel=f"{sysinfo.get('release', '?')} {sysinfo.get('version', '')}".strip(),
        slack_us=slack,
        over_slack=overflow + sum(n for us, n in histogram.items() if us >= slack),
    )


def cyclictest_args(
    executable: str, rate_hz: float, seconds: float, cpu: int, priority: int, json_path: Path
) -> list[str]:
    """The command line: one thread, SCHED_FIFO ``priority``, memory locked, on ``cpu``,
    absolute deadlines one cycle apart for ``seconds``, histogram to 10 cycles."""
    cycle_us = round(1e6 / rate_hz)
    return [
        executable,
        "--mlockall",
        f"--priority={priority}",
        f"--interval={cycle_us}",
        f"--loops={round(seconds * rate_hz)}",
        "--threads=1",
        f"--affinity={cpu}",
        "--quiet",
        f"--histogram={HISTOGRAM_CYCLES * cycle_us}",
        "--histfile=/dev/null",
        f"--json={json_path}",
    ]


Runner = Callable[[Sequence[str]], subprocess.CompletedProcess[str]]


def _run(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, check=False)


def measure(
    rate_hz: float,
    seconds: float,
    cpu: int,
    priority: int,
    *,
    executable: str | None = None,
    runner: Runner = _run,
    slack_us: int | None = None,
) -> HostLatency:
    """Run ``cyclictest`` once and read its result (:class:`HostLatencyError` with the
    reason when it is not installed or fails, e.g. SCHED_FIFO refused without root)."""
    exe = executable or shutil.which("cyclictest")
    if exe is None:
        raise HostLatencyError(
            "cyclictest not found: install rt-tests (Debian/Ubuntu: apt install rt-tests)"
        )
    with tempfile.TemporaryDirectory(prefix="host-latency-") as tmp:
        json_path = Path(tmp) / "cyclictest.json"
        done = runner(cyclictest_args(exe, rate_hz, seconds, cpu, priority, json_path))
        if done.returncode != 0 or not json_path.exists():
            why = (done.stderr or done.stdout or "").strip().splitlines()
            raise HostLatencyError(
                f"cyclictest failed (exit {done.returncode})"
                + (f": {why[-1]}" if why else "")
                + " (SCHED_FIFO and mlockall need root or CAP_SYS_NICE/CAP_IPC_LOCK)"
            )
        return parse_cyclictest_json(json_path.read_text(), round(1e6 / rate_hz), slack_us)

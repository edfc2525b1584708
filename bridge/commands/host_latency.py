"""``python -m bridge host-latency``: the host's wake-up latency floor (bridge/host_latency.py).

Runs ``cyclictest`` (rt-tests) with the bench's real-time settings, so its figures sit beside
``hil bench``'s: a deadline cyclictest misses, any loop at that rate misses on this host.
JSON keys (``--json``): ``host_latency.latency_us_median/p99/max``, ``late_cycles``,
``over_500us``, ``preempt_rt``, ``kernel``, ``host_steal_ms``; read by ``python3 dev.py bench``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cmdline import cli
from virtual_bus.atomic import write_atomic
from virtual_bus.errors import RealTimeRefused
from virtual_bus.realtime import check_cpu, cpu_number

NAME = "host-latency"
HELP = "the host's wake-up latency floor for a real-time loop, measured by cyclictest"
DESCRIPTION = (
    "One SCHED_FIFO thread, memory locked, pinned to --cpu, waking at every cycle of --rate-hz "
    "for --seconds (cyclictest from rt-tests, not this project's code): how late the host "
    "wakes any real-time loop. Wake-ups one cycle or more late are deadlines every loop at "
    "that rate misses here; compare them with hil bench's skipped SYNCs."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rate-hz", type=float, choices=[1000.0, 2000.0], default=1000.0, help="(1000)"
    )
    parser.add_argument("--seconds", type=cli.positive_float, default=60.0, help="(60 s)")
    parser.add_argument("--cpu", type=cpu_number, default=1, metavar="N", help="(CPU 1)")
    parser.add_argument(
        "--rt-priority",
        type=cli.bounded_int(1, 99),
        default=50,
        metavar="N",
        help="SCHED_FIFO priority 1..99 (50, the bench's)",
    )
    parser.add_argument("--json", type=Path, help="also write the figures to this file")


def run(args: argparse.Namespace) -> int:
    from virtual_bus.realtime import host_steal_s

    from ..host_latency import HostLatencyError, json_doc, measure

    check_cpu(args.cpu)
    if not args.quiet:
        print(f"cyclictest: {args.seconds:g} s at {args.rate_hz:g} Hz on CPU {args.cpu} ...")
    steal0 = host_steal_s()
    try:
        result = measure(args.rate_hz, args.seconds, args.cpu, args.rt_priority)
    except HostLatencyError as exc:
        raise RealTimeRefused(str(exc), setting="cyclictest") from exc
    steal1 = host_steal_s()
    steal_ms = {cpu: round(1e3 * (s - steal0.get(cpu, 0.0)), 1) for cpu, s in steal1.items()}
    late = result.late_cycles
    print(
        f"host wake-up latency ({result.kernel}{', PREEMPT_RT' if result.preempt_rt else ''}): "
        f"median {result.median_us:g} µs, p99 {result.p99_us:g} µs, max {result.max_us} µs; "
        f"{late} of {result.cycles} wake-ups one cycle ({result.cycle_us} µs) or more late, "
        f"{result.over_500us} later than 500 µs; hypervisor steal {steal_ms} ms"
    )
    if args.json:
        write_atomic(args.json, json.dumps(json_doc(result, steal_ms), indent=2) + "\n")
    return 0

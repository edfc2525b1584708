"""``python -m hil bench``: lockstep throughput and real-time latency (hil/bench.py).

The JSON keys of ``--json`` (``lockstep.cycles_per_s``, ``lockstep_recording.cycles_per_s``,
``realtime.latency_us_median/p99/max``, ``skipped_syncs``, ``missed_tpdo_cycles``) are read by
``python3 dev.py bench``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline import cli
from cmdline.progress import Progress
from plant_sim.fmu.arguments import add_fmu_arguments, fmu_spec
from virtual_bus.realtime import add_realtime_options, cpu_number, realtime_options
from virtual_bus.shipped import PAPER_AXIS

from .common import simulated_axis_file, simulated_source

NAME = "bench"
HELP = "lockstep cycles per second and real-time latency"
DESCRIPTION = (
    "Lockstep: control cycles per second through the full stack (bridge, virtual bus, "
    "simulated drive), with and without recording. Real time: SYNC from the wall clock at the "
    "axis' cycle for --seconds: SYNC-to-set-point latency, missed cycles, CPU."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cycles", type=cli.count, default=7000, help="lockstep cycles (7000)")
    parser.add_argument(
        "--seconds", type=cli.positive_float, default=60.0, help="real-time run (60 s)"
    )
    parser.add_argument("--skip-realtime", action="store_true", help="lockstep only")
    parser.add_argument("--skip-lockstep", action="store_true", help="real time only")
    parser.add_argument("--axis", type=Path, default=PAPER_AXIS, help="axis file")
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    parser.add_argument(
        "--rate-hz",
        type=float,
        choices=[1000.0, 2000.0],
        help="real time: SYNC rate (default: the axis' position cycle)",
    )
    parser.add_argument(
        "--drive",
        choices=["auto", "process", "thread"],
        default="auto",
        help="real time: the simulated drive in its own process (udp_multicast in a private "
        "network namespace; needs root), in a thread of the bench, or auto (process if root)",
    )
    parser.add_argument(
        "--drive-cpu",
        type=cpu_number,
        metavar="N",
        help="pin the drive process to CPU N (default with --cpu: another CPU)",
    )
    parser.add_argument(
        "--socketcan",
        metavar="CHANNEL",
        help="real time: the drive process and the bridge on this SocketCAN interface (e.g. "
        "vcan0) instead of udp_multicast in a private network namespace",
    )
    parser.add_argument(
        "--no-host-latency",
        action="store_true",
        help="real time: without cyclictest before the loop (default with --rt-priority and "
        "--cpu where cyclictest is installed: the host's floor in the same run)",
    )
    parser.add_argument(
        "--scope",
        action="store_true",
        help="real time: with the live scope on (bridge run --scope) and a reader polling it "
        "as its page does (docs/scope.md)",
    )
    add_realtime_options(parser)
    add_fmu_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..bench import run_bench

    if args.skip_lockstep and args.skip_realtime:
        raise cli.UsageError("--skip-lockstep and --skip-realtime together leave nothing to run")
    if args.socketcan is not None and args.drive == "thread":
        raise cli.UsageError(
            "--socketcan runs the drive as its own process; not with --drive thread"
        )
    axis = simulated_axis_file(args.axis)  # refused before anything is said or run
    fmu = fmu_spec(args)
    fmu_source = None
    if fmu is not None:  # beside the kernel's axis: its own data sheet configures the bridge
        if args.skip_lockstep:
            raise cli.UsageError("--fmu is measured in lockstep; not with --skip-lockstep")
        fmu_source = simulated_source(argparse.Namespace(**vars(args) | {"axis": None}), None)
    rt = realtime_options(args)
    progress = Progress(f"bridge {NAME}", quiet=args.quiet)
    stages = []
    if not args.skip_lockstep:
        stages.append(f"lockstep: {args.cycles} cycles without and with recording")
    if not args.skip_realtime:
        stages.append(f"real time: {args.seconds:g} s of SYNC from the wall clock")
    progress.stage("; then ".join(stages) + " (results print as each part ends)")
    run_bench(
        axis,
        cycles=args.cycles,
        seconds=None if args.skip_realtime else args.seconds,
        lockstep=not args.skip_lockstep,
        json_path=args.json,
        rate_hz=args.rate_hz,
        rt=rt,
        drive=args.drive,
        drive_cpu=args.drive_cpu,
        host_beside=not args.no_host_latency,
        socketcan=args.socketcan,
        fmu=fmu_source,
        scope=args.scope,
    )
    return 0

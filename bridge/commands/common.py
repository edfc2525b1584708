"""Defaults shared by the ``python -m bridge`` commands."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from plant_sim.axis import AxisConfig, load_axis
from plant_sim.model import AxisPlant
from regulator import RegulatorConfig
from regulator.errors import RegulatorError
from virtual_bus import cli

from ..params import BridgeParams
from ..realtime import RealTimeOptions, RealTimeRefused

ROOT = Path(__file__).resolve().parents[2]
PAPER_AXIS = ROOT / "config" / "paper_axis.toml"
PROG = "python -m bridge"


def regulated_axis(path: Path) -> AxisConfig:
    """The axis file, refused in one line (exit 2) when the regulator cannot run on it
    (e.g. a position cycle above section VII's sampling limit), before anything is written."""
    axis = load_axis(path)
    try:
        RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    except RegulatorError as exc:
        raise cli.UsageError(f"{path}: the regulator cannot run on this axis: {exc}") from None
    return axis


def simulated_axis_file(path: Path) -> AxisConfig:
    """:func:`regulated_axis` for the commands that also simulate the axis (demo, bench):
    the bridge's scaling limits and the physics' limits (substeps) are checked too, in one
    line before anything runs."""
    axis = regulated_axis(path)
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    BridgeParams.for_axis(axis, reg)
    AxisPlant(axis)
    return axis


def default_store_path(axis_path: Path) -> Path:
    """The bridge's parameter store beside its axis file: ``AXIS.bridge-store.json``."""
    return axis_path.with_name(f"{axis_path.stem}.bridge-store.json")


def add_realtime_options(parser: argparse.ArgumentParser) -> None:
    """--rt-priority, --cpu, --lock-memory, --freeze-gc, --busy-poll (bridge.realtime; all
    off by default; refused in one line, exit 1, where the OS does not allow them)."""
    parser.add_argument(
        "--rt-priority",
        type=_priority,
        metavar="N",
        help="run the loop under SCHED_FIFO at priority N (1..99; needs root/CAP_SYS_NICE)",
    )
    parser.add_argument("--cpu", type=cpu_number, metavar="N", help="pin the loop to CPU N")
    parser.add_argument(
        "--lock-memory", action="store_true", help="mlockall(MCL_CURRENT|MCL_FUTURE)"
    )
    parser.add_argument(
        "--freeze-gc",
        action="store_true",
        help="freeze the garbage collector after start-up; collect only between cycles",
    )
    parser.add_argument(
        "--busy-poll",
        action="store_true",
        help="poll the bus while waiting for the TPDOs instead of blocking (for an isolated CPU)",
    )


def _integer(text: str, low: int, high: int | None, allowed: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"{text!r}: {allowed}")
    return value


def _priority(text: str) -> int:
    return _integer(text, 1, 99, "a SCHED_FIFO priority is 1..99")


def cpu_number(text: str) -> int:
    """A CPU number (argparse type)."""
    return _integer(text, 0, None, "a CPU number is >= 0")


def realtime_options(args: argparse.Namespace) -> RealTimeOptions:
    """The real-time options of :func:`add_realtime_options` as :class:`RealTimeOptions`;
    a CPU this process may not use is refused here (RealTimeRefused, exit 1), before any
    work starts."""
    cpu = args.cpu
    if cpu is not None and hasattr(os, "sched_getaffinity"):
        allowed = sorted(os.sched_getaffinity(0))
        if cpu not in allowed:
            raise RealTimeRefused(
                f"--cpu {cpu}: not a CPU this process may use; allowed {allowed}", setting="cpu"
            )
    return RealTimeOptions(
        rt_priority=args.rt_priority,
        cpu=cpu,
        lock_memory=args.lock_memory,
        freeze_gc=args.freeze_gc,
        busy_poll=args.busy_poll,
    )

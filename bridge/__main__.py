"""``python -m bridge COMMAND``: run, demo, busload, bench, eds, config, probe.

Bad arguments or files end with a one-line message and exit status 2 (no traceback); a
failure while running (drive does not answer, bus error) with a one-line message and 1.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import can

from plant_sim.axis import AxisConfig, load_axis
from plant_sim.errors import PlantSimError
from regulator import RegulatorConfig
from regulator.errors import RegulatorError
from virtual_bus import BusConfig, Interface, VirtualBusError
from virtual_bus.errors import BusUnavailableError

from . import od as objdict
from . import probe as probe_command
from .commission import command as config_command
from .eds import render_eds
from .errors import BridgeError, DriveSetupError
from .interpolator import Move, load_move_file, parse_move
from .layout import check_node_id
from .node import DEFAULT_OVERRUN_LIMIT, BridgeConfig
from .profile import load_profile
from .realtime import RealTimeOptions, RealTimeRefused
from .timing import TimeMode

ROOT = Path(__file__).resolve().parent.parent
PAPER_AXIS = ROOT / "config" / "paper_axis.toml"
PROG = "python -m bridge"


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error message (no usage dump) and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


class UsageError(Exception):
    """An argument that passed argparse but is invalid (exit 2)."""


# --- argument types ---------------------------------------------------------------------------
def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number > 0")
    return value


def _integer(text: str, low: int, high: int | None, allowed: str) -> int:
    """``text`` as an integer in low..high (None: no upper bound), else the one-line error
    ``'TEXT': ALLOWED``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"{text!r}: {allowed}")
    return value


def _count(text: str) -> int:
    return _integer(text, 1, None, "must be >= 1")


def _node_id(text: str) -> int:
    try:
        return check_node_id("node-ID", int(text))
    except (ValueError, BridgeError):
        raise argparse.ArgumentTypeError(f"{text!r}: a CANopen node-ID is 1..127") from None


def _move(text: str) -> Move:
    try:
        return parse_move(text)
    except BridgeError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def default_store_path(axis_path: Path) -> Path:
    """The bridge's parameter store beside its axis file: ``AXIS.bridge-store.json``."""
    return axis_path.with_name(f"{axis_path.stem}.bridge-store.json")


def _read_axis(path: Path) -> AxisConfig:
    return load_axis(path)


def _priority(text: str) -> int:
    return _integer(text, 1, 99, "a SCHED_FIFO priority is 1..99")


def _cpu(text: str) -> int:
    return _integer(text, 0, None, "a CPU number is >= 0")


def _add_realtime_options(parser: argparse.ArgumentParser) -> None:
    """--rt-priority, --cpu, --lock-memory, --freeze-gc, --busy-poll (bridge.realtime; all
    off)."""
    parser.add_argument(
        "--rt-priority",
        type=_priority,
        metavar="N",
        help="run the loop under SCHED_FIFO at priority N (1..99; needs root/CAP_SYS_NICE)",
    )
    parser.add_argument("--cpu", type=_cpu, metavar="N", help="pin the loop to CPU N")
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


def _realtime_options(args: argparse.Namespace) -> RealTimeOptions:
    return RealTimeOptions(
        rt_priority=args.rt_priority,
        cpu=args.cpu,
        lock_memory=args.lock_memory,
        freeze_gc=args.freeze_gc,
        busy_poll=args.busy_poll,
    )


def _regulated_axis(path: Path) -> AxisConfig:
    """The axis file, refused (RegulatorError) when the regulator cannot run on it (e.g. a
    position cycle above section VII's sampling limit), before anything is written."""
    axis = load_axis(path)
    RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    return axis


# --- the parser ---------------------------------------------------------------------------------
def build_parser() -> _Parser:
    parser = _Parser(
        prog=PROG,
        description="CANopen bridge running the backlash regulator of Mohammadiasl, 'Vibration "
        "Detection and Backlash Suppression in Machine Tools' (eq. 7, 15) against a CiA 402 "
        "drive in cyclic synchronous velocity mode.",
    )
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=_Parser
    )

    run = sub.add_parser(
        "run",
        help="run the bridge against a drive on a CAN interface (real time)",
        description="Configure the drive over SDO, bring it to Operation Enabled, then close "
        "the loop every SYNC until the moves are done, --seconds pass, a fault stops the axis "
        "or Ctrl-C. Exit 0: done; 1: stopped by a fault or a failure; 2: bad arguments.",
    )
    run.add_argument("--interface", required=True, help="python-can interface, e.g. socketcan")
    run.add_argument("--channel", required=True, help="CAN channel, e.g. can0")
    run.add_argument(
        "--bitrate",
        type=int,
        default=1_000_000,
        help="bit/s, a CiA 301 rate (default 1000000: one axis at 1 ms is 44 %% of it)",
    )
    run.add_argument(
        "--drive-profile",
        type=Path,
        help="drive profile (config/drives/*.toml, `probe --out`); default: adapt to the drive",
    )
    run.add_argument(
        "--node-id",
        type=_node_id,
        default=objdict.DEFAULT_NODE_ID,
        help="the bridge's node-ID (default 1)",
    )
    run.add_argument(
        "--drive-id",
        type=_node_id,
        default=objdict.DEFAULT_DRIVE_ID,
        help="the drive's node-ID (default 2)",
    )
    run.add_argument("--axis", type=Path, required=True, help="axis file (axis-file.md)")
    run.add_argument(
        "--move",
        type=_move,
        action="append",
        default=[],
        metavar="target=X,feed=V[,accel=A][,dwell=S]",
        help="a move in load units, /s, /s^2, s (repeatable)",
    )
    run.add_argument("--move-file", type=Path, help="TOML file of [[move]] tables")
    run.add_argument("--seconds", type=_positive, help="stop after this long")
    run.add_argument(
        "--hold",
        type=_positive,
        default=1.0,
        help="seconds to hold after the last move (default 1)",
    )
    run.add_argument("--no-regulator", action="store_true", help="ordinary control (Fig. 1)")
    run.add_argument("--beta-t", type=_positive, help="vibration threshold beta_T, rad/s")
    run.add_argument(
        "--store",
        type=Path,
        metavar="FILE",
        help="parameter store of 1010h/1011h, loaded at start (default: beside the axis "
        "file, AXIS.bridge-store.json)",
    )
    run.add_argument("--trace", type=Path, help="trace file to write (trace-file.md)")
    run.add_argument("--bus-log", type=Path, help="candump log of the bus traffic")
    run.add_argument(
        "--clock",
        choices=[m.value for m in TimeMode],
        default="realtime",
        help="realtime (default; hardware) or lockstep (simulated drives)",
    )
    _add_realtime_options(run)
    run.add_argument(
        "--overrun-limit",
        type=_count,
        default=DEFAULT_OVERRUN_LIMIT,
        metavar="N",
        help=f"stop the axis after N overrunning cycles in a row (default {DEFAULT_OVERRUN_LIMIT})",
    )

    demo = sub.add_parser(
        "demo",
        help="the paper's section X over the bus with the simulated drive",
        description="Runs section X (Fig. 8 and Fig. 9) with the bridge closing the loop over "
        "CANopen against the simulated drive; writes the summary.json and figures of "
        "`python -m plant_sim paper`, the traces and the bus logs.",
    )
    demo.add_argument("--out", type=Path, required=True, help="output directory")
    demo.add_argument(
        "--axis", type=Path, default=PAPER_AXIS, help="axis file (default config/paper_axis.toml)"
    )
    demo.add_argument(
        "--bus",
        choices=["virtual", "socketcan"],
        default="virtual",
        help="virtual (default) or socketcan on vcan0",
    )

    busload = sub.add_parser(
        "busload",
        help="bus load of the PDO layout (SYNC + TPDO1 + TPDO2 + RPDO1 per axis)",
        description="Worst-case bit stuffing, 11-bit identifiers.",
    )
    busload.add_argument("--bitrate", type=int, default=1_000_000, help="bit/s (default 1000000)")
    busload.add_argument("--cycle-us", type=_positive, help="SYNC period in µs (default: axis)")
    busload.add_argument(
        "--axis",
        type=Path,
        default=PAPER_AXIS,
        help="axis file whose position cycle is the default",
    )
    busload.add_argument("--axes", type=_count, default=1, help="number of drives (default 1)")

    bench = sub.add_parser(
        "bench",
        help="lockstep cycles per second and real-time latency",
        description="Lockstep: control cycles per second through the full stack (bridge, "
        "virtual bus, simulated drive), with and without recording. Real time: SYNC from the "
        "wall clock at the axis' cycle for --seconds: SYNC-to-set-point latency, missed "
        "cycles, CPU.",
    )
    bench.add_argument("--cycles", type=_count, default=7000, help="lockstep cycles (7000)")
    bench.add_argument("--seconds", type=_positive, default=60.0, help="real-time run (60 s)")
    bench.add_argument("--skip-realtime", action="store_true", help="lockstep only")
    bench.add_argument("--skip-lockstep", action="store_true", help="real time only")
    bench.add_argument("--axis", type=Path, default=PAPER_AXIS, help="axis file")
    bench.add_argument("--json", type=Path, help="also write the figures to this file")
    bench.add_argument(
        "--rate-hz",
        type=float,
        choices=[1000.0, 2000.0],
        help="real time: SYNC rate (default: the axis' position cycle)",
    )
    bench.add_argument(
        "--drive",
        choices=["auto", "process", "thread"],
        default="auto",
        help="real time: the simulated drive in its own process (udp_multicast in a private "
        "network namespace; needs root), in a thread of the bench, or auto (process if root)",
    )
    bench.add_argument(
        "--drive-cpu",
        type=_cpu,
        metavar="N",
        help="pin the drive process to CPU N (default with --cpu: another CPU)",
    )
    _add_realtime_options(bench)

    eds = sub.add_parser(
        "eds",
        help="write (or --check) config/bridge.eds from the object table",
        description="Renders the bridge's EDS (CiA 306) from bridge.od.OBJECTS.",
    )
    eds.add_argument("--out", type=Path, default=objdict.DEFAULT_EDS_PATH, help="EDS path")
    eds.add_argument("--check", action="store_true", help="exit 1 if the file differs")

    config = sub.add_parser(
        config_command.NAME,
        help=config_command.HELP,
        description=(config_command.__doc__ or "").split("\n\n")[0],
    )
    config_command.add_arguments(config)
    probe = sub.add_parser(
        probe_command.NAME, help=probe_command.HELP, description=probe_command.__doc__
    )
    probe_command.add_arguments(probe)
    return parser


# --- commands -------------------------------------------------------------------------------------
def _cmd_run(args: argparse.Namespace) -> int:
    from .run import RunOptions, run_bridge

    moves = list(args.move)
    if args.move_file is not None:
        moves += load_move_file(args.move_file)
    options = RunOptions(
        bus=BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate),
        axis=_regulated_axis(args.axis),
        bridge=BridgeConfig(
            node_id=args.node_id,
            drive_id=args.drive_id,
            store_path=args.store or default_store_path(args.axis),
            profile=None if args.drive_profile is None else load_profile(args.drive_profile),
        ),
        moves=tuple(moves),
        seconds=args.seconds,
        hold_s=args.hold,
        regulator_enabled=not args.no_regulator,
        beta_t_rad_s=args.beta_t,
        trace_path=args.trace,
        bus_log_path=args.bus_log,
        time_mode=TimeMode(args.clock),
        realtime=_realtime_options(args),
        overrun_limit=args.overrun_limit,
    )
    if not moves and args.seconds is None:
        raise UsageError("give --move, --move-file or --seconds (otherwise it never ends)")
    store = options.bridge.store_path
    if store is not None and (store.is_dir() or not store.parent.is_dir()):
        raise UsageError(f"--store {store}: not a file in an existing directory")
    result = run_bridge(options)
    print(
        f"{result.cycles} cycles; state {result.state.name}; missed TPDOs "
        f"{result.missed_tpdos}, late {result.late_tpdos}, skipped SYNCs {result.skipped_syncs}"
    )
    if result.stop_message != "none":
        print(f"stopped: {result.stop_message}")
        return 1
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import print_summary, run_demo

    axis = _regulated_axis(args.axis)
    interface = Interface.VIRTUAL if args.bus == "virtual" else Interface.SOCKETCAN
    summary = run_demo(args.out, axis, str(args.axis), interface)
    print_summary(summary, args.out)
    return 0


def _cmd_busload(args: argparse.Namespace) -> int:
    from .busload import report

    cycle_s = (
        args.cycle_us * 1e-6 if args.cycle_us else _read_axis(args.axis).control.position_cycle
    )
    print(report(args.axes, cycle_s, args.bitrate))
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from .bench import run_bench

    if args.skip_lockstep and args.skip_realtime:
        raise UsageError("--skip-lockstep and --skip-realtime together leave nothing to run")
    run_bench(
        _regulated_axis(args.axis),
        cycles=args.cycles,
        seconds=None if args.skip_realtime else args.seconds,
        lockstep=not args.skip_lockstep,
        json_path=args.json,
        rate_hz=args.rate_hz,
        rt=_realtime_options(args),
        drive=args.drive,
        drive_cpu=args.drive_cpu,
    )
    return 0


def _cmd_eds(args: argparse.Namespace) -> int:
    text = render_eds()
    if args.check:
        current = args.out.read_text(encoding="utf-8") if args.out.is_file() else None
        if current != text:
            print(f"{args.out}: differs from bridge.od.OBJECTS (run `{PROG} eds`)")
            return 1
        print(f"{args.out}: up to date")
        return 0
    args.out.write_text(text, encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


COMMANDS = {
    "run": _cmd_run,
    "demo": _cmd_demo,
    "busload": _cmd_busload,
    "bench": _cmd_bench,
    "eds": _cmd_eds,
    config_command.NAME: config_command.run,
    probe_command.NAME: probe_command.run,
}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    # the bridge's master reports a failed SDO transfer itself, with object and tries
    logging.getLogger("canopen.sdo.client").setLevel(logging.CRITICAL)
    where = f"{PROG} {args.command}"
    try:
        return COMMANDS[args.command](args)
    except DriveSetupError as exc:
        print(f"{where}: drive start-up failed: {exc}", file=sys.stderr)
        return 1
    except BusUnavailableError as exc:
        print(f"{where}: {exc}", file=sys.stderr)
        return 1
    except RealTimeRefused as exc:
        print(f"{where}: refused: {exc}", file=sys.stderr)
        return 1
    except RegulatorError as exc:
        axis = getattr(args, "axis", None)
        print(
            f"{where}: error: {axis}: the regulator cannot run on this axis: {exc}", file=sys.stderr
        )
        return 2
    except (UsageError, BridgeError, PlantSimError, VirtualBusError) as exc:
        print(f"{where}: error: {exc}", file=sys.stderr)
        return 2
    except can.CanError as exc:
        print(f"{where}: CAN bus error: {exc}", file=sys.stderr)
        return 1
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as exc:
        print(f"{where}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{where}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

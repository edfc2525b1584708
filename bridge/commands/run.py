"""``python -m bridge run``: the bridge against a drive on a CAN interface (real time)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from cmdline import cli
from virtual_bus import BusConfig
from virtual_bus.formats.drive_profile import load_profile
from virtual_bus.realtime import add_realtime_options, realtime_options

from .. import od as objdict
from ..errors import BridgeError, DriveSetupError
from ..interpolator import Move, load_move_file, parse_move
from ..master import DriveSetup
from ..node import DEFAULT_OVERRUN_LIMIT, BridgeConfig
from ..timing import DEFAULT_LOCKSTEP_WAIT_S, TimeMode
from .common import add_clock_argument, default_store_path, regulated_axis

if TYPE_CHECKING:
    from ..node import Bridge
    from ..run import RunOptions, Watch

NAME = "run"
HELP = "run the bridge against a drive on a CAN interface (real time)"
DESCRIPTION = (
    "Configure the drive over SDO (its supervision of the bridge included: heartbeat consumer "
    "1016h, 6007h), bring it to Operation Enabled, then close the loop every SYNC until the "
    "moves are done, --seconds pass, a fault stops the axis, or SIGINT/SIGTERM. At the end "
    "the stop reaches the drive (by SYNC, else SDO, else NMT) and the drive is confirmed at "
    "standstill. Exit 0: done; 1: stopped by a fault, not confirmed at standstill, or a "
    "failure; 2: bad arguments."
)


def _move(text: str) -> Move:
    try:
        return parse_move(text)
    except BridgeError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..scope import add_scope_argument
    from ..status import DEFAULT_TARGET_TOLERANCE

    rates = "bit/s, a CiA 301 rate (default 1000000: one axis at 1 ms is 44 %% of it)"
    cli.add_can_bus(parser, bitrate_help=rates)
    parser.add_argument(
        "--drive-profile",
        type=Path,
        help="drive profile (config/drives/*.toml, `probe --out`); default: adapt to the drive",
    )
    parser.add_argument(
        "--node-id",
        type=cli.node_id,
        default=objdict.DEFAULT_NODE_ID,
        help="the bridge's node-ID (default 1)",
    )
    parser.add_argument(
        "--drive-id",
        type=cli.node_id,
        default=objdict.DEFAULT_DRIVE_ID,
        help="the drive's node-ID (default 2)",
    )
    parser.add_argument("--axis", type=Path, required=True, help="axis file (axis-file.md)")
    parser.add_argument(
        "--move",
        type=_move,
        action="append",
        default=[],
        metavar="target=X,feed=V[,accel=A][,dwell=S]",
        help="a move in load units, /s, /s^2, s (repeatable)",
    )
    parser.add_argument("--move-file", type=Path, help="TOML file of [[move]] tables")
    parser.add_argument("--seconds", type=cli.positive_float, help="stop after this long")
    parser.add_argument(
        "--hold",
        type=cli.positive_float,
        default=1.0,
        help="seconds to hold after the last move (default 1)",
    )
    parser.add_argument("--no-regulator", action="store_true", help="ordinary control (Fig. 1)")
    parser.add_argument(
        "--beta-t", type=cli.positive_float, help="vibration threshold beta_T, rad/s"
    )
    parser.add_argument(
        "--store",
        type=Path,
        metavar="FILE",
        help="parameter store of 1010h/1011h, loaded at start (default: beside the axis "
        "file, AXIS.bridge-store.json)",
    )
    parser.add_argument("--trace", type=Path, help="trace file to write (trace-file.md)")
    parser.add_argument("--bus-log", type=Path, help="candump log of the bus traffic")
    add_clock_argument(parser)
    add_realtime_options(parser)
    parser.add_argument(
        "--overrun-limit",
        type=cli.count,
        default=DEFAULT_OVERRUN_LIMIT,
        metavar="N",
        help=f"stop the axis after N overrunning cycles in a row (default {DEFAULT_OVERRUN_LIMIT})",
    )
    parser.add_argument(
        "--lockstep-wait",
        type=cli.bounded_float(1e-3, 60.0),
        default=DEFAULT_LOCKSTEP_WAIT_S,
        metavar="S",
        help="--clock lockstep: wall seconds to wait for a TPDO before counting it missed "
        f"(default {DEFAULT_LOCKSTEP_WAIT_S:g}; more for a slow simulated drive or a busy "
        "host, up to 60)",
    )
    parser.add_argument(
        "--target-tolerance",
        type=cli.positive_float,
        default=DEFAULT_TARGET_TOLERANCE * 1e6,
        metavar="UM",
        help="the verdict calls the target reached when the load ends this close to it, µm "
        f"(µrad on a rotary axis; default {DEFAULT_TARGET_TOLERANCE * 1e6:g})",
    )
    add_scope_argument(parser, "a live scope of the run")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the result and its verdict as one JSON document (SI units) on stdout",
    )


def _both(first: Watch, second: Watch) -> Watch:
    def watch(bridge: Bridge, options: RunOptions) -> None:
        first(bridge, options)
        second(bridge, options)

    return watch


def run(args: argparse.Namespace) -> int:
    from ..run import RunOptions, run_bridge
    from ..scope import Scope
    from ..status import RunTalk

    moves = list(args.move)
    if args.move_file is not None:
        moves += load_move_file(args.move_file)
    talk = RunTalk(target_tolerance=args.target_tolerance / 1e6)
    scope = None if args.scope is None else Scope(args.scope, stream=talk.stream)
    watch = talk.attach if scope is None else _both(talk.attach, scope.attach)
    options = RunOptions(
        bus=BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate),
        axis=regulated_axis(args.axis),
        bridge=BridgeConfig(
            node_id=args.node_id,
            drive_id=args.drive_id,
            store_path=args.store or default_store_path(args.axis),
            profile=None if args.drive_profile is None else load_profile(args.drive_profile),
            # lockstep: a simulated drive started beside the bridge may still be compiling
            drive_setup=DriveSetup(wait_for_drive=args.clock == TimeMode.LOCKSTEP.value),
        ),
        moves=tuple(moves),
        seconds=args.seconds,
        hold_s=args.hold,
        regulator_enabled=not args.no_regulator,
        beta_t_rad_s=args.beta_t,
        trace_path=args.trace,
        bus_log_path=args.bus_log,
        time_mode=TimeMode(args.clock),
        realtime=realtime_options(args),
        overrun_limit=args.overrun_limit,
        lockstep_wait_s=args.lockstep_wait,
        watch=watch,
    )
    if args.clock != TimeMode.LOCKSTEP.value and args.lockstep_wait != DEFAULT_LOCKSTEP_WAIT_S:
        raise cli.UsageError("--lockstep-wait applies to --clock lockstep only")
    if not moves and args.seconds is None:
        raise cli.UsageError("give --move, --move-file or --seconds (otherwise it never ends)")
    store = options.bridge.store_path
    if store is not None and (store.is_dir() or not store.parent.is_dir()):
        raise cli.UsageError(f"--store {store}: not a file in an existing directory")
    try:
        result = run_bridge(options)
    except KeyboardInterrupt:
        raise DriveSetupError(
            "interrupted during the start-up (the drive's supervision of the bridge, where it "
            "was configured, stops it)"
        ) from None
    finally:
        talk.close()
        if scope is not None:
            scope.close()
    drive = args.drive_id
    if args.json:
        print(json.dumps(talk.document(result), ensure_ascii=False))
        return 0 if result.stop_message == "none" and result.stopped_safely else 1
    print(talk.verdict(result).line())
    print(
        f"{result.cycles} cycles; state {result.state.name}; missed TPDOs "
        f"{result.missed_tpdos}, late {result.late_tpdos}, skipped SYNCs {result.skipped_syncs}"
    )
    for line in result.supervision:
        print(f"drive {drive} watches the bridge: {line}")
    for note in result.supervision_notes:
        print(f"warning: {note}")
    if result.interrupted is not None:
        print(f"{result.interrupted}: the run ended")
    if result.halt is not None:
        print(result.halt.describe(drive))
    if result.restored:
        print(f"drive {drive}: given back as before the start-up: {', '.join(result.restored)}")
    for why in result.not_restored:
        print(f"warning: drive {drive}: not given back: {why}")
    print(
        "refused frames (2110h): "
        + ", ".join(f"{fault.name.lower()} {n}" for fault, n in result.refused_frames)
    )
    if result.stop_message != "none":
        print(f"stopped: {result.stop_message}")
        return 1
    if not result.stopped_safely:
        print(f"stopped: drive {drive} not confirmed at standstill out of Operation Enabled")
        return 1
    return 0

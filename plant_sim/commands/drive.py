"""``python -m plant_sim drive --interface I --channel C --node-id N --axis AXIS.toml``
(or ``--fmu FMU [--fmu-param ...]``).

The simulated CiA 402 drive (``docs/drive.md``) as a process of its own on a CAN bus: it
loads the physics (the compiled kernel of the axis file, or an FMU as the plant with the
axis file or its data sheet as the drive's configuration, docs/fmu.md), sends its boot-up
message, serves NMT, SDO, SYNC (one position cycle of
the physics per SYNC) and PDOs until SIGINT or SIGTERM, then leaves the bus, closes it and
exits 0. Output: one line when the boot-up is out, one line at the end. Bad arguments or
files: one line, exit 2; a real-time option the OS refuses: one line, exit 1.

Real-time options (the bridge's, :mod:`virtual_bus.realtime`): ``--rt-priority N``,
``--cpu N``, ``--lock-memory``, ``--freeze-gc``, ``--busy-poll`` (poll the bus around the
instant the next SYNC is due instead of blocking: the drive answers without a thread's
wake-up delay). They are applied to the one thread that serves the bus after the boot-up.

Interfaces: ``virtual`` (python-can's in-process bus: only useful to a harness in the same
process), ``socketcan`` (vcan0, can0), ``udp_multicast`` (only inside a private network
namespace, ``virtual_bus.netns``; the channel defaults to the group 239.74.163.2), or any
other python-can interface whose driver is installed.
"""

from __future__ import annotations

import argparse
import signal
import threading
import tomllib
from pathlib import Path
from types import FrameType

from cmdline import cli
from virtual_bus import BusConfig, VirtualBusError, open_bus
from virtual_bus.config import CIA301_BITRATES, DEFAULT_BITRATE
from virtual_bus.realtime import add_realtime_options, realtime_options

from ..drive.config import DriveConfig, TimeMode
from ..drive.drive import SimulatedDrive
from ..drive.errors import DriveConfigError
from ..drive.process import DriveProcessConfig, serve
from ..fmu.arguments import add_fmu_arguments, axis_source

NAME = "drive"
HELP = (
    "run the simulated CiA 402 drive on a CAN bus until SIGINT/SIGTERM (its physics steps "
    "one position cycle per SYNC)"
)
CLOCKS = {"realtime": TimeMode.REAL_TIME, "lockstep": TimeMode.LOCKSTEP}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--interface",
        required=True,
        help="python-can interface: virtual, socketcan, udp_multicast (private network "
        "namespace only), or another installed one",
    )
    parser.add_argument(
        "--channel",
        help="channel: vcan0 / can0 (socketcan), a name (virtual), a multicast group "
        "(udp_multicast; default 239.74.163.2)",
    )
    parser.add_argument(
        "--node-id", type=cli.node_id, default=2, help="the drive's node-ID, 1..127 (default 2)"
    )
    parser.add_argument(
        "--axis",
        type=Path,
        metavar="AXIS.toml",
        help="axis file (with --fmu: the drive's configuration; default the FMU's data sheet)",
    )
    parser.add_argument(
        "--bitrate",
        type=int,
        default=DEFAULT_BITRATE,
        help=f"bit/s, one of {list(CIA301_BITRATES)} (hardware interfaces)",
    )
    parser.add_argument(
        "--clock",
        choices=sorted(CLOCKS),
        default="realtime",
        help="heartbeat on the wall clock (realtime, default) or on SYNC time (lockstep)",
    )
    parser.add_argument(
        "--drive-profile",
        type=Path,
        metavar="P.toml",
        help="reserved for drive profiles (config/drives/*.toml); not read by this drive yet",
    )
    add_realtime_options(parser)
    add_fmu_arguments(parser)


def check_drive_profile(path: Path | None) -> None:
    """``--drive-profile`` is reserved: a readable TOML file is still refused (this drive
    serves the contract's object dictionary, config/drive.eds, only)."""
    if path is None:
        return
    try:
        tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DriveConfigError(f"--drive-profile {path}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise DriveConfigError(
            f"--drive-profile {path}: not a readable TOML file ({exc})"
        ) from None
    raise DriveConfigError(
        f"--drive-profile {path}: drive profiles are reserved and not supported by this "
        "drive yet; it serves config/drive.eds (omit the option)"
    )


def run(args: argparse.Namespace) -> int:
    check_drive_profile(args.drive_profile)
    source = axis_source(args, args.axis)
    axis = source.axis
    rt = realtime_options(args)
    try:
        bus_config = BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate)
        config = DriveProcessConfig(
            axis,
            args.node_id,
            DriveConfig(time_mode=CLOCKS[args.clock]),
            realtime=rt,
            fmu=source.fmu,
        )
        bus = open_bus(bus_config)
    except VirtualBusError as exc:
        raise DriveConfigError(str(exc)) from None
    where = bus.channel_info
    stop = threading.Event()
    received: list[str] = []

    def on_signal(number: int, _frame: FrameType | None) -> None:
        received.append(signal.Signals(number).name)
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    options = f"; real time: {rt.describe()}" if rt.any else ""
    if source.fmu is not None:
        options += f"; plant: FMU {source.fmu.describe()}"

    def ready(drive: SimulatedDrive) -> None:
        print(
            f"drive {drive.node_id}: boot-up sent on {where}{options}; serving until "
            "SIGINT/SIGTERM",
            flush=True,
        )

    try:
        result = serve(config, bus, stop, ready=ready)
    finally:
        bus.shutdown()
        for number, handler in previous.items():
            signal.signal(number, handler)
    why = received[0] if received else "stop"
    print(f"drive {args.node_id}: stopped on {why}, bus closed; {result.summary()}", flush=True)
    return 0

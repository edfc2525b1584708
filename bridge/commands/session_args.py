"""Arguments and the bridge of the commissioning tests over the bus (``freqresp``, ``tune``):
the bridge is started against the drive like ``bridge run`` (start-up over SDO, CiA 402 to
Operation Enabled), the test runs, the axis is disabled at the end."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from pathlib import Path

from cmdline import cli
from virtual_bus import BusConfig, open_bus
from virtual_bus.formats.drive_profile import load_profile

from .. import od as objdict
from ..node import Bridge, BridgeConfig
from ..objects import params_with_store
from ..run import RunOptions, params_for
from ..scaling import LOAD_INCREMENTS_PER_UNIT
from ..store import ParameterStore
from ..timing import LockstepPacer, Pacer, RealTimePacer, TimeMode
from .common import add_clock_argument, default_store_path, regulated_axis


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_can_bus(parser)
    parser.add_argument("--drive-profile", type=cli.existing_file, help="drive profile (TOML)")
    parser.add_argument(
        "--node-id", type=cli.node_id, default=objdict.DEFAULT_NODE_ID, help="bridge (1)"
    )
    parser.add_argument(
        "--drive-id", type=cli.node_id, default=objdict.DEFAULT_DRIVE_ID, help="drive (2)"
    )
    parser.add_argument("--axis", type=cli.existing_file, required=True, help="axis file")
    parser.add_argument(
        "--store",
        type=cli.new_file,
        metavar="FILE",
        help="parameter store of 1010h (default: AXIS.bridge-store.json beside the axis file)",
    )
    add_clock_argument(parser)
    cli.add_output_dir(parser, "report directory")


@contextlib.contextmanager
def started_bridge(args: argparse.Namespace) -> Iterator[Bridge]:
    """The bridge of ``args`` on its bus, started against the drive; closed after."""
    axis = regulated_axis(args.axis)
    bridge_config = BridgeConfig(
        node_id=args.node_id,
        drive_id=args.drive_id,
        store_path=args.store or default_store_path(args.axis),
        profile=None if args.drive_profile is None else load_profile(args.drive_profile),
    )
    bus_config = BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate)
    params = params_for(RunOptions(bus=bus_config, axis=axis, bridge=bridge_config))
    store_path: Path | None = bridge_config.store_path
    if store_path is not None:
        params = params_with_store(
            params,
            LOAD_INCREMENTS_PER_UNIT[axis.kind],
            bridge_config.drive_id,
            ParameterStore(store_path),
        )
    pacer: Pacer = (
        LockstepPacer(params.cycle_s)
        if TimeMode(args.clock) is TimeMode.LOCKSTEP
        else RealTimePacer(params.cycle_s)
    )
    bus = open_bus(bus_config)
    try:
        bridge = Bridge(bus, params, axis.kind, pacer, config=bridge_config)
        try:
            bridge.start()
            yield bridge
        finally:
            bridge.close()
    finally:
        bus.shutdown()

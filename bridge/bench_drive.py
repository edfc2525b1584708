"""``python -m bridge.bench_drive AXIS --channel GROUP``: the simulated drive as its own process
for ``python -m bridge bench`` (real time), on a python-can ``udp_multicast`` bus.

Runs :class:`plant_sim.drive.SimulatedDrive` of the axis file (node-ID 2, real-time mode:
heartbeat on the wall clock) and receives in the main thread (:meth:`SimulatedDrive.polled`,
woken by ``select`` on the bus socket) until SIGTERM or SIGINT. Only inside a private network
namespace (the bench creates one); never on the host's interfaces.
"""

from __future__ import annotations

import argparse
import select
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

import can

from plant_sim.axis import load_axis
from plant_sim.drive import DriveConfig, SimulatedDrive, TimeMode


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bridge.bench_drive")
    parser.add_argument("axis", type=Path)
    parser.add_argument("--channel", required=True, help="udp_multicast group")
    parser.add_argument("--node-id", type=int, default=2)
    args = parser.parse_args(argv)
    axis = load_axis(args.axis)
    stop = [False]

    def on_signal(signum: int, frame: object) -> None:
        stop[0] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    bus = can.Bus(interface="udp_multicast", channel=args.channel, receive_own_messages=False)
    try:
        drive = SimulatedDrive(bus, args.node_id, axis, DriveConfig(time_mode=TimeMode.REAL_TIME))
        with drive, drive.polled() as poll:
            fd = bus.fileno()
            while not stop[0]:
                try:
                    ready, _, _ = select.select([fd], [], [], 0.1)
                except InterruptedError:
                    continue
                if ready:
                    poll()
            drive.check()
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

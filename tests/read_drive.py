"""A fresh process that reads the simulated drive (node 2) over SDO with python canopen's own
master and prints what it found as one JSON line: what a bridge that is gone left behind.

    python -m tests.read_drive INTERFACE CHANNEL [--until-rest] [--write IIII:SS=VALUE]

``--until-rest``: read until the drive is out of Operation Enabled and Fault Reaction Active
with the motor at rest (606Ch at most 0.1 rad/s and 6064h the same in two reads in a row), a
wait for a state (bounded only by :data:`BOUND_S`, a backstop for a drive that hangs).
Every SDO request is repeated until answered, within the same backstop: a busy machine may
hold an answer longer than any fixed timeout. ``--write``: only download VALUE (an integer of the
object's type), as a tool beside the bridge would (e.g. a TPDO switched off), and end: a
second SDO client on the drive's one SDO channel would take the bridge's answers.
"""

from __future__ import annotations

import json
import math
import sys
import time

import canopen
from canopen.sdo import SdoCommunicationError

from bridge.cycle import Drive402State, drive_state
from virtual_bus import BusConfig, open_bus

EDS = "config/drive.eds"
BOUND_S = 600.0
#: 606Ch at most this many increments/s is rest (0.1 rad/s at 2^20 per revolution).
REST_INC_S = 0.1 * 2**20 / (2 * math.pi)
MOVING = (Drive402State.OPERATION_ENABLED, Drive402State.FAULT_REACTION_ACTIVE)
OBJECTS = {
    "statusword": (0x6041, 0),
    "velocity": (0x606C, 0),
    "position": (0x6064, 0),
    "load_nm": (0x60E4, 1),
    "error_code": (0x603F, 0),
    "consumer": (0x1016, 1),
    "syncs": (0x2103, 0),
    **{f"refused_{sub}": (0x2105, sub) for sub in range(1, 8)},
}


def main(interface: str, channel: str, until_rest: bool, write: str | None = None) -> int:
    deadline = time.monotonic() + BOUND_S
    bus = open_bus(BusConfig(interface=interface, channel=channel))
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        node = network.add_node(2, EDS)
        node.sdo.RESPONSE_TIMEOUT = 1.0

        def read(index: int, sub: int) -> int:
            while True:
                try:
                    var = node.sdo[index] if sub == 0 else node.sdo[index][sub]
                    return int(var.raw)
                except SdoCommunicationError:
                    if time.monotonic() > deadline:
                        raise

        if write is not None:
            where, _, value = write.partition("=")
            index, _, sub = where.partition(":")
            var = node.sdo[int(index, 16)][int(sub, 16)]
            while True:
                try:
                    var.raw = int(value, 0)
                    break
                except SdoCommunicationError:
                    if time.monotonic() > deadline:
                        raise
            print(json.dumps({"written": write}), flush=True)
            return 0  # and off the drive's SDO channel: the bridge may use it now
        got = {name: read(*key) for name, key in OBJECTS.items()}
        reads = 1
        while until_rest:
            state = drive_state(got["statusword"])
            before = got["position"]
            got = {name: read(*key) for name, key in OBJECTS.items()}
            reads += 1
            rest = abs(got["velocity"]) <= REST_INC_S and got["position"] == before
            if state not in MOVING and drive_state(got["statusword"]) not in MOVING and rest:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"the drive is not at rest after {BOUND_S:g} s: {got}")
        got["state"] = drive_state(got["statusword"]).name
        got["reads"] = reads
        print(json.dumps(got), flush=True)
    finally:
        network.disconnect()
        bus.shutdown()
    return 0


if __name__ == "__main__":
    rest = sys.argv[3:]
    wanted = rest[rest.index("--write") + 1] if "--write" in rest else None
    sys.exit(main(sys.argv[1], sys.argv[2], "--until-rest" in rest, wanted))

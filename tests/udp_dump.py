"""``candump -L`` for the udp_multicast bus: every frame of the group as one line, read by
python-can's own ``UdpMulticastBus`` (not the project's ``LoopbackUdpBus``): an observer of
the bus written by others, as ``candump`` is on vcan0.

    python -m tests.udp_dump GROUP

Lines: ``(1764000000.123456) udp 123#11223344`` (receive time, epoch seconds), ``listening``
first once the socket has joined the group. Ends on SIGINT/SIGTERM.
"""

from __future__ import annotations

import signal
import sys
import time

import can


def main(group: str) -> int:
    bus = can.Bus(interface="udp_multicast", channel=group, receive_own_messages=False)
    stop = False

    def end(_signum: int, _frame: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, end)
    signal.signal(signal.SIGINT, end)
    print("listening", flush=True)
    try:
        while not stop:
            msg = bus.recv(0.1)
            if msg is None:
                continue
            width = 8 if msg.is_extended_id else 3
            body = f"R{msg.dlc}" if msg.is_remote_frame else bytes(msg.data).hex().upper()
            print(f"({time.time():.6f}) udp {msg.arbitration_id:0{width}X}#{body}", flush=True)
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))

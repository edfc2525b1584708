"""python-can's ``udp_multicast`` bus, confined to a private network namespace and without
the echo of its own frames.

Multicast is looped back to every socket of the host that joined the group, the sender's
own included (``IP_MULTICAST_LOOP``; python-can's ``UdpMulticastBus`` says
``receive_own_messages`` is unsupported, and in fact always receives its own frames). A CAN
controller does not receive its own frames, and the bridge and the drive rely on that (a
master would see its own SYNC as a second SYNC producer). :class:`LoopbackUdpBus` tags each
frame it sends with a token of its own in the ``channel`` field python-can packs with the
frame, and drops received frames carrying that token.
"""

from __future__ import annotations

import copy
import uuid

import can
from can.interfaces.udp_multicast import UdpMulticastBus

from virtual_bus.errors import BusConfigError
from virtual_bus.netns import UDP_GROUP, private_namespace_problem


class LoopbackUdpBus(UdpMulticastBus):
    """``UdpMulticastBus`` on ``channel`` (default :data:`UDP_GROUP`) that refuses to open
    outside a private network namespace (:func:`private_namespace_problem`) and never
    returns its own frames. Received frames carry ``channel`` = the group."""

    def __init__(self, channel: str = UDP_GROUP, *, fd: bool = False) -> None:
        problem = private_namespace_problem()
        if problem is not None:
            raise BusConfigError(
                f"interface 'udp_multicast' is not allowed here: it sends frames to a real "
                f"network interface ({problem}); use it only inside a private network "
                "namespace (virtual_bus.netns), or use 'virtual' or 'socketcan'"
            )
        super().__init__(channel=channel, fd=fd)
        self.group = channel
        self._token = f"own-{uuid.uuid4().hex}"
        self.channel_info = f"udp_multicast group {channel}"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        tagged = copy.copy(msg)
        tagged.channel = self._token
        super().send(tagged, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg, filtered = super()._recv_internal(timeout)
        if msg is None:
            return None, filtered
        if msg.channel == self._token:
            return None, filtered  # our own frame, looped back by the kernel
        msg.channel = self.group
        return msg, filtered

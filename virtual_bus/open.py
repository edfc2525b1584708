"""Open the bus a :class:`BusConfig` asks for, deciding AUTO from what the host offers.

AUTO picks SocketCAN when the kernel accepts a raw CAN socket *and* the configured channel
(default ``vcan0``) is a virtual CAN interface; otherwise python-can's in-process ``virtual``
interface. AUTO never picks a hardware CAN interface (that needs ``Interface.SOCKETCAN``).
"""

from __future__ import annotations

import contextlib
import logging
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import can

from virtual_bus.config import BusConfig, Interface
from virtual_bus.errors import BusUnavailableError, InterfaceUnavailableError, Missing
from virtual_bus.inprocess import InProcessBus
from virtual_bus.netns import UDP_GROUP
from virtual_bus.udp import LoopbackUdpBus
from virtual_bus.vcan import DEFAULT_VCAN_CHANNEL, HostProbe, LinkKind

_SYSTEM_PROBE = HostProbe()


@dataclass(frozen=True)
class BusChoice:
    """What :func:`open_bus` will open, and why.

    interface: ``Interface.VIRTUAL``, ``Interface.SOCKETCAN`` or another python-can name
        (never ``Interface.AUTO``). channel: the channel passed to python-can (``None`` only
        for other interfaces without a configured channel). reason: one sentence.
    """

    interface: Interface | str
    channel: str | None
    reason: str

    @property
    def python_can_interface(self) -> str:
        """The interface name python-can uses."""
        return self.interface.value if isinstance(self.interface, Interface) else self.interface


def _socketcan_or_error(config: BusConfig, probe: HostProbe) -> BusChoice:
    channel = config.socketcan_channel
    problem = probe.af_can_problem()
    if problem is not None:
        raise BusUnavailableError(
            f"SocketCAN requested on {channel}, but {problem}",
            missing=Missing.AF_CAN,
            channel=channel,
        )
    kind = probe.link_kind(channel)
    if kind is LinkKind.MISSING:
        raise BusUnavailableError(
            f"SocketCAN requested, but interface {channel} does not exist; "
            f"create it with `python -m virtual_bus setup {channel}` (needs root)",
            missing=Missing.INTERFACE,
            channel=channel,
        )
    if kind is LinkKind.NOT_CAN:
        raise BusUnavailableError(
            f"SocketCAN requested, but {channel} is not a CAN interface "
            "(/sys/class/net/<name>/type is not ARPHRD_CAN=280)",
            missing=Missing.NOT_CAN,
            channel=channel,
        )
    return BusChoice(
        Interface.SOCKETCAN, channel, f"SocketCAN requested; {channel} is a {kind.value}"
    )


def _auto(config: BusConfig, probe: HostProbe) -> BusChoice:
    channel = config.socketcan_channel
    problem = probe.af_can_problem()
    if problem is None:
        kind = probe.link_kind(channel)
        if kind is LinkKind.VCAN:
            return BusChoice(
                Interface.SOCKETCAN, channel, f"kernel has SocketCAN and {channel} is a vcan"
            )
        why = f"interface {channel} {kind.value}"
        if kind is LinkKind.MISSING:
            why += f" (create it with `python -m virtual_bus setup {channel}`)"
        elif kind is LinkKind.CAN:
            why += " (AUTO never uses hardware; ask for SOCKETCAN explicitly)"
    else:
        why = problem
    return BusChoice(Interface.VIRTUAL, config.virtual_channel, f"no SocketCAN vcan: {why}")


def resolve(config: BusConfig, probe: HostProbe = _SYSTEM_PROBE) -> BusChoice:
    """Decide which bus ``config`` means on this host (raises ``BusUnavailableError`` for an
    explicit SocketCAN request the host cannot serve). Opens nothing."""
    if config.interface is Interface.AUTO:
        return _auto(config, probe)
    if config.interface is Interface.SOCKETCAN:
        return _socketcan_or_error(config, probe)
    if config.interface is Interface.VIRTUAL:
        return BusChoice(Interface.VIRTUAL, config.virtual_channel, "virtual bus requested")
    return BusChoice(config.interface, config.channel, f"{config.interface} requested")


#: Receive buffer asked for a SocketCAN socket (bytes). The kernel's default (212,992) holds
#: about 240 frames (measured on Linux 7.2): a node that is not scheduled for a moment while
#: a flood of frames comes (another process sending 1,000-2,000 frames/s beside a busy
#: loop on one CPU) loses the rest without seeing them, and its frame guard cannot count
#: them. 8 MiB (candump's ``-r`` in the tests) hold about 9,600 frames, several seconds of a
#: flood (with 2 MiB, 2,400 frames, the guest's drive once counted 343 frames fewer than a
#: 3,400-frame cangen flood certainly sent it, with two CPU hogs on the host). SO_RCVBUF is
#: capped at net.core.rmem_max (4 MiB in the guest, 212,992 on a stock kernel); a process
#: with CAP_NET_ADMIN goes past it with SO_RCVBUFFORCE, as candump does.
SOCKETCAN_RCVBUF_BYTES = 8 * 1024 * 1024
#: Linux's SO_RCVBUFFORCE (asm-generic/socket.h); Python's socket module does not name it.
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)


def _deepen_receive_queue(bus: can.BusABC) -> None:
    """Ask for :data:`SOCKETCAN_RCVBUF_BYTES` of receive buffer: forced where the process may
    (root, CAP_NET_ADMIN), else as much as net.core.rmem_max allows."""
    sock = getattr(bus, "socket", None)
    if sock is None:
        return
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, SOCKETCAN_RCVBUF_BYTES)
    except OSError:  # EPERM: not privileged
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SOCKETCAN_RCVBUF_BYTES)


def open_bus(config: BusConfig, probe: HostProbe = _SYSTEM_PROBE) -> can.BusABC:
    """Open the bus ``config`` asks for (see :func:`resolve`); the caller shuts it down.

    python-can's config files and environment are *not* merged in here (``ignore_config``);
    use :meth:`BusConfig.from_python_can_config` to honour them explicitly. The virtual bus is
    python-can's with a shorter path (:class:`virtual_bus.inprocess.InProcessBus`).
    """
    choice = resolve(config, probe)
    if choice.interface is Interface.VIRTUAL:
        own = config.receive_own_messages
        return InProcessBus(config.virtual_channel, receive_own_messages=own)
    if choice.interface is Interface.SOCKETCAN:
        bus = can.Bus(
            channel=choice.channel,
            interface=choice.python_can_interface,
            ignore_config=True,
            receive_own_messages=config.receive_own_messages,
        )
        _deepen_receive_queue(bus)
        return bus
    if choice.interface == "udp_multicast":
        return _open_udp(config)
    with _driver_messages() as said:
        try:
            return can.Bus(
                channel=choice.channel,
                interface=choice.python_can_interface,
                ignore_config=True,
                receive_own_messages=config.receive_own_messages,
                bitrate=config.bitrate,
            )
        except Exception as exc:  # vendor back-ends raise anything (kvaser: NameError)
            note = f"; python-can said: {said[0]}" if said else ""
            raise InterfaceUnavailableError(
                f"python-can cannot open interface {choice.python_can_interface!r} channel "
                f"{choice.channel!r}: {type(exc).__name__}: {exc}{note} (is its vendor driver "
                "installed and the channel right?)",
                interface=choice.python_can_interface,
            ) from exc


def _open_udp(config: BusConfig) -> can.BusABC:
    if config.receive_own_messages:
        raise InterfaceUnavailableError(
            "udp_multicast cannot receive its own messages (receive_own_messages=True)",
            interface="udp_multicast",
        )
    try:
        return LoopbackUdpBus(config.channel or UDP_GROUP)
    except can.CanError as exc:
        cause = exc.__cause__
        raise InterfaceUnavailableError(
            f"cannot open udp_multicast on group {config.channel or UDP_GROUP}: {exc}"
            + (f" ({cause})" if cause else "")
            + "; inside a namespace made by virtual_bus.netns, lo is up and 224.0.0.0/4 is "
            "routed to it",
            interface="udp_multicast",
        ) from exc


#: What python-can's back-ends log while a bus opens that says nothing of why it failed
#: (pcan: its timestamps without the ``uptime`` package), left out of the error.
UNRELATED_DRIVER_NOTES = ("uptime library not available",)


@contextmanager
def _driver_messages() -> Iterator[list[str]]:
    """Collect what python-can's back-ends log at WARNING or above while a bus opens (e.g.
    "Kvaser canlib is unavailable."), instead of letting it reach stderr as extra lines."""
    said: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            message = record.getMessage()
            if not message.startswith(UNRELATED_DRIVER_NOTES):
                said.append(message)

    logger = logging.getLogger("can")
    handler = _Collect(logging.WARNING)
    logger.addHandler(handler)
    propagate, logger.propagate = logger.propagate, False
    try:
        yield said
    finally:
        logger.propagate = propagate
        logger.removeHandler(handler)


def available_modes(
    probe: HostProbe = _SYSTEM_PROBE, channel: str = DEFAULT_VCAN_CHANNEL
) -> tuple[Interface, ...]:
    """The modes that work on this host: always ``VIRTUAL``; ``SOCKETCAN`` only when the kernel
    has SocketCAN and ``channel`` (default ``vcan0``) is a vcan interface."""
    auto = resolve(BusConfig(interface=Interface.AUTO, channel=channel), probe)
    if auto.interface is Interface.SOCKETCAN:
        return (Interface.VIRTUAL, Interface.SOCKETCAN)
    return (Interface.VIRTUAL,)

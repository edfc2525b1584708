"""Bus configuration: which python-can interface, which channel, which bit rate.

:class:`BusConfig` is the only configuration object of this package; nothing is read from
global state unless :meth:`BusConfig.from_python_can_config` is called explicitly.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import can
import can.interfaces
import can.util

from virtual_bus.errors import BusConfigError
from virtual_bus.netns import private_namespace_problem
from virtual_bus.vcan import DEFAULT_VCAN_CHANNEL, check_ifname

#: CAN bit rates of CiA 301 (bit timing table, also CiA 305 LSS table indices 0-4, 6-8),
#: in bit/s. 100 kbit/s is not among them (LSS table index 5 is reserved).
CIA301_BITRATES: tuple[int, ...] = (
    10_000,
    20_000,
    50_000,
    125_000,
    250_000,
    500_000,
    800_000,
    1_000_000,
)
DEFAULT_BITRATE = 500_000
#: Channel of python-can's in-process ``virtual`` interface when none is configured.
DEFAULT_VIRTUAL_CHANNEL = "backlash-bridge"
#: python-can interfaces this project refuses outside a private network namespace:
#: ``udp_multicast`` sends every frame to the namespace's network interfaces (house rule: never
#: send traffic to a host's network interface; see :mod:`virtual_bus.netns`).
NAMESPACE_ONLY_INTERFACES: frozenset[str] = frozenset({"udp_multicast"})


class Interface(Enum):
    """The interface choices this package knows how to pick between.

    Any other python-can interface is named by its python-can string (``"pcan"``, ...),
    see :attr:`BusConfig.interface`.
    """

    AUTO = "auto"
    VIRTUAL = "virtual"
    SOCKETCAN = "socketcan"


def _normalise_interface(value: Interface | str) -> Interface | str:
    if isinstance(value, Interface):
        return value
    if not isinstance(value, str):
        raise BusConfigError(
            f"interface must be an Interface or a python-can interface name, got {value!r}"
        )
    for member in Interface:
        if value == member.value:
            return member
    if value in NAMESPACE_ONLY_INTERFACES:
        problem = private_namespace_problem()
        if problem is not None:
            raise BusConfigError(
                f"interface {value!r} is not allowed here: it sends frames to a real network "
                f"interface ({problem}); use it only inside a private network namespace "
                "(virtual_bus.netns), or use 'virtual' or 'socketcan' (vcan0)"
            )
    if value not in can.interfaces.VALID_INTERFACES:
        allowed = sorted(can.interfaces.VALID_INTERFACES)
        raise BusConfigError(
            f"unknown interface {value!r}; allowed: 'auto' or one of python-can's {allowed}"
        )
    return value


@dataclass(frozen=True)
class BusConfig:
    """Which bus to open.

    interface: ``Interface.AUTO`` (default: SocketCAN ``vcan0`` when the host has it, else the
        in-process ``virtual`` bus), ``Interface.VIRTUAL``, ``Interface.SOCKETCAN``, or the
        python-can name of any other interface (a str from ``can.interfaces.VALID_INTERFACES``;
        the strings "auto", "virtual", "socketcan" are turned into the Enum members).
    channel: interface-specific channel; ``None`` = ``vcan0`` for SocketCAN,
        ``"backlash-bridge"`` for the virtual bus and the IPv4 group 239.74.163.2 for
        ``udp_multicast`` (allowed only inside a private network namespace). SocketCAN/AUTO
        channels must be valid Linux interface names.
    bitrate: nominal bit rate in bit/s, one of :data:`CIA301_BITRATES`. Used for bus-load
        figures and passed to hardware interfaces; vcan and virtual ignore it.
    receive_own_messages: whether a bus also receives the frames it sends.
    """

    interface: Interface | str = Interface.AUTO
    channel: str | None = None
    bitrate: int = DEFAULT_BITRATE
    receive_own_messages: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "interface", _normalise_interface(self.interface))
        if self.channel is not None:
            if not isinstance(self.channel, str) or not self.channel:
                raise BusConfigError(
                    f"channel must be a non-empty string or None, got {self.channel!r}"
                )
            if self.interface in (Interface.AUTO, Interface.SOCKETCAN):
                check_ifname(self.channel)
            if self.interface == "udp_multicast":
                _check_multicast_group(self.channel)
        if isinstance(self.bitrate, bool) or not isinstance(self.bitrate, int):
            raise BusConfigError(f"bitrate must be an int in bit/s, got {self.bitrate!r}")
        if self.bitrate not in CIA301_BITRATES:
            raise BusConfigError(
                f"bitrate {self.bitrate} bit/s is not a CiA 301 bit rate; "
                f"allowed: {list(CIA301_BITRATES)}"
            )
        if not isinstance(self.receive_own_messages, bool):
            raise BusConfigError(
                f"receive_own_messages must be a bool, got {self.receive_own_messages!r}"
            )

    @property
    def socketcan_channel(self) -> str:
        """The interface name SocketCAN would use (``vcan0`` unless configured)."""
        return self.channel or DEFAULT_VCAN_CHANNEL

    @property
    def virtual_channel(self) -> str:
        """The channel name the in-process virtual bus would use."""
        return self.channel or DEFAULT_VIRTUAL_CHANNEL

    @classmethod
    def from_python_can_config(
        cls,
        interface: Interface | str | None = None,
        channel: str | None = None,
        bitrate: int | None = None,
        *,
        path: Path | None = None,
        context: str | None = None,
        loader: Callable[..., Mapping[str, Any]] = can.util.load_config,
    ) -> BusConfig:
        """Build a config, honouring python-can's own configuration when no interface is given.

        With ``interface`` given, only the arguments are used. Without it, python-can's
        ``can.util.load_config(path, context=context)`` is consulted (``can.rc``, the
        ``CAN_INTERFACE``/``CAN_CHANNEL``/``CAN_BITRATE``/``CAN_CONFIG`` environment variables
        and the config files ``~/can.conf``, ``/etc/can.conf``, ``~/.can``, ``~/.canrc``);
        arguments given here win over it. If python-can names no interface, AUTO is used.
        """
        if interface is not None:
            return cls(
                interface=interface,
                channel=channel,
                bitrate=DEFAULT_BITRATE if bitrate is None else bitrate,
            )
        try:
            try:
                found = dict(loader(path, config=None, context=context))
            except can.CanInterfaceNotImplementedError as exc:
                # python-can raises this both for "nothing configured" (interface None) and
                # for an unknown name; only the latter is the user's error.
                if '"None"' not in str(exc):
                    raise BusConfigError(f"python-can configuration: {exc}") from exc
                # No interface named: read the other keys with a placeholder interface.
                found = dict(loader(path, config={"interface": "virtual"}, context=context))
                found["interface"] = None
        except BusConfigError:
            raise
        except (ValueError, TypeError) as exc:
            raise BusConfigError(f"python-can configuration: {exc}") from exc
        found_channel = found.get("channel")
        found_bitrate = found.get("bitrate")
        return cls(
            interface=found.get("interface") or Interface.AUTO,
            channel=channel if channel is not None else _opt_str(found_channel),
            bitrate=bitrate
            if bitrate is not None
            else (DEFAULT_BITRATE if found_bitrate is None else found_bitrate),
        )


def _opt_str(value: object) -> str | None:
    return None if value is None else str(value)


def _check_multicast_group(channel: str) -> None:
    """python-can's udp_multicast channel is a multicast group address (IPv4 224.0.0.0/4 or
    IPv6 ff00::/8), not an interface name: ``can0`` would reach the resolver and fail there."""
    try:
        group = ipaddress.ip_address(channel)
    except ValueError:
        group = None
    if group is None or not group.is_multicast:
        raise BusConfigError(
            f"udp_multicast channel {channel!r} is not a multicast group address; allowed: "
            "an IPv4 address in 224.0.0.0/4 (e.g. 239.74.163.2) or an IPv6 one in ff00::/8"
        )

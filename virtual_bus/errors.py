"""Exception hierarchy of the ``virtual_bus`` package.

Every error raised on purpose by this package derives from :class:`VirtualBusError` and also
from the builtin that matches its meaning, so callers can catch either.
"""

from __future__ import annotations

from enum import Enum


class VirtualBusError(Exception):
    """Root of all errors raised by ``virtual_bus``."""


class BusConfigError(VirtualBusError, ValueError):
    """A bus, fault or bus-load setting is out of its allowed range (nothing was opened)."""


class FaultConfigError(BusConfigError):
    """A :class:`virtual_bus.faults.FaultConfig` field is out of its allowed range."""


class BusLoadError(BusConfigError):
    """An argument of the bus-load computation is out of its allowed range."""


class RealTimeConfigError(VirtualBusError, ValueError):
    """A real-time option (:class:`virtual_bus.realtime.RealTimeOptions`) is out of range."""


class RealTimeRefused(VirtualBusError, OSError):
    """The OS does not allow a real-time setting; ``setting`` names it, ``errno`` is the OS
    error number (or None)."""

    def __init__(self, message: str, *, setting: str, errno: int | None = None) -> None:
        super().__init__(message)
        self.setting = setting
        self.errno = errno


class Missing(Enum):
    """What the host lacks when a SocketCAN bus cannot be opened."""

    AF_CAN = "kernel AF_CAN/CAN_RAW socket support"
    INTERFACE = "network interface"
    NOT_CAN = "CAN type of the network interface"


class BusUnavailableError(VirtualBusError, OSError):
    """The requested bus cannot be opened on this host.

    ``missing`` says what is absent (:class:`Missing`), ``channel`` the interface name.
    """

    def __init__(self, message: str, *, missing: Missing, channel: str) -> None:
        super().__init__(message)
        self.missing = missing
        self.channel = channel

    def __str__(self) -> str:
        return str(self.args[0])


class VcanProblem(Enum):
    """Why ``ip`` could not create or bring up a vcan interface."""

    NOT_PERMITTED = "needs root or CAP_NET_ADMIN"
    NO_VCAN_MODULE = "no vcan kernel module"
    NOT_VCAN = "an interface of that name exists and is not vcan"
    NO_SUCH_DEVICE = "no such interface"
    NO_IP_COMMAND = "the ip command (iproute2) is missing"
    OTHER = "ip failed"


class VcanSetupError(VirtualBusError, OSError):
    """``ip link`` failed while creating or bringing up a vcan interface.

    Attributes: ``problem`` (:class:`VcanProblem`), ``command`` (the argument list that ran),
    ``returncode`` and ``stderr`` of ``ip`` (``None``/empty when ``ip`` could not be run).
    """

    def __init__(
        self,
        message: str,
        *,
        problem: VcanProblem,
        command: tuple[str, ...],
        returncode: int | None,
        stderr: str,
    ) -> None:
        super().__init__(message)
        self.problem = problem
        self.command = command
        self.returncode = returncode
        self.stderr = stderr

    def __str__(self) -> str:
        return str(self.args[0])


class InterfaceUnavailableError(BusConfigError):
    """python-can could not open the requested interface here (its vendor driver or library
    is missing, or the channel is wrong). ``interface`` is the python-can name."""

    def __init__(self, message: str, *, interface: str) -> None:
        super().__init__(message)
        self.interface = interface


class NetnsError(VirtualBusError, OSError):
    """An ``ip netns`` command failed (not root, no iproute2, ...). ``command`` is the
    argument list that ran."""

    def __init__(self, message: str, *, command: tuple[str, ...]) -> None:
        super().__init__(message)
        self.command = command

    def __str__(self) -> str:
        return str(self.args[0])

"""Shared CAN bus for the bridge and the simulated drive, without hardware.

SocketCAN ``vcan0`` where the kernel has it, python-can's in-process ``virtual`` bus
otherwise (:func:`open_bus` with ``Interface.AUTO``); seeded fault injection
(:class:`FaultInjectingBus`) and worst-case bus-load figures (:func:`bus_load`).
"""

from virtual_bus.busload import BusLoad, bus_load, frame_bits
from virtual_bus.config import CIA301_BITRATES, BusConfig, Interface
from virtual_bus.errors import (
    BusConfigError,
    BusLoadError,
    BusUnavailableError,
    FaultConfigError,
    Missing,
    VcanProblem,
    VcanSetupError,
    VirtualBusError,
)
from virtual_bus.faults import (
    Direction,
    FaultConfig,
    FaultCounters,
    FaultInjectingBus,
    FaultKind,
)
from virtual_bus.open import BusChoice, available_modes, open_bus, resolve
from virtual_bus.vcan import HostProbe, LinkKind, SetupOutcome, setup_vcan

__all__ = [
    "CIA301_BITRATES",
    "BusChoice",
    "BusConfig",
    "BusConfigError",
    "BusLoad",
    "BusLoadError",
    "BusUnavailableError",
    "Direction",
    "FaultConfig",
    "FaultConfigError",
    "FaultCounters",
    "FaultInjectingBus",
    "FaultKind",
    "HostProbe",
    "Interface",
    "LinkKind",
    "Missing",
    "SetupOutcome",
    "VcanProblem",
    "VcanSetupError",
    "VirtualBusError",
    "available_modes",
    "bus_load",
    "frame_bits",
    "open_bus",
    "resolve",
    "setup_vcan",
]

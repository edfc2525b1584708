"""Simulated CiA 402 servo drive (cyclic synchronous velocity) on canopen's LocalNode.

See ``docs/drive.md`` and the CANopen contract ``docs/canopen_layout.md``.

>>> drive = SimulatedDrive(bus, 2, load_axis("config/paper_axis.toml"))
>>> with drive:             # boot-up, heartbeat; the master sends NMT start, SYNC, RPDOs
...     ...
"""

from .cia402 import Command, Event, State402, StateMachine, Transition
from .drive import DriveConfig, SimulatedDrive, TimeMode
from .errors import (
    DriveConfigError,
    DriveEdsError,
    DriveError,
    DriveInputError,
    DriveSdoAbort,
    DriveStateError,
)
from .node import NmtCommand, NmtState
from .od import DEFAULT_EDS_PATH, load_drive_od

__all__ = [
    "DEFAULT_EDS_PATH",
    "Command",
    "DriveConfig",
    "DriveConfigError",
    "DriveEdsError",
    "DriveError",
    "DriveInputError",
    "DriveSdoAbort",
    "DriveStateError",
    "Event",
    "NmtCommand",
    "NmtState",
    "SimulatedDrive",
    "State402",
    "StateMachine",
    "TimeMode",
    "Transition",
    "load_drive_od",
]

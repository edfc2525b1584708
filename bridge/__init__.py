"""The backlash regulator of Mohammadiasl (eq. 7, eq. 15) as a CANopen master-side node.

Every SYNC the bridge reads the drive's encoder PDOs, runs the interpolator, the P position
controller on the load scale and the :class:`regulator.BacklashRegulator`, and writes the
controlword and target velocity (cyclic synchronous velocity, CiA 402). See docs/bridge.md and
the contract docs/canopen_layout.md.

Modules: :mod:`.cycle` (the pure per-SYNC controller), :mod:`.node` (the node on the bus and
its loop), :mod:`.master` (drive start-up over SDO), :mod:`.params` / :mod:`.objects` /
:mod:`.od` / :mod:`.eds` (parameters, SDO server, object table, EDS), :mod:`.adapt` /
:mod:`.probe` (adapting to a real drive; drive profiles: :mod:`virtual_bus.formats.drive_profile`),
:mod:`.interpolator`,
:mod:`.timing` (lockstep and real-time pacing), :mod:`.recorder`, :mod:`.sim` (with the
simulated drive), :mod:`.busload`, :mod:`.demo`, :mod:`.run`, :mod:`.bench`.
"""

from .cycle import BridgeState, Command, CycleController, StopReason
from .errors import (
    BridgeConfigError,
    BridgeError,
    DriveSetupError,
    DriveTimeoutError,
    MoveError,
    MoveFileError,
    ParameterError,
    PdoFrameError,
    SdoAbort,
)
from .interpolator import Interpolator, Move, Table, load_move_file, parse_move
from .layout import CycleLayout, RxFrame, Signal
from .master import DriveInfo, DriveMaster, DriveSetup
from .node import Bridge, BridgeConfig
from .objects import ObjectServer, PdoCounters
from .params import BridgeParams
from .recorder import BusLog, TraceRecorder
from .scaling import Scaling
from .timing import LockstepPacer, RealTimePacer, TimeMode

__all__ = [
    "Bridge",
    "BridgeConfig",
    "BridgeConfigError",
    "BridgeError",
    "BridgeParams",
    "BridgeState",
    "BusLog",
    "Command",
    "CycleController",
    "CycleLayout",
    "DriveInfo",
    "DriveMaster",
    "DriveSetup",
    "DriveSetupError",
    "DriveTimeoutError",
    "Interpolator",
    "LockstepPacer",
    "Move",
    "MoveError",
    "MoveFileError",
    "ObjectServer",
    "ParameterError",
    "PdoCounters",
    "PdoFrameError",
    "RealTimePacer",
    "RxFrame",
    "Scaling",
    "SdoAbort",
    "Signal",
    "StopReason",
    "Table",
    "TimeMode",
    "TraceRecorder",
    "load_move_file",
    "parse_move",
]

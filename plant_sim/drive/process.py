"""The simulated drive as a process of its own: serve one bus until told to stop.

:func:`serve` is the whole life of a standalone drive (``python -m plant_sim drive``, or a
harness that runs the drive in a subprocess or thread of its own):

1. build the :class:`SimulatedDrive` of the axis on the given bus (the EDS is checked);
2. ``start()``: the physics kernels are loaded / compiled first, *then* the boot-up message
   goes out and the drive is Pre-operational with its heartbeat running - so from the
   boot-up on, every SDO request and SYNC is answered at the normal pace (a master's 0.3 s
   SDO timeout never meets a compiling drive);
3. the drive's notifier thread serves NMT, SDO, SYNC and RPDOs (the physics steps on each
   SYNC); :func:`serve` waits for ``stop`` and checks every ``check_interval_s`` that no bus
   callback failed;
4. on ``stop`` (SIGINT/SIGTERM in the command) the drive leaves the bus (heartbeat and
   notifier stopped); the bus stays the caller's to shut down.

>>> stop = threading.Event()
>>> result = serve(DriveProcessConfig(axis), bus, stop, ready=lambda drive: ...)
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from plant_sim.axis import AxisConfig

from .cia402 import State402
from .config import DriveConfig, TimeMode
from .drive import SimulatedDrive
from .errors import DriveConfigError
from .node import NmtState


@dataclass(frozen=True)
class DriveProcessConfig:
    """What a standalone drive serves.

    axis: the axis the plant simulates; node_id: 1..127 (the contract's default 2);
    drive: drive settings (default: heartbeat on the wall clock, ``TimeMode.REAL_TIME``,
    since a drive on its own has no other clock before the first SYNC);
    check_interval_s: how often :func:`serve` looks for a failed bus callback (s).
    """

    axis: AxisConfig
    node_id: int = 2
    drive: DriveConfig = field(default_factory=lambda: DriveConfig(time_mode=TimeMode.REAL_TIME))
    check_interval_s: float = 0.2

    def __post_init__(self) -> None:
        if not isinstance(self.node_id, int) or not 1 <= self.node_id <= 127:
            raise DriveConfigError(f"node_id = {self.node_id!r}: allowed 1..127")
        if not 0.001 <= self.check_interval_s <= 10.0:
            raise DriveConfigError(
                f"check_interval_s = {self.check_interval_s}: allowed [0.001, 10] s"
            )


@dataclass(frozen=True)
class ServeResult:
    """How the drive ended: SYNCs run, CiA 402 state, NMT state, active error codes."""

    sync_count: int
    state: State402
    nmt_state: NmtState
    active_errors: tuple[int, ...]

    def summary(self) -> str:
        errors = ", ".join(f"0x{code:04X}" for code in self.active_errors) or "none"
        return (
            f"{self.sync_count} SYNCs served; CiA 402 {self.state.value}, NMT "
            f"{self.nmt_state.name.lower().replace('_', '-')}, active errors {errors}"
        )


def serve(
    config: DriveProcessConfig,
    bus: can.BusABC,
    stop: threading.Event,
    *,
    ready: Callable[[SimulatedDrive], None] | None = None,
) -> ServeResult:
    """Serve the drive on ``bus`` until ``stop`` is set (see the module docstring).

    ready(drive): called once the boot-up message is out. A bus callback that raised is
    raised here (after the drive has left the bus). The bus is not shut down.
    """
    drive = SimulatedDrive(bus, config.node_id, config.axis, config.drive)
    drive.start()
    try:
        if ready is not None:
            ready(drive)
        while not stop.wait(config.check_interval_s):
            drive.check()
    finally:
        drive.stop()
    drive.check()
    return ServeResult(drive.sync_count, drive.state, drive.nmt_state, drive.active_errors)

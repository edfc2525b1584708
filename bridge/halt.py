"""The end of a run: the drive brought to standstill and out of Operation Enabled, confirmed,
by the first of three ways that works, bounded in time, and said which.

A stop the bridge decides (a fault, an overrun, a signal, the end of the moves) goes out as a
controlword in the synchronous RPDO, which a drive applies at the next SYNC: a bridge that
stops sending SYNC after it leaves the drive running on its last set point. So:

1. **SYNC** -- the loop keeps cycling with the stop controlword (quick stop 0002h, or switch
   on 0007h at the end of the moves with the axis at rest) until the drive's TPDOs show it
   out of Operation Enabled (Quick Stop Active, Switch On Disabled, Switched On, Fault: not
   Fault Reaction Active) with the motor at standstill (|606Ch| or the change of 6064h at most
   :data:`STANDSTILL_RAD_S`) for :data:`CONFIRM_S` in a row; at most ``sync_s`` of cycles,
   fewer when the TPDOs stop coming (200Ah + 1 cycles in a row without them);
2. **SDO** -- the drive answers no TPDO (PDO loss, NMT changed by someone else): 6041h read
   over SDO, the quick stop written to 6040h if it is still enabled, then 6041h / 606Ch read
   until it is out and at rest; SYNC and the stop RPDO keep going meanwhile (a drive whose
   clock is SYNC keeps its ramp running); at most ``sdo_s`` of wall time;
3. **NMT** -- neither worked (no SDO answer): NMT Stop to the drive, whose 6007h reaction
   (CiA 402: NMT Stopped entered) is its last chance; confirmed only by its heartbeat
   showing Stopped.

:func:`halt` returns a :class:`HaltResult` that says which way was used, what the drive
reported and whether standstill was confirmed.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from canopen.nmt import NmtError

from virtual_bus.contract import Cia402, NmtCommand

from .cycle import CW_STOPPED, Drive402State, drive_state
from .errors import DriveSetupError
from .layout import Signal
from .master import DriveMaster, DriveSetup
from .node import Bridge

log = logging.getLogger("bridge")

#: A motor at most this fast (rad/s) is at standstill (the simulated drive's own threshold
#: for the end of a quick stop, plant_sim.drive.DriveConfig.standstill_rad_s).
STANDSTILL_RAD_S = 0.1
#: How long the SYNC way gives the drive's ramp (s of cycles): a quick stop from the highest
#: speed of a machine-tool axis takes well under a second.
HALT_SYNC_S = 3.0
#: The drive must report standstill out of Operation Enabled this long in a row (s, at least
#: three cycles): a motor whose power stage switched off at the end of the ramp can rebound
#: from the elastic load it held, and the stop is confirmed once that has settled too.
CONFIRM_S = 0.01
#: How long the SDO way polls the drive (s of wall time).
HALT_SDO_S = 3.0
#: SDO timeout and tries of the SDO way (a drive that answers PDOs no more may still be busy).
HALT_SDO_TIMEOUT_S = 0.5
HALT_SDO_RETRIES = 2
#: CiA 402 states in which the drive still drives the motor (it is not stopped yet).
DRIVING = (
    Drive402State.OPERATION_ENABLED,
    Drive402State.FAULT_REACTION_ACTIVE,
    Drive402State.UNKNOWN,
    Drive402State.NOT_READY_TO_SWITCH_ON,
)


class HaltWay(Enum):
    """How the stop reached the drive."""

    SYNC = "SYNC"  # the stop controlword in the RPDO, applied at the SYNCs that followed
    SDO = "SDO"  # the quick stop written to 6040h over SDO (no TPDO came)
    NMT = "NMT"  # NMT Stop: the drive's own 6007h reaction (nothing else answered)


@dataclass(frozen=True)
class HaltResult:
    """What the stop path did: the way, whether the drive was seen out of Operation Enabled
    at standstill (``confirmed``), its CiA 402 state and motor speed as last read (None:
    not read), the cycles and SDO reads it took."""

    way: HaltWay
    confirmed: bool
    state: Drive402State | None
    speed_rad_s: float | None
    cycles: int
    sdo_reads: int = 0
    detail: str = ""

    def describe(self, drive_id: int) -> str:
        """One line: ``drive 2: stopped by SYNC in 57 cycles: SWITCH ON DISABLED, 0.000
        rad/s``."""
        state = "state not read" if self.state is None else self.state.value
        speed = "speed not read" if self.speed_rad_s is None else f"{self.speed_rad_s:.3f} rad/s"
        how = {
            HaltWay.SYNC: f"by SYNC in {self.cycles} cycles",
            HaltWay.SDO: f"by SDO (6040h) after {self.cycles} cycles without its TPDOs, "
            f"{self.sdo_reads} SDO reads",
            HaltWay.NMT: "by NMT Stop (its 6007h reaction)",
        }[self.way]
        verdict = "stopped" if self.confirmed else "NOT confirmed stopped"
        return f"drive {drive_id}: {verdict} {how}: {state}, {speed}" + (
            f" ({self.detail})" if self.detail else ""
        )


def _has_velocity(bridge: Bridge) -> bool:
    return any(Signal.MOTOR_VELOCITY in f.signals for f in bridge.layout.frames)


def halt(
    bridge: Bridge,
    *,
    sync_s: float = HALT_SYNC_S,
    sdo_s: float = HALT_SDO_S,
    wall: Callable[[], float] = time.monotonic,
) -> HaltResult:
    """Bring the drive to standstill out of Operation Enabled with the controller's present
    stop controlword (module docstring); the controller must command no motion already
    (STOPPED, or DISABLED after ``command(DISABLE)`` / ``halt()``)."""
    c = bridge.controller
    cycle_s = bridge.pacer.cycle_s
    velocity = _has_velocity(bridge)
    limit = max(1, math.ceil(sync_s / cycle_s))
    silent_limit = c.params.pdo_loss_tolerance + 1
    confirm = max(3, math.ceil(CONFIRM_S / cycle_s))
    still = 0  # cycles in a row at rest out of Operation Enabled
    silent = 0
    state: Drive402State | None = None
    speed: float | None = None
    last_position: float | None = None
    n = 0
    while n < limit:
        bridge.run(cycles=1)
        n += 1
        if c.consecutive_missed:  # not every TPDO came: no fresh state and speed
            silent += 1
            still = 0
            last_position = None
            if silent > silent_limit:
                break
            continue
        silent = 0
        state = drive_state(c.statusword)
        position = c.motor_position_rad
        if velocity:
            speed = c.motor_speed_rad_s
        elif last_position is not None:
            speed = (position - last_position) / cycle_s
        last_position = position
        if state not in DRIVING and speed is not None and abs(speed) <= STANDSTILL_RAD_S:
            still += 1
            if still >= confirm:
                return HaltResult(HaltWay.SYNC, True, state, speed, n)
        else:
            still = 0
    if silent <= silent_limit:  # the drive answered, and did not stop within the bound
        return HaltResult(
            HaltWay.SYNC, False, state, speed, n, detail=f"not at rest after {sync_s:g} s"
        )
    log.error(
        "drive %d: no TPDO for %d cycles while stopping: quick stop over SDO",
        bridge.config.drive_id,
        silent,
    )
    return _halt_by_sdo(bridge, n, sdo_s, wall)


def _halt_by_sdo(
    bridge: Bridge, cycles: int, sdo_s: float, wall: Callable[[], float]
) -> HaltResult:
    setup = DriveSetup(sdo_timeout_s=HALT_SDO_TIMEOUT_S, sdo_retries=HALT_SDO_RETRIES)
    state: Drive402State | None = None
    speed: float | None = None
    reads = 0
    with bridge.serving():
        master = DriveMaster(bridge.drive, setup)
        try:
            state = drive_state(master.statusword())
            reads += 1
            if state in DRIVING:
                master.write(Cia402.CONTROLWORD, 0, struct.pack("<H", CW_STOPPED), " (quick stop)")
            deadline = wall() + sdo_s
            while True:
                bridge.keep_clock()  # SYNC and the stop RPDO: a SYNC-clocked drive ramps on
                state = drive_state(master.statusword())
                raw = master.read(Cia402.VELOCITY_ACTUAL_VALUE, 0, " (velocity actual)")
                reads += 2
                speed = struct.unpack("<i", raw[:4])[0] / bridge.scaling.velocity_units_per_rad_s
                if state not in DRIVING and abs(speed) <= STANDSTILL_RAD_S:
                    return HaltResult(HaltWay.SDO, True, state, speed, cycles, reads)
                if wall() > deadline:
                    return HaltResult(
                        HaltWay.SDO,
                        False,
                        state,
                        speed,
                        cycles,
                        reads,
                        f"not at rest after {sdo_s:g} s",
                    )
        except DriveSetupError as exc:
            log.error("drive %d: the quick stop over SDO failed: %s", bridge.config.drive_id, exc)
            return _halt_by_nmt(bridge, cycles, reads, state, speed, str(exc))


#: Heartbeats of the drive the NMT way reads for its Stopped state (its 1017h each).
NMT_HEARTBEATS = 3


def _halt_by_nmt(
    bridge: Bridge,
    cycles: int,
    reads: int,
    state: Drive402State | None,
    speed: float | None,
    why: str,
) -> HaltResult:
    """NMT Stop (inside :meth:`Bridge.serving`): standstill cannot be confirmed (no SDO in
    Stopped); the drive's heartbeat showing Stopped says at least that it took the command."""
    drive = bridge.drive
    drive.nmt.send_command(NmtCommand.STOP)
    seen = None
    for _ in range(NMT_HEARTBEATS):
        try:
            seen = drive.nmt.wait_for_heartbeat(timeout=1.0)
        except NmtError:
            break
        if seen == "STOPPED":
            break
    shown = "no heartbeat" if seen is None else f"its heartbeat shows {seen.lower()}"
    return HaltResult(
        HaltWay.NMT, False, state, speed, cycles, reads, f"SDO failed: {why}; {shown}"
    )

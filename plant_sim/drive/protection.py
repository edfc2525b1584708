"""Drive-side protection: the error list behind 603Fh / 1001h / EMCY, the set point watchdog,
the motor-encoder vs load-scale monitor and the torque limit of 6072h.

Error codes (CiA 301 table 21 / CiA 402 annex):

| code    | meaning                                        | 1001h bits                  |
| ------- | ---------------------------------------------- | --------------------------- |
| 0x7300  | sensor: motor encoder and load scale disagree  | generic, device profile     |
|         | by more than 2101h (paper section II.B)        |                             |
| 0x8210  | PDO not processed due to length error          | generic, communication      |
| 0x8240  | unexpected SYNC data length                    | generic, communication      |
| 0x8250  | RPDO timeout: no set point for 2102h SYNCs     | generic, communication      |
| 0x8130  | heartbeat error: the master's heartbeat (1016h) | generic, communication      |
|         | missed, or the master booted                   |                             |
| 0x8100  | communication: NMT took the enabled drive out  | generic, communication      |
|         | of Operational                                 |                             |

The set point timeout is off by default (2102h = 0): a master may send RPDO1 only when the
set point changes (CiA 301 allows it; python canopen's ``PdoMap.transmit`` does exactly that),
and a drive must not stop such a master's axis for holding still. A master that repeats its
RPDO every SYNC (the bridge) can ask for the timeout by writing 2102h; the reaction is the
CiA 402 abort connection option code 6007h. Its EMCY names the cause in the manufacturer
bytes (:func:`setpoint_timeout_data`): ``02 21`` (object 2102h, little-endian), the SYNC count
that ran out, the 6007h option code acted on, 0.

The drive supervises its master (CiA 301 heartbeat consumer, :class:`HeartbeatConsumer`):
1016h:01 names the master's node-ID and a consumer time; once a heartbeat of it came, none
for that long (or its boot-up: the master restarted) is a lost connection, and so is an NMT
command that takes the enabled drive out of Operational. Each acts through 6007h like the set
point timeout and says why in the same five bytes (:func:`connection_lost_data`): the object
that supervises (1016h, 2102h; 0000h for NMT), a detail (the master's node-ID, the SYNC
count, the NMT command), the 6007h code acted on, 0 (1016h: 1 when the master booted).

An EMCY frame (CiA 301: code, 1001h, 5 manufacturer bytes) goes out when an error becomes
active, and an "error reset" EMCY (code 0x0000 with the remaining 1001h) when one is cleared.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from virtual_bus.contract import (
    EMCY_COMMUNICATION,
    EMCY_HEARTBEAT,
    EMCY_NO_ERROR,
    EMCY_PDO_LENGTH,
    EMCY_RPDO_TIMEOUT,
    EMCY_SENSOR,
    EMCY_SOFTWARE,
    EMCY_SYNC_LENGTH,
    split_heartbeat_consumer_entry,
)

from ..plant import Plant

ERROR_REGISTER_GENERIC = 0x01
ERROR_REGISTER_COMMUNICATION = 0x10
ERROR_REGISTER_PROFILE = 0x20


@dataclass(frozen=True)
class ErrorSpec:
    code: int
    register: int
    description: str


ERRORS: dict[int, ErrorSpec] = {
    e.code: e
    for e in (
        ErrorSpec(EMCY_SOFTWARE, ERROR_REGISTER_GENERIC, "the plant (FMU) failed while it stepped"),
        ErrorSpec(EMCY_SENSOR, ERROR_REGISTER_PROFILE, "motor encoder and load scale disagree"),
        ErrorSpec(EMCY_PDO_LENGTH, ERROR_REGISTER_COMMUNICATION, "RPDO shorter than its mapping"),
        ErrorSpec(EMCY_SYNC_LENGTH, ERROR_REGISTER_COMMUNICATION, "SYNC with more than 1 byte"),
        ErrorSpec(EMCY_RPDO_TIMEOUT, ERROR_REGISTER_COMMUNICATION, "no RPDO set point in time"),
        ErrorSpec(EMCY_HEARTBEAT, ERROR_REGISTER_COMMUNICATION, "the master's heartbeat lost"),
        ErrorSpec(EMCY_COMMUNICATION, ERROR_REGISTER_COMMUNICATION, "NMT left Operational"),
    )
}

#: Sends one EMCY: (error code, error register, 5 manufacturer-specific bytes).
EmcySender = Callable[[int, int, bytes], None]


class ErrorList:
    """The active errors of the drive, in the order they occurred."""

    def __init__(self, send_emcy: EmcySender) -> None:
        self._send = send_emcy
        self._active: list[int] = []
        #: the active codes, oldest first (read it, change it through set/clear/forget): an
        #: empty list is false, for the per-SYNC code without a call
        self.codes = self._active

    @property
    def active(self) -> tuple[int, ...]:
        return tuple(self._active)

    @property
    def any_active(self) -> bool:
        return bool(self._active)

    @property
    def error_code(self) -> int:
        """603Fh: the most recent active error, 0 if none."""
        return self._active[-1] if self._active else EMCY_NO_ERROR

    @property
    def register(self) -> int:
        """1001h: generic bit plus the bits of every active error."""
        bits = 0
        for code in self._active:
            bits |= ERRORS[code].register
        return bits | ERROR_REGISTER_GENERIC if self._active else 0

    def __contains__(self, code: int) -> bool:
        return code in self._active

    def set(self, code: int, data: bytes = b"") -> bool:
        """Make ``code`` active and send its EMCY; False (no EMCY) if it already was."""
        if code not in ERRORS:
            raise ValueError(f"error code 0x{code:04X} unknown; known: {sorted(ERRORS)}")
        if code in self._active:
            return False
        self._active.append(code)
        self._send(code, self.register, data)
        return True

    def clear(self, code: int) -> bool:
        """Clear ``code`` and send the error reset EMCY; False if it was not active."""
        if code not in self._active:
            return False
        self._active.remove(code)
        self._send(EMCY_NO_ERROR, self.register, b"")
        return True

    def forget(self) -> None:
        """Drop every error without EMCY (NMT reset node: the device starts anew)."""
        self._active.clear()


def emcy_data_int32(value: int) -> bytes:
    """5 manufacturer bytes carrying a saturated little-endian INTEGER32 and a zero byte."""
    clamped = max(-(2**31), min(2**31 - 1, value))
    return struct.pack("<lB", clamped, 0)


def setpoint_timeout_data(cycles: int, option: int) -> bytes:
    """5 manufacturer bytes of EMCY 0x8250: the supervising object 2102h (UNSIGNED16 LE), the
    SYNC cycles without RPDO that ran out (2102h), the 6007h option code acted on, 0."""
    return struct.pack("<HBbB", 0x2102, cycles & 0xFF, option, 0)


def connection_lost_data(supervisor: int, detail: int, option: int, extra: int = 0) -> bytes:
    """5 manufacturer bytes of a lost-connection EMCY (8100h, 8130h, 8250h): the supervising
    object (UNSIGNED16 LE: 1016h, 2102h; 0 for an NMT command), a detail byte (the master's
    node-ID, the SYNC count, the NMT command specifier), the 6007h option code acted on, and
    ``extra`` (1016h: 1 when the master's boot-up was the cause)."""
    return struct.pack("<HBbB", supervisor, detail & 0xFF, option, extra & 0xFF)


class HeartbeatConsumer:
    """CiA 301 heartbeat consumer of one 1016h entry, on the drive's clock (µs).

    :meth:`configure` with the entry (node-ID << 16 | ms; a zero node-ID or time: off). The
    watch starts with the first heartbeat of that node (:meth:`received`); :meth:`check`
    is true once when none came for the consumer time, and again only after the next
    heartbeat. A boot-up message of the watched node while it was being watched means it
    restarted: :meth:`received` returns True (lost) and the watch waits for its next
    heartbeat, as CANopenNode's consumer does."""

    def __init__(self) -> None:
        self.node_id = 0
        self.time_us = 0
        #: drive clock (µs) of the last heartbeat; None: not watching (yet)
        self.last_us: int | None = None
        self.tripped = False

    def configure(self, entry: int) -> None:
        node_id, time_ms = split_heartbeat_consumer_entry(entry)
        on = node_id != 0 and time_ms != 0
        self.node_id = node_id if on else 0
        self.time_us = 1000 * time_ms if on else 0
        self.last_us = None
        self.tripped = False

    def received(self, nmt_state: int, now_us: int) -> bool:
        """A heartbeat (or boot-up, state 0) of the watched node at ``now_us``; True when it
        is a boot-up that ends a watch (the master restarted)."""
        if nmt_state & 0x7F == 0:
            restarted = self.last_us is not None and not self.tripped
            self.last_us = None
            self.tripped = False
            return restarted
        self.last_us = now_us
        self.tripped = False
        return False

    def deadline_us(self) -> int | None:
        """When the watch runs out unless a heartbeat comes (None: nothing to run out)."""
        if self.last_us is None or self.tripped:
            return None
        return self.last_us + self.time_us

    def check(self, now_us: int) -> bool:
        """True once, at the first check after the consumer time ran out."""
        last = self.last_us
        if last is None or self.tripped or now_us - last <= self.time_us:
            return False
        self.tripped = True
        return True


class SetpointWatchdog:
    """Counts SYNCs in Operation enabled without an RPDO (2102h; 0 disables it)."""

    def __init__(self) -> None:
        self.missed = 0
        self.tripped = False

    def reset(self) -> None:
        self.missed = 0
        self.tripped = False

    def on_sync(self, received: bool, limit_cycles: int) -> bool:
        """True once, at the SYNC where ``limit_cycles`` SYNCs in a row had no RPDO (or the
        first SYNC after the limit was lowered below the count); again only after an RPDO
        or :meth:`reset`."""
        if received:
            self.reset()
            return False
        self.missed += 1
        if limit_cycles > 0 and self.missed >= limit_cycles and not self.tripped:
            self.tripped = True
            return True
        return False


def discrepancy(motor_position_rad: float, load_position: float, ratio: float) -> float:
    """Load scale minus motor encoder in load units (m or rad): x_l − θ_m / k_r, k_r the
    transmission ratio (motor rad per load unit). The paper's section II.B: the two measuring
    systems must agree within about 0.5 mm or 0.5°."""
    return load_position - motor_position_rad / ratio


def axis_torque_limit_nm(plant: Plant) -> float:
    """The axis file's torque limit (N·m; inf when it has none)."""
    limit = plant.axis.control.torque_limit
    return math.inf if limit is None else limit


def apply_torque_limit(plant: Plant, limit_nm: float) -> None:
    """Set the PI speed controller's output limit (and anti-windup clamp) of ``plant``."""
    plant.set_torque_limit_nm(limit_nm)

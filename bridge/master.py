"""Start-up: configure the drive over SDO as a CANopen master does (blocking, off the cycle).

Sequence (docs/canopen_layout.md, CiA 301 PDO configuration procedure, CiA 402):

1. NMT "enter pre-operational" to the drive;
2. each PDO of :data:`bridge.layout.LAYOUT`: COB-ID invalid (bit 31), transmission type,
   mapping count 0, mapping entries, mapping count, COB-ID valid; the other PDOs of the drive
   are switched off (objects the drive lacks are skipped);
3. 6060h modes of operation = 9 (cyclic synchronous velocity), checked in 6061h;
4. 1017h producer heartbeat time; 6076h motor rated torque read for the torque scaling;
5. NMT "start remote node";
6. CiA 402 state machine to Operation Enabled through 6040h/6041h (paths of
   ``canopen.profiles.p402.State402``), after a fault reset if the drive is in Fault.

Every step names the object that failed (:class:`~bridge.errors.DriveSetupError`, with the
drive's abort code) or timed out (:class:`~bridge.errors.DriveTimeoutError`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import canopen
from canopen.profiles.p402 import OperationMode
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from virtual_bus.contract import (
    COB_ID_INVALID,
    NmtCommand,
    rpdo_cob_id,
    tpdo_cob_id,
)

from .cycle import Drive402State, drive_state, enable_controlword
from .errors import BridgeConfigError, DriveSetupError, DriveTimeoutError, SdoAbort
from .layout import LAYOUT, PdoSpec

log = logging.getLogger("bridge")

_U8 = struct.Struct("<B")
_I8 = struct.Struct("<b")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class DriveSetup:
    """How to configure the drive.

    heartbeat_producer_ms: 1017h of the drive, ms (1..65535), below the bridge's consumer
    time. sdo_timeout_s / sdo_retries: per SDO request. state_timeout_s: wall time for each
    CiA 402 transition. disable_other_pdos: switch off the drive's PDOs outside the layout.
    """

    heartbeat_producer_ms: int = 100
    sdo_timeout_s: float = 0.3
    sdo_retries: int = 3
    state_timeout_s: float = 2.0
    disable_other_pdos: bool = True

    def __post_init__(self) -> None:
        hb = self.heartbeat_producer_ms
        if isinstance(hb, bool) or not isinstance(hb, int) or not 1 <= hb <= 65535:
            raise BridgeConfigError(f"heartbeat_producer_ms = {hb!r}: must be an integer 1..65535")
        for name in ("sdo_timeout_s", "state_timeout_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and 0 < value <= 60):
                raise BridgeConfigError(f"{name} = {value!r}: must be in (0, 60] s")
        if not isinstance(self.sdo_retries, int) or not 1 <= self.sdo_retries <= 10:
            raise BridgeConfigError(f"sdo_retries = {self.sdo_retries!r}: must be 1..10")


@dataclass(frozen=True)
class DriveInfo:
    """What start-up learned: rated torque (6076h, N·m), statusword and mode at the end."""

    rated_torque_nm: float
    statusword: int
    mode_display: int
    sdo_transfers: int


class DriveMaster:
    """SDO client side of the start-up for one drive (a canopen RemoteNode on the network).

    Someone must feed received frames to the network meanwhile (the bridge's service thread).
    ``sleep`` is injected for the polling of the state machine.
    """

    def __init__(
        self,
        drive: canopen.RemoteNode,
        setup: DriveSetup = DriveSetup(),
        sleep: Callable[[float], None] = time.sleep,
        wall: Callable[[], float] = time.monotonic,
    ) -> None:
        self.drive = drive
        self.setup = setup
        self._sleep = sleep
        self._wall = wall
        drive.sdo.RESPONSE_TIMEOUT = setup.sdo_timeout_s
        drive.sdo.MAX_RETRIES = setup.sdo_retries
        self.transfers = 0

    # --- SDO with context ---------------------------------------------------------------------
    def _what(self, index: int, subindex: int) -> str:
        return f"drive {self.drive.id} object {index:04X}h:{subindex:02X}"

    @contextlib.contextmanager
    def _sdo(self, verb: str, index: int, subindex: int, what: str) -> Iterator[None]:
        """Count one transfer; turn canopen's SDO errors into the bridge's, with context."""
        self.transfers += 1
        where = f"{self._what(index, subindex)}{what}"
        try:
            yield
        except SdoAbortedError as exc:
            raise DriveSetupError(
                f"{where}: {verb} refused, SDO abort {exc}",
                index=index,
                subindex=subindex,
                abort_code=exc.code,
            ) from None
        except SdoCommunicationError as exc:
            raise DriveTimeoutError(
                f"{where}: no SDO answer ({exc}) after {self.setup.sdo_retries} tries of "
                f"{self.setup.sdo_timeout_s:g} s",
                index=index,
                subindex=subindex,
            ) from None

    def write(self, index: int, subindex: int, data: bytes, what: str = "") -> None:
        with self._sdo("write", index, subindex, what):
            self.drive.sdo.download(index, subindex, data)

    def read(self, index: int, subindex: int, what: str = "") -> bytes:
        data = b""
        with self._sdo("read", index, subindex, what):
            data = self.drive.sdo.upload(index, subindex)
        return data

    # --- steps ----------------------------------------------------------------------------
    def configure_pdo(self, spec: PdoSpec) -> None:
        """CiA 301 PDO (re)configuration of one PDO of the layout."""
        cob = spec.cob_id(self.drive.id)
        name = f" ({'TPDO' if spec.transmit else 'RPDO'}{spec.number})"
        self.write(spec.comm_index, 1, _U32.pack(COB_ID_INVALID | cob), name)
        self.write(spec.comm_index, 2, _U8.pack(spec.transmission_type), name)
        self.write(spec.mapping_index, 0, _U8.pack(0), name)
        for i, mapped in enumerate(spec.mapping, start=1):
            self.write(spec.mapping_index, i, _U32.pack(mapped.entry), name)
        self.write(spec.mapping_index, 0, _U8.pack(len(spec.mapping)), name)
        self.write(spec.comm_index, 1, _U32.pack(cob), name)

    def disable_pdo(self, transmit: bool, number: int) -> None:
        """Mark a PDO outside the layout invalid; a drive without it is fine."""
        index = (0x1800 if transmit else 0x1400) + number - 1
        cob = (tpdo_cob_id if transmit else rpdo_cob_id)(number, self.drive.id)
        try:
            self.write(index, 1, _U32.pack(COB_ID_INVALID | cob))
        except DriveSetupError as exc:
            if exc.abort_code not in (SdoAbort.NO_OBJECT, SdoAbort.NO_SUBINDEX):
                raise

    def set_mode_csv(self) -> int:
        mode = OperationMode.CYCLIC_SYNCHRONOUS_VELOCITY
        self.write(0x6060, 0, _I8.pack(mode), " (modes of operation)")
        deadline = self._wall() + self.setup.state_timeout_s
        while True:
            shown = _I8.unpack(self.read(0x6061, 0, " (modes of operation display)")[:1])[0]
            if shown == mode:
                return shown
            if self._wall() > deadline:
                raise DriveTimeoutError(
                    f"drive {self.drive.id}: 6061h shows mode {shown}, not {mode} (CSV), "
                    f"{self.setup.state_timeout_s:g} s after 6060h = {mode}",
                    index=0x6061,
                    subindex=0,
                )
            self._sleep(0.005)

    def statusword(self) -> int:
        return _U16.unpack(self.read(0x6041, 0, " (statusword)")[:2])[0]

    def enable_operation(self) -> int:
        """Walk the CiA 402 state machine to Operation Enabled; return the final statusword."""
        last_cw = 0
        for _ in range(12):  # longest path: fault -> ... -> operation enabled is 5 steps
            sw = self.statusword()
            state = drive_state(sw)
            if state is Drive402State.OPERATION_ENABLED:
                return sw
            cw = enable_controlword(state, last_cw)
            self.write(0x6040, 0, _U16.pack(cw), f" (controlword, drive in {state.value})")
            last_cw = cw
            self._wait_for_change(state)
        sw = self.statusword()
        raise DriveTimeoutError(
            f"drive {self.drive.id}: not in Operation Enabled after the CiA 402 sequence "
            f"(statusword 0x{sw:04X}, {drive_state(sw).value})",
            index=0x6041,
            subindex=0,
        )

    def _wait_for_change(self, before: Drive402State) -> None:
        deadline = self._wall() + self.setup.state_timeout_s
        while self._wall() <= deadline:
            if drive_state(self.statusword()) is not before:
                return
            self._sleep(0.002)
        raise DriveTimeoutError(
            f"drive {self.drive.id}: statusword stays in {before.value} for "
            f"{self.setup.state_timeout_s:g} s after the controlword",
            index=0x6041,
            subindex=0,
        )

    def run(self) -> DriveInfo:
        """The whole start-up sequence (module docstring); returns what it learned."""
        nmt = self.drive.nmt
        nmt.send_command(NmtCommand.ENTER_PRE_OPERATIONAL)
        for spec in LAYOUT:
            self.configure_pdo(spec)
        if self.setup.disable_other_pdos:
            used = {(spec.transmit, spec.number) for spec in LAYOUT}
            for transmit in (True, False):
                for number in range(1, 5):
                    if (transmit, number) not in used:
                        self.disable_pdo(transmit, number)
        mode = self.set_mode_csv()
        self.write(0x1017, 0, _U16.pack(self.setup.heartbeat_producer_ms), " (producer heartbeat)")
        rated_mnm = _U32.unpack(self.read(0x6076, 0, " (motor rated torque)")[:4])[0]
        if rated_mnm == 0:
            raise DriveSetupError(
                f"drive {self.drive.id}: 6076h motor rated torque is 0 mN·m; the torque "
                "scaling (6077h per mille of it) needs a value > 0",
                index=0x6076,
                subindex=0,
            )
        nmt.send_command(NmtCommand.START)
        sw = self.enable_operation()
        log.info(
            "drive %d configured: CSV, rated torque %d mN·m, statusword 0x%04X",
            self.drive.id,
            rated_mnm,
            sw,
        )
        return DriveInfo(rated_mnm / 1000.0, sw, mode, self.transfers)

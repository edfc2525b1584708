"""The PDO layout of the contract (docs/canopen_layout.md): COB-IDs, mappings, byte formats.

One place for what the master writes at start-up (:mod:`bridge.master`), what the cycle packs
and unpacks (:mod:`bridge.cycle`) and what the bus-load figure counts (:mod:`bridge.busload`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum

from virtual_bus.contract import NMT_COB_ID as NMT_COB_ID
from virtual_bus.contract import SYNC_COB_ID as SYNC_COB_ID
from virtual_bus.contract import (
    Cia402,
    DataType,
    emcy_cob_id,
    heartbeat_cob_id,
    mapping_entry,
    pdo_cob_id,
    pdo_struct,
    sdo_tx_cob_id,
    type_size,
)

from .errors import BridgeConfigError


def check_node_id(name: str, node_id: object) -> int:
    """A CANopen node-ID 1..127 or BridgeConfigError naming ``name``."""
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise BridgeConfigError(f"{name} = {node_id!r}: a CANopen node-ID must be 1..127")
    return node_id


@dataclass(frozen=True)
class MappedObject:
    """One mapping entry: object index, sub-index and CiA 301 data type."""

    index: int
    subindex: int
    data_type: DataType

    @property
    def bits(self) -> int:
        size = type_size(self.data_type)
        assert size is not None
        return 8 * size

    @property
    def entry(self) -> int:
        """The UNSIGNED32 mapping entry of CiA 301 (index << 16 | sub << 8 | bits)."""
        return mapping_entry(self.index, self.subindex, self.bits)


@dataclass(frozen=True)
class PdoSpec:
    """One PDO of the layout: number (1..4), direction, transmission type, mapping."""

    number: int
    transmit: bool  # TPDO of the drive (drive -> bridge)
    transmission_type: int
    mapping: tuple[MappedObject, ...]

    @property
    def dlc(self) -> int:
        return sum(m.bits for m in self.mapping) // 8

    @property
    def struct(self) -> struct.Struct:
        """Codec of the payload (the contract's PDO entry codec)."""
        return pdo_struct([m.data_type for m in self.mapping])

    @property
    def fmt(self) -> str:
        """The struct format of the payload (what :class:`RxFrame` takes)."""
        return self.struct.format

    def cob_id(self, drive_id: int) -> int:
        return pdo_cob_id(self.transmit, self.number, drive_id)


#: TPDO1: 6064h position actual value (I32) + 60E4h:01 load scale (I32), every SYNC.
_I16, _I32, _U16 = DataType.INTEGER16, DataType.INTEGER32, DataType.UNSIGNED16
TPDO1 = PdoSpec(
    1,
    True,
    1,
    (
        MappedObject(Cia402.POSITION_ACTUAL_VALUE, 0, _I32),
        MappedObject(Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 1, _I32),
    ),
)
#: TPDO2: 6041h statusword (U16) + 6077h torque actual (I16) + 606Ch velocity actual (I32).
TPDO2 = PdoSpec(
    2,
    True,
    1,
    (
        MappedObject(Cia402.STATUSWORD, 0, _U16),
        MappedObject(Cia402.TORQUE_ACTUAL_VALUE, 0, _I16),
        MappedObject(Cia402.VELOCITY_ACTUAL_VALUE, 0, _I32),
    ),
)
#: RPDO1: 6040h controlword (U16) + 60FFh target velocity (I32), asynchronous reception.
RPDO1 = PdoSpec(
    1,
    False,
    255,
    (MappedObject(Cia402.CONTROLWORD, 0, _U16), MappedObject(Cia402.TARGET_VELOCITY, 0, _I32)),
)

LAYOUT: tuple[PdoSpec, ...] = (TPDO1, TPDO2, RPDO1)
TPDO1_STRUCT = TPDO1.struct
TPDO2_STRUCT = TPDO2.struct
RPDO1_STRUCT = RPDO1.struct
assert TPDO1_STRUCT.size == TPDO1.dlc and TPDO2_STRUCT.size == TPDO2.dlc
assert RPDO1_STRUCT.size == RPDO1.dlc


@dataclass(frozen=True)
class CobIds:
    """The COB-IDs the bridge uses with one drive."""

    drive_id: int

    def __post_init__(self) -> None:
        check_node_id("drive_id", self.drive_id)

    @property
    def tpdo1(self) -> int:
        return TPDO1.cob_id(self.drive_id)

    @property
    def tpdo2(self) -> int:
        return TPDO2.cob_id(self.drive_id)

    @property
    def rpdo1(self) -> int:
        return RPDO1.cob_id(self.drive_id)

    @property
    def emcy(self) -> int:
        return emcy_cob_id(self.drive_id)

    @property
    def heartbeat(self) -> int:
        return heartbeat_cob_id(self.drive_id)

    @property
    def sdo_tx(self) -> int:
        """Drive's SDO responses (server -> client)."""
        return sdo_tx_cob_id(self.drive_id)


# --- the layout the cycle decodes (built at start-up from what the drive has) ------------------
class Signal(Enum):
    """A value the cycle takes from the frames of one SYNC (value: the CiA 402 object)."""

    MOTOR_POSITION = Cia402.POSITION_ACTUAL_VALUE  # position actual value, drive position units
    LOAD_POSITION = (
        Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE
    )  # load measuring system (60E4h, a vendor object or a CiA 406 6004h)
    STATUSWORD = Cia402.STATUSWORD
    TORQUE = Cia402.TORQUE_ACTUAL_VALUE  # torque actual value, per mille of 6076h
    MOTOR_VELOCITY = Cia402.VELOCITY_ACTUAL_VALUE  # velocity actual value, drive velocity units


#: struct codes of the integer types a mapped object may have, by bit length and signedness.
_STRUCT_CODE = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h"}
_STRUCT_CODE |= {(32, False): "I", (32, True): "i"}


def struct_code(bits: int, signed: bool) -> str:
    """The struct format letter of an integer object of ``bits`` bits."""
    try:
        return _STRUCT_CODE[(bits, signed)]
    except KeyError:
        raise BridgeConfigError(f"{bits}-bit objects cannot be mapped (8, 16 or 32)") from None


@dataclass(frozen=True)
class RxFrame:
    """A frame the bridge expects after every SYNC: CAN id, payload format, what it carries.

    ``signals[i]`` is the value unpacked by the i-th code of ``fmt`` (little endian)."""

    name: str
    can_id: int
    fmt: str
    signals: tuple[Signal, ...]

    def __post_init__(self) -> None:
        if len(struct.Struct(self.fmt).unpack(bytes(struct.calcsize(self.fmt)))) != len(
            self.signals
        ):
            raise BridgeConfigError(f"{self.name}: format {self.fmt} does not match the signals")

    @property
    def dlc(self) -> int:
        return struct.calcsize(self.fmt)


@dataclass(frozen=True)
class CycleLayout:
    """What the cycle decodes and encodes (the narrow interface between start-up and cycle).

    frames: the TPDOs (of the drive, and of a CiA 406 encoder if one supplies the load
    position) expected after every SYNC, in slot order; a missing one is ``None`` in
    :meth:`bridge.cycle.CycleController.step`. rpdo_can_id / rpdo_fmt: the bridge's set point
    frame, controlword (UNSIGNED16) then target velocity (INTEGER32). MOTOR_POSITION and
    STATUSWORD must be carried; without LOAD_POSITION the load position is the motor
    position over k_r (``position_feedback = "motor"``: the regulator has nothing to do).
    """

    frames: tuple[RxFrame, ...]
    rpdo_can_id: int
    rpdo_fmt: str = "<Hi"

    def __post_init__(self) -> None:
        carried = [s for f in self.frames for s in f.signals]
        for needed in (Signal.MOTOR_POSITION, Signal.STATUSWORD):
            if needed not in carried:
                raise BridgeConfigError(f"layout carries no {needed.name} (6064h / 6041h)")
        if len(carried) != len(set(carried)):
            raise BridgeConfigError("layout carries a signal twice")
        if not 1 <= len(self.frames) <= 8:
            raise BridgeConfigError(f"layout with {len(self.frames)} frames: allowed 1..8")

    @property
    def can_ids(self) -> tuple[int, ...]:
        return tuple(f.can_id for f in self.frames)

    @property
    def load_measured(self) -> bool:
        """A load measuring system is in the layout (else position feedback = motor)."""
        return any(Signal.LOAD_POSITION in f.signals for f in self.frames)

    @property
    def rpdo_dlc(self) -> int:
        return struct.calcsize(self.rpdo_fmt)

    def describe(self) -> str:
        """One line per frame, for logs and ``bridge probe``."""
        lines = [
            f"{f.name} 0x{f.can_id:03X}: " + " + ".join(s.name.lower() for s in f.signals)
            for f in self.frames
        ]
        lines.append(f"RPDO 0x{self.rpdo_can_id:03X}: controlword + target velocity")
        return "\n".join(lines)


def contract_layout(drive_id: int) -> CycleLayout:
    """The default layout of docs/canopen_layout.md (the simulated drive's)."""
    s = Signal
    return CycleLayout(
        (
            RxFrame(
                "TPDO1", TPDO1.cob_id(drive_id), TPDO1.fmt, (s.MOTOR_POSITION, s.LOAD_POSITION)
            ),
            RxFrame(
                "TPDO2",
                TPDO2.cob_id(drive_id),
                TPDO2.fmt,
                (s.STATUSWORD, s.TORQUE, s.MOTOR_VELOCITY),
            ),
        ),
        RPDO1.cob_id(drive_id),
        RPDO1.fmt,
    )

"""The PDO layout of the contract (docs/canopen_layout.md): COB-IDs, mappings, byte formats.

One place for what the master writes at start-up (:mod:`bridge.master`), what the cycle packs
and unpacks (:mod:`bridge.cycle`) and what the bus-load figure counts (:mod:`bridge.busload`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from virtual_bus.contract import NMT_COB_ID as NMT_COB_ID
from virtual_bus.contract import SYNC_COB_ID as SYNC_COB_ID
from virtual_bus.contract import (
    DataType,
    emcy_cob_id,
    heartbeat_cob_id,
    mapping_entry,
    pdo_struct,
    rpdo_cob_id,
    sdo_tx_cob_id,
    tpdo_cob_id,
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

    def cob_id(self, drive_id: int) -> int:
        return (tpdo_cob_id if self.transmit else rpdo_cob_id)(self.number, drive_id)

    @property
    def comm_index(self) -> int:
        """1800h+n-1 (TPDO) or 1400h+n-1 (RPDO) communication parameter of the drive."""
        return (0x1800 if self.transmit else 0x1400) + self.number - 1

    @property
    def mapping_index(self) -> int:
        """1A00h+n-1 (TPDO) or 1600h+n-1 (RPDO) mapping parameter of the drive."""
        return (0x1A00 if self.transmit else 0x1600) + self.number - 1


#: TPDO1: 6064h position actual value (I32) + 60E4h:01 load scale (I32), every SYNC.
_I16, _I32, _U16 = DataType.INTEGER16, DataType.INTEGER32, DataType.UNSIGNED16
TPDO1 = PdoSpec(1, True, 1, (MappedObject(0x6064, 0, _I32), MappedObject(0x60E4, 1, _I32)))
#: TPDO2: 6041h statusword (U16) + 6077h torque actual (I16) + 606Ch velocity actual (I32).
TPDO2 = PdoSpec(
    2,
    True,
    1,
    (MappedObject(0x6041, 0, _U16), MappedObject(0x6077, 0, _I16), MappedObject(0x606C, 0, _I32)),
)
#: RPDO1: 6040h controlword (U16) + 60FFh target velocity (I32), asynchronous reception.
RPDO1 = PdoSpec(1, False, 255, (MappedObject(0x6040, 0, _U16), MappedObject(0x60FF, 0, _I32)))

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

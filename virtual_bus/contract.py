"""The CANopen contract both ends of the wire share: constants and codecs, nothing else.

The bridge (:mod:`bridge`) and the simulated drive (:mod:`plant_sim.drive`) import their
COB-IDs, NMT states and commands, CiA 402 controlword/statusword bits, SDO abort codes,
scaling constants and the PDO entry codec from here, so the two sides cannot drift apart.
Behaviour stays on each side: the drive's CiA 402 state machine (``plant_sim.drive.cia402``)
is an implementation of its own and the bridge decodes statuswords with
``canopen.profiles.p402`` -- one is the other's test oracle.

References: CiA 301 v4.2 (communication profile: table 7.3 COB-IDs, 7.2.8 NMT, table 22 SDO
abort codes, 7.1.4 data types), CiA 402 (6040h/6041h bits), docs/canopen_layout.md.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from enum import Enum, IntEnum

# --- COB-IDs (CiA 301 table 7.3, predefined connection set) ----------------------------------
NMT_COB_ID = 0x000
SYNC_COB_ID = 0x080
EMCY_BASE = 0x080
TIME_COB_ID = 0x100
TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
SDO_TX_BASE = 0x580  # server -> client
SDO_RX_BASE = 0x600  # client -> server
HEARTBEAT_BASE = 0x700
#: Largest 11-bit CAN identifier.
CAN_ID_MASK = 0x7FF

#: PDO / SYNC COB-ID object bits (1005h, 1400h.., 1800h..: sub-index 1).
COB_ID_INVALID = 1 << 31
COB_ID_NO_RTR = 1 << 30  # PDO: no RTR allowed; 1005h: bit 30 = this node produces SYNC
COB_ID_SYNC_PRODUCER = 1 << 30
COB_ID_EXTENDED = 1 << 29

#: Data length of the fixed-format services (CiA 301): NMT 2, heartbeat 1, EMCY 8, SDO 8,
#: SYNC 0 or 1 (the optional counter).
NMT_LENGTH = 2
HEARTBEAT_LENGTH = 1
EMCY_LENGTH = 8
SDO_LENGTH = 8
SYNC_LENGTHS = (0, 1)


def _node(node_id: int) -> int:
    if not 1 <= node_id <= 127:
        raise ValueError(f"node-ID {node_id}: allowed 1..127")
    return node_id


def tpdo_cob_id(number: int, node_id: int) -> int:
    """Default COB-ID of TPDO ``number`` (1..4) of ``node_id``."""
    return TPDO_BASES[number - 1] + _node(node_id)


def rpdo_cob_id(number: int, node_id: int) -> int:
    """Default COB-ID of RPDO ``number`` (1..4) of ``node_id``."""
    return RPDO_BASES[number - 1] + _node(node_id)


def restricted_cob_id(can_id: int) -> bool:
    """CiA 301 restricted COB-IDs (NMT, SYNC/EMCY, TIME, SDO, NMT error control, LSS)."""
    return (
        can_id <= 0x07F
        or 0x101 <= can_id <= 0x180
        or SDO_TX_BASE < can_id <= SDO_TX_BASE + 0x7F
        or SDO_RX_BASE < can_id <= SDO_RX_BASE + 0x7F
        or 0x6E0 <= can_id <= 0x6FF
        or HEARTBEAT_BASE < can_id <= CAN_ID_MASK
    )


def pdo_cob_id(transmit: bool, number: int, node_id: int) -> int:
    """Default COB-ID of TPDO (``transmit``) or RPDO ``number`` (1..4) of ``node_id``."""
    return (tpdo_cob_id if transmit else rpdo_cob_id)(number, node_id)


def pdo_of_cob_id(cob_id: int) -> tuple[bool, int, int] | None:
    """(transmit, number, node-ID) of a COB-ID in a pre-defined PDO range, else None."""
    base, node_id = cob_id & 0x780, cob_id & 0x7F
    if node_id == 0:
        return None
    if base in TPDO_BASES:
        return True, TPDO_BASES.index(base) + 1, node_id
    if base in RPDO_BASES:
        return False, RPDO_BASES.index(base) + 1, node_id
    return None


# --- object indices: the only place the CiA 301 / 402 / 406 numbers are written ---------------
#: CiA 301 7.4.3: the communication profile area; 2000h..5FFFh is manufacturer specific.
COMMUNICATION_AREA = range(0x1000, 0x2000)
MANUFACTURER_AREA = range(0x2000, 0x6000)


class Cia301(IntEnum):
    """Objects of the communication profile (CiA 301 7.5.2) the bridge and drive use."""

    DEVICE_TYPE = 0x1000
    ERROR_REGISTER = 0x1001
    COB_ID_SYNC = 0x1005
    COMMUNICATION_CYCLE_PERIOD = 0x1006
    MANUFACTURER_DEVICE_NAME = 0x1008
    STORE_PARAMETERS = 0x1010
    RESTORE_DEFAULT_PARAMETERS = 0x1011
    CONSUMER_HEARTBEAT_TIME = 0x1016
    PRODUCER_HEARTBEAT_TIME = 0x1017
    IDENTITY = 0x1018  # :01 vendor-ID, :02 product code, :03 revision, :04 serial number
    SDO_SERVER_PARAMETER = 0x1200
    RPDO_COMMUNICATION = 0x1400  # RPDO n: + n - 1
    RPDO_MAPPING = 0x1600
    TPDO_COMMUNICATION = 0x1800
    TPDO_MAPPING = 0x1A00


class Cia402(IntEnum):
    """Objects of the drive profile (CiA 402-2) the bridge and drive use."""

    ABORT_CONNECTION_OPTION = 0x6007
    ERROR_CODE = 0x603F
    CONTROLWORD = 0x6040
    STATUSWORD = 0x6041
    QUICK_STOP_OPTION = 0x605A
    FAULT_REACTION_OPTION = 0x605E
    MODES_OF_OPERATION = 0x6060
    MODES_OF_OPERATION_DISPLAY = 0x6061
    POSITION_ACTUAL_VALUE = 0x6064
    VELOCITY_ACTUAL_VALUE = 0x606C
    MAX_TORQUE = 0x6072
    MOTOR_RATED_TORQUE = 0x6076
    TORQUE_ACTUAL_VALUE = 0x6077
    PROFILE_ACCELERATION = 0x6083
    PROFILE_DECELERATION = 0x6084
    QUICK_STOP_DECELERATION = 0x6085
    POSITION_ENCODER_RESOLUTION = 0x608F  # :01 increments, :02 motor revolutions
    GEAR_RATIO = 0x6091  # :01 motor revolutions, :02 shaft revolutions
    FEED_CONSTANT = 0x6092  # :01 feed, :02 shaft revolutions
    POSITION_FACTOR = 0x6093  # :01 numerator, :02 divisor (older drives)
    VELOCITY_ENCODER_FACTOR = 0x6094
    VELOCITY_FACTOR_1 = 0x6095
    VELOCITY_FACTOR = 0x6096
    TORQUE_OFFSET = 0x60B2
    INTERPOLATION_TIME_PERIOD = 0x60C2
    ADDITIONAL_POSITION_ACTUAL_VALUE = 0x60E4  # :01.. a second measuring system (the load)
    TARGET_VELOCITY = 0x60FF
    SUPPORTED_DRIVE_MODES = 0x6502


class Cia406(IntEnum):
    """Objects of the encoder profile (CiA 406) of an external load encoder node."""

    POSITION_VALUE = 0x6004


# --- PDO parameter objects (CiA 301 7.5.2.35-38): PDO n has n-1 added to its base ----------
RPDO_COMM_BASE = Cia301.RPDO_COMMUNICATION
RPDO_MAPPING_BASE = Cia301.RPDO_MAPPING
TPDO_COMM_BASE = Cia301.TPDO_COMMUNICATION
TPDO_MAPPING_BASE = Cia301.TPDO_MAPPING
#: The last index of the four PDO parameter areas (512 TPDO mappings end at 1BFFh).
PDO_PARAMETERS_END = 0x1BFF


def pdo_comm_index(transmit: bool, number: int) -> int:
    """1800h+n-1 (TPDO) or 1400h+n-1 (RPDO): communication parameter of PDO ``number``."""
    return (TPDO_COMM_BASE if transmit else RPDO_COMM_BASE) + number - 1


def pdo_mapping_index(transmit: bool, number: int) -> int:
    """1A00h+n-1 (TPDO) or 1600h+n-1 (RPDO): mapping parameter of PDO ``number``."""
    return (TPDO_MAPPING_BASE if transmit else RPDO_MAPPING_BASE) + number - 1


def emcy_cob_id(node_id: int) -> int:
    return EMCY_BASE + _node(node_id)


def heartbeat_cob_id(node_id: int) -> int:
    return HEARTBEAT_BASE + _node(node_id)


def sdo_rx_cob_id(node_id: int) -> int:
    """COB-ID the SDO server of ``node_id`` receives requests on."""
    return SDO_RX_BASE + _node(node_id)


def sdo_tx_cob_id(node_id: int) -> int:
    """COB-ID the SDO server of ``node_id`` answers on."""
    return SDO_TX_BASE + _node(node_id)


# --- NMT (CiA 301 7.2.8) -----------------------------------------------------------------------
class NmtState(IntEnum):
    """NMT states with their heartbeat codes (CiA 301 table 48)."""

    INITIALISING = 0  # boot-up
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class NmtCommand(IntEnum):
    """NMT command specifiers (CiA 301 7.2.8.3.1)."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


#: The state each command that is no reset leads to (CiA 301 figure 48); the reset commands
#: pass through Initialising (the boot-up message) to Pre-operational.
NMT_TARGET_STATE = {
    NmtCommand.START: NmtState.OPERATIONAL,
    NmtCommand.STOP: NmtState.STOPPED,
    NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
}


def nmt_command_for(data: bytes | bytearray, node_id: int) -> NmtCommand | None:
    """The command of an NMT frame's data (command specifier, node-ID; 0 addresses every
    node) when it addresses ``node_id``, None when it addresses another node. ValueError
    naming what is wrong for a frame of another length or an unknown specifier."""
    if len(data) != NMT_LENGTH:
        raise ValueError(f"NMT frame with {len(data)} data bytes ignored (needs {NMT_LENGTH})")
    specifier, target = data[0], data[1]
    if target not in (0, node_id):
        return None
    try:
        return NmtCommand(specifier)
    except ValueError:
        allowed = ", ".join(f"0x{c:02X}" for c in NmtCommand)
        raise ValueError(f"NMT command 0x{specifier:02X} ignored; allowed {allowed}") from None


# --- master supervision (CiA 301 7.2.8.3.2 heartbeat, CiA 402 6007h) ----------------------------
#: Consumer heartbeat time (ARRAY of UNSIGNED32: node-ID << 16 | ms) and producer heartbeat
#: time (UNSIGNED16, ms) of every CANopen device (CiA 301 7.5.2.19/20).
HEARTBEAT_CONSUMER_INDEX = Cia301.CONSUMER_HEARTBEAT_TIME
HEARTBEAT_PRODUCER_INDEX = Cia301.PRODUCER_HEARTBEAT_TIME
#: CiA 402 abort connection option code (INTEGER16): what a drive does when it loses its
#: master (heartbeat or life guarding lost, NMT Stopped entered, reset communication, bus-off).
ABORT_CONNECTION_INDEX = Cia402.ABORT_CONNECTION_OPTION
#: A consumer's time is this many of the producer's periods: one heartbeat may be lost and
#: the next come late by half a period before the consumer reacts (both ends: the bridge
#: watches the drive's 100 ms with 250 ms, the drive the bridge's with 2.5 x its 1017h).
HEARTBEAT_CONSUMER_MARGIN = 2.5
#: The node-ID field of a 1016h entry is bits 16..23; bits 24..31 are reserved (0).
HEARTBEAT_CONSUMER_MAX = 0x007F_FFFF


class AbortConnection(IntEnum):
    """6007h values of CiA 402 (negative values are manufacturer specific)."""

    NO_ACTION = 0
    FAULT = 1  # fault signal: Fault Reaction Active, then Fault
    DISABLE_VOLTAGE = 2  # the power stage off at once: the axis coasts
    QUICK_STOP = 3  # the quick stop ramp (6085h), then per 605Ah


def heartbeat_consumer_entry(node_id: int, time_ms: int) -> int:
    """A 1016h entry: ``node_id`` watched with ``time_ms`` (1..65535; 0 switches it off)."""
    if not 0 <= time_ms <= 0xFFFF:
        raise ValueError(f"consumer heartbeat time {time_ms} ms: allowed 0..65535")
    return (_node(node_id) << 16) | time_ms


def split_heartbeat_consumer_entry(entry: int) -> tuple[int, int]:
    """(node-ID, time in ms) of a 1016h entry (node-ID 0 or time 0: the entry is unused)."""
    return (entry >> 16) & 0xFF, entry & 0xFFFF


def consumer_time_ms(producer_ms: int) -> int:
    """The consumer time that watches a producer of ``producer_ms``: the margin, rounded up."""
    return min(0xFFFF, math.ceil(producer_ms * HEARTBEAT_CONSUMER_MARGIN))


#: The contract's drive (1018h vendor 0, product 402h; plant_sim.drive) has a set-point
#: watchdog: SYNCs in Operation enabled without an RPDO before 6007h acts (UNSIGNED8, 0 off).
CONTRACT_SETPOINT_TIMEOUT = (0x2102, 0)


# --- EMCY error codes (CiA 301 table 21; the drive's use of them: plant_sim.drive.protection) ---
EMCY_NO_ERROR = 0x0000
#: Internal software: the plant behind the simulated drive (an FMU) failed while it stepped.
EMCY_SOFTWARE = 0x6100
EMCY_SENSOR = 0x7300
EMCY_PDO_LENGTH = 0x8210
EMCY_SYNC_LENGTH = 0x8240
EMCY_RPDO_TIMEOUT = 0x8250
#: Communication, generic: the drive left NMT Operational while enabled (6007h acted).
EMCY_COMMUNICATION = 0x8100
#: Life guard error or heartbeat error: the consumer missed the master's heartbeat (6007h).
EMCY_HEARTBEAT = 0x8130


# --- CiA 402 controlword / statusword bits -----------------------------------------------------
CW_SWITCH_ON = 1 << 0
CW_ENABLE_VOLTAGE = 1 << 1
CW_QUICK_STOP = 1 << 2  # active low
CW_ENABLE_OPERATION = 1 << 3
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8

SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5  # active low
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_FOLLOWS_COMMAND = 1 << 12  # cyclic synchronous modes: the drive follows the command value

#: 6060h value of cyclic synchronous velocity mode (CiA 402).
MODE_CSV = 9


# --- SDO abort codes (CiA 301 table 22) --------------------------------------------------------
class SdoAbort(IntEnum):
    """Every SDO abort code the bridge and the drive send or interpret (CiA 301 names)."""

    TOGGLE_BIT = 0x0503_0000  # toggle bit not alternated
    TIMEOUT = 0x0504_0000  # SDO protocol timed out
    COMMAND_SPECIFIER = 0x0504_0001  # client/server command specifier not valid or unknown
    BLOCK_SIZE = 0x0504_0002  # invalid block size (block mode only)
    SEQUENCE_NUMBER = 0x0504_0003  # invalid sequence number (block mode only)
    CRC = 0x0504_0004  # CRC error (block mode only)
    OUT_OF_MEMORY = 0x0504_0005
    UNSUPPORTED_ACCESS = 0x0601_0000  # unsupported access to an object
    WRITE_ONLY = 0x0601_0001  # attempt to read a write only object
    READ_ONLY = 0x0601_0002  # attempt to write a read only object
    NO_OBJECT = 0x0602_0000  # object does not exist in the object dictionary
    NOT_MAPPABLE = 0x0604_0041  # object cannot be mapped to the PDO
    PDO_LENGTH = 0x0604_0042  # number and length of mapped objects would exceed PDO length
    INCOMPATIBLE = 0x0604_0043  # general parameter incompatibility
    HARDWARE = 0x0606_0000  # access failed due to a hardware error
    LENGTH_MISMATCH = 0x0607_0010  # data type does not match, length of service parameter
    LENGTH_TOO_HIGH = 0x0607_0012  # data type does not match, length too high
    LENGTH_TOO_LOW = 0x0607_0013  # data type does not match, length too low
    NO_SUBINDEX = 0x0609_0011  # sub-index does not exist
    VALUE_RANGE = 0x0609_0030  # invalid value for parameter (download only)
    TOO_HIGH = 0x0609_0031  # value of parameter written too high (download only)
    TOO_LOW = 0x0609_0032  # value of parameter written too low (download only)
    MAX_BELOW_MIN = 0x0609_0036
    GENERAL = 0x0800_0000  # general error
    TRANSFER = 0x0800_0020  # data cannot be transferred or stored to the application
    NOT_STORED = 0x0800_0020  # alias of TRANSFER: what 1010h/1011h answer to a bad signature
    LOCAL_CONTROL = 0x0800_0021  # ... because of local control
    DEVICE_STATE = 0x0800_0022  # ... because of the present device state
    NO_DATA = 0x0800_0024  # no data available


# --- scaling (docs/canopen_layout.md, drive table) -----------------------------------------------
#: Motor encoder increments per motor revolution (6064h, 606Ch, 60FFh).
MOTOR_INCREMENTS_PER_REV = 1 << 20
#: Load-scale increments (60E4h:01) per load unit: nm per m (linear), µrad per rad (rotary).
LOAD_INCREMENTS_PER_M = 1e9
LOAD_INCREMENTS_PER_RAD = 1e6
#: 6077h / 6072h are per mille of 6076h; 6076h is in mN·m.
PERMILLE = 1000
MNM_PER_NM = 1000
INT16_MIN, INT16_MAX = -(1 << 15), (1 << 15) - 1
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1


# --- data types and the PDO entry codec (CiA 301 7.1.4) ----------------------------------------
class DataType(IntEnum):
    """CiA 301 static data types used by the two nodes (object 0001h.. codes)."""

    BOOLEAN = 0x0001
    INTEGER8 = 0x0002
    INTEGER16 = 0x0003
    INTEGER32 = 0x0004
    UNSIGNED8 = 0x0005
    UNSIGNED16 = 0x0006
    UNSIGNED32 = 0x0007
    REAL32 = 0x0008
    VISIBLE_STRING = 0x0009


#: Little-endian struct format of each fixed-size data type.
STRUCT_FORMATS: dict[DataType, str] = {
    DataType.BOOLEAN: "B",
    DataType.INTEGER8: "b",
    DataType.INTEGER16: "h",
    DataType.INTEGER32: "i",
    DataType.UNSIGNED8: "B",
    DataType.UNSIGNED16: "H",
    DataType.UNSIGNED32: "I",
    DataType.REAL32: "f",
}


def type_size(data_type: int) -> int | None:
    """Bytes of a fixed-size data type; None for VISIBLE_STRING / unknown types."""
    try:
        fmt = STRUCT_FORMATS[DataType(data_type)]
    except (ValueError, KeyError):
        return None
    return struct.calcsize("<" + fmt)


def mapping_entry(index: int, subindex: int, bits: int) -> int:
    """The UNSIGNED32 PDO mapping entry of CiA 301 (index << 16 | sub << 8 | bits)."""
    return (index << 16) | (subindex << 8) | bits


def split_mapping_entry(entry: int) -> tuple[int, int, int]:
    """(index, sub-index, bits) of a PDO mapping entry."""
    return entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF


def pdo_struct(data_types: Sequence[int]) -> struct.Struct:
    """The precompiled struct of a PDO whose mapped entries have ``data_types`` in order."""
    try:
        return struct.Struct("<" + "".join(STRUCT_FORMATS[DataType(t)] for t in data_types))
    except (KeyError, ValueError):
        raise ValueError(f"data types {list(data_types)}: only fixed-size types map") from None


# --- time modes ---------------------------------------------------------------------------------
class TimeMode(Enum):
    """How time advances for the loop and the drive (the physics steps per SYNC in both).

    LOCKSTEP: SYNC is the only clock (simulated time; the drive's heartbeat on it too);
    REAL_TIME: SYNC from the wall clock (the drive's heartbeat on the wall clock)."""

    LOCKSTEP = "lockstep"
    REAL_TIME = "realtime"

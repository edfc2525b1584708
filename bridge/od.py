"""The bridge's object dictionary: one table, rendered to ``config/bridge.eds`` (CiA 306).

The table (:data:`OBJECTS`) is the single source: :func:`bridge.eds.render_eds` writes the EDS that
CANopen tools read, :func:`load_od` reads that file back with ``canopen.import_od`` for the
bridge's own :class:`canopen.LocalNode`, and ``tests/bridge/test_od.py`` checks that the
committed file equals the rendering and that every object behaves in a running node.

Units and scaling (also in each object's ``Unit``/``Description`` keys, a python-canopen
extension other tools ignore): gains, times and limits are REAL32 in SI units (speeds in rad/s
at the motor, positions in load units: m for a linear axis, rad for a rotary one); move
targets and feeds are integers in load-scale increments like the drive's 60E4h:01 (nm or
µrad). Defaults are the paper's axis (``config/paper_axis.toml``, section IX); at run time
the axis file's values apply.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import canopen
from canopen.objectdictionary import datatypes as dt

from virtual_bus.contract import Cia301
from virtual_bus.sdo_server import apply_real_limits
from virtual_bus.shipped import BRIDGE_EDS

from .errors import BridgeConfigError
from .params import BOUNDS

#: Where the rendered EDS lives in the repository.
DEFAULT_EDS_PATH = BRIDGE_EDS
DEFAULT_NODE_ID = 1
DEFAULT_DRIVE_ID = 2
PAPER_KR = 100.0 * math.pi  # rad/m, section IX


class Access(Enum):
    """CiA 306 AccessType."""

    RO = "ro"
    RW = "rw"
    WO = "wo"
    CONST = "const"


class ObjectKind(Enum):
    """CiA 306 ObjectType."""

    VAR = 0x7
    ARRAY = 0x8
    RECORD = 0x9


@dataclass(frozen=True)
class Entry:
    """One VAR (or one sub-index of an ARRAY/RECORD).

    data_type: CiA 301 data type code (``canopen.objectdictionary.datatypes``). default: the
    EDS DefaultValue. low/high: LowLimit/HighLimit, enforced by the SDO server before the
    application (REAL32 too: an open bound at 0 is the smallest positive REAL32,
    :data:`SMALLEST_REAL32`). rules: what the node enforces beyond the limits (dependencies on
    other objects and on the bridge state), written into the Description in the notation of
    :data:`RULES_NOTE` so that a tool reading only the EDS predicts every SDO answer.
    """

    index: int
    subindex: int
    name: str
    data_type: int
    access: Access
    default: int | float | str
    unit: str = ""
    description: str = ""
    low: int | float | None = None
    high: int | float | None = None
    rules: tuple[str, ...] = ()


@dataclass(frozen=True)
class Group:
    """An ARRAY or RECORD: sub-index 0 (highest sub-index) is generated."""

    index: int
    name: str
    kind: ObjectKind
    members: tuple[Entry, ...]
    description: str = ""


def _var(
    index: int,
    name: str,
    data_type: int,
    access: Access,
    default: int | float | str,
    unit: str = "",
    description: str = "",
    low: int | float | None = None,
    high: int | float | None = None,
    rules: tuple[str, ...] = (),
) -> Entry:
    return Entry(index, 0, name, data_type, access, default, unit, description, low, high, rules)


R, U8, U16, U32, I32, BOOL, VS = (
    dt.REAL32,
    dt.UNSIGNED8,
    dt.UNSIGNED16,
    dt.UNSIGNED32,
    dt.INTEGER32,
    dt.BOOLEAN,
    dt.VISIBLE_STRING,
)
RO, RW, WO, CONST = Access.RO, Access.RW, Access.WO, Access.CONST

# --- indices used by the code ----------------------------------------------------------------
DEVICE_TYPE, ERROR_REGISTER, COB_ID_SYNC, CYCLE_PERIOD = (
    Cia301.DEVICE_TYPE,
    Cia301.ERROR_REGISTER,
    Cia301.COB_ID_SYNC,
    Cia301.COMMUNICATION_CYCLE_PERIOD,
)
DEVICE_NAME, HEARTBEAT_CONSUMER, HEARTBEAT_PRODUCER, IDENTITY = (
    Cia301.MANUFACTURER_DEVICE_NAME,
    Cia301.CONSUMER_HEARTBEAT_TIME,
    Cia301.PRODUCER_HEARTBEAT_TIME,
    Cia301.IDENTITY,
)
STORE_PARAMETERS, RESTORE_DEFAULTS = Cia301.STORE_PARAMETERS, Cia301.RESTORE_DEFAULT_PARAMETERS
KV, REG_ENABLE, BETA_T, WINDOW_N, TV, TF, KR = range(0x2000, 0x2007)
SPEED_LIMIT, FE_LIMIT, DISC_LIMIT, PDO_TOLERANCE, VELOCITY_FF = range(0x2007, 0x200C)
TARGET, FEED, ACCEL, MOVE_STATUS, POSITION_LIMITS = range(0x2010, 0x2015)
COMMAND = 0x2020
BETA, LAMBDA, FOLLOWING_ERROR, MOTOR_LOAD_DIFF, STATE, STOP_REASON, STOP_MESSAGE = range(
    0x2100, 0x2107
)
PDO_COUNTERS, SPEED_SETPOINT, POSITION_REFERENCE, DRIVE_ERROR = range(0x2107, 0x210B)
FRAME_COUNTERS = 0x2110

#: 1005h: bit 30 set = this node produces SYNC, COB-ID 0x080.
SYNC_COB_ID_VALUE = 0x4000_0080
#: CiA 301 signatures: "save" written to 1010h, "load" to 1011h (ISO 8859 bytes, LSB first).
SAVE_SIGNATURE = 0x6576_6173
LOAD_SIGNATURE = 0x6461_6F6C
#: Read value of 1010h:01 / 1011h:01: bit 0 = the node saves (restores) on command.
STORE_ON_COMMAND = 0x0000_0001
#: Default software position limits (2014h), load units: +-2 m covers the INTEGER32 nm range
#: of 2010h (+-2.147 m).
DEFAULT_POSITION_LIMIT = 2.0
#: Heartbeat producer time 1017h default, ms (CiA 301; 0 = off): the drive's heartbeat
#: consumer (1016h, configured by the start-up) and any watching node (CANopenNode, Lely) see
#: the bridge alive by it (bridge.nmt, bridge.supervision).
DEFAULT_HEARTBEAT_MS = 100
#: The smallest positive REAL32 (2^-149): the LowLimit of a range open at 0, "(0, x]".
SMALLEST_REAL32 = 2.0**-149
#: Load-scale increments per load unit the EDS's rules assume (a linear axis: nm per m; a
#: rotary axis, µrad per rad, scales 2010h-2012h by 1e6 instead).
RULE_INCREMENTS_PER_UNIT = 1e9
_INC = "1e9"  # RULE_INCREMENTS_PER_UNIT as the rules write it
#: How the rules in the Descriptions read (also in the EDS's [Comments]).
RULES_NOTE = (
    "Rules: [requires EXPR else CODE] in a Description: a write (after the CiA 301 checks and "
    "the limits) is answered with abort CODE when EXPR is false; EXPR reads value (the value "
    "written), present (the object's present value) and other objects as XXXXh or XXXXh:SS "
    "(their present values); docs/peers.md"
)
_STATE = 0x2104  # the bridge state 2104h (bridge.cycle.BridgeState: 2 enabling, 3 running)
#: Parameters locked while the axis is enabled (bridge.params.LOCKED).
LOCKED_RULE = f"[requires {_STATE:04X}h not in (2, 3) else 0800 0022]"


def _limits(field: str) -> tuple[float, float]:
    """LowLimit/HighLimit of a REAL32 parameter from its :data:`bridge.params.BOUNDS`."""
    bound = BOUNDS[field]
    low = SMALLEST_REAL32 if bound.low_open and bound.low == 0.0 else bound.low
    assert not bound.low_open or bound.low == 0.0, f"{field}: open bound other than 0"
    return low, bound.high


_STORE_RULE = (
    "[requires value == 0x{sig:08X} and {index:04X}h:01 == 1 else 0800 0020]"  # CiA 301 7.5.2.13
)
_LOW_KV = f"[requires {TV:04X}h == 0 or {TV:04X}h >= 20 / value * (1 - 1e-12) else 0609 0032]"
_SAMPLING = "{c} / 1e6 < 1 / ({kv} * 2 * ({n} + 1))"  # section VII, regulator.max_cycle_s
_FEED_RULE = "{feed} / {inc} * {kr} <= {limit}"  # feed * k_r <= speed set point limit

OBJECTS: tuple[Entry | Group, ...] = (
    # --- communication profile (CiA 301) -----------------------------------------------------
    _var(DEVICE_TYPE, "Device type", U32, CONST, 0, description="no device profile"),
    _var(
        ERROR_REGISTER,
        "Error register",
        U8,
        RO,
        0,
        description="bit 0 generic error: set while the bridge is stopped by a fault",
    ),
    _var(
        COB_ID_SYNC,
        "COB-ID SYNC message",
        U32,
        RW,
        SYNC_COB_ID_VALUE,
        description="bit 30: the bridge is the SYNC producer; COB-ID 0x080 (rw as CiA 301 "
        "defines it; LowLimit = HighLimit: no other value is accepted)",
        low=SYNC_COB_ID_VALUE,
        high=SYNC_COB_ID_VALUE,
    ),
    _var(
        CYCLE_PERIOD,
        "Communication cycle period",
        U32,
        RW,
        1000,
        "us",
        "SYNC period = position-control cycle; section VII sampling rule "
        "cycle < 1/(2 (n+1) kv); locked while the axis is enabled",
        100,
        100_000,
        rules=(
            LOCKED_RULE,
            "[requires "
            + _SAMPLING.format(c="value", kv=f"{KV:04X}h", n=f"{WINDOW_N:04X}h")
            + " else 0609 0031]",
        ),
    ),
    _var(DEVICE_NAME, "Manufacturer device name", VS, CONST, "backlash-bridge"),
    Group(
        HEARTBEAT_CONSUMER,
        "Consumer heartbeat time",
        ObjectKind.ARRAY,
        (
            Entry(
                HEARTBEAT_CONSUMER,
                1,
                "Consumer heartbeat time 1",
                U32,
                RW,
                (DEFAULT_DRIVE_ID << 16) | 250,
                "ms",
                f"bits 16-23 drive node-ID ({DEFAULT_DRIVE_ID}: the limits), bits 0-15 timeout "
                "in ms (0: not monitored); locked while the axis is enabled",
                DEFAULT_DRIVE_ID << 16,
                (DEFAULT_DRIVE_ID << 16) | 0xFFFF,
                (LOCKED_RULE,),
            ),
        ),
    ),
    Group(
        STORE_PARAMETERS,
        "Store parameters",
        ObjectKind.ARRAY,
        (
            Entry(
                STORE_PARAMETERS,
                1,
                "Save all parameters",
                U32,
                RW,
                STORE_ON_COMMAND,
                "",
                "CiA 301: write 0x65766173 ('save') to store the objects marked "
                "StorageLocation=PERSIST in the store file; other values, or no store file "
                "(read 0): 0800 0020; read: 1 (saves on command)",
                rules=(_STORE_RULE.format(sig=SAVE_SIGNATURE, index=STORE_PARAMETERS),),
            ),
        ),
    ),
    Group(
        RESTORE_DEFAULTS,
        "Restore default parameters",
        ObjectKind.ARRAY,
        (
            Entry(
                RESTORE_DEFAULTS,
                1,
                "Restore all default parameters",
                U32,
                RW,
                STORE_ON_COMMAND,
                "",
                "CiA 301: write 0x64616F6C ('load') to discard the store file; the defaults "
                "(axis file) apply at the next start; other values, or no store file "
                "(read 0): 0800 0020",
                rules=(_STORE_RULE.format(sig=LOAD_SIGNATURE, index=RESTORE_DEFAULTS),),
            ),
        ),
    ),
    _var(
        HEARTBEAT_PRODUCER,
        "Producer heartbeat time",
        U16,
        RW,
        DEFAULT_HEARTBEAT_MS,
        "ms",
        "the bridge's heartbeat (its NMT state) every so many ms; 0: off (then the drive "
        "cannot watch the bridge: the start-up configures its 1016h from this)",
    ),
    Group(
        IDENTITY,
        "Identity object",
        ObjectKind.RECORD,
        (
            Entry(IDENTITY, 1, "Vendor-ID", U32, RO, 0),
            Entry(IDENTITY, 2, "Product code", U32, RO, 0),
            Entry(IDENTITY, 3, "Revision number", U32, RO, 0x0001_0000),
            Entry(IDENTITY, 4, "Serial number", U32, RO, 0),
        ),
    ),
    # --- parameters (locked while the axis is enabled, see bridge.params.LOCKED) ------------
    _var(
        KV,
        "Position gain kv",
        R,
        RW,
        25.0,
        "1/s",
        "P position controller on the load scale, eq. 7: omega_c = k_r kv (x_ref - x_l); "
        "(0, 1000]; section VII sampling rule with 1006h and 2003h; eq. 14 with 2004h; "
        "locked while enabled",
        *_limits("kv_per_s"),
        rules=(
            LOCKED_RULE,
            "[requires "
            + _SAMPLING.format(c=f"{CYCLE_PERIOD:04X}h", kv="value", n=f"{WINDOW_N:04X}h")
            + " else 0609 0031]",
            _LOW_KV,
        ),
    ),
    _var(
        REG_ENABLE,
        "Regulator enable",
        BOOL,
        RW,
        1,
        "",
        "1: speed regulator of eq. 15 in the loop; 0: omega_r = omega_c (beta still "
        "measured); locked while enabled",
        rules=(LOCKED_RULE,),
    ),
    _var(
        BETA_T,
        "Vibration threshold beta_T",
        R,
        RW,
        0.2,
        "rad/s",
        "beta_T of eq. 15, motor side; (0, 1e4]; locked while enabled",
        *_limits("beta_t_rad_s"),
        rules=(LOCKED_RULE,),
    ),
    _var(
        WINDOW_N,
        "Detector window n",
        U8,
        RW,
        4,
        "",
        "the detector averages n+1 samples (section VII, paper: 4); sampling rule with 1006h "
        "and 2000h; locked while enabled",
        1,
        64,
        rules=(
            LOCKED_RULE,
            "[requires "
            + _SAMPLING.format(c=f"{CYCLE_PERIOD:04X}h", kv=f"{KV:04X}h", n="value")
            + " else 0609 0031]",
        ),
    ),
    _var(
        TV,
        "Holder decay time T_v",
        R,
        RW,
        0.0,
        "s",
        "0: eq. 14 default 20/kv; else >= 20/kv (eq. 14), at most 1000; locked while enabled",
        0.0,
        BOUNDS["tv_s"].high,
        rules=(
            LOCKED_RULE,
            f"[requires value == 0 or value >= 20 / {KV:04X}h * (1 - 1e-12) else 0609 0032]",
        ),
    ),
    _var(
        TF,
        "Low-pass time constant T_f",
        R,
        RW,
        0.05,
        "s",
        "vibration level smoothing (section VII); (0, 100]; locked while enabled",
        *_limits("tf_s"),
        rules=(LOCKED_RULE,),
    ),
    _var(
        KR,
        "Transmission ratio k_r",
        R,
        RW,
        PAPER_KR,
        "rad per load unit",
        "motor rad per load unit (m or rad); feed 2011h times k_r within 2007h; locked while "
        "enabled",
        *_limits("transmission_ratio"),
        rules=(
            LOCKED_RULE,
            "[requires "
            + _FEED_RULE.format(
                feed=f"{FEED:04X}h",
                inc=_INC,
                kr="value",
                limit=f"{SPEED_LIMIT:04X}h",
            )
            + " else 0609 0031]",
        ),
    ),
    # --- limits (may change at any time) ----------------------------------------------------
    _var(
        SPEED_LIMIT,
        "Speed set point limit",
        R,
        RW,
        100.0 * math.pi,
        "rad/s",
        "|omega_r| is clamped to this; (0, 12867]; at least feed 2011h times k_r 2006h",
        *_limits("speed_limit_rad_s"),
        rules=(
            "[requires "
            + _FEED_RULE.format(feed=f"{FEED:04X}h", inc=_INC, kr=f"{KR:04X}h", limit="value")
            + " else 0609 0032]",
        ),
    ),
    _var(
        FE_LIMIT,
        "Following error limit",
        R,
        RW,
        0.005,
        "load unit",
        "stop (reason 5) when |x_ref - x_l| exceeds it; (0, 10]",
        *_limits("following_error_limit"),
    ),
    _var(
        DISC_LIMIT,
        "Encoder discrepancy limit",
        R,
        RW,
        0.0005,
        "load unit",
        "stop (reason 6) when motor and load scale differ by more than this relative to "
        "enable (section II.B: about 0.5 mm or 0.5 deg); (0, 10]",
        *_limits("discrepancy_limit"),
    ),
    _var(
        PDO_TOLERANCE,
        "PDO loss tolerance",
        U8,
        RW,
        5,
        "cycles",
        "consecutive cycles with a missing TPDO before the axis is stopped (reason 1)",
        0,
        255,
    ),
    _var(
        VELOCITY_FF,
        "Velocity feed-forward k_vff",
        R,
        RW,
        0.0,
        "",
        "omega_c = k_r kv (x_ref - x_l) + k_vff omega_s (axis file control.velocity_feedforward); "
        "[0, 1.5]; locked while enabled",
        *_limits("velocity_feedforward"),
        rules=(LOCKED_RULE,),
    ),
    # --- moves ------------------------------------------------------------------------------
    _var(
        TARGET,
        "Target position",
        I32,
        RW,
        0,
        "load increments",
        "nm (linear) or urad (rotary); a write starts a move at 2011h/2012h (only while "
        "running and no move is active, else 0800 0022) to a target within 2014h",
        rules=(
            f"[requires {_STATE:04X}h == 3 and {MOVE_STATUS:04X}h == 0 else 0800 0022]",
            f"[requires value / {_INC} >= {POSITION_LIMITS:04X}h:01 else 0609 0032]",
            f"[requires value / {_INC} <= {POSITION_LIMITS:04X}h:02 else 0609 0031]",
        ),
    ),
    _var(
        FEED,
        "Feed",
        U32,
        RW,
        50_000_000,
        "load increments/s",
        "nm/s or urad/s; feed * k_r must not exceed the speed set point limit",
        1,
        0xFFFF_FFFF,
        rules=(
            "[requires "
            + _FEED_RULE.format(
                feed="value",
                inc=_INC,
                kr=f"{KR:04X}h",
                limit=f"{SPEED_LIMIT:04X}h",
            )
            + " else 0609 0031]",
        ),
    ),
    _var(
        ACCEL,
        "Acceleration",
        U32,
        RW,
        0,
        "load increments/s^2",
        "nm/s^2 or urad/s^2; 0: speed step (the paper's section X input)",
        0,
        0xFFFF_FFFF,
    ),
    _var(MOVE_STATUS, "Move status", U8, RO, 0, "", "0: idle (holding), 1: moving"),
    Group(
        POSITION_LIMITS,
        "Software position limit",
        ObjectKind.RECORD,
        (
            Entry(
                POSITION_LIMITS,
                1,
                "Min position limit",
                R,
                RW,
                -DEFAULT_POSITION_LIMIT,
                "load unit",
                "like CiA 402 607Dh:01, in m or rad: a move to a target below it is refused "
                "(0609 0032); the axis is stopped (reason 10) when the load scale is below it "
                "and no move heads back; [-1000, 1000], below 2014h:02",
                *_limits("position_limit_min"),
                (f"[requires value < {POSITION_LIMITS:04X}h:02 else 0609 0031]",),
            ),
            Entry(
                POSITION_LIMITS,
                2,
                "Max position limit",
                R,
                RW,
                DEFAULT_POSITION_LIMIT,
                "load unit",
                "like CiA 402 607Dh:02, in m or rad: a move to a target above it is refused "
                "(0609 0031); the axis is stopped (reason 10) when the load scale is above it "
                "and no move heads back; [-1000, 1000], above 2014h:01",
                *_limits("position_limit_max"),
                (f"[requires value > {POSITION_LIMITS:04X}h:01 else 0609 0032]",),
            ),
        ),
    ),
    _var(
        COMMAND,
        "Command",
        U8,
        WO,
        0,
        "",
        "0: idle (no command), 1: enable (from disabled), 2: disable (while enabling or "
        "running), 3: reset a stop (to disabled); above 3: 0609 0031; not possible in the "
        "present state (2104h): 0800 0022",
        0,
        3,
        rules=(
            f"[requires value == 0 or (value == 1 and {_STATE:04X}h == 1) or (value == 2 and "
            f"{_STATE:04X}h in (2, 3)) or (value == 3 and {_STATE:04X}h == 4) else 0800 0022]",
        ),
    ),
    # --- live values (read only) ------------------------------------------------------------
    _var(BETA, "Vibration level beta", R, RO, 0.0, "rad/s", "Fig. 5 detector output"),
    _var(LAMBDA, "Switching factor lambda", R, RO, 1.0, "", "eq. 15"),
    _var(FOLLOWING_ERROR, "Following error", R, RO, 0.0, "load unit", "x_ref - x_l, eq. 1"),
    _var(
        MOTOR_LOAD_DIFF,
        "Motor-load difference",
        R,
        RO,
        0.0,
        "load unit",
        "theta_m/k_r - x_l minus its value at enable (section II.B)",
    ),
    _var(
        STATE,
        "Bridge state",
        U8,
        RO,
        0,
        "",
        "0 configuring, 1 disabled, 2 enabling, 3 running, 4 stopped",
    ),
    _var(STOP_REASON, "Stop reason", U8, RO, 0, "", "bridge.cycle.StopReason value; 0: none"),
    _var(STOP_MESSAGE, "Stop message", VS, RO, "none", "", "why the axis was stopped"),
    Group(
        PDO_COUNTERS,
        "PDO counters",
        ObjectKind.RECORD,
        (
            Entry(
                PDO_COUNTERS,
                1,
                "Missed TPDOs",
                U32,
                RO,
                0,
                "frames",
                "TPDO slots with no frame by the end of their cycle",
            ),
            Entry(
                PDO_COUNTERS,
                2,
                "Late TPDOs",
                U32,
                RO,
                0,
                "frames",
                "TPDO frames received outside their cycle (extra or after the deadline)",
            ),
            Entry(
                PDO_COUNTERS,
                3,
                "Invalid TPDOs",
                U32,
                RO,
                0,
                "frames",
                "TPDO frames of the wrong length (counted as missed too)",
            ),
            Entry(PDO_COUNTERS, 4, "Cycles", U32, RO, 0, "cycles", "SYNCs sent"),
            Entry(
                PDO_COUNTERS,
                5,
                "Missed cycles",
                U32,
                RO,
                0,
                "cycles",
                "cycles computed without a complete TPDO set",
            ),
        ),
    ),
    _var(SPEED_SETPOINT, "Speed set point omega_r", R, RO, 0.0, "rad/s", "last 60FFh sent"),
    _var(
        POSITION_REFERENCE,
        "Position reference",
        R,
        RO,
        0.0,
        "load unit",
        "interpolator output x_ref",
    ),
    _var(
        DRIVE_ERROR,
        "Drive error code",
        U16,
        RO,
        0,
        "",
        "last EMCY error code of the drive (0: none)",
    ),
    Group(
        FRAME_COUNTERS,
        "Refused frames",
        ObjectKind.RECORD,
        tuple(
            Entry(FRAME_COUNTERS, sub, name, U32, RO, 0, "frames", text)
            for sub, name, text in (
                (1, "Bad length", "data length not the one the service at its COB-ID needs"),
                (2, "Unknown COB-ID", "no service of the bridge consumes it"),
                (3, "Not allowed in state", "the NMT state does not allow the service"),
                (4, "Second SYNC producer", "SYNC frames the bridge did not send (axis stops)"),
                (5, "Remote frames", "RTR frames (no remote service here)"),
                (6, "Extended identifiers", "29-bit identifiers"),
                (7, "Error frames", "error frames reported by the interface"),
            )
        ),
    ),
)


#: Objects 1010h saves and a start-up loads (StorageLocation=PERSIST in the EDS): the
#: parameters. Live values, moves (2010h) and commands are not stored (StorageLocation=RAM).
STORED: frozenset[tuple[int, int]] = frozenset(
    {
        (CYCLE_PERIOD, 0),
        (HEARTBEAT_CONSUMER, 1),
        *((index, 0) for index in range(KV, VELOCITY_FF + 1)),
        (FEED, 0),
        (ACCEL, 0),
        (POSITION_LIMITS, 1),
        (POSITION_LIMITS, 2),
    }
)


def entries() -> Iterator[Entry]:
    """Every VAR and sub-index (without the generated sub-index 0 of groups)."""
    for obj in OBJECTS:
        if isinstance(obj, Group):
            yield from obj.members
        else:
            yield obj


def load_od(
    path: str | Path = DEFAULT_EDS_PATH, node_id: int = DEFAULT_NODE_ID
) -> canopen.ObjectDictionary:
    """Read the bridge's EDS with ``canopen.import_od`` (raises BridgeConfigError)."""
    path = Path(path)
    if not path.is_file():
        raise BridgeConfigError(f"{path}: no such EDS file (render it with `python -m bridge eds`)")
    try:
        od = canopen.import_od(str(path), node_id)
        apply_real_limits(od, str(path))  # python canopen drops REAL32 LowLimit/HighLimit
    except Exception as exc:  # configparser and canopen raise assorted types
        raise BridgeConfigError(f"{path}: not a readable EDS ({exc})") from exc
    return od

"""From what a drive reports to the bridge's layout, mode and scaling (pure, no bus).

:class:`DriveFacts` is what the start-up read over SDO (:meth:`bridge.master.DriveMaster.
read_facts`); :func:`plan` turns facts and a drive profile
(:class:`~virtual_bus.formats.drive_profile.DriveProfile`) into a
:class:`Plan`: which drive TPDOs carry which objects (first fit in the order of
:data:`TPDO_ITEMS`, at most 64 bits and the drive's number of mapping entries per PDO),
the velocity mode (CiA 402 6060h), the scaling. Whatever is missing and needed raises
:class:`~bridge.errors.DriveSetupError` with one line naming the object and what to
configure instead -- before anything has been written to the drive.

The contract's drive (docs/canopen_layout.md, identity 1018h:01 = 0, :02 = 402h) gets the
contract's layout and scaling.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import TypeVar

from virtual_bus.contract import (
    TPDO_COMM_BASE,
    Cia301,
    Cia402,
    Cia406,
    DataType,
    pdo_comm_index,
    pdo_mapping_index,
    rpdo_cob_id,
    tpdo_cob_id,
)
from virtual_bus.formats.drive_profile import (
    OBJECT_TYPES,
    DriveProfile,
    LoadSource,
    ModeChoice,
    ObjectKey,
    format_key,
)

from .errors import DriveSetupError
from .layout import CycleLayout, MappedObject, RxFrame, Signal, struct_code
from .scaling import MOTOR_INCREMENTS_PER_REV, Scaling

log = logging.getLogger("bridge")
_T = TypeVar("_T")

#: 1018h:01/:02 of the contract's (simulated) drive: its scaling is the contract's.
CONTRACT_IDENTITY = (0x0000_0000, 0x0000_0402)
#: 6502h bits (CiA 402): profile velocity, cyclic synchronous velocity.
PV_BIT = 1 << 2
CSV_BIT = 1 << 8
#: CiA 406 encoder: position value (UNSIGNED32, steps; decoded as two's complement).
ENCODER_POSITION: ObjectKey = (Cia406.POSITION_VALUE, 0)


class VelocityMode(IntEnum):
    """6060h values the bridge runs a drive in."""

    PROFILE_VELOCITY = 3
    CYCLIC_SYNCHRONOUS_VELOCITY = 9


@dataclass(frozen=True)
class PdoFacts:
    """One PDO of the drive: number, COB-ID (1800h+n-1:01 / 1400h+n-1:01), transmission
    type, how many mapping entries the mapping record has."""

    number: int
    cob_id: int
    transmission_type: int | None
    entries: int


@dataclass(frozen=True)
class DriveFacts:
    """What the start-up read from the drive. ``objects``: candidate objects present, with
    their raw value where readable (b"" when present but without a value)."""

    device_type: int | None
    vendor_id: int | None
    product_code: int | None
    supported_modes: int | None
    objects: dict[ObjectKey, bytes] = field(default_factory=dict)
    tpdos: tuple[PdoFacts, ...] = ()
    rpdos: tuple[PdoFacts, ...] = ()

    def has(self, key: ObjectKey) -> bool:
        return key in self.objects

    def u32(self, key: ObjectKey) -> int | None:
        raw = self.objects.get(key)
        return int.from_bytes(raw[:4], "little") if raw and len(raw) >= 4 else None

    def ratio(self, index: int) -> tuple[int, int] | None:
        """Sub 1 / sub 2 of a factor object (608Fh, 6091h, 6092h, 6093h, ...) if both read."""
        num, den = self.u32((index, 1)), self.u32((index, 2))
        return None if num is None or den is None or den == 0 else (num, den)

    @property
    def contract_drive(self) -> bool:
        return (self.vendor_id, self.product_code) == CONTRACT_IDENTITY


#: CiA 301 data type of an integer object by (bits, signed).
_DATA_TYPES = {
    (8, False): DataType.UNSIGNED8,
    (8, True): DataType.INTEGER8,
    (16, False): DataType.UNSIGNED16,
    (16, True): DataType.INTEGER16,
    (32, False): DataType.UNSIGNED32,
    (32, True): DataType.INTEGER32,
}


@dataclass(frozen=True)
class Item:
    """An object to map in a drive TPDO and the signal it carries."""

    signal: Signal
    key: ObjectKey
    type_name: str  # OBJECT_TYPES key

    @property
    def bits(self) -> int:
        return OBJECT_TYPES[self.type_name][0]

    @property
    def code(self) -> str:
        return struct_code(*OBJECT_TYPES[self.type_name])

    @property
    def data_type(self) -> DataType:
        """The CiA 301 data type of the object (for the mapping entry)."""
        bits, signed = OBJECT_TYPES[self.type_name]
        return _DATA_TYPES[(bits, signed)]


@dataclass(frozen=True)
class PdoPlan:
    number: int
    cob_id: int
    transmit: bool
    transmission_type: int
    items: tuple[Item, ...]

    @property
    def mapping(self) -> tuple[MappedObject, ...]:
        return tuple(MappedObject(i.key[0], i.key[1], i.data_type) for i in self.items)

    @property
    def comm_index(self) -> int:
        return pdo_comm_index(self.transmit, self.number)

    @property
    def mapping_index(self) -> int:
        return pdo_mapping_index(self.transmit, self.number)

    @property
    def name(self) -> str:
        return f"{'TPDO' if self.transmit else 'RPDO'}{self.number}"


@dataclass(frozen=True)
class Plan:
    """The start-up's decisions: PDOs to write, mode, scaling, load source, layout."""

    tpdos: tuple[PdoPlan, ...]
    rpdo: PdoPlan
    mode: VelocityMode
    scaling: Scaling
    load_source: LoadSource
    encoder_id: int | None
    rated_torque_mnm: int | None
    layout: CycleLayout
    notes: tuple[str, ...]


def _fail(message: str, key: ObjectKey | None = None) -> DriveSetupError:
    return DriveSetupError(
        message, index=None if key is None else key[0], subindex=None if key is None else key[1]
    )


# --- mode ----------------------------------------------------------------------------------------
def choose_mode(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> VelocityMode:
    """CSV when 6502h lists it (or the profile asks for it), else profile velocity."""
    modes = facts.supported_modes
    where = f"drive {drive_id}"
    if profile.mode is ModeChoice.CSV:
        if modes is not None and not modes & CSV_BIT:
            raise _fail(
                f"{where}: 6502h = 0x{modes:08X} does not list cyclic synchronous velocity "
                '(bit 8); set mode.mode = "pv" (profile velocity) in the drive profile',
                (Cia402.SUPPORTED_DRIVE_MODES, 0),
            )
        return VelocityMode.CYCLIC_SYNCHRONOUS_VELOCITY
    if profile.mode is ModeChoice.PV:
        if modes is not None and not modes & PV_BIT:
            raise _fail(
                f"{where}: 6502h = 0x{modes:08X} does not list profile velocity (bit 2)",
                (Cia402.SUPPORTED_DRIVE_MODES, 0),
            )
        return VelocityMode.PROFILE_VELOCITY
    if modes is None:
        raise _fail(
            f'{where}: 6502h supported drive modes not readable; set mode.mode = "csv" or '
            '"pv" in the drive profile',
            (Cia402.SUPPORTED_DRIVE_MODES, 0),
        )
    if modes & CSV_BIT:
        return VelocityMode.CYCLIC_SYNCHRONOUS_VELOCITY
    if modes & PV_BIT:
        return VelocityMode.PROFILE_VELOCITY
    raise _fail(
        f"{where}: 6502h = 0x{modes:08X} lists neither cyclic synchronous velocity (bit 8) nor "
        "profile velocity (bit 2): the bridge needs one of them",
        (Cia402.SUPPORTED_DRIVE_MODES, 0),
    )


# --- load position -------------------------------------------------------------------------------
def load_item(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> Item | None:
    """The drive object carrying the load position (None: encoder node or motor feedback)."""
    source = profile.load_source
    sub1, var = (
        (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 1),
        (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0),
    )
    is_var = len(facts.objects.get(var, b"")) == 4  # sub 0 of an array is one byte
    if source is LoadSource.AUTO:
        if facts.has(sub1) and not is_var and profile.may_map(sub1):
            return Item(Signal.LOAD_POSITION, sub1, "i32")
        if is_var and profile.may_map(var):
            return Item(Signal.LOAD_POSITION, var, "i32")
        return None
    if source is LoadSource.ADDITIONAL_SUB1:
        if not facts.has(sub1) or is_var:
            raise _fail(
                f'drive {drive_id}: load.source = "60E4h:01" but the drive has no 60E4h:01 '
                '(try "60E4h:00", "vendor" with load.object, "encoder" or "motor")',
                sub1,
            )
        item = Item(Signal.LOAD_POSITION, sub1, "i32")
    elif source is LoadSource.ADDITIONAL_VAR:
        if not is_var:
            raise _fail(
                f'drive {drive_id}: load.source = "60E4h:00" but 60E4h is not a plain '
                'INTEGER32 variable there (try "60E4h:01", "vendor", "encoder" or "motor")',
                var,
            )
        item = Item(Signal.LOAD_POSITION, var, "i32")
    elif source is LoadSource.VENDOR:
        key = profile.load_object
        assert key is not None
        if not facts.has(key):
            raise _fail(
                f"drive {drive_id}: load.object {format_key(key)} does not exist on the drive",
                key,
            )
        item = Item(Signal.LOAD_POSITION, key, profile.load_object_type)
    else:
        return None
    if not profile.may_map(item.key):
        raise _fail(
            f"drive {drive_id}: load position {format_key(item.key)} cannot be mapped into a "
            'TPDO (not PDO-mappable); choose another load.source ("encoder", "motor", ...)',
            item.key,
        )
    return item


# --- PDO packing ---------------------------------------------------------------------------------
def tpdo_items(facts: DriveFacts, profile: DriveProfile, load: Item | None) -> list[Item]:
    """Objects to map, in packing order; optional ones the drive lacks are left out."""
    items = [Item(Signal.MOTOR_POSITION, (Cia402.POSITION_ACTUAL_VALUE, 0), "i32")]
    if load is not None:
        items.append(load)
    items.append(Item(Signal.STATUSWORD, (Cia402.STATUSWORD, 0), "u16"))
    for signal, key, type_name in (
        (Signal.TORQUE, (Cia402.TORQUE_ACTUAL_VALUE, 0), "i16"),
        (Signal.MOTOR_VELOCITY, (Cia402.VELOCITY_ACTUAL_VALUE, 0), "i32"),
    ):
        if facts.has(key) and profile.may_map(key):
            items.append(Item(signal, key, type_name))
    return items


def pack(
    items: list[Item], pdos: list[PdoFacts], profile: DriveProfile, drive_id: int
) -> list[tuple[PdoFacts, list[Item]]]:
    """First fit of ``items`` into ``pdos`` (64 bits and the mapping entries of each)."""
    bins: list[tuple[PdoFacts, list[Item]]] = [(p, []) for p in pdos]
    for item in items:
        for pdo, content in bins:
            room = min(pdo.entries, profile.max_entries)
            if len(content) < room and sum(i.bits for i in content) + item.bits <= 64:
                content.append(item)
                break
        else:
            if item.signal in (Signal.MOTOR_POSITION, Signal.STATUSWORD, Signal.LOAD_POSITION):
                raise _fail(
                    f"drive {drive_id}: {format_key(item.key)} ({item.signal.name.lower()}) "
                    f"does not fit into TPDOs {[p.number for p in pdos]} (64 bits, "
                    f"{profile.max_entries} entries each); give more in pdo.tpdos",
                    item.key,
                )
            log.warning(
                "drive %d: no TPDO room for %s (%s): left out",
                drive_id,
                format_key(item.key),
                item.signal.name.lower(),
            )
    return [(p, c) for p, c in bins if c]


def _usable_pdos(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> list[PdoFacts]:
    have = {p.number: p for p in facts.tpdos}
    usable = [have[n] for n in profile.tpdos if n in have and have[n].entries > 0]
    if not usable:
        raise _fail(
            f"drive {drive_id}: none of the TPDOs {list(profile.tpdos)} exists (1800h+n-1); "
            "set pdo.tpdos in the drive profile",
            (TPDO_COMM_BASE, 1),
        )
    return usable


# --- scaling -------------------------------------------------------------------------------------
#: Fewest 6064h units per motor revolution the bridge accepts (1.4° per increment): the motor
#: position feeds the encoder-discrepancy check (2009h) and, without a load scale, the position
#: loop itself; a drive whose factor group defaults to 1 unit per revolution (6092h/6091h =
#: 1/1) would pass the loop a position 314 mm coarse on the paper's axis.
MIN_POSITION_UNITS_PER_REV = 256


def _position_source(facts: DriveFacts, profile: DriveProfile) -> tuple[float, str] | None:
    """6064h units per motor revolution and where the value came from (None: unknown)."""
    if profile.position_increments_per_rev is not None:
        return float(profile.position_increments_per_rev), "scaling.position_increments_per_rev"
    feed, gear = facts.ratio(Cia402.FEED_CONSTANT), facts.ratio(Cia402.GEAR_RATIO)
    if feed is not None:
        # CiA 402 factor group: position unit = feed / (feed constant) per driving shaft rev
        g_motor, g_shaft = gear or (1, 1)
        where = f"6092h feed constant {feed[0]}/{feed[1]}" + (
            f" x 6091h gear ratio {g_motor}:{g_shaft}" if gear is not None else ""
        )
        return feed[0] / feed[1] * g_shaft / g_motor, where
    resolution = facts.ratio(Cia402.POSITION_ENCODER_RESOLUTION)
    if resolution is not None:
        return resolution[0] / resolution[1], (
            f"608Fh position encoder resolution {resolution[0]}/{resolution[1]}"
        )
    return None


def position_units_per_rev(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> float:
    """6064h units per motor revolution: profile, else 6092h/6091h (user units), else 608Fh
    (increments), else the contract's 2^20 for the contract's drive. Fewer than
    :data:`MIN_POSITION_UNITS_PER_REV` is refused with where the number came from."""
    found = _position_source(facts, profile)
    if found is not None:
        value, where = found
        if value < MIN_POSITION_UNITS_PER_REV:
            key = (
                (Cia402.POSITION_ENCODER_RESOLUTION, 1)
                if where.startswith("608F")
                else (Cia402.FEED_CONSTANT, 1)
            )
            raise _fail(
                f"drive {drive_id}: 6064h would count {value:g} units per motor revolution "
                f"({where}): too coarse for the position loop and the discrepancy check "
                f"(at least {MIN_POSITION_UNITS_PER_REV}); set "
                "scaling.position_increments_per_rev in the drive profile (or the drive's "
                "6092h/6091h)",
                key,
            )
        return value
    factor = facts.ratio(Cia402.POSITION_FACTOR)
    if factor is not None and factor != (1, 1):
        raise _fail(
            f"drive {drive_id}: 6093h position factor {factor[0]}/{factor[1]} and no 608Fh: "
            "set scaling.position_increments_per_rev in the drive profile",
            (Cia402.POSITION_FACTOR, 1),
        )
    if facts.contract_drive:
        return float(MOTOR_INCREMENTS_PER_REV)
    raise _fail(
        f"drive {drive_id}: 608Fh position encoder resolution not readable (and no 6092h feed "
        "constant): set scaling.position_increments_per_rev (6064h units per motor "
        "revolution) in the drive profile",
        (Cia402.POSITION_ENCODER_RESOLUTION, 1),
    )


def velocity_units_per_rev_s(
    facts: DriveFacts, profile: DriveProfile, position_per_rev: float, drive_id: int
) -> float:
    """606Ch/60FFh units per motor rev/s: profile, else position units per s unless a
    velocity factor (6094h, 6095h, 6096h) other than 1 says otherwise."""
    if profile.velocity_units_per_rev_s is not None:
        return float(profile.velocity_units_per_rev_s)
    for index in (Cia402.VELOCITY_ENCODER_FACTOR, Cia402.VELOCITY_FACTOR_1, Cia402.VELOCITY_FACTOR):
        present = facts.has((index, 1)) or facts.has((index, 0))
        if present and facts.ratio(index) != (1, 1):
            ratio = facts.ratio(index)
            shown = "not readable" if ratio is None else f"{ratio[0]}/{ratio[1]}"
            raise _fail(
                f"drive {drive_id}: velocity factor {index:04X}h is {shown}: set "
                "scaling.velocity_units_per_rev_s (60FFh units per motor rev/s) in the drive "
                "profile",
                (index, 1),
            )
    return position_per_rev


def rated_torque(facts: DriveFacts, profile: DriveProfile) -> int | None:
    """6076h in mN·m, None when 0 or absent (torque then in per mille)."""
    value = profile.rated_torque_mnm
    if value is None:
        value = facts.u32((Cia402.MOTOR_RATED_TORQUE, 0))
    return value or None


# --- the plan ------------------------------------------------------------------------------------
def combined_error(problems: list[DriveSetupError], drive_id: int) -> DriveSetupError:
    """One error for every problem the plan found (a single one unchanged): the message
    lists each (object, what was found, what to set), the error names the first object."""
    if len(problems) == 1:
        return problems[0]
    prefix = f"drive {drive_id}: "
    parts = [f"({i}) {str(p).removeprefix(prefix)}" for i, p in enumerate(problems, start=1)]
    first = problems[0]
    return DriveSetupError(
        f"{prefix}{len(problems)} problems, all found before anything was written: "
        + "; ".join(parts),
        index=first.index,
        subindex=first.subindex,
        problems=tuple(problems),
    )


def _required_objects(
    facts: DriveFacts, profile: DriveProfile, drive_id: int
) -> list[DriveSetupError]:
    found = []
    core = (
        (Cia402.CONTROLWORD, 0),
        (Cia402.STATUSWORD, 0),
        (Cia402.POSITION_ACTUAL_VALUE, 0),
        (Cia402.TARGET_VELOCITY, 0),
        (Cia402.MODES_OF_OPERATION, 0),
    )
    if not any(facts.has(key) for key in core):  # not a drive at all: nothing else matters
        shown = "not readable" if facts.device_type is None else f"0x{facts.device_type:08X}"
        raise _fail(
            f"drive {drive_id}: {format_key(core[0])} missing: not a CiA 402 drive (1000h "
            f"device type {shown}; "
            + ", ".join(format_key(key) for key in core[1:])
            + " missing too)",
            core[0],
        )
    for key in core:
        if not facts.has(key):
            found.append(
                _fail(f"drive {drive_id}: {format_key(key)} missing: not a CiA 402 drive", key)
            )
    for key, what in (
        ((Cia402.POSITION_ACTUAL_VALUE, 0), "position actual value, in a TPDO every SYNC"),
        ((Cia402.STATUSWORD, 0), "statusword, in a TPDO every SYNC"),
        ((Cia402.CONTROLWORD, 0), "controlword, in the RPDO"),
        ((Cia402.TARGET_VELOCITY, 0), "target velocity, in the RPDO"),
    ):
        if facts.has(key) and not profile.may_map(key):
            found.append(
                _fail(
                    f"drive {drive_id}: {format_key(key)} is not PDO-mappable ({what}): the "
                    "bridge cannot run this drive (no profile key replaces it)",
                    key,
                )
            )
    return found


def _identity(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> None:
    for name, want, got in (
        ("1018h:01 vendor-ID", profile.vendor_id, facts.vendor_id),
        ("1018h:02 product code", profile.product_code, facts.product_code),
    ):
        if want is not None and got is not None and want != got:
            raise _fail(
                f"drive {drive_id}: {name} is 0x{got:08X}, the drive profile "
                f"'{profile.name}' is for 0x{want:08X}: wrong profile or wrong node-ID",
                (Cia301.IDENTITY, 1 if "vendor" in name else 2),
            )


def _rpdo(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> PdoPlan:
    rpdo_numbers = {p.number for p in facts.rpdos}
    if profile.rpdo not in rpdo_numbers:
        raise _fail(
            f"drive {drive_id}: RPDO{profile.rpdo} does not exist "
            f"({pdo_comm_index(False, profile.rpdo):04X}h); set pdo.rpdo in the drive profile",
            (pdo_comm_index(False, profile.rpdo), 1),
        )
    rpdo_cob = profile.rpdo_cob_id or rpdo_cob_id(profile.rpdo, drive_id)
    return PdoPlan(
        profile.rpdo,
        rpdo_cob,
        False,
        255,
        (
            Item(Signal.STATUSWORD, (Cia402.CONTROLWORD, 0), "u16"),
            Item(Signal.STATUSWORD, (Cia402.TARGET_VELOCITY, 0), "i32"),
        ),
    )


def plan(
    facts: DriveFacts,
    profile: DriveProfile,
    drive_id: int,
    contract_load_increments: float,
) -> Plan:
    """Layout, mode and scaling for this drive (module docstring). Every check runs, so a
    drive that lacks several things is refused once, naming all of them
    (:func:`combined_error`), not once per round of commissioning."""
    problems: list[DriveSetupError] = []

    def attempt(check: Callable[..., _T], *args: object) -> _T | None:
        try:
            return check(*args)
        except DriveSetupError as exc:
            problems.append(exc)
            return None

    notes: list[str] = []
    attempt(_identity, facts, profile, drive_id)
    problems += _required_objects(facts, profile, drive_id)
    mode = attempt(choose_mode, facts, profile, drive_id)
    load_failed = len(problems)
    load = attempt(load_item, facts, profile, drive_id)
    load_failed = len(problems) > load_failed
    source = profile.load_source
    if source is LoadSource.AUTO:
        source = (
            LoadSource.MOTOR
            if load is None
            else (LoadSource.ADDITIONAL_SUB1 if load.key[1] else LoadSource.ADDITIONAL_VAR)
        )
    tt = profile.transmission_type
    cob_of = dict(zip(profile.tpdos, profile.tpdo_cob_ids or (), strict=False))
    tpdo_plans: tuple[PdoPlan, ...] = ()
    pdos = attempt(_usable_pdos, facts, profile, drive_id)
    if (
        pdos is not None
        and facts.has((Cia402.POSITION_ACTUAL_VALUE, 0))
        and facts.has((Cia402.STATUSWORD, 0))
    ):
        packed = attempt(pack, tpdo_items(facts, profile, load), pdos, profile, drive_id)
        tpdo_plans = tuple(
            PdoPlan(
                p.number,
                cob_of.get(p.number, tpdo_cob_id(p.number, drive_id)),
                True,
                tt,
                tuple(items),
            )
            for p, items in packed or ()
        )
    rpdo = attempt(_rpdo, facts, profile, drive_id)
    position = attempt(position_units_per_rev, facts, profile, drive_id)
    velocity = None
    if position is not None:
        velocity = attempt(velocity_units_per_rev_s, facts, profile, position, drive_id)
    else:  # a velocity factor is a problem of its own, whatever the position scale
        attempt(velocity_units_per_rev_s, facts, profile, 1.0, drive_id)
    torque_mnm = rated_torque(facts, profile)
    if torque_mnm is None:
        notes.append(
            "6076h motor rated torque is 0 or absent: torque shown in per mille of the rated torque"
        )
    load_inc: float = contract_load_increments
    if source in (LoadSource.ADDITIONAL_SUB1, LoadSource.ADDITIONAL_VAR):
        load_inc = profile.load_increments_per_unit or contract_load_increments
    elif source is LoadSource.MOTOR:
        notes.append(
            "position_feedback = motor: no load measuring system, the position loop closes "
            "on the motor encoder and the backlash regulator has nothing to do"
        )
    elif profile.load_increments_per_unit is None:
        if not load_failed:
            what = "load.object" if source is LoadSource.VENDOR else "encoder 6004h"
            problems.append(
                _fail(
                    f"drive {drive_id}: the scale of {what} is unknown: set "
                    "load.increments_per_unit (increments per m or rad) in the drive profile"
                )
            )
    else:
        load_inc = profile.load_increments_per_unit
    if problems:
        raise combined_error(problems, drive_id)
    assert mode is not None and rpdo is not None and position is not None
    assert velocity is not None
    scaling = Scaling(
        load_inc, None if torque_mnm is None else torque_mnm / 1000.0, position, velocity
    )
    frames = [
        RxFrame(
            f"TPDO{p.number}",
            p.cob_id,
            "<" + "".join(i.code for i in p.items),
            tuple(i.signal for i in p.items),
        )
        for p in tpdo_plans
    ]
    encoder_id = profile.encoder_id if source is LoadSource.ENCODER else None
    if encoder_id is not None:
        frames.append(
            RxFrame(
                f"encoder {encoder_id} TPDO1",
                tpdo_cob_id(1, encoder_id),
                "<i",
                (Signal.LOAD_POSITION,),
            )
        )
    layout = CycleLayout(tuple(frames), rpdo.cob_id, "<Hi")
    if mode is VelocityMode.PROFILE_VELOCITY:
        notes.append(
            "profile velocity (6060h = 3): 6502h lists no cyclic synchronous velocity; "
            "set points act on reception, ramps opened (docs/commissioning.md, limits)"
        )
    return Plan(
        tpdo_plans, rpdo, mode, scaling, source, encoder_id, torque_mnm, layout, tuple(notes)
    )


#: Objects the start-up reads (existence and value) besides the PDO parameters.
CANDIDATES: tuple[ObjectKey, ...] = (
    (Cia402.CONTROLWORD, 0),
    (Cia402.STATUSWORD, 0),
    (Cia402.MODES_OF_OPERATION, 0),
    (Cia402.MODES_OF_OPERATION_DISPLAY, 0),
    (Cia402.POSITION_ACTUAL_VALUE, 0),
    (Cia402.VELOCITY_ACTUAL_VALUE, 0),
    (Cia402.MOTOR_RATED_TORQUE, 0),
    (Cia402.TORQUE_ACTUAL_VALUE, 0),
    (Cia402.PROFILE_ACCELERATION, 0),
    (Cia402.PROFILE_DECELERATION, 0),
    (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0),
    (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 1),
    (Cia402.TARGET_VELOCITY, 0),
    (Cia402.POSITION_ENCODER_RESOLUTION, 1),
    (Cia402.POSITION_ENCODER_RESOLUTION, 2),
    (Cia402.GEAR_RATIO, 1),
    (Cia402.GEAR_RATIO, 2),
    (Cia402.FEED_CONSTANT, 1),
    (Cia402.FEED_CONSTANT, 2),
    (Cia402.POSITION_FACTOR, 1),
    (Cia402.POSITION_FACTOR, 2),
    (Cia402.VELOCITY_ENCODER_FACTOR, 1),
    (Cia402.VELOCITY_ENCODER_FACTOR, 2),
    (Cia402.VELOCITY_FACTOR_1, 1),
    (Cia402.VELOCITY_FACTOR_1, 2),
    (Cia402.VELOCITY_FACTOR, 1),
    (Cia402.VELOCITY_FACTOR, 2),
)

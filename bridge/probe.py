"""``python -m bridge probe``: read a connected drive over SDO, print what it supports and
(``--out``) write a drive profile for ``bridge run --drive-profile``.

Reads only (the drive is put into NMT pre-operational; nothing is written): 1000h, 1018h,
6502h, the PDO parameters and the objects of :data:`bridge.adapt.CANDIDATES`. SDO cannot
tell whether an object is PDO-mappable; ``--eds`` takes that from the drive's EDS (its
``PDOMapping`` flags), otherwise the profile leaves ``mappable`` out and the start-up finds
out by trying. Then the start-up's plan for the profile is printed, or the one line that
says what is missing and what to configure (exit 0 either way: the profile is written for
the user to complete). Exit 1 when the drive does not answer, 2 for bad arguments.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable

from virtual_bus import BusConfig, open_bus
from virtual_bus.contract import NmtCommand
from virtual_bus.formats.axis import AxisKind

from .adapt import (
    CANDIDATES,
    CSV_BIT,
    PV_BIT,
    DriveFacts,
    plan,
    position_units_per_rev,
)
from .errors import BridgeConfigError, DriveSetupError
from .layout import check_node_id
from .master import DriveMaster, DriveSetup
from .node import pumping
from .profile import DriveProfile, LoadSource, ModeChoice, ObjectKey, format_key, render_profile
from .scaling import LOAD_INCREMENTS_PER_UNIT

NAME = "probe"
HELP = "read a connected drive over SDO: what it supports; --out writes a drive profile"

#: CiA 402 modes (6502h bit -> name), for the printout.
MODE_BITS = {
    0: "profile position",
    1: "velocity",
    2: "profile velocity",
    3: "profile torque",
    5: "homing",
    6: "interpolated position",
    7: "cyclic synchronous position",
    8: "cyclic synchronous velocity",
    9: "cyclic synchronous torque",
}
#: Fields a probe cannot know: the commissioning engineer adds them to the written profile.
COMMISSIONING_FIELDS = (
    "name",
    "load_source",
    "load_object",
    "load_object_type",
    "encoder_id",
    "load_increments_per_unit",
    "position_increments_per_rev",
    "velocity_units_per_rev_s",
    "ramp",
)


def mappable_from_eds(path: Path, node_id: int) -> frozenset[ObjectKey]:
    """The bridge's candidate objects and the drive's manufacturer INTEGER32/UNSIGNED32
    objects (candidates for a vendor load position) that the EDS marks PDO-mappable."""
    try:
        od = canopen.import_od(str(path), node_id)
    except Exception as exc:  # the EDS parser raises many kinds
        raise BridgeConfigError(f"{path}: cannot import EDS ({exc})") from None
    wanted = set(CANDIDATES)
    found: set[ObjectKey] = set()
    for index in od:
        obj = od[index]
        variables = [obj] if isinstance(obj, ODVariable) else [obj[s] for s in obj]
        for var in variables:
            key = (var.index, var.subindex)
            vendor = 0x2000 <= var.index <= 0x5FFF and len(var) == 32
            if var.pdo_mappable and (key in wanted or vendor):
                found.add(key)
    return frozenset(found)


def profile_from_facts(
    facts: DriveFacts, name: str, mappable: frozenset[ObjectKey] | None
) -> DriveProfile:
    """The profile a probe can write: identity, mode, PDOs, mappable objects, the scaling
    the drive's objects give, the load position if 60E4h has it (else motor)."""
    modes = facts.supported_modes or 0
    mode = ModeChoice.CSV if modes & CSV_BIT else ModeChoice.PV if modes & PV_BIT else None
    var = len(facts.objects.get((0x60E4, 0), b"")) == 4
    if facts.has((0x60E4, 1)) and not var:
        source = LoadSource.ADDITIONAL_SUB1
    elif var:
        source = LoadSource.ADDITIONAL_VAR
    else:
        source = LoadSource.MOTOR
    try:
        position: float | None = position_units_per_rev(facts, DriveProfile(), 0)
    except DriveSetupError:
        position = None
    entries = [p.entries for p in facts.tpdos if p.entries]
    rpdos = [p.number for p in facts.rpdos]
    rated = None if facts.u32((0x6076, 0)) else 0
    return DriveProfile(
        name=name,
        vendor_id=facts.vendor_id,
        product_code=facts.product_code,
        mode=mode or ModeChoice.AUTO,
        tpdos=tuple(p.number for p in facts.tpdos if p.entries) or (1,),
        rpdo=rpdos[0] if rpdos else 1,
        max_entries=min(entries) if entries else 8,
        mappable=mappable,
        load_source=source,
        position_increments_per_rev=position,
        rated_torque_mnm=rated,
    )


def describe(facts: DriveFacts) -> str:
    """What the drive reported, as ``bridge probe`` prints it."""

    def hex_or(value: int | None) -> str:
        return "not readable" if value is None else f"0x{value:08X}"

    modes = facts.supported_modes
    lines = [
        f"1000h device type     {hex_or(facts.device_type)}"
        + (f" (profile {facts.device_type & 0xFFFF})" if facts.device_type is not None else ""),
        f"1018h vendor-ID       {hex_or(facts.vendor_id)}",
        f"1018h product code    {hex_or(facts.product_code)}",
        f"6502h drive modes     {hex_or(modes)}: "
        + (
            ", ".join(name for bit, name in MODE_BITS.items() if modes & (1 << bit)) or "none"
            if modes is not None
            else "-"
        ),
    ]
    for pdo in facts.tpdos:
        lines.append(
            f"TPDO{pdo.number}  COB-ID 0x{pdo.cob_id:08X}  transmission type "
            f"{pdo.transmission_type}  mapping entries {pdo.entries}"
        )
    for pdo in facts.rpdos:
        lines.append(
            f"RPDO{pdo.number}  COB-ID 0x{pdo.cob_id:08X}  transmission type "
            f"{pdo.transmission_type}  mapping entries {pdo.entries}"
        )
    present = ", ".join(format_key(k) for k in sorted(facts.objects))
    lines.append(f"objects present: {present}")
    for index, name in ((0x608F, "position encoder resolution"), (0x6091, "gear ratio")):
        ratio = facts.ratio(index)
        if ratio is not None:
            lines.append(f"{index:04X}h {name}: {ratio[0]} / {ratio[1]}")
    rated = facts.u32((0x6076, 0))
    lines.append(
        "6076h motor rated torque: "
        + (f"{rated} mN·m" if rated else "0 or absent (torque shown in per mille)")
    )
    return "\n".join(lines)


def probe_drive(bus: can.BusABC, drive_id: int, setup: DriveSetup | None = None) -> DriveFacts:
    """Read the drive ``drive_id`` on ``bus`` (NMT pre-operational, then reads only)."""
    network = canopen.Network(bus)
    drive = canopen.RemoteNode(drive_id, canopen.ObjectDictionary())
    network.add_node(drive)
    master = DriveMaster(drive, setup or DriveSetup())

    def handle(msg: can.Message) -> None:
        network.notify(msg.arbitration_id, msg.data, msg.timestamp)

    with pumping(bus.recv, handle, "bridge-probe"):
        drive.nmt.send_command(NmtCommand.ENTER_PRE_OPERATIONAL)
        return master.read_facts()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--interface", required=True, help="python-can interface, e.g. socketcan")
    parser.add_argument("--channel", required=True, help="CAN channel, e.g. can0")
    parser.add_argument("--bitrate", type=int, default=1_000_000, help="bit/s (default 1000000)")
    parser.add_argument("--drive-id", type=int, required=True, help="the drive's node-ID")
    parser.add_argument("--eds", type=Path, help="the drive's EDS: which objects are mappable")
    parser.add_argument("--name", help="profile name (default: from 1018h)")
    parser.add_argument("--out", type=Path, help="write the drive profile (TOML) here")


def run(args: argparse.Namespace) -> int:
    drive_id = check_node_id("--drive-id", args.drive_id)
    mappable = mappable_from_eds(args.eds, drive_id) if args.eds is not None else None
    bus = open_bus(BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate))
    try:
        facts = probe_drive(bus, drive_id)
    finally:
        bus.shutdown()
    return report(facts, drive_id, mappable, args.name, args.out)


def report(
    facts: DriveFacts,
    drive_id: int,
    mappable: frozenset[ObjectKey] | None,
    name: str | None,
    out: Path | None,
) -> int:
    """Print what was found and the start-up's plan; write the profile to ``out``."""
    name = name or f"vendor 0x{facts.vendor_id or 0:08X} product 0x{facts.product_code or 0:08X}"
    profile = profile_from_facts(facts, name, mappable)
    print(describe(facts))
    try:
        the_plan = plan(facts, profile, drive_id, LOAD_INCREMENTS_PER_UNIT[AxisKind.LINEAR])
    except DriveSetupError as exc:
        print(f"start-up would stop: {exc}")
    else:
        print(f"start-up plan: 6060h = {int(the_plan.mode)} ({the_plan.mode.name})")
        print(the_plan.layout.describe())
        for note in the_plan.notes:
            print(f"note: {note}")
    if out is not None:
        comments = (
            f"Drive profile written by `python -m bridge probe` (drive node {drive_id}).",
            "Keys and units: docs/commissioning.md. Add what a probe cannot know:",
            "[load] source/object/increments_per_unit, [scaling] if not read from the drive.",
        )
        out.write_text(render_profile(profile, comments), encoding="utf-8")
        print(f"wrote {out}")
    return 0

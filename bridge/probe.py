"""``python -m bridge probe``: read a connected drive over SDO, print what it supports and
(``--out``) write a drive profile for ``bridge run --drive-profile``.

Reads only (the drive is put into NMT pre-operational; nothing is written): 1000h, 1018h,
6502h, the PDO parameters, the objects of :data:`bridge.adapt.CANDIDATES` and every 60E4h
sub-index the drive has. SDO cannot tell whether an object is PDO-mappable; ``--eds`` takes
that from the drive's EDS (its ``PDOMapping`` flags) and names the manufacturer objects that
could carry the load position (:mod:`bridge.candidates`); CiA 406 encoder nodes are found
among the nodes heard on the bus and ``--scan`` node-IDs.

Then it prints the load-scale candidates, how the drive can supervise the bridge (1016h
heartbeat consumer, 6007h abort connection option code, a set-point watchdog;
:mod:`bridge.supervision`) and what the start-up would write for it, the start-up's plan for
the profile it writes -- or **every** problem the start-up would stop on, each with its
object, what the drive showed and the profile key that replaces it (one round of
commissioning, not one per problem). The written profile is consistent with what the probe
found: its load source is the best usable candidate (never an object the EDS marks not
mappable). ``--dcf`` writes the drive's CiA 306 DCF carrying that supervision
(:mod:`bridge.commission.supervision_dcf`). ``--eds`` is checked before the bus is opened (a
file that is not an EDS: one line, exit 2). Exit 0 when the start-up would run the drive; 1
when it would stop (the
profile is written all the same, for the user to complete) or the drive does not answer;
2 for bad arguments.
"""

from __future__ import annotations

import argparse
import contextlib
from dataclasses import dataclass, replace
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable

from cmdline import cli
from virtual_bus import BusConfig, open_bus
from virtual_bus.atomic import write_atomic
from virtual_bus.contract import (
    ABORT_CONNECTION_INDEX,
    MANUFACTURER_AREA,
    TPDO_MAPPING_BASE,
    Cia301,
    Cia402,
    NmtCommand,
    pdo_comm_index,
    pdo_mapping_index,
)
from virtual_bus.formats.axis import AxisKind
from virtual_bus.formats.drive_profile import (
    DriveProfile,
    LoadSource,
    ModeChoice,
    ObjectKey,
    format_key,
    render_profile,
)
from virtual_bus.formats.eds import check_eds_file

from . import candidates as cand
from .adapt import (
    CANDIDATES,
    CSV_BIT,
    PV_BIT,
    DriveFacts,
    plan,
    position_units_per_rev,
)
from .commission.supervision_dcf import supervision_dcf
from .errors import BridgeConfigError, DriveSetupError
from .layout import check_node_id
from .master import DriveMaster, DriveSetup
from .node import pumping
from .od import DEFAULT_HEARTBEAT_MS, DEFAULT_NODE_ID
from .scaling import LOAD_INCREMENTS_PER_UNIT
from .supervision import Supervision, consumer_entries, plan_supervision

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
    "setpoint_timeout_object",
    "setpoint_timeout",
    "setpoint_timeout_type",
)


def import_eds(path: Path, node_id: int) -> canopen.ObjectDictionary:
    """The drive's EDS (EdsFileError when the file is not an EDS at all, BridgeConfigError
    when python canopen cannot import it; one line each)."""
    check_eds_file(path)
    try:
        return canopen.import_od(str(path), node_id)
    except Exception as exc:  # the EDS parser raises many kinds
        raise BridgeConfigError(f"{path}: cannot import EDS ({exc})") from None


def mappable_from_eds(path: Path, node_id: int) -> frozenset[ObjectKey]:
    """The bridge's candidate objects and the drive's manufacturer INTEGER32/UNSIGNED32
    objects (candidates for a vendor load position) that the EDS marks PDO-mappable."""
    od = import_eds(path, node_id)
    wanted = set(CANDIDATES) | {(Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, s) for s in range(0xFF)}
    found: set[ObjectKey] = set()
    for index in od:
        obj = od[index]
        variables = [obj] if isinstance(obj, ODVariable) else [obj[s] for s in obj]
        for var in variables:
            key = (var.index, var.subindex)
            vendor = var.index in MANUFACTURER_AREA and len(var) == 32
            if var.pdo_mappable and (key in wanted or vendor):
                found.add(key)
    return frozenset(found)


def profile_from_facts(
    facts: DriveFacts,
    name: str,
    mappable: frozenset[ObjectKey] | None,
    load: cand.LoadCandidate | None = None,
) -> DriveProfile:
    """The profile a probe can write: identity, mode, PDOs, mappable objects, the scaling
    the drive's objects give (left out when implausible: the plan says why), the load
    position from ``load`` (the best candidate, :func:`bridge.candidates.best`; without one:
    60E4h where the mappable list allows it, else motor)."""
    modes = facts.supported_modes or 0
    mode = ModeChoice.CSV if modes & CSV_BIT else ModeChoice.PV if modes & PV_BIT else None
    if load is None:
        found = cand.additional_position(facts, None)
        usable = [c for c in found if mappable is None or c.key in mappable]
        load = cand.best(usable)
    source, load_object, load_type, encoder_id = LoadSource.MOTOR, None, "i32", None
    if load is not None:
        source = load.source
        if load.source is LoadSource.VENDOR:
            load_object, load_type = load.key, load.type_name or "i32"
        encoder_id = load.encoder_id
    try:
        position: float | None = position_units_per_rev(facts, DriveProfile(), 0)
    except DriveSetupError:
        position = None
    entries = [p.entries for p in facts.tpdos if p.entries]
    rpdos = [p.number for p in facts.rpdos]
    rated = None if facts.u32((Cia402.MOTOR_RATED_TORQUE, 0)) else 0
    has_6007 = facts.has((ABORT_CONNECTION_INDEX, 0))
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
        load_object=load_object,
        load_object_type=load_type,
        encoder_id=encoder_id,
        position_increments_per_rev=position,
        rated_torque_mnm=rated,
        heartbeat_consumer_entries=consumer_entries(facts, DriveProfile()),
        abort_connection_option=3 if has_6007 else None,
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
    for index, name in (
        (Cia402.POSITION_ENCODER_RESOLUTION, "position encoder resolution"),
        (Cia402.GEAR_RATIO, "gear ratio"),
    ):
        ratio = facts.ratio(index)
        if ratio is not None:
            lines.append(f"{index:04X}h {name}: {ratio[0]} / {ratio[1]}")
    rated = facts.u32((Cia402.MOTOR_RATED_TORQUE, 0))
    lines.append(
        "6076h motor rated torque: "
        + (f"{rated} mN·m" if rated else "0 or absent (torque shown in per mille)")
    )
    return "\n".join(lines)


@dataclass(frozen=True)
class ProbeResult:
    """What a probe read: the drive's facts and the CiA 406 encoder nodes it found."""

    facts: DriveFacts
    encoder_nodes: tuple[int, ...] = ()


#: SDO timeout of a scan for encoder nodes (a node that is not there costs this, once).
SCAN_TIMEOUT_S = 0.05


def _more_60e4(master: DriveMaster, facts: DriveFacts) -> DriveFacts:
    """60E4h sub-indices 02h.. the drive has (an array's sub-index 0 counts them)."""
    sub0 = facts.objects.get((Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0))
    if sub0 is None or len(sub0) != 1 or sub0[0] < 2:
        return facts
    objects = dict(facts.objects)
    for sub in range(2, min(sub0[0], 8) + 1):
        raw = master.try_read(Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, sub)
        if raw is not None:
            objects[(Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, sub)] = raw
    return replace(facts, objects=objects)


def _is_encoder(network: canopen.Network, node_id: int, setup: DriveSetup) -> bool:
    """Node ``node_id`` answers 1000h with CiA 406 in its low word."""
    node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    network.add_node(node)
    try:
        master = DriveMaster(node, replace(setup, sdo_timeout_s=SCAN_TIMEOUT_S, sdo_retries=1))
        with contextlib.suppress(DriveSetupError):
            raw = master.try_read(Cia301.DEVICE_TYPE, 0)
            return raw is not None and len(raw) >= 2 and int.from_bytes(raw[:2], "little") == 406
        return False
    finally:
        del network[node_id]


def probe_drive(
    bus: can.BusABC,
    drive_id: int,
    setup: DriveSetup | None = None,
    scan: tuple[int, ...] = (),
    extra: tuple[ObjectKey, ...] = (),
) -> ProbeResult:
    """Read the drive ``drive_id`` on ``bus`` (NMT pre-operational, then reads only), and
    the objects ``extra`` (vendor load-scale candidates of its EDS: present or not); check
    the nodes heard on the bus (heartbeat, boot-up) and those of ``scan`` for CiA 406."""
    setup = setup or DriveSetup()
    network = canopen.Network(bus)
    drive = canopen.RemoteNode(drive_id, canopen.ObjectDictionary())
    network.add_node(drive)
    master = DriveMaster(drive, setup)
    heard: set[int] = set()

    def handle(msg: can.Message) -> None:
        if 0x701 <= msg.arbitration_id <= 0x77F and not msg.is_extended_id:
            heard.add(msg.arbitration_id - 0x700)
        network.notify(msg.arbitration_id, msg.data, msg.timestamp)

    with pumping(bus.recv, handle, "bridge-probe"):
        drive.nmt.send_command(NmtCommand.ENTER_PRE_OPERATIONAL)
        facts = _more_60e4(master, master.read_facts())
        if extra:
            objects = dict(facts.objects)
            for key in extra:
                raw = master.try_read(*key)
                if raw is not None:
                    objects[key] = raw
            facts = replace(facts, objects=objects)
        others = sorted((heard | set(scan)) - {drive_id})
        encoders = tuple(n for n in others if _is_encoder(network, n, setup))
    return ProbeResult(facts, encoders)


def _node_range(text: str) -> tuple[int, ...]:
    """``--scan 3-10`` / ``--scan 5`` / ``--scan 3,5,7`` -> node-IDs (1..127)."""
    ids: list[int] = []
    for part in text.split(","):
        low, dash, high = part.strip().partition("-")
        try:
            first = int(low)
            last = int(high) if dash else first
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: node-IDs like 5, 3-10 or 3,5,7") from None
        if not 1 <= first <= last <= 127:
            raise argparse.ArgumentTypeError(f"{text!r}: node-IDs 1..127, low-high")
        ids += range(first, last + 1)
    return tuple(sorted(set(ids)))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_can_bus(parser)
    parser.add_argument("--drive-id", type=cli.node_id, required=True, help="the drive's node-ID")
    parser.add_argument(
        "--eds",
        type=cli.existing_file,
        help="the drive's EDS: which objects are mappable, which vendor objects could carry "
        "the load position",
    )
    parser.add_argument(
        "--scan",
        type=_node_range,
        default=(),
        metavar="IDS",
        help="also look for CiA 406 encoder nodes at these node-IDs (5, 3-10, 3,5,7; "
        f"{SCAN_TIMEOUT_S:g} s each that does not answer); nodes heard on the bus are checked "
        "anyway",
    )
    parser.add_argument("--name", help="profile name (default: from 1018h)")
    parser.add_argument("--out", type=cli.new_file, help="write the drive profile (TOML) here")
    parser.add_argument(
        "--dcf",
        type=cli.new_file,
        metavar="FILE.dcf",
        help="write the drive's CiA 306 DCF carrying the supervision of the bridge the start-up "
        "plans (1016h, 6007h, set-point watchdog; needs --eds); load it with `bridge config "
        "load` to have the drive watch the bridge from power-on",
    )
    parser.add_argument(
        "--bridge-id",
        type=cli.node_id,
        default=DEFAULT_NODE_ID,
        help=f"the bridge's node-ID the drive is to watch (default {DEFAULT_NODE_ID})",
    )
    parser.add_argument(
        "--bridge-heartbeat",
        type=int,
        default=DEFAULT_HEARTBEAT_MS,
        metavar="MS",
        help=f"the bridge's heartbeat period, 1017h, in ms (default {DEFAULT_HEARTBEAT_MS})",
    )


def run(args: argparse.Namespace) -> int:
    drive_id = check_node_id("--drive-id", args.drive_id)
    if args.dcf is not None and args.eds is None:
        raise cli.UsageError("--dcf needs --eds: the DCF is the drive's EDS with its values")
    if not 1 <= args.bridge_heartbeat <= 0xFFFF:
        raise cli.UsageError(
            f"--bridge-heartbeat {args.bridge_heartbeat}: allowed 1..65535 ms (1017h, UNSIGNED16)"
        )
    od = import_eds(args.eds, drive_id) if args.eds is not None else None
    mappable = mappable_from_eds(args.eds, drive_id) if args.eds is not None else None
    bus = open_bus(BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate))
    extra = tuple(c.key for c in cand.vendor_objects(od) if c.key) if od is not None else ()
    try:
        result = probe_drive(bus, drive_id, scan=args.scan, extra=extra)
    finally:
        bus.shutdown()
    dcf = None if args.dcf is None else DcfRequest(args.dcf, args.eds, args.bitrate)
    bridge = (args.bridge_id, args.bridge_heartbeat)
    return report(result, drive_id, mappable, args.name, args.out, od, dcf=dcf, bridge=bridge)


@dataclass(frozen=True)
class DcfRequest:
    """``--dcf``: the file to write, the drive's EDS it is made from, the bus's bit/s."""

    path: Path
    eds: Path
    bitrate: int


def identity_name(facts: DriveFacts) -> str:
    """A profile name from 1018h, saying which part was not readable."""

    def shown(value: int | None) -> str:
        return "unreadable" if value is None else f"0x{value:08X}"

    return f"vendor {shown(facts.vendor_id)} product {shown(facts.product_code)}"


def load_candidates(
    result: ProbeResult, mappable: frozenset[ObjectKey] | None, od: canopen.ObjectDictionary | None
) -> list[cand.LoadCandidate]:
    """Every load-scale candidate the probe saw: 60E4h sub-indices, vendor objects of the
    EDS the drive answers, CiA 406 nodes."""
    facts = result.facts
    found = cand.additional_position(facts, od)
    if od is None and mappable is not None:
        found = [replace(c, mappable=c.key in mappable) for c in found]
    if od is not None:  # the ones the drive answered (an EDS may list more than it has)
        found += [c for c in cand.vendor_objects(od) if c.key in facts.objects]
    found += [cand.encoder_node(n) for n in result.encoder_nodes]
    return found


def static_mapping(
    od: canopen.ObjectDictionary, profile: DriveProfile, drive_id: int
) -> list[DriveSetupError]:
    """PDOs of the profile whose COB-ID or mapping the EDS marks read-only: the start-up
    could not configure them (a drive with a static mapping)."""
    found = []
    pdos = [(True, n) for n in profile.tpdos] + [(False, profile.rpdo)]
    usable_tpdo = False
    for transmit, number in pdos:
        comm, mapping = pdo_comm_index(transmit, number), pdo_mapping_index(transmit, number)
        fixed = []
        for index, sub in ((comm, 1), (mapping, 0), (mapping, 1)):
            obj = od.get(index)
            var = None if obj is None or isinstance(obj, ODVariable) else obj.get(sub)
            if var is not None and var.access_type in ("ro", "const"):
                fixed.append(f"{index:04X}h:{sub:02X}")
        if obj is None:
            continue
        name = f"{'TPDO' if transmit else 'RPDO'}{number}"
        if not fixed:
            usable_tpdo = usable_tpdo or transmit
            continue
        if not transmit:
            found.append(
                DriveSetupError(
                    f"drive {drive_id}: {name} cannot be configured, the EDS marks "
                    f"{', '.join(fixed)} read-only (a static mapping): set pdo.rpdo to an RPDO "
                    "the bridge may map (6040h + 60FFh)",
                    index=mapping,
                    subindex=0,
                )
            )
    if not usable_tpdo:
        found.append(
            DriveSetupError(
                f"drive {drive_id}: none of the TPDOs {list(profile.tpdos)} can be configured "
                "(the EDS marks their COB-ID or mapping read-only: a static mapping); the "
                "bridge needs TPDOs it can map",
                index=TPDO_MAPPING_BASE,
                subindex=0,
            )
        )
    return found


def describe_supervision(facts: DriveFacts, supervision: Supervision | None) -> list[str]:
    """How the drive can watch the bridge, and what the start-up would write for it."""
    entries = consumer_entries(facts, DriveProfile())
    abort = facts.objects.get((ABORT_CONNECTION_INDEX, 0))
    lines = [
        "supervision of the bridge (if the bridge dies, the drive stops by these):",
        "  1016h heartbeat consumer: "
        + (f"{entries} entr{'y' if entries == 1 else 'ies'}" if entries else "absent"),
        "  6007h abort connection option code: "
        + (
            f"present (now {int.from_bytes(abort[:2], 'little', signed=True)})"
            if abort
            else "absent"
        ),
    ]
    if supervision is not None:
        lines += [f"  the start-up writes {line}" for line in supervision.describe()]
        lines += [f"  note: {note}" for note in supervision.notes]
    return lines


def report(
    result: ProbeResult | DriveFacts,
    drive_id: int,
    mappable: frozenset[ObjectKey] | None,
    name: str | None,
    out: Path | None,
    od: canopen.ObjectDictionary | None = None,
    *,
    dcf: DcfRequest | None = None,
    bridge: tuple[int, int] = (DEFAULT_NODE_ID, DEFAULT_HEARTBEAT_MS),
) -> int:
    """Print what was found, the load-scale candidates, the drive's supervision of the bridge
    and the start-up's plan -- or every problem it would stop on; write the profile to
    ``out`` and the supervision DCF to ``dcf``; ``bridge``: the node-ID and heartbeat period
    (ms) of the bridge the drive is to watch. 0: the start-up would run the drive; 1: it
    would stop."""
    if isinstance(result, DriveFacts):
        result = ProbeResult(result)
    facts = result.facts
    found = load_candidates(result, mappable, od)
    chosen = cand.best(found)
    profile = profile_from_facts(facts, name or identity_name(facts), mappable, chosen)
    print(describe(facts))
    if found:
        print(f"load-scale candidates ({len(found)}):")
        for c in sorted(found, key=lambda c: (c.encoder_id is not None, c.key or (0, 0))):
            mark = "*" if c is chosen else " "
            print(f"  {mark} {c.describe()}")
    else:
        print(
            "load-scale candidates: none seen (no 60E4h"
            + ("" if od is not None else "; --eds names vendor objects")
            + "; --scan looks for CiA 406 encoder nodes)"
        )
    fixed = static_mapping(od, profile, drive_id) if od is not None else []
    problems: list[DriveSetupError] = []
    supervision = None
    try:  # the bridge's defaults: node-ID 1, heartbeat 100 ms (1017h)
        supervision = plan_supervision(facts, profile, drive_id, *bridge)
    except DriveSetupError as exc:
        problems.append(exc)
    for line in describe_supervision(facts, supervision):
        print(line)
    try:
        the_plan = plan(facts, profile, drive_id, LOAD_INCREMENTS_PER_UNIT[AxisKind.LINEAR])
        if fixed or problems:
            raise (fixed or problems)[0]
    except DriveSetupError as exc:
        problems = [*(exc.problems or (exc,)), *(p for p in [*fixed, *problems] if p is not exc)]
        print(f"start-up would stop: {len(problems)} problem(s), all of them:")
        for i, problem in enumerate(problems, start=1):
            print(f"  {i}. {problem}")
    else:
        print(f"start-up plan: 6060h = {int(the_plan.mode)} ({the_plan.mode.name})")
        print(the_plan.layout.describe())
        for note in the_plan.notes:
            print(f"note: {note}")
    if out is not None:
        comments = (
            f"Drive profile written by `python -m bridge probe` (drive node {drive_id}).",
            "Keys and units: docs/commissioning.md. Add what a probe cannot know:",
            "[load] increments_per_unit, [scaling] if not read from the drive.",
        )
        if chosen is not None:
            comments += (f"load source: the best candidate the probe saw, {chosen.describe()}",)
        write_atomic(out, render_profile(profile, comments))
        print(f"wrote {out}")
    if dcf is not None and supervision is None:
        print(f"{dcf.path} not written: the supervision plan stopped (above)")
    if dcf is not None and supervision is not None:
        assert od is not None, "--dcf needs --eds (checked by run)"
        text = supervision_dcf(
            dcf.eds,
            od,
            supervision,
            drive_id=drive_id,
            bitrate=dcf.bitrate,
            dcf_name=dcf.path.name,
            node_name=profile.name,
        )
        write_atomic(dcf.path, text)
        print(
            f"wrote {dcf.path}: the supervision of the bridge (node {bridge[0]}) on drive "
            f"{drive_id}: {', '.join(format_key(w.key) for w in supervision.writes)}"
        )
    return 1 if problems else 0

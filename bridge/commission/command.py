"""``python -m bridge config get|set|dump|load``: commissioning of any node over SDO.

Reads and writes any object of the bridge or the drive (or another node with ``--eds``) by
name or index, with the EDS's data types and units (:mod:`bridge.commission.access`); dumps
all readable objects to a CiA 306 DCF and loads a DCF back (:mod:`bridge.commission.dcf`).

EDS of the node: ``--eds FILE``, else the node is identified by 1000h (device type),
1018h:02 (product code) and 1008h (device name) against config/bridge.eds and config/drive.eds.
``dump`` leaves out 0001h-0FFFh (data type definitions) and keeps the EDS default where the
node answers 0800 0024 "no data available" (an empty 1003h entry).

``load`` writes only what differs from the node's values, in passes (a write refused because
of another object's value, such as a feed above the speed limit, is retried after the
others), and never leaves the node half-written: if any write stays refused, every object
already written gets its previous value back and the refusals are listed with their abort
codes. Not loaded: read-only objects, 1010h/1011h (commands), write-only objects (their old
value cannot be read back) and, unless ``--all``, process data (PDO-mappable objects or
``StorageLocation=RAM``: controlword, target velocity, the bridge's target position).
``--save`` then writes "save" to 1010h:01 (CiA 301) so the node keeps the values.

Exit status: 0 done; 1 the node refused or did not answer (nothing changed, or what could
not be undone is listed); 2 bad arguments or files (nothing sent).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary import datatypes as dt

from cmdline import cli
from virtual_bus import BusConfig, open_bus
from virtual_bus.atomic import write_atomic
from virtual_bus.contract import COMMUNICATION_AREA, Cia301, SdoAbort
from virtual_bus.formats.eds import check_eds_file
from virtual_bus.shipped import DRIVE_EDS

from .. import od as bridge_od
from ..errors import CommissionInputError, NodeAccessError
from .access import (
    SIGNATURES,
    SdoAccess,
    Value,
    abort_text,
    display,
    display_change,
    encode,
    key_text,
    parse_value,
    resolve,
    resolve_one,
    value_text,
    variables,
)
from .dcf import Commissioning, key_of, read_dcf, render_dcf

NAME = "config"
HELP = "read, write, dump (DCF) and load (DCF) any object of a node over SDO"
KNOWN_EDS = (bridge_od.DEFAULT_EDS_PATH, DRIVE_EDS)
READABLE = {"ro", "rw", "rwr", "rww", "const"}
WRITABLE = {"rw", "rwr", "rww", "wo"}
STORE_COMMANDS = {Cia301.STORE_PARAMETERS, Cia301.RESTORE_DEFAULT_PARAMETERS}


def _timeout(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.01 <= value <= 60.0:
        raise argparse.ArgumentTypeError(f"{text!r}: SDO timeout must be 0.01..60 s")
    return value


def _common(parser: argparse.ArgumentParser) -> None:
    cli.add_can_bus(parser, bitrate_help="bit/s (DCF Baudrate; default 1000000, as run and probe)")
    parser.add_argument("--node-id", type=cli.node_id, required=True, help="the node (1..127)")
    parser.add_argument(
        "--eds", type=Path, help="EDS (or DCF) of the node; default: identified by 1000h/1018h"
    )
    parser.add_argument("--timeout", type=_timeout, default=1.0, help="SDO timeout, s (1)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(
        dest="action", required=True, metavar="ACTION", parser_class=type(parser)
    )
    get = actions.add_parser("get", help="read objects (an ARRAY/RECORD: all its sub-objects)")
    _common(get)
    get.add_argument("objects", nargs="+", metavar="OBJECT", help="2001h, 0x2001:00, or a name")
    set_ = actions.add_parser("set", help="write one object, then read it back")
    _common(set_)
    set_.add_argument("object", metavar="OBJECT", help="2001h, 0x2001:00, 2001sub0, or a name")
    set_.add_argument("value", metavar="VALUE", help="in the object's data type and unit")
    dump = actions.add_parser("dump", help="write every readable object to a CiA 306 DCF")
    _common(dump)
    dump.add_argument("--out", type=Path, required=True, metavar="FILE.dcf", help="DCF to write")
    dump.add_argument("--node-name", help="DCF NodeName (default: the EDS ProductName)")
    load = actions.add_parser("load", help="write a DCF's values (all or none: refusals roll back)")
    _common(load)
    load.add_argument("dcf", type=Path, metavar="FILE.dcf", help="DCF to load")
    load.add_argument("--save", action="store_true", help="then store them: 1010h:01 = save")
    load.add_argument(
        "--all", action="store_true", help="also process data (PDO-mappable, RAM objects)"
    )


# --- the node ---------------------------------------------------------------------------------
@contextlib.contextmanager
def connect(args: argparse.Namespace) -> Iterator[canopen.Network]:
    """A canopen Network on the bus of ``args``, received frames fed by a Notifier."""
    bus = open_bus(BusConfig(interface=args.interface, channel=args.channel, bitrate=args.bitrate))
    try:
        network = canopen.Network(bus)
        notifier = can.Notifier(bus, network.listeners, 0.05)
        network.notifier = notifier
        try:
            yield network
        finally:
            notifier.stop(2.0)
    finally:
        bus.shutdown()


def load_eds(path: Path, node_id: int) -> canopen.ObjectDictionary:
    """The node's EDS or DCF; a file that is not one is refused in one line before any bus
    is opened (virtual_bus.formats.eds)."""
    if not path.is_file():
        raise CommissionInputError(f"--eds {path}: no such file")
    check_eds_file(path)
    try:
        return canopen.import_od(str(path), node_id)
    except Exception as exc:  # configparser and canopen raise assorted types
        raise CommissionInputError(f"{path}: not a readable EDS ({exc})") from None


def _default(od: canopen.ObjectDictionary, index: int, sub: int) -> object:
    try:
        obj = od[index]
        return (obj if isinstance(obj, ODVariable) else obj[sub]).default
    except KeyError:
        return None


def identify(network: canopen.Network, node_id: int, timeout_s: float) -> Path:
    """The EDS of :data:`KNOWN_EDS` whose 1000h, 1018h:02 and 1008h (device name) defaults
    the node shows (1000h = 0 and product code 0 alone would take any node without a profile
    and identity, e.g. CANopenNode's demo device, for the bridge)."""
    probe = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    network.add_node(probe)
    probe.sdo.RESPONSE_TIMEOUT = timeout_s
    access = SdoAccess(probe)
    product: int | None = None
    name: str | None = None
    try:
        shown = int.from_bytes(
            access.read_raw(_u32_var(Cia301.DEVICE_TYPE, 0, "Device type"))[:4], "little"
        )
        with contextlib.suppress(NodeAccessError):
            raw = access.read_raw(_u32_var(Cia301.IDENTITY, 2, "Product code"))
            product = int.from_bytes(raw[:4], "little")
        with contextlib.suppress(NodeAccessError):
            raw = access.read_raw(
                ODVariable("Manufacturer device name", Cia301.MANUFACTURER_DEVICE_NAME, 0)
            )
            name = raw.decode("ascii", "replace")
    finally:
        del network[node_id]
    for path in KNOWN_EDS:
        od = load_eds(path, node_id)
        wanted = (
            _default(od, Cia301.DEVICE_TYPE, 0),
            _default(od, Cia301.IDENTITY, 2),
            _default(od, Cia301.MANUFACTURER_DEVICE_NAME, 0),
        )
        if wanted == (shown, product, name):
            return path
    product_text = "none" if product is None else f"0x{product:08X}"
    raise CommissionInputError(
        f"node {node_id}: device type 0x{shown:08X}, product code {product_text} match "
        f"neither {', '.join(p.name for p in KNOWN_EDS)}; give --eds FILE"
    )


def _u32_var(index: int, sub: int, name: str) -> ODVariable:
    var = ODVariable(name, index, sub)
    var.data_type = dt.UNSIGNED32
    return var


@contextlib.contextmanager
def open_node(args: argparse.Namespace) -> Iterator[tuple[SdoAccess, canopen.ObjectDictionary]]:
    """Bus, EDS and node of ``args``; prints which EDS when it was identified."""
    od = load_eds(args.eds, args.node_id) if args.eds is not None else None
    with connect(args) as network:
        path = args.eds
        if od is None:
            path = identify(network, args.node_id, args.timeout)
            od = load_eds(path, args.node_id)
        node = canopen.RemoteNode(args.node_id, od)
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = args.timeout
        args.eds_used = path
        yield SdoAccess(node), od


# --- actions ----------------------------------------------------------------------------------
def _get(args: argparse.Namespace) -> int:
    with open_node(args) as (access, od):
        chosen = [var for text in args.objects for var in resolve(od, text)]
        for var in chosen:
            if var.access_type not in READABLE:
                raise CommissionInputError(
                    f"{key_text(var)} {var.name} is write-only ({var.access_type}) per the EDS"
                )
        refused = 0
        for var in chosen:
            try:
                print(display(var, access.read(var)))
            except NodeAccessError as exc:
                # a silent node ends the command (exit 1); a refused sub-index is shown with
                # its abort code and the others are still read (a record reads whole)
                if exc.abort_code is None or len(chosen) == 1:
                    raise
                refused += 1
                print(f"{key_text(var)} {var.name}: not read, {abort_text(exc.abort_code)}")
        if refused:
            print(
                f"python -m bridge config get: node {args.node_id}: {refused} of {len(chosen)} "
                "objects refused (above)",
                file=sys.stderr,
            )
            return 1
    return 0


def _set(args: argparse.Namespace) -> int:
    with open_node(args) as (access, od):
        var = resolve_one(od, args.object)
        if var.access_type not in WRITABLE:
            raise CommissionInputError(
                f"{key_text(var)} {var.name} is {var.access_type} per the EDS: not writable"
            )
        value = parse_value(var, args.value, args.node_id)
        readable = var.access_type in READABLE
        before = access.read(var) if readable else None
        access.write(var, value)
        if readable:
            print(display_change(var, before, access.read(var)))  # type: ignore[arg-type]
        else:
            print(f"{key_text(var)} {var.name} <- {value_text(var, value)}")
    return 0


def _dump(args: argparse.Namespace) -> int:
    out: Path = args.out
    if out.is_dir() or not out.parent.is_dir():
        raise CommissionInputError(f"--out {out}: not a file in an existing directory")
    with open_node(args) as (access, od):
        values: dict[tuple[int, int | None], str] = {}
        refused: list[NodeAccessError] = []
        serial = None
        count = 0
        no_data: list[NodeAccessError] = []
        for var in variables(od):
            # 0001h-0FFFh are data type definitions (an EDS's [DummyUsage]), not parameters
            if var.access_type not in READABLE or var.index < COMMUNICATION_AREA.start:
                continue
            try:
                value = access.read(var)
            except NodeAccessError as exc:
                if exc.abort_code is None:
                    raise
                # CiA 301 0800 0024 "no data available": e.g. an empty 1003h entry
                (no_data if exc.abort_code == SdoAbort.NO_DATA else refused).append(exc)
                continue
            count += 1
            values[key_of(var, od)] = value_text(var, value)
            if (var.index, var.subindex) == (Cia301.IDENTITY, 4):
                serial = int(value)
        info = od.device_information
        commissioning = Commissioning(
            node_id=args.node_id,
            node_name=args.node_name or info.product_name or f"node {args.node_id}",
            baudrate_kbit=args.bitrate // 1000,
            canopen_manager=bool(info.simple_boot_up_master),
            lss_serial=serial,
        )
        eds_path: Path = args.eds_used
        text = render_dcf(
            eds_path.read_text(encoding="utf-8"),
            eds_name=eds_path.name,
            dcf_name=out.name,
            values=values,
            commissioning=commissioning,
        )
    write_atomic(out, text)
    print(f"wrote {out}: {count} objects of node {args.node_id} (EDS {eds_path.name})")
    for exc in no_data:
        print(f"no value (EDS default kept): {exc}", file=sys.stderr)
    for exc in refused:
        print(f"not read: {exc}", file=sys.stderr)
    return 1 if refused else 0


def _same(var: ODVariable, a: Value, b: Value) -> bool:
    return encode(var, a) == encode(var, b)


def _write_all(
    access: SdoAccess, items: list[tuple[ODVariable, Value]], done: list[ODVariable]
) -> list[tuple[ODVariable, NodeAccessError]]:
    """Write ``items`` in passes until all are in or a pass makes no progress; appends each
    written variable to ``done``; returns the refusals (a silent node raises)."""
    pending = list(items)
    while pending:
        refused: list[tuple[ODVariable, Value, NodeAccessError]] = []
        for var, value in pending:
            try:
                access.write(var, value)
            except NodeAccessError as exc:
                if exc.abort_code is None:
                    raise
                refused.append((var, value, exc))
                continue
            done.append(var)
        if len(refused) == len(pending):
            return [(var, exc) for var, _, exc in refused]
        pending = [(var, value) for var, value, _ in refused]
    return []


def _rollback(
    access: SdoAccess, previous: dict[tuple[int, int], Value], written: list[ODVariable]
) -> list[str]:
    """Write the previous values of ``written`` back; what could not be undone."""
    back = [(var, previous[(var.index, var.subindex)]) for var in reversed(written)]
    try:
        failed = _write_all(access, back, [])
    except NodeAccessError as exc:
        return [str(exc)]
    return [str(exc) for _, exc in failed]


def _load(args: argparse.Namespace) -> int:
    with open_node(args) as (access, od):
        if args.save and not _has(od, Cia301.STORE_PARAMETERS, 1):
            raise CommissionInputError(
                f"--save: node {args.node_id}'s EDS has no 1010h:01 (store parameters)"
            )
        dcf = read_dcf(args.dcf, od, args.node_id)
        if dcf.node_id is not None and dcf.node_id != args.node_id:
            raise CommissionInputError(
                f"{args.dcf}: made for node-ID {dcf.node_id} ([DeviceComissioning] NodeID), "
                f"not {args.node_id}"
            )
        skipped: list[str] = []
        candidates: list[tuple[ODVariable, Value]] = []
        for var, value in dcf.values:
            if var.access_type not in WRITABLE or var.index in STORE_COMMANDS:
                continue
            if var.access_type == "wo":
                skipped.append(f"{key_text(var)} (write-only)")
            elif not args.all and (var.pdo_mappable or var.storage_location == "RAM"):
                if not _same(var, value, access.read(var)):
                    skipped.append(f"{key_text(var)} (process data; --all loads it)")
            else:
                candidates.append((var, value))
        previous = {(var.index, var.subindex): access.read(var) for var, _ in candidates}
        changes = [
            (var, value)
            for var, value in candidates
            if not _same(var, value, previous[(var.index, var.subindex)])
        ]
        written: list[ODVariable] = []
        try:
            refused = _write_all(access, changes, written)
        except NodeAccessError as exc:
            undone = _rollback(access, previous, written)
            print(f"load stopped: {exc}", file=sys.stderr)
            _report_rollback(written, undone)
            return 1
        if refused:
            wanted = {(var.index, var.subindex): value for var, value in changes}
            for var, exc in refused:
                value = wanted[(var.index, var.subindex)]
                code = abort_text(exc.abort_code or 0)
                print(f"refused: {display(var, value)}: {code}", file=sys.stderr)
            undone = _rollback(access, previous, written)
            _report_rollback(written, undone)
            return 1
        print(
            f"node {args.node_id}: loaded {len(written)} objects from {args.dcf} "
            f"({len(candidates) - len(changes)} already equal"
            + (f"; not loaded: {', '.join(skipped)}" if skipped else "")
            + ")"
        )
        if args.save:
            access.write(od[Cia301.STORE_PARAMETERS][1], SIGNATURES["save"])
            print(f"node {args.node_id}: stored (1010h:01 = save)")
    return 0


def _has(od: canopen.ObjectDictionary, index: int, sub: int) -> bool:
    obj = od.indices.get(index)
    return obj is not None and not isinstance(obj, ODVariable) and sub in obj.subindices


def _report_rollback(written: list[ODVariable], undone: list[str]) -> None:
    if not undone:
        print(
            f"nothing changed: {len(written)} objects written before the refusal were "
            "restored to their previous values",
            file=sys.stderr,
        )
    else:
        print(f"node left partly changed; could not restore: {'; '.join(undone)}", file=sys.stderr)


ACTIONS = {"get": _get, "set": _set, "dump": _dump, "load": _load}


def run(args: argparse.Namespace) -> int:
    """Run the action; a node that refuses or is silent: one line on stderr, exit 1."""
    # canopen logs an SDO timeout itself; the one line below says it with the object
    logging.getLogger("canopen.sdo.client").setLevel(logging.CRITICAL)
    try:
        return ACTIONS[args.action](args)
    except NodeAccessError as exc:
        print(f"python -m bridge config {args.action}: {exc}", file=sys.stderr)
        return 1

"""Where the load position could come from: the load-scale candidates a probe can see.

The paper's regulator fades the *load* scale out of the position loop (eq. 15); a drive set up
on motor feedback gives it nothing to do. A probe therefore names every candidate it finds,
with its data type and whether it can be mapped into a TPDO:

* CiA 402's 60E4h additional position actual value, each sub-index the drive answers (or
  60E4h as a plain INTEGER32);
* manufacturer objects (2000h-5FFFh) whose EDS name says position, encoder, auxiliary, second,
  external, load or scale, that are read-only 32-bit integers (a measured value, not a setting
  or a reference) -- the iPOS' 208Dh "Auxiliary encoder position", the EuServo's 202Bh "second
  encoder value";
* CiA 406 encoder nodes on the bus (1000h low word 406, position value 6004h).

:func:`best` picks the one the written profile uses: a mappable 60E4h sub-index, else the
best-named mappable vendor object, else an encoder node, else none (motor feedback). Pure: the
bus work is :mod:`bridge.probe`'s.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import canopen
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary import datatypes as dt

from virtual_bus.contract import MANUFACTURER_AREA, Cia402
from virtual_bus.formats.drive_profile import LoadSource, ObjectKey, format_key

from .adapt import DriveFacts

#: Words in an EDS name that make a manufacturer object a load-position candidate, and the
#: rank they give (higher first): a second measuring system is what the regulator needs.
_RANK = (
    (re.compile(r"auxiliar|second|external|load|scale|linear", re.I), 3),
    (re.compile(r"master", re.I), 2),
    (re.compile(r"encoder", re.I), 1),
    (re.compile(r"position", re.I), 0),
)
#: Names of settings and derived values, never a measured load position.
_NOT_A_POSITION = re.compile(
    r"demand|target|limit|window|offset|resolution|factor|hom|range|error|deviation|internal|"
    r"set.?point|command|velocity|speed|current|torque|time|count|number|polarity|type|mode|"
    r"config|increment|ratio|filter|gain|capture|latch|tolerance|trigger|motor|refused|frame|"
    r"counter|producer|sync|status|word",
    re.I,
)
_TYPES = {
    dt.INTEGER32: "i32",
    dt.UNSIGNED32: "u32",
}


@dataclass(frozen=True)
class LoadCandidate:
    """One place the load position could come from.

    source: the profile's ``load.source`` that selects it; key: the drive object (None for an
    encoder node); name: EDS name or what the drive showed; type_name: ``i32``/``u32`` (None:
    unknown); mappable: per the EDS (None: no EDS, the start-up finds out by trying);
    encoder_id: the CiA 406 node. rank: higher is a likelier load scale.
    """

    source: LoadSource
    key: ObjectKey | None
    name: str
    type_name: str | None
    mappable: bool | None
    encoder_id: int | None = None
    rank: int = 0

    def describe(self) -> str:
        if self.encoder_id is not None:
            return (
                f"node {self.encoder_id}: CiA 406 encoder, 6004h position value (u32), its "
                f'TPDO1 on SYNC -- load.source = "encoder", load.encoder_id = {self.encoder_id}'
            )
        assert self.key is not None
        mapping = {True: "PDO-mappable", False: "NOT PDO-mappable", None: "mappability unknown"}
        kind = self.type_name or "type unknown"
        key = format_key(self.key)
        if self.source is LoadSource.VENDOR:
            use = f'load.source = "vendor", load.object = "{key}", load.object_type = "{kind}"'
        else:
            use = f'load.source = "{self.source.value}"'
        return f"{key} {self.name!r} ({kind}, {mapping[self.mappable]}) -- {use}"

    @property
    def usable(self) -> bool:
        """Not ruled out by the EDS (mappable or unknown)."""
        return self.mappable is not False


def _mappable(od: canopen.ObjectDictionary | None, key: ObjectKey) -> bool | None:
    if od is None:
        return None
    obj = od.get(key[0])
    if obj is None:
        return None
    var = obj if isinstance(obj, ODVariable) else obj.get(key[1])
    return None if var is None else bool(var.pdo_mappable)


def additional_position(
    facts: DriveFacts, od: canopen.ObjectDictionary | None
) -> list[LoadCandidate]:
    """60E4h as the drive answered it: a plain INTEGER32 (sub-index 0 reads 4 bytes) or the
    sub-indices 01h.. it has."""
    sub0 = facts.objects.get((Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0))
    if sub0 is not None and len(sub0) == 4:
        return [
            LoadCandidate(
                LoadSource.ADDITIONAL_VAR,
                (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0),
                "additional position actual value (plain variable)",
                "i32",
                _mappable(od, (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0)),
                rank=5,
            )
        ]
    found = []
    for (index, sub), _raw in sorted(facts.objects.items()):
        if index != Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE or sub == 0:
            continue
        found.append(
            LoadCandidate(
                LoadSource.ADDITIONAL_SUB1 if sub == 1 else LoadSource.VENDOR,
                (index, sub),
                f"additional position actual value {sub}",
                "i32",
                _mappable(od, (index, sub)),
                rank=5 if sub == 1 else 4,
            )
        )
    return found


def vendor_objects(od: canopen.ObjectDictionary) -> list[LoadCandidate]:
    """Manufacturer objects of the EDS whose name and type say "a measured position"."""
    found = []
    for index in sorted(od.indices):
        if index not in MANUFACTURER_AREA:
            continue
        obj = od[index]
        members = [obj] if isinstance(obj, ODVariable) else [obj[s] for s in sorted(obj.subindices)]
        for var in members:
            name = var.name if var is obj else f"{obj.name} / {var.name}"
            type_name = _TYPES.get(var.data_type)
            if type_name is None or var.access_type not in ("ro", "const"):
                continue
            if _NOT_A_POSITION.search(name):
                continue
            rank = next((r for pattern, r in _RANK if pattern.search(name)), None)
            if rank is None:
                continue
            found.append(
                LoadCandidate(
                    LoadSource.VENDOR,
                    (var.index, var.subindex),
                    name,
                    type_name,
                    bool(var.pdo_mappable),
                    rank=rank,
                )
            )
    return found


def encoder_node(node_id: int) -> LoadCandidate:
    return LoadCandidate(
        LoadSource.ENCODER, None, f"CiA 406 encoder node {node_id}", "u32", True, node_id, rank=3
    )


def best(candidates: list[LoadCandidate]) -> LoadCandidate | None:
    """The candidate a probe writes into the profile: usable ones only, 60E4h first, then by
    rank, then by index (a mappable one before one of unknown mappability)."""
    usable = [c for c in candidates if c.usable]
    if not usable:
        return None
    return max(
        usable,
        key=lambda c: (c.rank, c.mappable is True, -(c.key or (0xFFFF, 0xFF))[0]),
    )

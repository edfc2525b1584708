"""How the drive supervises the bridge: planned from what the drive has, written at start-up,
given back at the end (pure planning; :mod:`bridge.master` writes it).

A bridge that dies (a crash, ``kill -9``, a hung host, a cut cable) must leave an axis that
stops by itself. The bridge supervises the drive (heartbeat, EMCY, PDO loss); this is the
other direction, with the objects CiA 301 and CiA 402 give a drive for it:

* **1016h heartbeat consumer** (CiA 301 7.2.8.3.2): one entry names the bridge's node-ID and
  a consumer time of :data:`~virtual_bus.contract.HEARTBEAT_CONSUMER_MARGIN` times the
  bridge's own heartbeat period (1017h, default 100 ms: 250 ms). The entry already watching
  the bridge is reused, else the first unused one (node-ID or time 0);
* **6007h abort connection option code** (CiA 402): what the drive does when that heartbeat
  is lost (or NMT takes it out of Operational): 3, quick stop, unless the drive profile says
  otherwise (``supervision.abort_connection_option``);
* **a set-point watchdog** where the drive has one (a manufacturer object named by the drive
  profile, ``supervision.setpoint_timeout_object``; the contract's drive: 2102h, SYNCs
  without an RPDO): the bridge sends its RPDO every SYNC, so a master that sends SYNC but no
  set point is lost too.

What the drive lacks is said (a note per missing piece; a drive that supervises nothing of
the bridge is said loudly); what the profile names and the drive lacks stops the start-up
before anything is written. The values these objects had before are read first and written
back when the bridge ends in order (:attr:`Supervision.keys`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from virtual_bus.contract import (
    ABORT_CONNECTION_INDEX,
    CONTRACT_SETPOINT_TIMEOUT,
    HEARTBEAT_CONSUMER_INDEX,
    AbortConnection,
    consumer_time_ms,
    heartbeat_consumer_entry,
    split_heartbeat_consumer_entry,
)
from virtual_bus.formats.drive_profile import OBJECT_TYPES, DriveProfile, ObjectKey, format_key

from .adapt import DriveFacts
from .errors import DriveSetupError

#: 6007h of the start-up unless the drive profile says otherwise.
DEFAULT_ABORT_CONNECTION = AbortConnection.QUICK_STOP
#: The objects the start-up reads to plan the supervision (the entries of 1016h follow from
#: its sub-index 0, :func:`consumer_entries`).
SUPERVISION_OBJECTS: tuple[ObjectKey, ...] = (
    (HEARTBEAT_CONSUMER_INDEX, 0),
    (ABORT_CONNECTION_INDEX, 0),
)


@dataclass(frozen=True)
class Write:
    """One object the start-up writes: its key, the bytes, what it is for."""

    key: ObjectKey
    data: bytes
    what: str


@dataclass(frozen=True)
class Supervision:
    """The drive's supervision of the bridge: what to write, and what the drive cannot do.

    consumer_ms: the drive's consumer time of the bridge's heartbeat (None: not watched).
    """

    writes: tuple[Write, ...]
    notes: tuple[str, ...]
    consumer_ms: int | None = None

    @property
    def keys(self) -> tuple[ObjectKey, ...]:
        return tuple(w.key for w in self.writes)

    @property
    def watched(self) -> bool:
        """The drive stops by itself when the bridge dies (a heartbeat consumer or a set
        point watchdog is configured)."""
        return bool(self.writes) and any(w.key[0] != ABORT_CONNECTION_INDEX for w in self.writes)

    def describe(self) -> list[str]:
        """One line per object written (``probe`` and the start-up's log)."""
        return [
            f"{format_key(w.key)} = 0x{w.data[::-1].hex().upper()}: {w.what}" for w in self.writes
        ]


def consumer_entries(facts: DriveFacts, profile: DriveProfile) -> int:
    """How many 1016h entries the drive has: the profile's, else 1016h:00 as read (0: none)."""
    if profile.heartbeat_consumer_entries is not None:
        return profile.heartbeat_consumer_entries
    raw = facts.objects.get((HEARTBEAT_CONSUMER_INDEX, 0))
    return raw[0] if raw else 0


def _consumer(
    facts: DriveFacts, profile: DriveProfile, drive_id: int, bridge_id: int, producer_ms: int
) -> tuple[Write | None, str | None, int | None]:
    where = f"drive {drive_id}"
    entries = consumer_entries(facts, profile)
    if entries == 0:
        return (
            None,
            f"{where} has no heartbeat consumer (1016h): it cannot tell that the bridge died",
            None,
        )
    if producer_ms == 0:
        return (
            None,
            f"the bridge's 1017h is 0 (it sends no heartbeat): {where} cannot watch it; set "
            "1017h (default 100 ms)",
            None,
        )
    free: int | None = None
    for sub in range(1, entries + 1):
        raw = facts.objects.get((HEARTBEAT_CONSUMER_INDEX, sub))
        if raw is None or len(raw) < 4:  # not read (the profile's count): take it
            free = sub if free is None else free
            continue
        node, time_ms = split_heartbeat_consumer_entry(int.from_bytes(raw[:4], "little"))
        if node == bridge_id:
            free = sub
            break
        if (node == 0 or time_ms == 0) and free is None:
            free = sub
    if free is None:
        return (
            None,
            f"{where}: all {entries} entries of 1016h watch other nodes: it does not watch "
            "the bridge (free one: node-ID or time 0)",
            None,
        )
    consumer_ms = consumer_time_ms(producer_ms)
    entry = heartbeat_consumer_entry(bridge_id, consumer_ms)
    what = (
        f"heartbeat consumer: the bridge (node {bridge_id}) within {consumer_ms} ms "
        f"({producer_ms} ms x {consumer_ms / producer_ms:g})"
    )
    write = Write((HEARTBEAT_CONSUMER_INDEX, free), struct.pack("<I", entry), what)
    return write, None, consumer_ms


def _setpoint_timeout(facts: DriveFacts, profile: DriveProfile, drive_id: int) -> Write | None:
    key = profile.setpoint_timeout_object
    if key is None:
        if not facts.contract_drive:
            return None
        key = CONTRACT_SETPOINT_TIMEOUT
    elif not facts.has(key):
        raise DriveSetupError(
            f"drive {drive_id}: supervision.setpoint_timeout_object {format_key(key)} does not "
            "exist on the drive; remove it from the drive profile or name the drive's object",
            index=key[0],
            subindex=key[1],
        )
    bits, signed = OBJECT_TYPES[profile.setpoint_timeout_type]
    value = profile.setpoint_timeout
    data = value.to_bytes(bits // 8, "little", signed=signed)
    return Write(key, data, f"set-point watchdog: {value} (the bridge sends its RPDO every SYNC)")


def plan_supervision(
    facts: DriveFacts, profile: DriveProfile, drive_id: int, bridge_id: int, producer_ms: int
) -> Supervision:
    """The drive's supervision of the bridge (module docstring) from what the start-up read;
    ``producer_ms``: the bridge's own heartbeat period (1017h). DriveSetupError when the
    profile names an object the drive does not have."""
    writes: list[Write] = []
    notes: list[str] = []
    consumer, note, consumer_ms = _consumer(facts, profile, drive_id, bridge_id, producer_ms)
    if consumer is not None:
        writes.append(consumer)
    if note is not None:
        notes.append(note)
    option = profile.abort_connection_option
    if facts.has((ABORT_CONNECTION_INDEX, 0)):
        value = DEFAULT_ABORT_CONNECTION if option is None else option
        name = AbortConnection(value).name.lower() if 0 <= value <= 3 else "manufacturer's"
        writes.append(
            Write(
                (ABORT_CONNECTION_INDEX, 0),
                struct.pack("<h", value),
                f"abort connection option: {value} ({name.replace('_', ' ')}) when the bridge "
                "is lost",
            )
        )
    elif option is not None:
        raise DriveSetupError(
            f"drive {drive_id}: supervision.abort_connection_option = {option} but the drive has "
            "no 6007h; remove it from the drive profile",
            index=ABORT_CONNECTION_INDEX,
            subindex=0,
        )
    else:
        notes.append(
            f"drive {drive_id} has no 6007h abort connection option code: what it does when it "
            "loses the bridge is its manufacturer's choice (read its manual)"
        )
    watchdog = _setpoint_timeout(facts, profile, drive_id)
    if watchdog is not None:
        writes.append(watchdog)
    supervision = Supervision(tuple(writes), tuple(notes), consumer_ms)
    if not supervision.watched:
        notes.append(
            f"drive {drive_id} does not supervise the bridge at all: if the bridge dies, the "
            "drive keeps its last set point (a hardware enable or safe torque off must stop it)"
        )
        supervision = Supervision(tuple(writes), tuple(notes), consumer_ms)
    return supervision

"""Candump logs of the bridge's bus as a stream of chunks, one sample per SYNC.

A log of a real machine carries its own PDO layout: the bridge's start-up writes the PDO
parameters over SDO (CiA 301: 1800h+n / 1A00h+n of the drive's and an encoder's TPDOs,
1400h+n / 1600h+n of the drive's RPDO), and ``candump -l`` records those writes before the
first SYNC. The decoder reads them from the log and decodes every TPDO by its own mapping, so
a drive whose layout the bridge adapted (other PDO numbers, a vendor load object, a CiA 406
encoder node, motor feedback only) is read as it was on the bus. A log that starts after the
start-up falls back to the contract's layout (docs/canopen_layout.md: TPDO1 6064h + 60E4h:01,
TPDO2 6041h + 6077h + 606Ch, RPDO1 6040h + 60FFh).

Scaling (:class:`CandumpLayout`): the contract's by default, or a drive profile's
(``--drive-profile``, ``virtual_bus/formats/drive_profile.py``): 6064h increments per motor
revolution, 606Ch /
60FFh units per revolution per second, load increments per load unit, the rated torque
(6076h, else the start-up's SDO answer for 6076h in the log, else torque in ‰).

Signals per SYNC: motor position (6064h), load position (60E4h:01 / 60E4h:00, 6004h of a
CiA 406 encoder, or the profile's vendor object), torque (6077h), motor speed (606Ch) and
the speed set point the bridge sent (60FFh of the drive's RPDO).

Time base: the SYNC frames' time stamps, which a log of a real-time run stamps with the
wall clock a cycle apart. A log of a run in lockstep (``hil demo``, ``bridge run --clock
lockstep``) is stamped with the wall clock of a loop that ran many times faster than real time
(the demo's 7 s in 1.7 s, a median step of 48 µs for a 1 ms cycle): when the layout knows the
axis's position cycle (:attr:`CandumpLayout.cycle_s`) and the median SYNC step of the first
block differs from it by more than :data:`CYCLE_TOLERANCE`, the time of a sample is the SYNC
count times the cycle (0 at the first sample), with one
:class:`~fleet.errors.TimeBaseWarning` that says which time base was used and why.

A log a kill or a power loss cut short: a last line without its line end is not a frame,
and a last SYNC cycle with fewer of the layout's PDOs than the cycle before it (the first:
than the layout has) is where the log was cut, not a sample; both are dropped with one
:class:`~virtual_bus.formats.errors.TornTailWarning` naming the byte they start at and their
length. Every whole cycle before them is read.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from virtual_bus.contract import (
    CAN_ID_MASK,
    COB_ID_INVALID,
    PDO_PARAMETERS_END,
    RPDO_COMM_BASE,
    SDO_RX_BASE,
    SYNC_COB_ID,
    Cia402,
    Cia406,
    pdo_comm_index,
    pdo_mapping_index,
    pdo_of_cob_id,
    rpdo_cob_id,
    sdo_tx_cob_id,
    split_mapping_entry,
    tpdo_cob_id,
)
from virtual_bus.formats.axis import AxisKind
from virtual_bus.formats.drive_profile import load_profile
from virtual_bus.formats.errors import TornTailWarning

from .chunks import CHUNK_ROWS, Chunk, checked, first_line
from .errors import RecordingError, TimeBaseWarning

MOTOR_POSITION = (Cia402.POSITION_ACTUAL_VALUE, 0)
TORQUE = (Cia402.TORQUE_ACTUAL_VALUE, 0)
MOTOR_VELOCITY = (Cia402.VELOCITY_ACTUAL_VALUE, 0)
TARGET_VELOCITY = (Cia402.TARGET_VELOCITY, 0)
STATUSWORD = (Cia402.STATUSWORD, 0)
#: Load measuring systems in the order the bridge prefers them (bridge/adapt.py).
LOAD_OBJECTS = (
    (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 1),
    (Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 0),
    (Cia406.POSITION_VALUE, 0),
)
ObjectKey = tuple[int, int]
#: A median SYNC step further than this (relative) from the axis's cycle is not a cycle apart:
#: the log was stamped by a lockstep run, and the SYNC count is its time base.
CYCLE_TOLERANCE = 0.1


@dataclass(frozen=True)
class CandumpLayout:
    """How the log scales its signals (defaults: the contract, docs/canopen_layout.md).

    motor_increments_per_rev: 6064h units per motor revolution. velocity_units_per_rev_s:
    606Ch/60FFh units per motor revolution per second (None: the position units).
    load_increments_per_unit: load-position increments per m (linear) or rad (rotary).
    rated_torque_nm: 6076h in N·m; None: from the log's 6076h SDO answer, else torque in ‰;
    0: torque in ‰. load_object: a vendor object carrying the load position.
    drive_id: the drive's node-ID, 0 = the node whose TPDOs are seen most often.
    cycle_s: the axis's position cycle (the SYNC period), s; None: the log's time stamps are
    its time base whatever their step (see the module docstring).
    """

    motor_increments_per_rev: float = float(1 << 20)
    velocity_units_per_rev_s: float | None = None
    load_increments_per_unit: float = 1e9
    rated_torque_nm: float | None = None
    load_object: ObjectKey | None = None
    drive_id: int = 0
    cycle_s: float | None = None

    @property
    def rad_per_increment(self) -> float:
        return 2.0 * math.pi / self.motor_increments_per_rev

    @property
    def rad_s_per_velocity_unit(self) -> float:
        units = self.velocity_units_per_rev_s or self.motor_increments_per_rev
        return 2.0 * math.pi / units


def layout_for(
    kind: AxisKind, profile_path: Path | None = None, cycle_s: float | None = None
) -> CandumpLayout:
    """The contract's scaling for an axis of ``kind``, or a drive profile's over it;
    ``cycle_s``: the axis's position cycle (the time base of a lockstep log)."""
    load = 1e9 if kind is AxisKind.LINEAR else 1e6  # nm per m, µrad per rad (60E4h:01)
    if profile_path is None:
        return CandumpLayout(load_increments_per_unit=load, cycle_s=cycle_s)
    p = load_profile(profile_path)
    rated = None if p.rated_torque_mnm is None else p.rated_torque_mnm / 1000.0
    return CandumpLayout(
        motor_increments_per_rev=p.position_increments_per_rev or float(1 << 20),
        velocity_units_per_rev_s=p.velocity_units_per_rev_s,
        load_increments_per_unit=p.load_increments_per_unit or load,
        rated_torque_nm=rated,
        load_object=p.load_object,
        cycle_s=cycle_s,
    )


def parse_line(line: str) -> tuple[float, int, bytes] | None:
    """(epoch s, CAN-ID, data) of one ``candump -l`` line; None for a blank line."""
    line = line.strip()
    if not line:
        return None
    stamp, _iface, frame = line.split(" ", 2)
    if not (stamp.startswith("(") and stamp.endswith(")")):
        raise ValueError("no (timestamp)")
    can_id, sep, data = frame.strip().split(" ")[0].partition("#")
    if not sep:
        raise ValueError("no ID#DATA")
    if data.startswith("R"):
        return float(stamp[1:-1]), int(can_id, 16), b""
    return float(stamp[1:-1]), int(can_id, 16), bytes.fromhex(data)


def _tpdo_node(cob_id: int) -> int | None:
    """The node of a frame in one of the four pre-defined TPDO ranges, else None."""
    pdo = pdo_of_cob_id(cob_id)
    return pdo[2] if pdo is not None and pdo[0] else None


def find_drive(path: Path, head: list[tuple[float, int, bytes]]) -> int:
    """The node whose TPDOs are the most frequent in the log's first frames."""
    counts: dict[int, int] = {}
    for _, cid, _ in head:
        node = _tpdo_node(cid)
        if node is not None:
            counts[node] = counts.get(node, 0) + 1
    if not counts:
        raise RecordingError(
            f"{path}: candump log without TPDOs (0x181..0x4FF): not a log of the bridge's bus",
            path=str(path),
        )
    return max(counts, key=lambda k: counts[k])


@dataclass(frozen=True)
class _Field:
    key: ObjectKey
    offset: int
    size: int
    signed: bool


class PdoMap:
    """PDO parameters seen as SDO downloads in the log, per node (CiA 301 objects)."""

    def __init__(self) -> None:
        self.writes: dict[tuple[int, int, int], int] = {}
        self.changed = False

    def feed_sdo_request(self, node: int, data: bytes) -> None:
        """An SDO request to ``node``: keep expedited downloads to PDO parameters."""
        if len(data) != 8 or data[0] & 0xE3 != 0x23:  # expedited download with size
            return
        index = int.from_bytes(data[1:3], "little")
        if not (RPDO_COMM_BASE <= index <= PDO_PARAMETERS_END):
            return
        size = 4 - ((data[0] >> 2) & 3)
        self.writes[(node, index, data[3])] = int.from_bytes(data[4 : 4 + size], "little")
        self.changed = True

    def frames(self, node: int, transmit: bool) -> dict[int, tuple[_Field, ...]]:
        """COB-ID -> fields of each valid PDO of ``node`` the log configured."""
        out: dict[int, tuple[_Field, ...]] = {}
        for n in range(512):
            comm, mapping = pdo_comm_index(transmit, n + 1), pdo_mapping_index(transmit, n + 1)
            cob = self.writes.get((node, comm, 1))
            count = self.writes.get((node, mapping, 0))
            if cob is None or not count or cob & COB_ID_INVALID:
                continue
            fields, offset = [], 0
            for sub in range(1, count + 1):
                entry = self.writes.get((node, mapping, sub))
                if entry is None:
                    break
                index, subindex, bits = split_mapping_entry(entry)
                key = (index, subindex)
                size = bits // 8
                fields.append(_Field(key, offset, size, key != STATUSWORD))
                offset += size
            else:
                out[cob & CAN_ID_MASK] = tuple(fields)
        return out

    def nodes(self) -> set[int]:
        return {node for node, _, _ in self.writes}


def _contract(drive: int) -> tuple[dict[int, tuple[_Field, ...]], dict[int, tuple[_Field, ...]]]:
    def f(key: ObjectKey, offset: int, size: int) -> _Field:
        return _Field(key, offset, size, key != STATUSWORD)

    tpdos = {
        tpdo_cob_id(1, drive): (
            f(MOTOR_POSITION, 0, 4),
            f((Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE, 1), 4, 4),
        ),
        tpdo_cob_id(2, drive): (f(STATUSWORD, 0, 2), f(TORQUE, 2, 2), f(MOTOR_VELOCITY, 4, 4)),
    }
    return tpdos, {
        rpdo_cob_id(1, drive): (f((Cia402.CONTROLWORD, 0), 0, 2), f(TARGET_VELOCITY, 2, 4))
    }


class Decoder:
    """Frames in, one row per SYNC out (the values sampled at that SYNC)."""

    def __init__(self, path: Path, layout: CandumpLayout, drive_id: int) -> None:
        self.path = path
        self.layout = layout
        self.drive = drive_id
        self.map = PdoMap()
        self.tpdos, self.rpdos = _contract(drive_id)
        self.sdo_tx = sdo_tx_cob_id(drive_id)
        self.rated_torque_nm = layout.rated_torque_nm
        self.rows: list[tuple[float, float, float, float, float, float, int]] = []
        #: the time base: None until the first block decides it, then True where the SYNC
        #: count times the cycle is the time (a lockstep log), False for the time stamps
        self.by_sync_count: bool | None = None
        self._first_sync: tuple[float, int] | None = None  # (time stamp, SYNC count) of row 0
        self.load_seen = False
        self.syncs = 0
        #: the last cycle was cut short (see the module docstring) and left out
        self.dropped_last = False
        self._sync_t = math.nan
        self._values: dict[ObjectKey, int] = {}
        self._setpoint = math.nan
        self._pdos: set[int] = set()  # COB-IDs of the layout's PDOs seen since the SYNC
        self._pdos_before: set[int] | None = None  # those of the cycle before
        self._load_keys = (
            (layout.load_object, *LOAD_OBJECTS) if layout.load_object else LOAD_OBJECTS
        )

    def _rebuild(self) -> None:
        tpdos: dict[int, tuple[_Field, ...]] = {}
        for node in self.map.nodes():
            tpdos |= self.map.frames(node, transmit=True)
        rpdos = self.map.frames(self.drive, transmit=False)
        if tpdos:
            self.tpdos = tpdos
        if rpdos:
            self.rpdos = rpdos
        self.map.changed = False

    def feed(self, t: float, cid: int, data: bytes) -> None:
        if cid == SYNC_COB_ID:
            if self.map.changed:
                self._rebuild()
            self._close_cycle()
            self._sync_t = t
            self.syncs += 1
            return
        fields = self.tpdos.get(cid)
        if fields is not None:
            self._pdos.add(cid)
            for fd in fields:
                if fd.offset + fd.size <= len(data):
                    raw = data[fd.offset : fd.offset + fd.size]
                    self._values[fd.key] = int.from_bytes(raw, "little", signed=fd.signed)
            return
        fields = self.rpdos.get(cid)
        if fields is not None:
            self._pdos.add(cid)
            for fd in fields:
                if fd.key == TARGET_VELOCITY and fd.offset + fd.size <= len(data):
                    raw = data[fd.offset : fd.offset + fd.size]
                    self._setpoint = int.from_bytes(raw, "little", signed=True)
            return
        if SDO_RX_BASE < cid <= SDO_RX_BASE + 0x7F:
            self.map.feed_sdo_request(cid - SDO_RX_BASE, data)
        elif (
            cid == self.sdo_tx
            and self.rated_torque_nm is None
            and len(data) == 8
            and data[0] & 0xE2 == 0x42  # expedited upload response (CiA 301)
            and data[1:4] == b"\x76\x60\x00"  # 6076h:00 motor rated torque, mN·m
        ):
            self.rated_torque_nm = int.from_bytes(data[4:8], "little") / 1000.0

    def _close_cycle(self, last: bool = False) -> None:
        v = self._values
        if last and math.isfinite(self._sync_t):
            expected = self._pdos_before
            if expected is None:
                expected = set(self.tpdos) | set(self.rpdos)
            if not expected <= self._pdos:  # the log ends inside this cycle
                self.dropped_last = True
                self._values = {}
                return
        if self._pdos:
            self._pdos_before, self._pdos = self._pdos, set()
        if MOTOR_POSITION in v and math.isfinite(self._sync_t):
            load = next((v[k] for k in self._load_keys if k in v), None)
            self.load_seen |= load is not None
            lay = self.layout
            self.rows.append(
                (
                    self._sync_t,
                    v[MOTOR_POSITION] * lay.rad_per_increment,
                    math.nan if load is None else load / lay.load_increments_per_unit,
                    float(v.get(TORQUE, 0)),
                    v.get(MOTOR_VELOCITY, 0) * lay.rad_s_per_velocity_unit,
                    self._setpoint * lay.rad_s_per_velocity_unit,
                    self.syncs,
                )
            )
        self._values = {}

    def take(self, final: bool = False) -> Chunk | None:
        if final:
            self._close_cycle(last=True)
        if not self.rows:
            return None
        a = np.asarray(self.rows, dtype=np.float64)
        self.rows.clear()
        rated = self.rated_torque_nm
        return Chunk(
            time_s=self._time(a[:, 0], a[:, 6]),
            motor_position_rad=a[:, 1],
            motor_torque=a[:, 3] * (rated / 1000.0) if rated else a[:, 3],
            load_position=a[:, 2] if self.load_seen else None,
            speed_setpoint_rad_s=a[:, 5],
            motor_speed_rad_s=a[:, 4],
            torque_unit="N·m" if rated else "‰",
        )

    def _time(self, stamps: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """The samples' times: their SYNC time stamps, or for a lockstep log the SYNC count
        times the cycle (decided on the first block, with one warning; module docstring)."""
        cycle = self.layout.cycle_s
        if self.by_sync_count is None:
            self._first_sync = (float(stamps[0]), int(counts[0]))
            self.by_sync_count = False
            if cycle is not None and stamps.size >= 2:
                step = float(np.median(np.diff(stamps) / np.diff(counts)))
                if abs(step / cycle - 1.0) > CYCLE_TOLERANCE:
                    self.by_sync_count = True
                    warnings.warn(
                        f"{self.path}: the SYNC frames are stamped {_duration(step)} apart "
                        f"(median), the axis's position cycle is {_duration(cycle)}: a log of "
                        "a run in lockstep (or of another cycle); its time base is the SYNC "
                        f"count times {_duration(cycle)} (0 s at its first sample), not the "
                        "time stamps",
                        TimeBaseWarning,
                        stacklevel=4,
                    )
        if not self.by_sync_count or cycle is None or self._first_sync is None:
            return stamps
        return (counts - self._first_sync[1]) * cycle


def _duration(seconds: float) -> str:
    """'1 ms', '48.1 µs'."""
    if seconds >= 1.0:
        return f"{seconds:.3g} s"
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds * 1e6:.3g} µs"


def read_candump_chunks(path: Path, layout: CandumpLayout = CandumpLayout()) -> Iterator[Chunk]:
    """Chunks of a candump log of the bridge's bus (see the module docstring)."""
    try:
        handle = path.open("rb")
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read it ({exc.strerror})", path=str(path)) from None
    with handle:
        lines = _WholeLines(handle)
        head: list[tuple[float, int, bytes]] = []
        sync_at = 0  # where the line of the last SYNC starts
        try:
            for at, line in lines:
                parsed = parse_line(line.decode("ascii"))
                if parsed is not None:
                    sync_at = at if parsed[1] == SYNC_COB_ID else sync_at
                    head.append(parsed)
                if len(head) >= 4000:
                    break
            decoder = Decoder(path, layout, layout.drive_id or find_drive(path, head))
            for frame in head:
                decoder.feed(*frame)
            for at, line in lines:
                parsed = parse_line(line.decode("ascii"))
                if parsed is None:
                    continue
                if parsed[1] == SYNC_COB_ID:
                    sync_at = at
                decoder.feed(*parsed)
                if len(decoder.rows) >= CHUNK_ROWS:
                    chunk = decoder.take()
                    if chunk is not None:
                        yield checked(chunk, path)
        except RecordingError:
            raise
        except (ValueError, UnicodeDecodeError) as exc:
            raise RecordingError(
                f"{path}: line {lines.lineno}: not a candump -l log line ({first_line(exc)})",
                path=str(path),
            ) from None
        chunk = decoder.take(final=True)
        if decoder.syncs == 0:
            raise RecordingError(f"{path}: candump log without SYNC frames (0x080)", path=str(path))
        size = lines.size
        _warn_cut(path, sync_at if decoder.dropped_last else lines.torn, size)
        if chunk is not None:
            yield checked(chunk, path)


class _WholeLines:
    """(byte offset, line) of each whole line of a binary file; ``lineno``: the number of the
    line handed out last. A last line without its line end is not handed out: ``torn`` is
    where it starts, ``size`` the file's length once the lines are through."""

    def __init__(self, handle: BinaryIO) -> None:
        self._handle = handle
        self.torn: int | None = None
        self.size = 0
        self.lineno = 0

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        return self

    def __next__(self) -> tuple[int, bytes]:
        line = self._handle.readline()
        at = self.size
        self.size += len(line)
        if not line:
            raise StopIteration
        if not line.endswith(b"\n"):
            self.torn = at
            raise StopIteration
        self.lineno += 1
        return at, line


def _warn_cut(path: Path, start: int | None, size: int) -> None:
    """The one warning about the tail a cut left (nothing when ``start`` is None)."""
    if start is None or start >= size:
        return
    warnings.warn(
        f"{path}: the last {size - start} bytes (from byte {start}) are a SYNC cycle or a line "
        "the log was cut inside (a writer stopped mid-write): dropped, every whole cycle "
        "before it is read",
        TornTailWarning,
        stacklevel=3,
    )

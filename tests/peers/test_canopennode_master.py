"""CANopenNode (an industrial C stack, ``canopend``) as the master on vcan0, through its
CiA 309-3 ASCII gateway, against the simulated drive (its own process) and the bridge node:

* every object of each EDS read; every writable object written in range, out of range and
  with wrong lengths; absent objects and sub-indices: the abort codes CANopenNode reports equal
  CiA 301 as the project's oracle (``tests/sdo_oracle.py``) and the EDS-only predictor
  (``eds_predict``, which also reads the rules the Descriptions state) have them;
* seeded random writes through the gateway: every answer predicted from the EDS alone;
* NMT start / stop / pre-operational, seen by CANopenNode's heartbeat consumer for both nodes;
  no SDO answer in Stopped (CiA 301 table 46);
* an EMCY of a drive fault decoded by CANopenNode with the error register 1001h shows, and
  the error reset EMCY (0000h) when the fault is reset.
"""

from __future__ import annotations

import struct
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

import tests.sdo_oracle as oracle
from bridge.node import Bridge
from tests.peers import canopennode as cn
from tests.peers import eds_predict as ep
from tests.peers.peers_common import BRIDGE_EDS, BRIDGE_ID, DRIVE_EDS, DRIVE_ID, GATEWAY_ID
from virtual_bus import BusConfig, Interface, open_bus

pytestmark = pytest.mark.vcan

#: Random writes per node through the gateway (each also reads what its rules need).
GATEWAY_RANDOM_WRITES = 3000
#: Heartbeat consumer time CANopenNode is given for both nodes, ms (5 heartbeats of 100 ms).
CONSUMER_MS = 500
HEARTBEAT_MS = 100


@dataclass
class Peer:
    """One node as the tests see it through the gateway."""

    node_id: int
    eds: Path
    gw: cn.Gateway

    def read(self, index: int, sub: int) -> bytes:
        answer = self.gw.read(self.node_id, index, sub)
        assert answer.ok, f"{index:04X}h:{sub:02X}: {answer.text}"
        return answer.data

    def write(self, index: int, sub: int, data: bytes) -> int | None:
        answer = self.gw.write(self.node_id, index, sub, data)
        if answer.ok:
            return None
        assert answer.abort is not None, f"{index:04X}h:{sub:02X}: {answer.text}"
        return answer.abort


def heartbeat_seen(gw: cn.Gateway, node: int, state: str, start: int = 0) -> str:
    return gw.wait_log(
        lambda line: f"Remote node ID = 0x{node:02X}" in line and f'"{state}"' in line, start
    )


def consume(gw: cn.Gateway, slot: int, node: int) -> None:
    """CANopenNode's heartbeat consumer ``slot`` (1016h:slot) watches ``node``."""
    assert gw.write(GATEWAY_ID, 0x1016, slot, ((node << 16) | CONSUMER_MS).to_bytes(4, "little")).ok


@pytest.fixture
def gateway(canopennode: cn.Binaries) -> Iterator[cn.Gateway]:
    with cn.gateway(canopennode, GATEWAY_ID) as gw:
        consume(gw, 1, BRIDGE_ID)
        consume(gw, 2, DRIVE_ID)
        yield gw


@pytest.fixture
def drive(gateway: cn.Gateway, drive_process: subprocess.Popen) -> Peer:
    heartbeat_seen(gateway, DRIVE_ID, "pre-operational")  # its boot-up, then heartbeats
    return Peer(DRIVE_ID, DRIVE_EDS, gateway)


@pytest.fixture
def bridge(gateway: cn.Gateway, bridge_on_vcan: Bridge) -> Peer:
    peer = Peer(BRIDGE_ID, BRIDGE_EDS, gateway)
    assert peer.write(0x1017, 0, HEARTBEAT_MS.to_bytes(2, "little")) is None
    heartbeat_seen(gateway, BRIDGE_ID, "operational")
    return peer


@pytest.fixture(params=["drive", "bridge"])
def peer(request: pytest.FixtureRequest) -> Peer:
    return request.getfixturevalue(request.param)


def _check(peer: Peer, index: int, sub: int, data: bytes, where: str) -> int | None:
    """Write; the answer must be the project oracle's and the EDS predictor's."""
    od = oracle.read_eds(peer.eds, peer.node_id)
    eds = ep.Eds(peer.eds, peer.node_id)
    predicted = ep.predict(eds, index, sub, data, peer.read)
    want = oracle.expected(od, index, sub, data)
    got = peer.write(index, sub, data)
    if want == oracle.APPLICATION:
        assert got is None or got in oracle.APPLICATION_CODES, f"{where}: 0x{got:08X}"
    else:
        assert got == want, f"{where}: CiA 301 0x{want:08X}, CANopenNode reports {got}"
    assert got == predicted, f"{where}: predicted {predicted}, CANopenNode reports {got}"
    return got


# --- reads -----------------------------------------------------------------------------------
def test_every_object_of_the_eds_reads(peer: Peer) -> None:
    eds = ep.Eds(peer.eds, peer.node_id)
    read = 0
    for (index, sub), obj in sorted(eds.objects.items()):
        answer = peer.gw.read(peer.node_id, index, sub)
        where = f"{index:04X}h:{sub:02X}"
        if obj.access == "wo":
            assert answer.abort == oracle.WRITE_ONLY, f"{where}: {answer.text}"
            continue
        assert answer.ok, f"{where}: {answer.text}"
        if obj.size is not None:
            assert len(answer.data) == obj.size, f"{where}: {answer.text}"
        read += 1
    assert read == sum(o.access != "wo" for o in eds.objects.values()) > 40


# --- writes ----------------------------------------------------------------------------------
def _lengths_and_limits(obj: ep.Obj, present: bytes) -> Iterator[tuple[str, bytes]]:
    yield "present value", present
    size = obj.size or len(present)
    for length in sorted({max(1, size - 1), size + 1, 5, 8} - {size}):
        yield f"{length} bytes", (present + bytes(8))[:length]
    if obj.size is None or obj.data_type not in oracle.TYPES:
        return
    if isinstance(obj.low, int) and obj.low > ep._type_range(obj)[0]:
        yield "LowLimit - 1", obj.encode(obj.low - 1)
    if isinstance(obj.high, int) and obj.high < ep._type_range(obj)[1]:
        yield "HighLimit + 1", obj.encode(obj.high + 1)
    if isinstance(obj.low, float):
        yield "below LowLimit", obj.encode(obj.low - abs(obj.low) - 1.0)
        yield "NaN", obj.encode(float("nan"))
    if isinstance(obj.high, float):
        yield "above HighLimit", obj.encode(obj.high + abs(obj.high) + 1.0)


def test_every_writable_object_in_range_out_of_range_wrong_lengths(peer: Peer) -> None:
    eds = ep.Eds(peer.eds, peer.node_id)
    checked = 0
    for obj in eds.writable:
        present = peer.read(obj.index, obj.sub) if obj.access != "wo" else bytes(obj.size or 1)
        for what, data in _lengths_and_limits(obj, present):
            _check(peer, obj.index, obj.sub, data, f"{obj.index:04X}h:{obj.sub:02X} {what}")
            checked += 1
    assert checked >= 4 * len(eds.writable)


def test_absent_objects_and_subindices(peer: Peer) -> None:
    eds = ep.Eds(peer.eds, peer.node_id)
    for index in (0x1FFF, 0x2FFF, 0x5FFF, 0x9000):
        assert index not in eds.indices
        assert peer.gw.read(peer.node_id, index, 0).abort == oracle.NO_OBJECT
        _check(peer, index, 0, b"\x00", f"{index:04X}h")
    for index in sorted(eds.indices):
        subs = {s for i, s in eds.objects if i == index}
        for sub in sorted({1, 2, 0x7F, 0xFF} - subs):
            where = f"{index:04X}h:{sub:02X}"
            assert peer.gw.read(peer.node_id, index, sub).abort == oracle.NO_SUBINDEX, where
            _check(peer, index, sub, b"\x01\x00", where)


def test_random_writes_answer_as_the_eds_predicts(peer: Peer) -> None:
    eds = ep.Eds(peer.eds, peer.node_id)
    tally = ep.random_writes(
        eds,
        peer.write,
        peer.read,
        GATEWAY_RANDOM_WRITES,
        seed=21,
        lengths=range(1, 9),  # the gateway cannot send an empty download
    )
    assert tally.unpredicted == [], "\n".join(tally.unpredicted[:20])
    assert tally.answers.get(None, 0) > GATEWAY_RANDOM_WRITES // 10


# --- NMT and heartbeat -----------------------------------------------------------------------
def _timed_read(peer: Peer) -> float:
    """How long one SDO upload of the node takes now (s): the test's own measure."""
    started = time.monotonic()
    peer.read(0x1000, 0)
    return time.monotonic() - started


#: A node silent in Stopped is given this many times its slowest answer of the test (at least
#: :data:`SILENT_MIN_MS`): sized from what the test measures, not a fixed time-out a busy
#: machine can outlast.
SILENT_FACTOR = 20
SILENT_MIN_MS = 500


def _sdo_answers(gw: cn.Gateway, node: int, expect: bool, slowest_s: list[float]) -> bool:
    """Whether the node answers an SDO upload. Where an answer is expected, the gateway's long
    time-out (a busy machine may answer late, the answer counts); where silence is expected,
    :data:`SILENT_FACTOR` times the slowest answer measured so far in ``slowest_s``."""
    if expect:
        started = time.monotonic()
        answer = gw.read(node, 0x1000, 0)
        slowest_s.append(time.monotonic() - started)
    else:
        wait_ms = max(SILENT_MIN_MS, round(SILENT_FACTOR * 1e3 * max(slowest_s, default=0.0)))
        assert gw.command(f"set sdo_timeout {wait_ms}").ok
        try:
            answer = gw.read(node, 0x1000, 0)
        finally:
            assert gw.command(f"set sdo_timeout {cn.SDO_TIMEOUT_MS}").ok
    assert answer.ok or answer.abort == 0x0504_0000, answer.text  # data or time-out
    return answer.ok


def test_nmt_stop_preop_start_seen_by_the_heartbeat_consumer(peer: Peer) -> None:
    """Each command changes the state (the drive boots pre-operational, the bridge is
    operational): CANopenNode's consumer logs each change; no SDO in Stopped."""
    slowest: list[float] = [_timed_read(peer)]
    for command, state in (
        ("stop", "stopped"),
        ("preop", "pre-operational"),
        ("start", "operational"),
    ):
        start = len(peer.gw.log)
        assert peer.gw.nmt(peer.node_id, command).ok
        heartbeat_seen(peer.gw, peer.node_id, state, start)
        answers = state != "stopped"
        assert _sdo_answers(peer.gw, peer.node_id, answers, slowest) is answers, state


def test_heartbeat_consumer_sees_both_nodes(drive: Peer, bridge: Peer) -> None:
    states = drive.gw.heartbeat_states()
    assert (DRIVE_ID, "pre-operational") in states
    assert (BRIDGE_ID, "operational") in states
    # node 0: all nodes at once, canopend too (its consumer pauses while it is Stopped itself,
    # so the broadcast goes pre-operational -> operational)
    start = len(drive.gw.log)
    assert drive.gw.nmt(0, "preop").ok
    heartbeat_seen(drive.gw, BRIDGE_ID, "pre-operational", start)
    start = len(drive.gw.log)
    assert drive.gw.nmt(0, "start").ok
    heartbeat_seen(drive.gw, DRIVE_ID, "operational", start)
    heartbeat_seen(drive.gw, BRIDGE_ID, "operational", start)


# --- EMCY ------------------------------------------------------------------------------------
SYNC_PERIOD_US = 10_000


def test_emcy_of_a_drive_fault_decoded_by_canopennode(drive: Peer) -> None:
    """CANopenNode produces SYNC (its own 1005h/1006h); the drive in Operation enabled gets no
    RPDO for 3 SYNCs (2102h), faults (6007h = 1) and sends EMCY 8250h; CANopenNode decodes it
    with the error register the drive's 1001h shows. An RPDO with fault reset (a frame from
    this process) clears it: the error reset EMCY 0000h with 1001h = 0."""
    gw = drive.gw
    assert drive.write(0x6007, 0, (1).to_bytes(2, "little")) is None  # fault on time-out
    assert drive.write(0x2102, 0, bytes([3])) is None
    start = len(gw.log)
    assert gw.nmt(DRIVE_ID, "start").ok
    heartbeat_seen(gw, DRIVE_ID, "operational", start)
    for controlword in (0x06, 0x07, 0x0F):  # CiA 402: shutdown, switch on, enable operation
        assert drive.write(0x6040, 0, controlword.to_bytes(2, "little")) is None
    assert int.from_bytes(drive.read(0x6041, 0), "little") & 0x6F == 0x27  # operation enabled
    start = len(gw.log)
    own = GATEWAY_ID
    assert gw.write(own, 0x1006, 0, SYNC_PERIOD_US.to_bytes(4, "little")).ok
    assert gw.write(own, 0x1005, 0, (0x4000_0080).to_bytes(4, "little")).ok  # produce SYNC
    try:
        gw.wait_log(lambda line: "Emergency message from node 0x02" in line, start)
        (emcy,) = [e for e in gw.emcys(start) if e.node == DRIVE_ID]
        assert emcy.code == 0x8250
        assert emcy.register == drive.read(0x1001, 0)[0] == 0x11  # generic + communication
        assert int.from_bytes(drive.read(0x603F, 0), "little") == 0x8250
        start = len(gw.log)
        bus = open_bus(BusConfig(interface=Interface.SOCKETCAN, channel="vcan0"))
        try:  # RPDO1 of the drive: controlword 0080h (fault reset), target velocity 0
            bus.send(can.Message(arbitration_id=0x202, data=struct.pack("<Hi", 0x80, 0),
                                 is_extended_id=False))  # fmt: skip
            gw.wait_log(lambda line: "node 0x02: errorCode=0x0000" in line, start)
        finally:
            bus.shutdown()
        (reset,) = [e for e in gw.emcys(start) if e.node == DRIVE_ID]
        assert (reset.code, reset.register) == (0x0000, drive.read(0x1001, 0)[0]) == (0, 0)
    finally:
        assert gw.write(own, 0x1005, 0, (0x80).to_bytes(4, "little")).ok  # SYNC off

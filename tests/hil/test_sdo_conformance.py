"""Both SDO servers (the bridge's, the simulated drive's) against python canopen's own SDO
client and an oracle derived from the EDS files alone (tests/sdo_oracle.py).

* every declared object written with every length 0..8, expedited and segmented: the abort
  code is the oracle's; a refused write changes nothing;
* 10,000 seeded random writes per node (about 2-4 s each): the CiA 301 code every time,
  and nothing changed by a refusal;
* block upload (canopen's BlockUploadStream, with CRC) returns what a normal upload does;
* protocol errors: toggle bit, unknown command specifier, block download.
"""

from __future__ import annotations

import copy
import random
import uuid
from collections.abc import Callable, Iterator

import can
import pytest
from canopen.sdo import SdoAbortedError, SdoClient

import tests.sdo_oracle as oracle  # tests/ helper module
from bridge import od as objdict
from plant_sim.drive.od import DEFAULT_EDS_PATH as DRIVE_EDS
from plant_sim.drive.rig import virtual_rig
from tests.bridge_helpers import idle_bridge, sdo_tool
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")
BRIDGE_OD = oracle.read_eds(objdict.DEFAULT_EDS_PATH, 1)
DRIVE_OD = oracle.read_eds(DRIVE_EDS, 2)
RANDOM_WRITES = 10_000
TIMEOUT_S = 10.0  # the machine is shared: a generous bound, never reached when all is well


def write(sdo: SdoClient, index: int, sub: int, data: bytes, segmented: bool) -> int | None:
    """Download; the abort code or None."""
    try:
        sdo.download(index, sub, data, force_segment=segmented)
    except SdoAbortedError as exc:
        return exc.code
    return None


def read(sdo: SdoClient, index: int, sub: int) -> bytes | int:
    try:
        return sdo.upload(index, sub)
    except SdoAbortedError as exc:
        return exc.code


def check(want: int, got: int | None, where: str) -> None:
    if want == oracle.APPLICATION:
        assert got is None or got in oracle.APPLICATION_CODES, f"{where}: 0x{got:08X}"
    else:
        assert got == want, f"{where}: want 0x{want:08X}, got {got if got is None else hex(got)}"


# --- the two servers --------------------------------------------------------------------------
@pytest.fixture
def bridge_server() -> Iterator[tuple]:
    channel = f"sdo-{uuid.uuid4().hex[:12]}"
    bridge_bus = can.Bus(interface="virtual", channel=channel)
    tool_bus = can.Bus(interface="virtual", channel=channel)
    try:
        with idle_bridge(bridge_bus) as b, sdo_tool(tool_bus, TIMEOUT_S) as tool:

            def snapshot() -> object:
                c = b.controller
                data = copy.deepcopy(b.node.data_store)
                return (c.params, c.state, b.objects._last_target, data)

            yield tool.sdo, BRIDGE_OD, snapshot
    finally:
        bridge_bus.shutdown()
        tool_bus.shutdown()


@pytest.fixture
def drive_server() -> Iterator[tuple]:
    with virtual_rig(AXIS) as rig:
        sdo = rig.sdo.sdo
        sdo.RESPONSE_TIMEOUT = TIMEOUT_S
        drive = rig.drive

        def snapshot() -> object:
            return (dict(drive._table._values), drive.state, drive.nmt_state)

        yield sdo, DRIVE_OD, snapshot


@pytest.fixture(params=["bridge", "drive"])
def server(request: pytest.FixtureRequest) -> tuple[SdoClient, dict, Callable[[], object]]:
    return request.getfixturevalue(f"{request.param}_server")


# --- every object, every length -----------------------------------------------------------------
def test_every_object_every_length(server: tuple) -> None:
    sdo, od, snapshot = server
    for (index, sub), obj in sorted(od.items()):
        current = read(sdo, index, sub)
        if obj.access == "wo":
            assert current == oracle.WRITE_ONLY
            current = bytes(obj.size or 1)  # 2020h: 0 = idle
        assert isinstance(current, bytes), f"{index:04X}h:{sub:02X}: upload aborted {current}"
        for length in range(9):
            data = (current + bytes(8))[:length] if length != obj.size else current
            for segmented in (False, True) if 1 <= length <= 4 else (True,):
                where = f"{index:04X}h:{sub:02X} {length} bytes {'seg' if segmented else 'exp'}"
                want = oracle.expected(od, index, sub, data)
                before = snapshot()
                got = write(sdo, index, sub, data, segmented)
                check(want, got, where)
                if got is not None:
                    assert snapshot() == before, f"{where}: refused but changed something"


def test_missing_objects_and_subindices(server: tuple) -> None:
    sdo, od, _ = server
    declared_indices = {i for i, _ in od}
    for index in (0x1FFF, 0x2FFF, 0x5FFF, 0x9000):
        assert index not in declared_indices
        assert read(sdo, index, 0) == oracle.NO_OBJECT
        assert write(sdo, index, 0, b"\x00", False) == oracle.NO_OBJECT
    for index in sorted(declared_indices):
        subs = {s for i, s in od if i == index}
        for sub in (1, 2, 0x7F, 0xFF):
            if sub not in subs:
                where = f"{index:04X}h:{sub:02X}"
                assert read(sdo, index, sub) == oracle.NO_SUBINDEX, where
                assert write(sdo, index, sub, b"\x01\x00", False) == oracle.NO_SUBINDEX, where


# --- random writes --------------------------------------------------------------------------------
def test_random_writes_get_the_cia301_code_and_refusals_change_nothing(server: tuple) -> None:
    sdo, od, snapshot = server
    rng = random.Random(20261123)
    keys = sorted(od)
    indices = [*sorted({i for i, _ in keys}), 0x2FFF, 0x5000]
    codes: dict[int | None, int] = {}
    for n in range(RANDOM_WRITES):
        if rng.random() < 0.8:
            index, sub = rng.choice(keys)
        else:
            index, sub = rng.choice(indices), rng.randrange(256)
        length = rng.randrange(9)
        data = rng.randbytes(length)
        segmented = not 1 <= length <= 4 or rng.random() < 0.3
        want = oracle.expected(od, index, sub, data)
        before = snapshot()
        got = write(sdo, index, sub, data, segmented)
        check(want, got, f"write {n}: {index:04X}h:{sub:02X} = {data.hex()}")
        if got is not None:
            assert snapshot() == before, f"write {n}: refused but changed something"
        codes[got] = codes.get(got, 0) + 1
    # the random writes reach every kind of answer
    for code in (None, oracle.NO_OBJECT, oracle.NO_SUBINDEX, oracle.READ_ONLY):
        assert codes.get(code), f"no write answered {code}"
    assert codes.get(oracle.LENGTH_TOO_HIGH) and codes.get(oracle.LENGTH_TOO_LOW)


# --- block upload and protocol errors -----------------------------------------------------------
def test_block_upload_returns_what_a_normal_upload_does(server: tuple) -> None:
    sdo, od, _ = server
    blocks = 0
    for (index, sub), obj in sorted(od.items()):
        if obj.access == "wo":
            continue
        plain = sdo.upload(index, sub)
        for crc in (True, False):
            with sdo.open(index, sub, "rb", block_transfer=True, request_crc_support=crc) as f:
                data = f.read()
            assert bytes(data) == plain, f"{index:04X}h:{sub:02X}"
            blocks += 1
    assert blocks > 10


def test_block_upload_of_a_write_only_object_and_block_download(server: tuple) -> None:
    sdo, od, _ = server
    wo = [key for key, obj in od.items() if obj.access == "wo"]
    for index, sub in wo:
        with pytest.raises(SdoAbortedError) as info:
            sdo.open(index, sub, "rb", block_transfer=True)
        assert info.value.code == oracle.WRITE_ONLY
    index, sub = next(key for key, obj in sorted(od.items()) if obj.access == "rw")
    with (
        pytest.raises(SdoAbortedError) as info,
        sdo.open(index, sub, "wb", size=4, block_transfer=True) as f,
    ):
        f.write(b"\x00\x00\x00\x00")
    assert info.value.code == 0x0504_0001  # block download: command specifier not valid


def test_toggle_bit_and_unknown_command(server: tuple) -> None:
    sdo, od, _ = server
    index, sub = next(k for k, o in sorted(od.items()) if o.data_type == oracle.VISIBLE_STRING)
    first = sdo.request_response(bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))
    assert first[0] & 0xE3 == 0x41  # segmented upload initiated
    with pytest.raises(SdoAbortedError) as info:
        sdo.request_response(bytes([0x70]) + bytes(7))  # toggle 1 where 0 is due
    assert info.value.code == 0x0503_0000
    with pytest.raises(SdoAbortedError) as info:
        sdo.request_response(bytes([0xE0]) + bytes(7))  # ccs 7 does not exist
    assert info.value.code == 0x0504_0001
    with pytest.raises(SdoAbortedError) as info:
        sdo.request_response(bytes([0x60]) + bytes(7))  # upload segment, no transfer open
    assert info.value.code == 0x0504_0001

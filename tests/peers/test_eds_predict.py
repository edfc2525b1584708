"""Every SDO answer of the bridge and the drive predicted from their EDS files alone
(``eds_predict``: configparser, CiA 301, the rules the Descriptions state), through python
canopen's SDO client on python-can's virtual bus: seeded random writes (any object, any length,
values in and outside the limits, rule constants, mapping entries, toggled COB-ID bits, NaN)
and 0 answers the EDS does not predict. The same check through CANopenNode's gateway on vcan0
is in ``test_canopennode_master.py``.
"""

from __future__ import annotations

import re
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoClient

import tests.sdo_oracle as oracle  # also works around a canopen client bug
from bridge import od as objdict
from plant_sim.drive.rig import virtual_rig
from tests.bridge_helpers import idle_bridge, sdo_tool
from tests.peers import eds_predict as ep
from tests.peers.peers_common import AXIS_FILE, BRIDGE_EDS, BRIDGE_ID, DRIVE_EDS, DRIVE_ID
from virtual_bus.formats.axis import load_axis

RANDOM_WRITES = 10_000
TIMEOUT_S = 10.0  # a bound for a stuck server, never reached when all is well
AXIS = load_axis(AXIS_FILE)


def _client(sdo: SdoClient) -> tuple:
    def write(index: int, sub: int, data: bytes) -> int | None:
        try:
            sdo.download(index, sub, data, force_segment=not 1 <= len(data) <= 4)
        except SdoAbortedError as exc:
            return exc.code
        return None

    def read(index: int, sub: int) -> bytes:
        return bytes(sdo.upload(index, sub))

    return write, read


@pytest.fixture
def bridge_client(tmp_path: Path) -> Iterator[tuple]:
    channel = f"pred-{uuid.uuid4().hex[:10]}"
    bridge_bus = can.Bus(interface="virtual", channel=channel)
    tool_bus = can.Bus(interface="virtual", channel=channel)
    try:
        with idle_bridge(bridge_bus, tmp_path / "store.json"), sdo_tool(tool_bus) as tool:
            tool.sdo.RESPONSE_TIMEOUT = TIMEOUT_S
            yield _client(tool.sdo)
    finally:
        bridge_bus.shutdown()
        tool_bus.shutdown()


@pytest.fixture
def drive_client() -> Iterator[tuple]:
    with virtual_rig(AXIS, node_id=DRIVE_ID) as rig:
        sdo = rig.sdo.sdo
        sdo.RESPONSE_TIMEOUT = TIMEOUT_S
        yield _client(sdo)


def _codes_of_rules(eds: ep.Eds) -> set[int]:
    return {r.code for o in eds.objects.values() for r in o.rules if r.code is not None}


@pytest.mark.parametrize(
    ("node", "eds_path", "node_id"),
    [("bridge", BRIDGE_EDS, BRIDGE_ID), ("drive", DRIVE_EDS, DRIVE_ID)],
)
def test_random_writes_answer_as_the_eds_alone_predicts(
    request: pytest.FixtureRequest, node: str, eds_path: Path, node_id: int
) -> None:
    write, read = request.getfixturevalue(f"{node}_client")
    eds = ep.Eds(eds_path, node_id)
    tally = ep.random_writes(eds, write, read, RANDOM_WRITES, seed=20260421)
    assert tally.unpredicted == [], f"{len(tally.unpredicted)} unpredicted:\n" + "\n".join(
        tally.unpredicted[:30]
    )
    # the writes reached every code the rules name, the CiA 301 checks and successes
    reached = set(tally.answers)
    assert _codes_of_rules(eds) <= reached
    cia301 = (oracle.NO_OBJECT, oracle.NO_SUBINDEX, oracle.READ_ONLY, oracle.LENGTH_TOO_HIGH)
    for code in (None, *cia301):
        assert code in reached, hex(code or 0)
    assert len(tally.written) > 20


def test_the_check_finds_an_answer_the_eds_does_not_state(
    bridge_client: tuple, tmp_path: Path
) -> None:
    """Without the 2014h rules (the EDS before issue 21) the same writes are unpredictable."""
    text = BRIDGE_EDS.read_text(encoding="utf-8")
    blind = tmp_path / "bridge.eds"
    blind.write_text(re.sub(r" \[requires value [<>] 2014h:0[12] else 0609 003[12]\]", "", text))
    write, read = bridge_client
    tally = ep.random_writes(ep.Eds(blind, BRIDGE_ID), write, read, 3000, seed=20260421)
    assert tally.unpredicted
    assert all(line.startswith("2014h") for line in tally.unpredicted)


def test_bridge_od_keeps_the_real32_limits_python_canopen_drops() -> None:
    """python canopen 2.4 parses LowLimit/HighLimit with int(): REAL32 limits are lost on
    import; the bridge's load_od reads them itself (its SDO server enforces them)."""
    plain = canopen.import_od(str(BRIDGE_EDS), BRIDGE_ID)
    assert plain[objdict.KV].min in (None, objdict.SMALLEST_REAL32)  # None with canopen 2.4
    ours = objdict.load_od()
    assert (ours[objdict.KV].min, ours[objdict.KV].max) == (objdict.SMALLEST_REAL32, 1000.0)

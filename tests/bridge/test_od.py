"""config/bridge.eds and the bridge's SDO server: every declared object exists and behaves in
the running node, every refused write gets its CiA 301 abort code and changes nothing.

A CANopen "tool" (canopen RemoteNode with the EDS, on the other end of the bus) talks to the
bridge's LocalNode while the bridge's service thread feeds it frames.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator

import can
import canopen
import pytest
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary import datatypes as dt

import tests.sdo_oracle as sdo_oracle  # noqa: F401  (tests/ helper: works around a canopen client bug)
from bridge import od as objdict
from bridge.cycle import BridgeState, Command
from bridge.eds import render_eds
from bridge.errors import SdoAbort
from bridge.layout import TPDO1_STRUCT, TPDO2_STRUCT
from bridge.node import Bridge
from tests.bridge_helpers import abort_code, idle_bridge, sdo_tool  # tests/ helper module
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")
STRUCTS = {
    dt.BOOLEAN: "<B",
    dt.UNSIGNED8: "<B",
    dt.UNSIGNED16: "<H",
    dt.UNSIGNED32: "<I",
    dt.INTEGER32: "<i",
    dt.REAL32: "<f",
}


def all_variables(od: canopen.ObjectDictionary) -> list[ODVariable]:
    out = []
    for index in od:
        obj = od[index]
        if isinstance(obj, ODVariable):
            out.append(obj)
        else:
            out.extend(obj[sub] for sub in obj)
    return out


@pytest.fixture
def bridge(bus_pair: tuple[can.BusABC, can.BusABC]) -> Iterator[Bridge]:
    with idle_bridge(bus_pair[0]) as b:  # no drive on this bus
        yield b


@pytest.fixture
def tool(bus_pair: tuple[can.BusABC, can.BusABC]) -> Iterator[canopen.RemoteNode]:
    with sdo_tool(bus_pair[1]) as node:
        yield node


def enter_running(b: Bridge) -> None:
    """Through the controller as the loop would: ENABLE, then a cycle whose TPDO2 shows
    Operation Enabled."""
    b.controller.command(Command.ENABLE)
    b.controller.step(0.0, TPDO1_STRUCT.pack(0, 0), TPDO2_STRUCT.pack(0x0027, 0, 0))
    assert b.controller.state is BridgeState.RUNNING


# --- the file -------------------------------------------------------------------------------
def test_committed_eds_is_the_rendering_of_the_object_table() -> None:
    assert objdict.DEFAULT_EDS_PATH.read_text(encoding="utf-8") == render_eds()


def test_eds_imports_and_declares_the_table() -> None:
    od = canopen.import_od(str(objdict.DEFAULT_EDS_PATH), 1)
    declared = {(v.index, v.subindex): v for v in all_variables(od)}
    for entry in objdict.entries():
        var = declared[(entry.index, entry.subindex)]
        assert var.data_type == entry.data_type, entry.name
        assert var.access_type == entry.access.value, entry.name
        assert var.default == entry.default, entry.name
    groups = [o for o in objdict.OBJECTS if isinstance(o, objdict.Group)]
    for group in groups:
        assert declared[(group.index, 0)].default == len(group.members)
    # manufacturer objects lie in 2000h-5FFFh
    assert all(0x2000 <= e.index <= 0x5FFF or e.index < 0x2000 for e in objdict.entries())
    assert any(e.index >= 0x2000 for e in objdict.entries())


# --- every object in the running node -----------------------------------------------------
def test_every_declared_object_behaves_in_the_running_node(
    bridge: Bridge, tool: canopen.RemoteNode
) -> None:
    od = canopen.import_od(str(objdict.DEFAULT_EDS_PATH), 1)
    for var in all_variables(od):
        index, sub = var.index, var.subindex
        where = f"{index:04X}h:{sub:02X} {var.name}"
        if var.access_type == "wo":
            assert abort_code(lambda i=index, s=sub: tool.sdo.upload(i, s)) == 0x0601_0001, where
            continue
        raw = tool.sdo.upload(index, sub)
        if var.data_type == dt.VISIBLE_STRING:
            assert raw.decode("ascii"), where
        else:
            assert len(raw) == struct.calcsize(STRUCTS[var.data_type]), where
        if var.access_type in ("ro", "const"):
            assert abort_code(lambda i=index, s=sub, r=raw: tool.sdo.download(i, s, r)) == (
                0x0601_0002
            ), where
        elif index in (objdict.STORE_PARAMETERS, objdict.RESTORE_DEFAULTS):
            # CiA 301: only the signature is accepted (tests/bridge/test_store.py)
            code = abort_code(lambda i=index, s=sub, r=raw: tool.sdo.download(i, s, r))
            assert code == SdoAbort.NOT_STORED, where
        elif index != objdict.TARGET:  # writing a target starts a move (below)
            tool.sdo.download(index, sub, raw)  # the current value back: accepted
            assert tool.sdo.upload(index, sub) == raw, where


def test_reads_show_the_running_values(bridge: Bridge, tool: canopen.RemoteNode) -> None:
    def real(index: int) -> float:
        return struct.unpack("<f", tool.sdo.upload(index, 0))[0]

    assert real(objdict.KV) == 25.0
    assert real(objdict.KR) == pytest.approx(AXIS.transmission_ratio, rel=1e-7)
    assert struct.unpack("<I", tool.sdo.upload(objdict.CYCLE_PERIOD, 0))[0] == 1000
    assert tool.sdo.upload(objdict.STATE, 0)[0] == BridgeState.DISABLED.value
    hb = struct.unpack("<I", tool.sdo.upload(objdict.HEARTBEAT_CONSUMER, 1))[0]
    assert hb == (2 << 16) | 250
    assert tool.sdo.upload(objdict.STOP_MESSAGE, 0) == b"none"
    assert tool.sdo.upload(objdict.DEVICE_NAME, 0) == b"backlash-bridge"


def test_valid_writes_take_effect(bridge: Bridge, tool: canopen.RemoteNode) -> None:
    c = bridge.controller
    tool.sdo.download(objdict.KV, 0, struct.pack("<f", 30.0))
    tool.sdo.download(objdict.BETA_T, 0, struct.pack("<f", 0.5))
    tool.sdo.download(objdict.TV, 0, struct.pack("<f", 2.0))
    tool.sdo.download(objdict.REG_ENABLE, 0, b"\x00")
    tool.sdo.download(objdict.CYCLE_PERIOD, 0, struct.pack("<I", 500))
    reg = c.regulator_config
    assert (reg.kv, reg.beta_t_rad_s, reg.tv_s, reg.enabled, reg.cycle_s) == (
        30.0,
        0.5,
        2.0,
        False,
        0.0005,
    )
    assert c.params.kv_per_s == 30.0
    tool.sdo.download(objdict.TV, 0, struct.pack("<f", 0.0))  # 0: eq. 14 default
    assert c.regulator_config.tv_s is None
    tool.sdo.download(objdict.HEARTBEAT_CONSUMER, 1, struct.pack("<I", (2 << 16) | 400))
    assert c.params.heartbeat_consumer_ms == 400
    tool.sdo.download(objdict.FEED, 0, struct.pack("<I", 20_000_000))  # 20 mm/s in nm/s
    assert c.params.feed == pytest.approx(0.02)
    tool.sdo.download(objdict.COMMAND, 0, bytes([Command.ENABLE]))
    assert c.state is BridgeState.ENABLING


def test_target_position_starts_a_move_while_running(
    bridge: Bridge, tool: canopen.RemoteNode
) -> None:
    enter_running(bridge)
    assert tool.sdo.upload(objdict.MOVE_STATUS, 0) == b"\x00"
    tool.sdo.download(objdict.TARGET, 0, struct.pack("<i", 1_000_000))  # 1 mm
    assert tool.sdo.upload(objdict.MOVE_STATUS, 0) == b"\x01"
    assert struct.unpack("<i", tool.sdo.upload(objdict.TARGET, 0))[0] == 1_000_000
    # a second target while the first move runs: device state
    code = abort_code(lambda: tool.sdo.download(objdict.TARGET, 0, struct.pack("<i", 0)))
    assert code == SdoAbort.DEVICE_STATE


F = struct.Struct("<f")
REFUSED = [
    ("kv zero", objdict.KV, 0, F.pack(0.0), SdoAbort.TOO_LOW),
    ("kv huge", objdict.KV, 0, F.pack(5000.0), SdoAbort.TOO_HIGH),
    ("kv NaN", objdict.KV, 0, F.pack(math.nan), SdoAbort.VALUE_RANGE),
    ("kv breaks the sampling rule", objdict.KV, 0, F.pack(150.0), SdoAbort.TOO_HIGH),
    ("n zero", objdict.WINDOW_N, 0, b"\x00", SdoAbort.TOO_LOW),
    ("n breaks the sampling rule", objdict.WINDOW_N, 0, bytes([20]), SdoAbort.TOO_HIGH),
    ("T_v below eq. 14", objdict.TV, 0, F.pack(0.5), SdoAbort.TOO_LOW),
    ("T_f negative", objdict.TF, 0, F.pack(-1.0), SdoAbort.TOO_LOW),
    # +inf is above the EDS HighLimit (1e4), as a tool reading the EDS predicts
    ("beta_T inf", objdict.BETA_T, 0, F.pack(math.inf), SdoAbort.TOO_HIGH),
    ("enable = 2", objdict.REG_ENABLE, 0, b"\x02", SdoAbort.VALUE_RANGE),
    ("cycle 50 us", objdict.CYCLE_PERIOD, 0, struct.pack("<I", 50), SdoAbort.TOO_LOW),
    ("cycle 5 ms", objdict.CYCLE_PERIOD, 0, struct.pack("<I", 5000), SdoAbort.TOO_HIGH),
    (
        "heartbeat of node 5",
        objdict.HEARTBEAT_CONSUMER,
        1,
        struct.pack("<I", (5 << 16) | 100),
        SdoAbort.TOO_HIGH,  # above the EDS HighLimit 0x0002FFFF (drive node-ID 2)
    ),
    ("speed limit 0", objdict.SPEED_LIMIT, 0, F.pack(0.0), SdoAbort.TOO_LOW),
    (
        "feed above speed limit",
        objdict.FEED,
        0,
        struct.pack("<I", 2_000_000_000),
        SdoAbort.TOO_HIGH,
    ),
    ("command 7", objdict.COMMAND, 0, b"\x07", SdoAbort.TOO_HIGH),
    ("reset without a stop", objdict.COMMAND, 0, bytes([Command.RESET]), SdoAbort.DEVICE_STATE),
    ("target while disabled", objdict.TARGET, 0, struct.pack("<i", 5), SdoAbort.DEVICE_STATE),
    ("write read-only beta", objdict.BETA, 0, F.pack(1.0), SdoAbort.READ_ONLY),
    ("write const device type", objdict.DEVICE_TYPE, 0, b"\x00\x00\x00\x00", SdoAbort.READ_ONLY),
    ("no such object", 0x2FFF, 0, b"\x00", SdoAbort.NO_OBJECT),
    ("no such sub-index of a VAR", objdict.KV, 5, F.pack(1.0), SdoAbort.NO_SUBINDEX),
    ("no such sub-index of a RECORD", objdict.PDO_COUNTERS, 9, b"\x00", SdoAbort.NO_SUBINDEX),
    ("two bytes to a REAL32", objdict.KV, 0, b"\x00\x00", SdoAbort.LENGTH_TOO_LOW),
]


def _snapshot(b: Bridge, tool: canopen.RemoteNode) -> tuple[object, ...]:
    readable = [
        (v.index, v.subindex)
        for v in all_variables(objdict.load_od())
        if v.access_type != "wo" and v.index < 0x2100
    ]
    return (b.controller.params, b.controller.state, *(tool.sdo.upload(i, s) for i, s in readable))


@pytest.mark.parametrize(
    ("index", "sub", "data", "code"),
    [pytest.param(*case[1:], id=case[0]) for case in REFUSED],
)
def test_refused_writes_get_their_abort_code_and_change_nothing(
    bridge: Bridge, tool: canopen.RemoteNode, index: int, sub: int, data: bytes, code: SdoAbort
) -> None:
    before = _snapshot(bridge, tool)
    assert abort_code(lambda: tool.sdo.download(index, sub, data)) == code
    assert _snapshot(bridge, tool) == before


@pytest.mark.parametrize(
    ("index", "data"),
    [
        (objdict.KV, F.pack(25.0)),
        (objdict.REG_ENABLE, b"\x01"),
        (objdict.BETA_T, F.pack(0.2)),
        (objdict.WINDOW_N, b"\x04"),
        (objdict.TF, F.pack(0.05)),
        (objdict.KR, F.pack(314.0)),
        (objdict.CYCLE_PERIOD, struct.pack("<I", 1000)),
    ],
)
def test_locked_parameters_refuse_writes_while_the_axis_is_enabled(
    bridge: Bridge, tool: canopen.RemoteNode, index: int, data: bytes
) -> None:
    enter_running(bridge)
    before = _snapshot(bridge, tool)
    assert abort_code(lambda: tool.sdo.download(index, 0, data)) == SdoAbort.DEVICE_STATE
    assert _snapshot(bridge, tool) == before
    # limits may change while running
    tool.sdo.download(objdict.FE_LIMIT, 0, F.pack(0.004))
    assert bridge.controller.params.following_error_limit == pytest.approx(0.004)


def test_read_of_a_write_only_object(bridge: Bridge, tool: canopen.RemoteNode) -> None:
    assert abort_code(lambda: tool.sdo.upload(objdict.COMMAND, 0)) == SdoAbort.WRITE_ONLY

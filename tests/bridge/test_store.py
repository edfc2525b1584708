"""1010h store / 1011h restore of the bridge (CiA 301), driven by python-canopen's own SDO
client (``RemoteNode.sdo[...]`` with the bridge's EDS): store, restart the bridge on the same
file, read back; wrong signatures (0800 0020) change nothing; restore brings the axis file's
defaults back at the next start; a store file the bridge would refuse stops the start.
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from bridge.errors import SdoAbort, StoreError
from bridge.node import BridgeConfig
from bridge.store import ParameterStore
from tests.bridge.store_trials import NEW, OLD
from tests.bridge_helpers import (  # tests/ helper module
    abort_code,
    idle_bridge,
    paper_bridge,
    sdo_tool,
)
from tests.forking import Forker
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")
SAVE, LOAD = 0x65766173, 0x64616F6C


@pytest.fixture
def tool(bus_pair: tuple[can.BusABC, can.BusABC]) -> Iterator[canopen.RemoteNode]:
    with sdo_tool(bus_pair[1]) as node:
        yield node


def test_store_restart_and_read_back(
    bus_pair: tuple[can.BusABC, can.BusABC], tool: canopen.RemoteNode, tmp_path: Path
) -> None:
    store = tmp_path / "axis.bridge-store.json"
    sdo = tool.sdo
    with idle_bridge(bus_pair[0], store):
        assert sdo[0x1010][1].raw == 1  # saves on command (CiA 301 bit 0)
        assert sdo[0x1011][1].raw == 1
        sdo["Position gain kv"].raw = 30.0
        sdo["Software position limit"]["Max position limit"].raw = 0.25
        sdo["Consumer heartbeat time"][1].raw = (2 << 16) | 400
        sdo["Feed"].raw = 20_000_000
        sdo["Regulator enable"].raw = False
        sdo[0x1010][1].raw = SAVE
        assert store.is_file()
        assert [p.name for p in tmp_path.iterdir()] == [store.name]  # no temporary left
    # the values as a person reads them beside the raw ones; an edit there changes nothing
    doc = json.loads(store.read_text())
    readable = doc["readable"]
    assert readable["2000h:00"] == "Position gain kv = 30 1/s", readable
    assert readable["1016h:01"].endswith(" = node 2 within 400 ms"), readable
    assert set(readable) <= set(doc["objects"])
    assert all(" = " in text for text in readable.values())
    readable["2000h:00"] = "Position gain kv = 99 1/s"
    store.write_text(json.dumps(doc))
    with idle_bridge(bus_pair[0], store) as restarted:
        assert sdo["Position gain kv"].raw == 30.0
        assert sdo[0x2014][2].raw == pytest.approx(0.25)
        assert sdo[0x1016][1].raw == (2 << 16) | 400
        assert sdo["Feed"].raw == 20_000_000
        assert sdo["Regulator enable"].raw is False
        p = restarted.controller.params
        assert (p.kv_per_s, p.regulator_enabled, p.heartbeat_consumer_ms) == (30.0, False, 400)
        assert restarted.controller.regulator_config.kv == 30.0  # the regulator uses it
        # restore defaults: effective at the next start, not now
        sdo[0x1011][1].raw = LOAD
        assert sdo["Position gain kv"].raw == 30.0
        assert not store.exists()
    with idle_bridge(bus_pair[0], store):
        assert sdo["Position gain kv"].raw == 25.0
        assert sdo[0x2014][2].raw == 2.0
        assert sdo["Regulator enable"].raw is True


WRONG = [(0x1010, v) for v in (0, 1, LOAD, SAVE ^ 0x100)] + [
    (0x1011, v) for v in (0, 1, SAVE, LOAD ^ 0x100)
]


@pytest.mark.parametrize(("index", "value"), WRONG, ids=[f"{i:04X}h={v:#x}" for i, v in WRONG])
def test_wrong_signature_is_refused_and_changes_nothing(
    bus_pair: tuple[can.BusABC, can.BusABC],
    tool: canopen.RemoteNode,
    tmp_path: Path,
    index: int,
    value: int,
) -> None:
    store = tmp_path / "store.json"
    with idle_bridge(bus_pair[0], store):
        tool.sdo["Position gain kv"].raw = 30.0
        tool.sdo[0x1010][1].raw = SAVE
        before = store.read_bytes()
        tool.sdo["Position gain kv"].raw = 20.0
        code = abort_code(lambda: tool.sdo.download(index, 1, struct.pack("<I", value)))
        assert code == SdoAbort.NOT_STORED == 0x0800_0020
        assert store.read_bytes() == before


def test_without_a_store_file_the_bridge_says_so(
    bus_pair: tuple[can.BusABC, can.BusABC], tool: canopen.RemoteNode
) -> None:
    with idle_bridge(bus_pair[0], None):
        assert tool.sdo[0x1010][1].raw == 0  # does not save on command
        code = abort_code(lambda: tool.sdo.download(0x1010, 1, struct.pack("<I", SAVE)))
        assert code == SdoAbort.NOT_STORED


def test_unwritable_store_directory_is_a_hardware_abort(
    bus_pair: tuple[can.BusABC, can.BusABC], tool: canopen.RemoteNode, tmp_path: Path
) -> None:
    store = tmp_path / "missing-dir" / "store.json"
    with idle_bridge(bus_pair[0], store):
        code = abort_code(lambda: tool.sdo.download(0x1010, 1, struct.pack("<I", SAVE)))
        assert code == SdoAbort.HARDWARE == 0x0606_0000


def _stored(tmp_path: Path, objects: dict[str, str]) -> Path:
    path = tmp_path / "store.json"
    doc = {"format": "backlash-bridge parameter store", "version": 1, "objects": objects}
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        ("{not json", "invalid JSON"),
        ('{"format": "x", "version": 1, "objects": {}}', "not a parameter store"),
        (
            '{"format": "backlash-bridge parameter store", "version": 9, "objects": {}}',
            "store version 9",
        ),
    ],
)
def test_malformed_store_file_stops_the_start(
    bus_pair: tuple[can.BusABC, can.BusABC], tmp_path: Path, content: str, fragment: str
) -> None:
    path = tmp_path / "store.json"
    path.write_text(content)
    with pytest.raises(StoreError, match=fragment):
        paper_bridge(bus_pair[0], BridgeConfig(store_path=path))


@pytest.mark.parametrize(
    ("objects", "fragment"),
    [
        ({"2000h:00": struct.pack("<f", 5000.0).hex()}, "kv_per_s = 5000.0: too high"),
        ({"2106h:00": "00"}, "not a stored object"),
        ({"2000h:00": "0000"}, "2 bytes, expected 4"),
        ({"2000h:00": "zz"}, "not hex bytes"),
        ({"1016h:01": struct.pack("<I", (7 << 16) | 100).hex()}, "drive node-ID 2"),
        # each value is fine alone, together they break feed * k_r <= speed limit
        (
            {
                "2007h:00": struct.pack("<f", 10.0).hex(),
                "2011h:00": struct.pack("<I", 50_000_000).hex(),
            },
            "feed",
        ),
    ],
)
def test_store_file_with_refused_values_stops_the_start(
    bus_pair: tuple[can.BusABC, can.BusABC], tmp_path: Path, objects: dict, fragment: str
) -> None:
    path = _stored(tmp_path, objects)
    with pytest.raises(StoreError, match=fragment):
        paper_bridge(bus_pair[0], BridgeConfig(store_path=path))


KILL_TRIALS = 20
#: Backstop of the wait for a store's saves (the child ends it first only by failing).
SAVES_BACKSTOP_S = 300.0


def test_a_store_killed_at_any_moment_leaves_the_old_or_the_new(tmp_path: Path) -> None:
    """A process saving two sets of values in turn, SIGKILLed after a random number of
    saves and a random number of further looks: the store is one set or the other, complete,
    every time; at most a temporary file beside it, which nothing reads."""
    rng = random.Random()
    with Forker(["tests.bridge.store_trials"]) as forker:
        for trial in range(KILL_TRIALS):
            folder = tmp_path / f"trial_{trial}"
            store = folder / "axis.bridge-store.json"
            folder.mkdir()
            ParameterStore(store).save(OLD)
            pid = forker.start("tests.bridge.store_trials:save_in_turn", [str(store)], folder)
            saves, inode = rng.randrange(0, 6), store.stat().st_ino
            deadline = time.monotonic() + SAVES_BACKSTOP_S
            while saves and time.monotonic() < deadline and not forker.ended():
                if store.stat().st_ino != inode:  # a rename: one save more
                    inode, saves = store.stat().st_ino, saves - 1
            for _ in range(rng.randrange(0, 2000)):
                store.exists()
            os.kill(pid, signal.SIGKILL)
            assert forker.wait() == "signal 9", (folder / "child.err").read_text()
            assert ParameterStore(store).load() in (OLD, NEW)
            left = {p.name for p in folder.iterdir()} - {store.name, "child.out", "child.err"}
            temporary = rf"\.{re.escape(store.name)}\.[0-9a-f]{{8}}\.tmp"
            assert all(re.fullmatch(temporary, name) for name in left), left

"""``python -m bridge config get|set|dump|load`` against the bridge and the simulated drive on
a virtual bus, checked with python-canopen's own master: its SDO client and EDS decoding
read what the command wrote, its ``import_od`` re-imports the DCFs the command dumped.
Bad input: one line, exit 2, nothing sent; refusals: exit 1 with the abort code and the node
unchanged (a load with one refused value rolls back what it wrote).
"""

from __future__ import annotations

import re
import struct
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import pytest
from canopen.objectdictionary import ODVariable

from bridge import od as objdict
from bridge.__main__ import main
from bridge.cycle import Command
from bridge.node import Bridge, BridgeConfig
from plant_sim.drive import DriveConfig, SimulatedDrive
from plant_sim.drive.od import DEFAULT_EDS_PATH as DRIVE_EDS
from tests.bridge_helpers import paper_bridge
from tests.command_line import exit_status
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")


@dataclass
class Nodes:
    channel: str
    interface: str
    bridge: Bridge
    drive: SimulatedDrive
    tool: canopen.Network  # python-canopen's master on the same bus
    store: Path

    def node(self, node_id: int) -> canopen.RemoteNode:
        """python-canopen's RemoteNode of the bridge (1) or the drive (2) with its EDS."""
        if node_id not in self.tool:
            eds = objdict.DEFAULT_EDS_PATH if node_id == 1 else DRIVE_EDS
            node = canopen.RemoteNode(node_id, canopen.import_od(str(eds), node_id))
            node.sdo.RESPONSE_TIMEOUT = 2.0
            self.tool.add_node(node)
        return self.tool[node_id]

    def argv(self, action: str, node_id: int, *rest: str) -> list[str]:
        return [
            "config",
            action,
            "--interface",
            self.interface,
            "--channel",
            self.channel,
            "--node-id",
            str(node_id),
            # a guest on a host with both CPUs busy once answered after the default 1 s:
            # canopen's client asked again and then read the late answer of the object
            # before ("Node returned a value for 0x2110:00 instead"); a test's own --timeout
            # comes after and wins
            "--timeout",
            "10",
            *rest,
        ]


@pytest.fixture
def nodes(tmp_path: Path, bus_mode: Interface) -> Iterator[Nodes]:
    """Bridge (node 1) and simulated drive (node 2) on one bus of each mode (virtual; vcan0
    where the host has it), python-canopen's master as a third station."""
    vcan = bus_mode is Interface.SOCKETCAN
    channel = "vcan0" if vcan else f"config-{uuid.uuid4().hex[:10]}"
    config = BusConfig(interface=bus_mode, channel=channel)
    buses = [open_bus(config) for _ in range(3)]
    store = tmp_path / "bridge-store.json"
    bridge = paper_bridge(buses[0], BridgeConfig(store_path=store))
    bridge.start(configure_drive=False)
    bridge.controller.command(Command.DISABLE)
    drive = SimulatedDrive(buses[1], 2, AXIS, DriveConfig())
    tool = canopen.Network(buses[2])
    notifier = can.Notifier(buses[2], tool.listeners, 0.02)
    drive.start()
    try:
        with bridge.serving():
            yield Nodes(channel, bus_mode.value, bridge, drive, tool, store)
    finally:
        notifier.stop(2.0)
        drive.stop()
        bridge.close()
        for bus in buses:
            bus.shutdown()


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = exit_status(main, argv)
    out, err = capsys.readouterr()
    return code, out, err


def variables(od: canopen.ObjectDictionary) -> list[ODVariable]:
    out: list[ODVariable] = []
    for index in sorted(od.indices):
        obj = od[index]
        out += [obj] if isinstance(obj, ODVariable) else [obj[s] for s in sorted(obj.subindices)]
    return out


def writable_snapshot(node: canopen.RemoteNode) -> dict[tuple[int, int], bytes]:
    """Raw values of every readable rw object, read by python-canopen."""
    return {
        (v.index, v.subindex): node.sdo.upload(v.index, v.subindex)
        for v in variables(node.object_dictionary)
        if v.access_type == "rw"
    }


def with_value(dcf: str, section: str, value: str) -> str:
    """``dcf`` with the ParameterValue of ``[section]`` replaced."""
    # the section's lines up to its ParameterValue (a Description may hold "[requires ...]")
    pattern = re.compile(
        rf"(^\[{section}\]\n(?:(?!\[)[^\n]*\n)*?ParameterValue=)[^\n]*",
        re.IGNORECASE | re.MULTILINE,
    )
    new, count = pattern.subn(lambda m: m[1] + value, dcf)
    assert count == 1, section
    return new


# --- get / set --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "ref", ["2001h", "0x2001:00", "2001sub0", "2001:0", "Regulator enable", "REGULATOR ENABLE"]
)
def test_every_way_of_naming_an_object_reads_it(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], ref: str
) -> None:
    code, out, _ = run(nodes.argv("get", 1, ref), capsys)
    assert code == 0
    assert out == "2001h:00 Regulator enable = 1\n"


def test_get_shows_values_and_units_as_canopen_decodes_them(
    nodes: Nodes, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run(
        nodes.argv("get", 1, "Position gain kv", "Max position limit", "1016h:01", "1018h"),
        capsys,
    )
    assert code == 0
    lines = out.splitlines()
    sdo = nodes.node(1).sdo
    assert lines[0] == f"2000h:00 Position gain kv = {sdo['Position gain kv'].raw:g}.0 1/s"
    assert lines[1] == "2014h:02 Max position limit = 2.0 load unit"
    hb = sdo[0x1016][1].raw
    assert lines[2] == f"1016h:01 Consumer heartbeat time 1 = {hb} (0x{hb:08X}) ms"
    assert len(lines) == 3 + 5  # 1018h: sub-indices 0..4
    code, out, _ = run(nodes.argv("get", 2, "Statusword", "0x6060"), capsys)  # the drive
    assert code == 0
    sw = nodes.node(2).sdo["Statusword"].raw
    assert out.splitlines() == [
        f"6041h:00 Statusword = {sw} (0x{sw:04X})",
        "6060h:00 Modes of operation = 9",
    ]


def test_set_writes_what_canopen_reads_back(
    nodes: Nodes, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run(nodes.argv("set", 1, "Position gain kv", "30"), capsys)
    assert (code, out) == (0, "2000h:00 Position gain kv = 30.0 1/s (was 25.0 1/s)\n")
    assert nodes.node(1).sdo["Position gain kv"].raw == 30.0
    assert nodes.bridge.controller.params.kv_per_s == 30.0
    assert run(nodes.argv("set", 1, "2014sub1", "-0.25"), capsys)[0] == 0
    assert nodes.bridge.controller.params.position_limit_min == -0.25
    assert run(nodes.argv("set", 1, "Regulator enable", "off"), capsys)[0] == 0
    assert nodes.node(1).sdo["Regulator enable"].raw is False
    assert run(nodes.argv("set", 2, "Producer heartbeat time", "0x50"), capsys)[0] == 0
    assert nodes.node(2).sdo[0x1017].raw == 80


@pytest.mark.parametrize(
    ("node_id", "args", "fragment"),
    [
        (1, ["get", "2FFFh"], "2FFFh is not in this node's EDS"),
        (1, ["get", "no such thing"], "not a name of this EDS nor an index"),
        (1, ["get", "2000h:03"], "is a VAR, only sub-index 00"),
        (1, ["get", "2014h:07"], "has no sub-index 07"),
        (1, ["get", "Command"], "write-only"),
        (1, ["set", "2000h", "abc"], "'abc' is not a number"),
        (1, ["set", "2000h", "nan"], "must be a finite number"),
        (1, ["set", "2003h", "100"], "100 is out of range; allowed 1..64"),
        (1, ["set", "2003h", "-1"], "-1 is out of range"),
        (1, ["set", "Regulator enable", "2"], "is not a boolean"),
        (1, ["set", "2100h", "1"], "is ro per the EDS: not writable"),
        (1, ["set", "2014h", "1"], "give one, e.g. 2014h:02"),
        (2, ["set", "6060h", "300"], "out of range; allowed -128..127"),
        (1, ["set", "--eds", "missing.eds", "2000h", "1"], "no such file"),
        (1, ["get", "--timeout", "0", "2000h"], "SDO timeout must be 0.01..60 s"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_changes_nothing(
    nodes: Nodes,
    capsys: pytest.CaptureFixture[str],
    node_id: int,
    args: list[str],
    fragment: str,
) -> None:
    before = writable_snapshot(nodes.node(node_id))
    code, out, err = run(nodes.argv(args[0], node_id, *args[1:]), capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and fragment in err, err
    assert writable_snapshot(nodes.node(node_id)) == before


def test_refusal_and_silence_exit_1_with_the_abort_code(
    nodes: Nodes, capsys: pytest.CaptureFixture[str]
) -> None:
    before = writable_snapshot(nodes.node(1))
    code, _, err = run(nodes.argv("set", 1, "2000h", "5000"), capsys)
    assert code == 1 and err.count("\n") == 1
    assert "SDO abort 0x06090031" in err and "2000h:00 Position gain kv" in err
    assert writable_snapshot(nodes.node(1)) == before
    code, _, err = run(nodes.argv("get", 9, "--timeout", "0.05", "1000h"), capsys)
    assert code == 1 and err.count("\n") == 1 and "node 9" in err and "no SDO answer" in err


# --- dump ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("node_id", [1, 2])
def test_dump_is_a_dcf_canopen_imports_with_the_node_values(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path, node_id: int
) -> None:
    if node_id == 1:
        nodes.node(1).sdo["Position gain kv"].raw = 30.0  # not the EDS default
    dcf = tmp_path / f"node{node_id}.dcf"
    code, out, _ = run(nodes.argv("dump", node_id, "--out", str(dcf)), capsys)
    assert code == 0 and f"wrote {dcf}" in out
    od = canopen.import_od(str(dcf))  # no node-ID given: [DeviceComissioning] NodeID
    assert (od.node_id, od.bitrate) == (node_id, 1_000_000)  # run and probe's default
    node = nodes.node(node_id)
    compared = 0
    for var in variables(node.object_dictionary):
        if var.access_type == "wo":
            continue
        mine = (
            od[var.index]
            if var.subindex == 0 and var.index in od and isinstance(od[var.index], ODVariable)
            else od[var.index][var.subindex]
        )
        assert mine.value is not None, f"{var.index:04X}h:{var.subindex:02X} has no value"
        assert mine.encode_raw(mine.value) == node.sdo.upload(var.index, var.subindex), var.name
        compared += 1
    assert compared > (40 if node_id == 1 else 120)
    if node_id == 1:
        assert od["Position gain kv"].value == 30.0


# --- load ---------------------------------------------------------------------------------------
def test_dump_then_load_restores_the_node(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    dcf = tmp_path / "bridge.dcf"
    assert run(nodes.argv("dump", 1, "--out", str(dcf)), capsys)[0] == 0
    original = writable_snapshot(nodes.node(1))
    sdo = nodes.node(1).sdo
    sdo["Position gain kv"].raw = 20.0
    sdo["Software position limit.Max position limit"].raw = 0.5
    sdo["Feed"].raw = 10_000_000
    sdo["Detector window n"].raw = 2
    code, out, _ = run(nodes.argv("load", 1, str(dcf)), capsys)
    assert code == 0 and "loaded 4 objects" in out
    assert writable_snapshot(nodes.node(1)) == original


def test_load_into_the_drive(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    dcf = tmp_path / "drive.dcf"
    assert run(nodes.argv("dump", 2, "--out", str(dcf)), capsys)[0] == 0
    text = with_value(dcf.read_text(), "1017", "250")
    text = with_value(text, "6085", "0x00100000")
    dcf.write_text(text)
    code, out, _ = run(nodes.argv("load", 2, str(dcf)), capsys)
    assert code == 0 and "loaded 2 objects" in out
    assert nodes.node(2).sdo[0x1017].raw == 250
    assert nodes.node(2).sdo[0x6085].raw == 0x0010_0000


def test_load_with_one_refused_value_changes_nothing(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """kv = 150 passes the EDS (REAL32) but breaks the section VII sampling rule in the
    bridge (0609 0031); the other values of the DCF were written first and are undone."""
    dcf = tmp_path / "bad.dcf"
    assert run(nodes.argv("dump", 1, "--out", str(dcf)), capsys)[0] == 0
    text = with_value(dcf.read_text(), "2002", "0.5")  # beta_T: accepted
    text = with_value(text, "2008", "0.004")  # following error limit: accepted
    text = with_value(text, "2000", "150")  # refused by the bridge
    dcf.write_text(text)
    before = writable_snapshot(nodes.node(1))
    params = nodes.bridge.controller.params
    code, _, err = run(nodes.argv("load", 1, str(dcf)), capsys)
    assert code == 1
    assert "refused: 2000h:00 Position gain kv = 150.0 1/s: SDO abort 0x06090031" in err
    assert "nothing changed: 2 objects written before the refusal were restored" in err
    assert writable_snapshot(nodes.node(1)) == before  # bit-exact over SDO
    # inside the bridge: the previous values again, to the REAL32 resolution of the objects
    now = nodes.bridge.controller.params
    assert now.kv_per_s == params.kv_per_s
    assert now.beta_t_rad_s == pytest.approx(params.beta_t_rad_s, rel=1e-7)
    assert now.following_error_limit == pytest.approx(params.following_error_limit, rel=1e-7)


@pytest.mark.parametrize(
    ("section", "value", "fragment"),
    [
        ("2003", "100", "100 is out of range; allowed 1..64"),
        ("2000", "fast", "'fast' is not a number"),
        ("2001", "maybe", "is not a boolean"),
    ],
)
def test_load_of_an_invalid_dcf_value_sends_nothing(
    nodes: Nodes,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    section: str,
    value: str,
    fragment: str,
) -> None:
    dcf = tmp_path / "bad.dcf"
    assert run(nodes.argv("dump", 1, "--out", str(dcf)), capsys)[0] == 0
    dcf.write_text(with_value(with_value(dcf.read_text(), "2002", "0.5"), section, value))
    before = writable_snapshot(nodes.node(1))
    code, _, err = run(nodes.argv("load", 1, str(dcf)), capsys)
    assert code == 2 and err.count("\n") == 1
    assert f"[{section}] ParameterValue={value}" in err and fragment in err
    assert writable_snapshot(nodes.node(1)) == before


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (None, "cannot read the DCF"),
        ("this is not an ini file\n", "not a readable DCF"),
        ("[FileInfo]\nFileName=x.dcf\n", "no ParameterValue keys"),
        ("[2FFF]\nParameterName=x\nParameterValue=1\n", "2FFFh is not in the node's EDS"),
        (
            "[DeviceComissioning]\nNodeID=5\n[2000]\nParameterValue=30\n",
            "made for node-ID 5",
        ),
        ("[2000]\nDataType=0x0007\nParameterValue=30\n", "DataType 0x0007 differs"),
    ],
)
def test_unreadable_dcf_is_exit_2(
    nodes: Nodes,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    content: str | None,
    fragment: str,
) -> None:
    dcf = tmp_path / "x.dcf"
    if content is not None:
        dcf.write_text(content)
    before = writable_snapshot(nodes.node(1))
    code, _, err = run(nodes.argv("load", 1, str(dcf)), capsys)
    assert code == 2 and err.count("\n") == 1 and fragment in err, err
    assert writable_snapshot(nodes.node(1)) == before


def test_load_orders_writes_that_depend_on_each_other(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """2007h (speed limit) below the current feed (2011h) * k_r is refused until 2011h has
    its new value: the second pass writes it."""
    dcf = tmp_path / "slow.dcf"
    assert run(nodes.argv("dump", 1, "--out", str(dcf)), capsys)[0] == 0
    text = with_value(dcf.read_text(), "2007", "10.0")  # rad/s; feed 50 mm/s = 15.7 rad/s
    dcf.write_text(with_value(text, "2011", "0x01312D00"))  # 20 mm/s = 6.3 rad/s
    code, out, _ = run(nodes.argv("load", 1, str(dcf)), capsys)
    assert code == 0 and "loaded 2 objects" in out
    p = nodes.bridge.controller.params
    assert (p.speed_limit_rad_s, p.feed) == (10.0, pytest.approx(0.02))


def test_load_and_save_survives_a_restart(
    nodes: Nodes, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    dcf = tmp_path / "b.dcf"
    assert run(nodes.argv("dump", 1, "--out", str(dcf)), capsys)[0] == 0
    dcf.write_text(with_value(dcf.read_text(), "2000", "30"))
    code, out, _ = run(nodes.argv("load", 1, str(dcf), "--save"), capsys)
    assert code == 0 and "stored (1010h:01 = save)" in out
    assert nodes.store.is_file()
    restarted = paper_bridge(nodes.bridge.port.bus, BridgeConfig(store_path=nodes.store))
    assert restarted.controller.params.kv_per_s == 30.0
    restarted.close()
    # the drive has no 1010h: --save is refused before anything is sent
    code, _, err = run(nodes.argv("load", 2, str(dcf), "--save"), capsys)
    assert code == 2 and "no 1010h:01" in err


def test_store_commands_through_set(nodes: Nodes, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(nodes.argv("set", 1, "2000h", "30"), capsys)[0] == 0
    code, _, err = run(nodes.argv("set", 1, "1010h:01", "1"), capsys)
    assert code == 1 and "SDO abort 0x08000020" in err
    assert not nodes.store.exists()
    code, out, _ = run(nodes.argv("set", 1, "Save all parameters", "save"), capsys)
    assert code == 0 and nodes.store.is_file()
    code, out, _ = run(nodes.argv("set", 1, "1011h:01", "load"), capsys)
    assert code == 0 and not nodes.store.exists()
    assert out == "1011h:01 Restore all default parameters = 1 (0x00000001) (was 1 (0x00000001))\n"


def test_the_node_is_identified_without_eds(
    nodes: Nodes, capsys: pytest.CaptureFixture[str]
) -> None:
    """No --eds: 1000h/1018h:02 pick bridge.eds or drive.eds; with --eds the file is used."""
    code, out, _ = run(nodes.argv("get", 2, "1008h"), capsys)
    assert out == "1008h:00 Manufacturer device name = 'SimDrive402'\n"
    code, out, _ = run(
        nodes.argv("get", 1, "--eds", str(objdict.DEFAULT_EDS_PATH), "1008h"), capsys
    )
    assert out == "1008h:00 Manufacturer device name = 'backlash-bridge'\n"
    # the bridge's EDS for the drive: 2000h is not there (the drive aborts 0602 0000)
    code, _, err = run(
        nodes.argv("get", 2, "--eds", str(objdict.DEFAULT_EDS_PATH), "2000h"), capsys
    )
    assert code == 1 and "0x06020000" in err


def test_raw_bytes_of_reals_round_trip(nodes: Nodes, capsys: pytest.CaptureFixture[str]) -> None:
    """A REAL32 written as text reads back bit-exact (shortest float32 text)."""
    value = struct.unpack("<f", struct.pack("<f", 0.1))[0]
    assert run(nodes.argv("set", 1, "2005h", "0.1"), capsys)[0] == 0
    assert nodes.node(1).sdo.upload(0x2005, 0) == struct.pack("<f", value)
    code, out, _ = run(nodes.argv("get", 1, "2005h"), capsys)
    assert code == 0
    assert out == "2005h:00 Low-pass time constant T_f = 0.1 s\n"

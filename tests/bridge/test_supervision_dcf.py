"""``bridge probe --dcf``: the drive's DCF carrying its supervision of the bridge.

Independent references: python canopen's LocalNode of the vendors' EDS files answers the
probe, python canopen's own CiA 306 reader (``import_od``) reads the DCF back, and the
simulated drive, configured by nothing but ``bridge config load`` of that DCF (no bridge
start-up), stops itself with EMCY 8130h when a heartbeat of the bridge came once and no more
(CiA 301: a consumer watches from the first heartbeat it receives).
"""

from __future__ import annotations

import configparser
import struct
import threading
import uuid
from pathlib import Path

import can
import canopen
import pytest

from bridge.__main__ import main
from tests.adapt_helpers import (
    FAULHABER_CF_EDS,
    FAULHABER_CO_EDS,
    TECHNOSOFT_EDS,
    YIYOU_EDS,
    mirror_mode,
    require_eds,
)
from tests.bridge.conftest import BOUND_S, SIM_EDS
from tests.command_line import exit_status


def entry(node_id: int, time_ms: int) -> int:
    """CiA 301 1016h entry: node-ID in bits 16-23, consumer time in ms in bits 0-15."""
    return node_id << 16 | time_ms


Capture = pytest.CaptureFixture[str]


def probe_with_dcf(
    eds: Path, dcf: Path, capsys: Capture, *extra: str
) -> tuple[int, str, str, dict]:
    """``bridge probe --eds EDS --dcf DCF`` against a LocalNode of ``eds`` (node 2); exit
    status, stdout, stderr and what the probe wrote into the node (nothing, it only reads)."""
    channel = f"dcf-{uuid.uuid4().hex[:12]}"
    server = canopen.Network()
    server.NOTIFIER_CYCLE = 0.02
    server.connect(interface="virtual", channel=channel)
    try:
        node = canopen.LocalNode(2, canopen.import_od(str(require_eds(eds)), 2))
        mirror_mode(node)
        server.add_node(node)
        argv = ["probe", "--interface", "virtual", "--channel", channel, "--drive-id", "2"]
        code = exit_status(main, [*argv, "--eds", str(eds), "--dcf", str(dcf), *extra])
        written = dict(node.data_store)
    finally:
        server.disconnect()
    out, err = capsys.readouterr()
    return code, out, err, written


def parameter_values(dcf: Path) -> dict[str, str]:
    """Section name -> ParameterValue, read as plain INI."""
    parser = configparser.RawConfigParser(strict=False)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read(dcf, encoding="utf-8")
    return {
        s: parser.get(s, "ParameterValue")
        for s in parser.sections()
        if parser.has_option(s, "ParameterValue")
    }


@pytest.mark.parametrize(
    ("eds", "expected"),
    [
        (SIM_EDS, {(0x1016, 1): entry(1, 250), (0x6007, 0): 3, (0x2102, 0): 3}),
        (YIYOU_EDS, {(0x1016, 1): entry(1, 250)}),
        (FAULHABER_CO_EDS, {(0x1016, 1): entry(1, 250)}),
        (TECHNOSOFT_EDS, {(0x6007, 0): 3}),
    ],
    ids=["simulated drive", "Yiyou", "Faulhaber CO", "Technosoft"],
)
def test_the_dcf_carries_what_the_start_up_would_write(
    eds: Path, expected: dict[tuple[int, int], int], tmp_path: Path, capsys: Capture
) -> None:
    dcf = tmp_path / "drive.dcf"
    _, out, err, written = probe_with_dcf(eds, dcf, capsys)
    assert written == {}  # the probe only reads
    assert f"wrote {dcf}: the supervision of the bridge (node 1) on drive 2" in out, out + err
    od = canopen.import_od(str(dcf))  # python canopen's CiA 306 reader
    assert (od.node_id, od.bitrate) == (2, 1_000_000)
    for (index, sub), value in expected.items():
        var = od[index] if isinstance(od[index], canopen.objectdictionary.ODVariable) else None
        var = var or od[index][sub]
        assert var.value == value, f"{index:04X}h:{sub:02X}"
    # nothing else carries a value: every other object keeps what the drive has
    assert len(parameter_values(dcf)) == len(expected)
    # the EDS is kept as it was around the values (a DCF is the EDS with values)
    eds_lines = set(eds.read_text(encoding="utf-8-sig").splitlines())
    dcf_lines = dcf.read_text(encoding="utf-8").splitlines()
    assert sum(line in eds_lines for line in dcf_lines) >= 0.9 * len(eds_lines)


def test_another_bridge_node_and_heartbeat(tmp_path: Path, capsys: Capture) -> None:
    dcf = tmp_path / "drive.dcf"
    _, out, _, _ = probe_with_dcf(
        YIYOU_EDS, dcf, capsys, "--bridge-id", "5", "--bridge-heartbeat", "40"
    )
    assert "(node 5)" in out
    od = canopen.import_od(str(dcf))
    assert od[0x1016][1].value == entry(5, 100)  # 2.5 x 40 ms


def test_a_drive_without_supervision_gets_no_dcf(tmp_path: Path, capsys: Capture) -> None:
    """Faulhaber MCBL CF: neither 1016h nor 6007h: one line, exit 2, no file."""
    dcf = tmp_path / "drive.dcf"
    code, out, err, _ = probe_with_dcf(FAULHABER_CF_EDS, dcf, capsys)
    assert code == 2
    assert "does not supervise the bridge at all" in out
    assert err.count("\n") == 1 and "no supervision of the bridge to put in a DCF" in err
    assert not dcf.exists()


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (("--bridge-heartbeat", "0"), "--bridge-heartbeat 0: allowed 1..65535 ms"),
        (("--bridge-id", "128"), "--bridge-id"),
    ],
)
def test_bad_arguments_exit_2_before_the_bus(
    extra: tuple[str, ...], needle: str, capsys: Capture
) -> None:
    argv = ["probe", "--interface", "virtual", "--channel", "nobody", "--drive-id", "2"]
    code = exit_status(main, [*argv, "--eds", str(SIM_EDS), "--dcf", "x.dcf", *extra])
    _, err = capsys.readouterr()
    assert code == 2 and needle in err


def test_dcf_without_eds_is_refused(tmp_path: Path, capsys: Capture) -> None:
    argv = ["probe", "--interface", "virtual", "--channel", "nobody", "--drive-id", "2"]
    code = exit_status(main, [*argv, "--dcf", str(tmp_path / "x.dcf")])
    _, err = capsys.readouterr()
    assert code == 2 and "--dcf needs --eds" in err


# --- the DCF alone makes the drive watch the bridge -----------------------------------------
def test_the_drive_loaded_with_the_dcf_watches_the_bridge(
    served: tuple[str, threading.Event, list],
    tool: canopen.RemoteNode,
    tmp_path: Path,
    capsys: Capture,
) -> None:
    channel, _, drives = served
    drive = drives[0]
    dcf = tmp_path / "drive.dcf"
    probe_with_dcf(SIM_EDS, dcf, capsys)  # the values a LocalNode of the same EDS led to
    bus_args = ["--interface", "virtual", "--channel", channel, "--node-id", "2"]
    code = exit_status(main, ["config", "load", *bus_args, "--eds", str(SIM_EDS), str(dcf)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "loaded 2 objects" in out and "(1 already equal)" in out  # 6007h = 3 by default
    assert tool.sdo.upload(0x1016, 1) == struct.pack("<I", entry(1, 250))
    assert drive.error_code == 0
    # the bridge's heartbeat once (Operational), then never again: the bridge died
    tool.network.bus.send(can.Message(arbitration_id=0x701, data=[0x05], is_extended_id=False))
    for _ in range(int(BOUND_S * 10)):  # the drive's heartbeats: its clock goes on
        if drive.error_code == 0x8130:
            break
        tool.nmt.wait_for_heartbeat(timeout=1.0)
    assert drive.error_code == 0x8130  # heartbeat of the master lost (CiA 301)

"""CANopenNode as the slave on vcan0: ``canopend`` with its demo object dictionary
(``CANopenNode/example``, a CiA 301 device, not a CiA 402 drive) as node 5, read by the
project's commands as separate processes:

* ``bridge probe`` ends in one line naming what is missing for the bridge's start-up;
* ``bridge config get/dump`` without ``--eds`` does not take the demo device for one of the
  project's nodes; with CANopenNode's own EDS they read its object dictionary and write a DCF
  that ``canopen.import_od`` loads and whose values are those CANopenNode's gateway reads from
  its own dictionary, object by object, for every object of CANopenNode's EDS.

CANopenNode's EDS has empty ``VendorNumber=`` / ``ProductNumber=`` in ``[DeviceInfo]``, which
python canopen 2.4 refuses (``int('', 0)``); the tests use a copy with both ``0`` (CiA 306
gives them as UNSIGNED32; docs/peers.md).
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODVariable

from tests.peers import canopennode as cn
from tests.peers.peers_common import GATEWAY_ID

pytestmark = pytest.mark.vcan

BUS = ["--interface", "socketcan", "--channel", "vcan0"]


@pytest.fixture
def demo(canopennode: cn.Binaries) -> Iterator[cn.Gateway]:
    """canopend as node 5; its gateway reads its own dictionary (no bus traffic)."""
    with cn.gateway(canopennode, GATEWAY_ID) as gw:
        yield gw


@pytest.fixture
def demo_eds(canopennode: cn.Binaries, tmp_path: Path) -> Path:
    text = canopennode.demo_eds.read_text(encoding="utf-8")
    fixed = re.sub(r"(?m)^(VendorNumber|ProductNumber)=\s*$", r"\1=0", text)
    path = tmp_path / "DS301_profile.eds"
    path.write_text(fixed, encoding="utf-8")
    return path


def _run(subprocess_env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bridge", *args],
        capture_output=True,
        text=True,
        env=subprocess_env,
        timeout=cn.BOUND_S,
        check=False,
    )


def test_probe_ends_in_one_line_naming_what_is_missing(
    demo: cn.Gateway, subprocess_env: dict[str, str]
) -> None:
    done = _run(subprocess_env, "probe", *BUS, "--drive-id", str(GATEWAY_ID))
    assert done.returncode == 1, done.stderr  # the start-up it plans would stop
    assert "Traceback" not in done.stderr
    lines = done.stdout.strip().splitlines()
    # CANopenNode's demo device has none of the CiA 402 objects: one problem, in one line
    assert lines[-2:] == [
        "start-up would stop: 1 problem(s), all of them:",
        f"  1. drive {GATEWAY_ID}: 6040h:00 missing: not a CiA 402 drive (1000h device type "
        "0x00000000; 6041h:00, 6064h:00, 60FFh:00, 6060h:00 missing too)",
    ]
    assert lines[0].startswith("1000h device type     0x00000000")  # no device profile


def test_config_without_eds_does_not_take_the_demo_for_the_bridge(
    demo: cn.Gateway, subprocess_env: dict[str, str]
) -> None:
    """1000h = 0 and product code 0 match the bridge's EDS too; 1008h tells them apart."""
    done = _run(subprocess_env, "config", "get", *BUS, "--node-id", str(GATEWAY_ID), "1018")
    assert done.returncode == 2, done.stdout + done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert "match neither bridge.eds, drive.eds; give --eds FILE" in line


def _own(gw: cn.Gateway, var: ODVariable) -> bytes:
    answer = gw.read(GATEWAY_ID, var.index, var.subindex)
    assert answer.ok, f"{var.index:04X}h:{var.subindex:02X}: {answer.text}"
    return answer.data


def test_config_get_reads_what_canopennode_holds(
    demo: cn.Gateway, demo_eds: Path, subprocess_env: dict[str, str]
) -> None:
    done = _run(
        subprocess_env, "config", "get", *BUS, "--node-id", str(GATEWAY_ID), "--eds",
        str(demo_eds), "0x1018", "0x1017", "0x1014",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    od = canopen.import_od(str(demo_eds), GATEWAY_ID)
    for line in done.stdout.strip().splitlines():
        m = re.match(r"([0-9A-F]{4})h:([0-9A-F]{2}) .* = (-?\d+)", line)
        assert m, line
        index, sub, value = int(m[1], 16), int(m[2], 16), int(m[3])
        obj = od[index]
        var = obj if isinstance(obj, ODVariable) else obj[sub]
        assert value == var.decode_raw(_own(demo, var)), line


def test_config_dump_writes_a_dcf_canopen_and_canopennode_agree_with(
    demo: cn.Gateway, demo_eds: Path, subprocess_env: dict[str, str], tmp_path: Path
) -> None:
    dcf = tmp_path / "node5.dcf"
    done = _run(
        subprocess_env, "config", "dump", *BUS, "--node-id", str(GATEWAY_ID), "--eds",
        str(demo_eds), "--out", str(dcf),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    eds_od = canopen.import_od(str(demo_eds), GATEWAY_ID)
    dcf_od = canopen.import_od(str(dcf), GATEWAY_ID)
    declared = {
        (v.index, v.subindex)
        for v in _variables(eds_od)
        if v.index >= 0x1000 and ("r" in v.access_type or v.access_type == "const")
    }
    compared = 0
    for var in _variables(dcf_od):
        key = (var.index, var.subindex)
        if key not in declared:
            continue
        declared.discard(key)
        raw = _own(demo, var) if var.value is not None else None
        if raw is None:  # 0800 0024 "no data available": the EDS default is kept
            continue
        assert var.encode_raw(var.value) == raw, f"{key}: DCF {var.value!r}, node {raw.hex()}"
        compared += 1
    assert declared == set(), f"objects of the EDS missing in the DCF: {sorted(declared)}"
    assert compared > 60


def _variables(od: canopen.ObjectDictionary) -> Iterator[ODVariable]:
    for index in sorted(od.indices):
        obj = od[index]
        if isinstance(obj, ODVariable):
            yield obj
        else:
            yield from (obj[s] for s in sorted(obj.subindices))

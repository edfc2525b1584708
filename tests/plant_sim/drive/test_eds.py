"""config/drive.eds: it loads with canopen.import_od, and every object it declares exists and
behaves in the running node (SDO upload of each readable object, download of each writable
one, the EDS limits, read-only objects, missing sub-indices); an EDS that does not fit the
drive is refused."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import canopen
import pytest
from canopen import objectdictionary as cod
from canopen.sdo import SdoAbortedError

import tests.sdo_oracle as sdo_oracle  # noqa: F401  (tests/ helper: works around a canopen client bug)
from plant_sim.drive import DEFAULT_EDS_PATH, DriveEdsError, SimulatedDrive
from plant_sim.drive.od import KNOWN_OBJECTS, iter_variables
from plant_sim.drive.rig import virtual_rig
from tests.paths import ROOT
from virtual_bus.formats.axis import AxisConfig, load_axis

REPO = ROOT
EDS = REPO / "config" / "drive.eds"

# objects whose value the running drive computes or sets from the axis / DriveConfig
LIVE_OR_DERIVED = {
    (0x1001, 0),
    (0x603F, 0),
    (0x6041, 0),
    (0x6064, 0),
    (0x606C, 0),
    (0x6077, 0),
    (0x60E4, 1),
    (0x2103, 0),
    (0x2104, 0),
}


@pytest.fixture(scope="module")
def axis() -> AxisConfig:
    return load_axis(REPO / "config" / "paper_axis.toml")


def test_default_eds_is_config_drive_eds() -> None:
    assert DEFAULT_EDS_PATH == EDS


def test_eds_loads_with_canopen_and_declares_the_contract_objects() -> None:
    od = canopen.import_od(str(EDS), 2)
    assert od.device_information.nr_of_RXPDO == 4
    assert od.device_information.nr_of_TXPDO == 4
    keys = {(v.index, v.subindex) for v in iter_variables(od)}
    assert keys == set(KNOWN_OBJECTS)
    # docs/canopen_layout.md: default PDO layout and COB-IDs for node 2
    assert od[0x1800][1].default == 0x182 and od[0x1801][1].default == 0x282
    assert od[0x1400][1].default == 0x202
    assert [od[0x1A00][s].default for s in (1, 2)] == [0x60640020, 0x60E40120]
    assert [od[0x1A01][s].default for s in (1, 2, 3)] == [0x60410010, 0x60770010, 0x606C0020]
    assert [od[0x1600][s].default for s in (1, 2)] == [0x60400010, 0x60FF0020]
    assert od[0x1800][2].default == 1 and od[0x1400][2].default == 255
    types = {
        0x6040: cod.UNSIGNED16,
        0x6041: cod.UNSIGNED16,
        0x6060: cod.INTEGER8,
        0x6061: cod.INTEGER8,
        0x6064: cod.INTEGER32,
        0x606C: cod.INTEGER32,
        0x60FF: cod.INTEGER32,
        0x6076: cod.UNSIGNED32,
        0x6077: cod.INTEGER16,
        0x6072: cod.UNSIGNED16,
        0x603F: cod.UNSIGNED16,
        0x1001: cod.UNSIGNED8,
    }
    for index, data_type in types.items():
        assert od[index].data_type == data_type, f"{index:04X}h"
    assert od[0x60E4][1].data_type == cod.INTEGER32


def test_every_object_uploads_and_writable_ones_download(axis: AxisConfig) -> None:
    od = canopen.import_od(str(EDS), 2)
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        uploaded = 0
        for var in iter_variables(od):
            key = (var.index, var.subindex)
            raw = sdo.upload(var.index, var.subindex)
            value = var.decode_raw(raw)
            uploaded += 1
            if key not in LIVE_OR_DERIVED and key not in {(0x6072, 0), (0x60C2, 1), (0x60C2, 2)}:
                assert value == var.default, f"{var.index:04X}h:{var.subindex:02X} {var.name}"
            if var.writable:
                sdo.download(var.index, var.subindex, raw)
                assert sdo.upload(var.index, var.subindex) == raw or key in LIVE_OR_DERIVED
        assert uploaded == len(KNOWN_OBJECTS)
        # axis-derived values: 150 N·m / 50 N·m = 3000 ‰, 1 ms = 1 * 10^-3 s
        assert sdo[0x6072].raw == 3000
        assert (sdo[0x60C2][1].raw, sdo[0x60C2][2].raw) == (1, -3)


def limited_variables() -> list[cod.ODVariable]:
    od = canopen.import_od(str(EDS), 2)
    return [
        v for v in iter_variables(od) if v.writable and (v.min is not None or v.max is not None)
    ]


LIMITED = limited_variables()


@pytest.mark.parametrize("var", LIMITED, ids=[f"{v.index:04X}h:{v.subindex:02X}" for v in LIMITED])
def test_eds_limits_are_enforced(axis: AxisConfig, var: cod.ODVariable) -> None:
    fmt = var.STRUCT_TYPES[var.data_type]
    low, high = {
        cod.UNSIGNED8: (0, 0xFF),
        cod.UNSIGNED16: (0, 0xFFFF),
        cod.UNSIGNED32: (0, 0xFFFFFFFF),
        cod.INTEGER16: (-(2**15), 2**15 - 1),
    }[var.data_type]
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        before = sdo.upload(var.index, var.subindex)
        tried = 0
        if var.max is not None and var.max < high:
            with pytest.raises(SdoAbortedError) as info:
                sdo.download(var.index, var.subindex, fmt.pack(var.max + 1))
            assert info.value.code == 0x06090031
            tried += 1
        if var.min is not None and var.min > low:
            with pytest.raises(SdoAbortedError) as info:
                sdo.download(var.index, var.subindex, fmt.pack(var.min - 1))
            assert info.value.code == 0x06090032
            tried += 1
        assert tried
        assert sdo.upload(var.index, var.subindex) == before


def test_read_only_objects_refuse_downloads(axis: AxisConfig) -> None:
    od = canopen.import_od(str(EDS), 2)
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        for var in iter_variables(od):
            if var.writable:
                continue
            raw = sdo.upload(var.index, var.subindex)
            with pytest.raises(SdoAbortedError) as info:
                sdo.download(var.index, var.subindex, raw)
            assert info.value.code == 0x06010002, f"{var.index:04X}h:{var.subindex:02X}"


def test_missing_objects_and_subindices(axis: AxisConfig) -> None:
    with virtual_rig(axis) as rig:
        sdo = rig.sdo.sdo
        with pytest.raises(SdoAbortedError) as info:
            sdo.upload(0x2200, 0)
        assert info.value.code == 0x06020000
        for index, sub in ((0x6040, 1), (0x60E4, 2), (0x1A00, 9)):
            with pytest.raises(SdoAbortedError) as info:
                sdo.upload(index, sub)
            assert info.value.code == 0x06090011, f"{index:04X}h:{sub:02X}"
        with pytest.raises(SdoAbortedError) as info:
            sdo.download(0x6040, 0, struct.pack("<L", 6))  # 4 bytes into UNSIGNED16
        assert info.value.code == 0x06070012  # length too high
        assert sdo[0x6040].raw == 0


def edit_eds(tmp_path: Path, change: str) -> Path:
    text = EDS.read_text(encoding="ascii")
    if change == "drop 6041h":
        text = re.sub(r"\[6041\]\n(?:[^\[\n][^\n]*\n)*", "", text)
    elif change == "unknown 2200h":
        text += "\n[2200]\nParameterName=Extra\nObjectType=0x7\nDataType=0x0007\n"
        text += "AccessType=rw\nDefaultValue=0\nPDOMapping=0\n"
    elif change == "6040h as UNSIGNED32":
        text = text.replace(
            "[6040]\nParameterName=Controlword\nObjectType=0x7\nDataType=0x0006",
            "[6040]\nParameterName=Controlword\nObjectType=0x7\nDataType=0x0007",
        )
    elif change == "6041h writable":
        text = text.replace(
            "ParameterName=Statusword\nObjectType=0x7\nDataType=0x0006\nAccessType=ro",
            "ParameterName=Statusword\nObjectType=0x7\nDataType=0x0006\nAccessType=rw",
        )
    path = tmp_path / "drive.eds"
    path.write_text(text, encoding="ascii")
    assert text != EDS.read_text(encoding="ascii")
    return path


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ("drop 6041h", (0x6041, 0)),
        ("unknown 2200h", (0x2200, 0)),
        ("6040h as UNSIGNED32", (0x6040, 0)),
        ("6041h writable", (0x6041, 0)),
    ],
)
def test_eds_that_does_not_fit_is_refused(
    tmp_path: Path, axis: AxisConfig, change: str, key: tuple[int, int]
) -> None:
    from plant_sim.drive import DriveConfig

    path = edit_eds(tmp_path, change)
    canopen.import_od(str(path), 2)  # still a valid EDS for canopen
    with pytest.raises(DriveEdsError) as info:
        SimulatedDrive(canopen.Network(), 2, axis, DriveConfig(eds_path=path))
    assert info.value.key == key


def test_missing_eds_file(tmp_path: Path, axis: AxisConfig) -> None:
    from plant_sim.drive import DriveConfig

    with pytest.raises(DriveEdsError, match="no such EDS file"):
        SimulatedDrive(canopen.Network(), 2, axis, DriveConfig(eds_path=tmp_path / "x.eds"))

"""The bridge's start-up against real drives' EDS files, answered by python canopen's own
LocalNode (tests/adapt_helpers.py), over a python-can virtual bus.

Independent references: the vendors' EDS files (shared/vendor_eds/README.md) -- the
expected layout, mode and scaling below are read off them by hand, with the line of the EDS
named -- and canopen's own PDO machinery, which encodes the CiA 406 encoder's TPDO from the
mapping the bridge wrote. A LocalNode runs no CiA 402 state machine, so these tests stop
before "enable operation"; the full loop with an adapted layout runs against the simulated
drive at the end.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import struct
from pathlib import Path

import pytest
from canopen.sdo import SdoAbortedError

from bridge.adapt import CSV_BIT, DriveFacts, PdoFacts, VelocityMode
from bridge.adapt import plan as adapt_plan
from bridge.errors import DriveSetupError
from bridge.layout import Signal
from bridge.probe import COMMISSIONING_FIELDS, mappable_from_eds, profile_from_facts
from tests.adapt_helpers import ENCODER_EDS, TECHNOSOFT_EDS, YIYOU_EDS, local_rig
from tests.paths import ROOT
from virtual_bus.formats.drive_profile import DriveProfile, LoadSource, load_profile

DRIVES = ROOT / "config" / "drives"
SIM_EDS = ROOT / "config" / "drive.eds"
INVALID = 0x8000_0000


def entry(index: int, sub: int, bits: int) -> int:
    """CiA 301 mapping entry."""
    return index << 16 | sub << 8 | bits


def test_technosoft_ipos_profile_velocity_vendor_load_per_mille_torque() -> None:
    profile = load_profile(DRIVES / "technosoft_ipos.toml")
    with local_rig(TECHNOSOFT_EDS, profile) as rig:
        plan, facts, mode = rig.master.configure()
        s = rig.stored
        # [6502] DefaultValue=0x001F0065: bit 2 (pv) set, bit 8 (csv) not -> 6060h = 3
        assert facts.supported_modes == 0x001F0065
        assert plan.mode is VelocityMode.PROFILE_VELOCITY and mode == 3
        assert s(2, 0x6060, 0) == 3
        # [6083] HighLimit=4294967295: opened; the iPOS has no [6084]
        assert s(2, 0x6083, 0) == 0xFFFF_FFFF
        # TPDO1 = 6064h + 208Dh auxiliary encoder (both INTEGER32, PDOMapping=1), on SYNC
        assert [s(2, 0x1A00, i) for i in range(3)] == [
            2,
            entry(0x6064, 0, 32),
            entry(0x208D, 0, 32),
        ]
        assert (s(2, 0x1800, 1), s(2, 0x1800, 2)) == (0x182, 1)
        # TPDO2 = 6041h (U16) + 6077h (I16) + 606Ch (I32)
        assert [s(2, 0x1A01, i) for i in range(4)] == [
            3,
            entry(0x6041, 0, 16),
            entry(0x6077, 0, 16),
            entry(0x606C, 0, 32),
        ]
        assert (s(2, 0x1801, 1), s(2, 0x1801, 2)) == (0x282, 1)
        # RPDO1 = 6040h + 60FFh; TPDO3/4 (default invalid) stay off, RPDO2-4 switched off
        assert [s(2, 0x1600, i) for i in range(3)] == [
            2,
            entry(0x6040, 0, 16),
            entry(0x60FF, 0, 32),
        ]
        assert s(2, 0x1400, 1) == 0x202
        assert all(s(2, 0x1400 + n, 1) & INVALID for n in (1, 2, 3))
        assert all(s(2, 0x1800 + n, 1) & INVALID for n in (2, 3))
        assert s(2, 0x1017, 0) == 100
    layout = plan.layout
    assert [(f.can_id, f.fmt) for f in layout.frames] == [(0x182, "<ii"), (0x282, "<Hhi")]
    assert layout.frames[0].signals == (Signal.MOTOR_POSITION, Signal.LOAD_POSITION)
    assert layout.load_measured and layout.rpdo_can_id == 0x202
    sc = plan.scaling
    # no [6076]: torque in per mille (1 unit = 1 per mille), never a refusal
    assert sc.rated_torque_nm is None and sc.torque_nm_per_permille == 1.0
    assert "per mille" in sc.torque_unit
    assert sc.motor_rad_per_increment == pytest.approx(2 * math.pi / 2000)
    assert sc.velocity_units_per_rad_s == pytest.approx(131072 / (2 * math.pi))
    assert sc.load_unit_per_increment == pytest.approx(1e-6)
    assert any("profile velocity" in n for n in plan.notes)


def test_technosoft_without_profile_stops_before_writing_and_names_the_object() -> None:
    with local_rig(TECHNOSOFT_EDS) as rig:
        with pytest.raises(DriveSetupError) as info:
            rig.master.configure()
        node = rig.nodes[2]
        written = dict(node.data_store)
    message = str(info.value)
    assert "\n" not in message
    # no [608F], no [6092]: the resolution is unknown; the message says what to configure
    assert "608Fh" in message and "position_increments_per_rev" in message
    assert info.value.index == 0x608F
    assert written == {}  # reads only: nothing was written half-way


def test_yiyou_euservo_csv_vendor_load_and_configured_resolution() -> None:
    profile = load_profile(DRIVES / "yiyou_euservo.toml")
    with local_rig(YIYOU_EDS, profile) as rig:
        plan, facts, _ = rig.master.configure()
        s = rig.stored
        # [6502] DefaultValue=0x03cd: bit 8 set -> cyclic synchronous velocity
        assert plan.mode is VelocityMode.CYCLIC_SYNCHRONOUS_VELOCITY and s(2, 0x6060, 0) == 9
        assert s(2, 0x6083, 0) == 0  # CSV: the profile ramps are left alone
        # [1800sub1] $NODEID+0x40000180, [1800sub2] 0 -> the bridge writes 0x182 and type 1
        assert (s(2, 0x1800, 1), s(2, 0x1800, 2)) == (0x182, 1)
        assert [s(2, 0x1A00, i) for i in range(3)] == [
            2,
            entry(0x6064, 0, 32),
            entry(0x202B, 0, 32),
        ]
        assert (s(2, 0x1801, 1), s(2, 0x1801, 2)) == (0x282, 1)
        assert s(2, 0x1803, 1) & INVALID and s(2, 0x1802, 1) & INVALID
    assert facts.ratio(0x6091) == (5308416, 5308416)  # [6091sub1]/[6091sub2]
    assert facts.vendor_id == 0x668 and facts.product_code == 0x00220811
    sc = plan.scaling
    assert sc.motor_rad_per_increment == pytest.approx(2 * math.pi / 65536)
    assert sc.velocity_units_per_rad_s == pytest.approx(65536 / (2 * math.pi))  # inc/s
    assert sc.load_unit_per_increment == pytest.approx(2 * math.pi / 65536)
    assert sc.rated_torque_nm is None  # no [6076]


def test_a_profile_for_another_drive_is_refused() -> None:
    profile = load_profile(DRIVES / "technosoft_ipos.toml")
    with local_rig(YIYOU_EDS, profile) as rig:
        with pytest.raises(DriveSetupError, match=r"vendor-ID is 0x00000668.*0x000001A3"):
            rig.master.configure()
        assert rig.nodes[2].data_store == {}


@pytest.mark.parametrize(
    ("source", "needle"),
    [
        (LoadSource.ADDITIONAL_SUB1, "no 60E4h:01"),
        (LoadSource.ADDITIONAL_VAR, "60E4h is not a plain"),
    ],
)
def test_asking_for_60e4_on_a_drive_without_it_names_the_object(
    source: LoadSource, needle: str
) -> None:
    profile = dataclasses.replace(
        load_profile(DRIVES / "yiyou_euservo.toml"), load_source=source, load_object=None
    )
    with local_rig(YIYOU_EDS, profile) as rig, pytest.raises(DriveSetupError, match=needle) as info:
        rig.master.configure()
    assert info.value.index == 0x60E4


def test_yiyou_without_load_object_runs_on_motor_feedback_and_says_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    profile = dataclasses.replace(
        load_profile(DRIVES / "yiyou_euservo.toml"),
        load_source=LoadSource.AUTO,
        load_object=None,
    )
    with local_rig(YIYOU_EDS, profile) as rig:
        plan, _, _ = rig.master.configure()
        # 6064h + 6041h + 6077h = 64 bits in TPDO1, 606Ch in TPDO2
        assert [rig.stored(2, 0x1A00, i) for i in range(4)] == [
            3,
            entry(0x6064, 0, 32),
            entry(0x6041, 0, 16),
            entry(0x6077, 0, 16),
        ]
        assert [rig.stored(2, 0x1A01, i) for i in range(2)] == [1, entry(0x606C, 0, 32)]
    assert plan.load_source is LoadSource.MOTOR and not plan.layout.load_measured
    assert [n for n in plan.notes if "position_feedback = motor" in n]


@pytest.mark.parametrize(
    ("eds", "profile_file"),
    [
        (TECHNOSOFT_EDS, "technosoft_ipos.toml"),
        (YIYOU_EDS, "yiyou_euservo.toml"),
        (SIM_EDS, "simdrive.toml"),
    ],
)
def test_probe_writes_the_shipped_profile(eds: Path, profile_file: str) -> None:
    """What a probe can know equals the shipped profile; the commissioning keys (load
    source, scales) are the ones added by hand."""
    shipped = load_profile(DRIVES / profile_file)
    with local_rig(eds) as rig:
        facts = rig.master.read_facts()
        assert rig.nodes[2].data_store == {}  # the probe only reads
    probed = profile_from_facts(facts, shipped.name, mappable_from_eds(eds, 2))
    kept = {name: getattr(shipped, name) for name in COMMISSIONING_FIELDS}
    assert dataclasses.replace(probed, **kept) == shipped
    if eds == SIM_EDS:  # nothing to add for the contract's drive
        assert probed == shipped


def test_cia406_encoder_node_supplies_the_load_position() -> None:
    """The drive (Yiyou EDS) without a load object and a CiA 406 encoder LocalNode (node 5):
    the encoder's TPDO1 is set to 6004h on SYNC; canopen's own PDO code then encodes a
    position with that mapping, and the bridge's layout decodes it."""
    profile = dataclasses.replace(
        load_profile(DRIVES / "yiyou_euservo.toml"),
        load_source=LoadSource.ENCODER,
        load_object=None,
        encoder_id=5,
        load_increments_per_unit=1e6,  # [6005sub1] 1000 nm steps
    )
    received: list[bytes] = []
    with local_rig(YIYOU_EDS, profile, extra={5: ENCODER_EDS}) as rig:
        plan, _, _ = rig.master.configure()
        rig.master.configure_encoder(plan.encoder_id)
        s = rig.stored
        assert (s(5, 0x1800, 1), s(5, 0x1800, 2)) == (0x185, 1)
        assert [s(5, 0x1A00, i) for i in range(2)] == [1, entry(0x6004, 0, 32)]
        assert s(5, 0x1017, 0) == 100
        remote = rig.client[5]
        remote.sdo.upload(0x1000, 0)  # answered after the NMT start frame was handled
        assert rig.nodes[5].nmt.state == "OPERATIONAL"
        encoder = rig.nodes[5]
        rig.client.subscribe(0x185, lambda cid, data, ts: received.append(bytes(data)))
        encoder.tpdo.read(from_od=False)
        encoder.tpdo[1]["Position value"].raw = 123_456
        encoder.tpdo[1].transmit()
        # the encoder answers this SDO after its TPDO: the client has seen the TPDO by then
        remote.sdo.upload(0x1000, 0)
    frames = {f.can_id: f for f in plan.layout.frames}
    enc = frames[0x185]
    assert enc.signals == (Signal.LOAD_POSITION,)
    assert struct.unpack(enc.fmt, received[0]) == (123_456,)
    assert 123_456 * plan.scaling.load_unit_per_increment == pytest.approx(0.123456)
    # the drive's own TPDOs carry no load position now
    drive_signals = [s for f in plan.layout.frames if f.can_id != 0x185 for s in f.signals]
    assert Signal.LOAD_POSITION not in drive_signals


def test_a_node_that_is_not_an_encoder_is_refused() -> None:
    profile = dataclasses.replace(
        load_profile(DRIVES / "yiyou_euservo.toml"),
        load_source=LoadSource.ENCODER,
        load_object=None,
        encoder_id=3,
        load_increments_per_unit=1e6,
    )
    with local_rig(YIYOU_EDS, profile, extra={3: YIYOU_EDS}) as rig:
        plan, _, _ = rig.master.configure()
        with pytest.raises(DriveSetupError, match="not a CiA 406 encoder"):
            rig.master.configure_encoder(plan.encoder_id)


def test_an_object_the_drive_refuses_to_map_is_left_out(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A drive that answers 0604 0041 to mapping 6077h: the start-up plans again without it."""
    with local_rig(SIM_EDS, DriveProfile()) as rig:
        node = rig.nodes[2]

        def refuse_torque(index: int, subindex: int, od: object, data: bytes) -> None:
            if 0x1A00 <= index <= 0x1A03 and subindex and data == struct.pack("<I", 0x60770010):
                raise SdoAbortedError(0x0604_0041)

        node.add_write_callback(refuse_torque)
        with caplog.at_level(logging.WARNING, logger="bridge"):
            plan, _, _ = rig.master.configure()
        assert [rig.stored(2, 0x1A01, i) for i in range(3)] == [
            2,
            entry(0x6041, 0, 16),
            entry(0x606C, 0, 32),
        ]
    carried = [s for f in plan.layout.frames for s in f.signals]
    assert Signal.TORQUE not in carried and Signal.LOAD_POSITION in carried
    assert "0x06040041" in caplog.text.lower() or "6040041" in caplog.text


def test_60e4_as_a_plain_variable_is_mapped_at_sub_index_0(tmp_path: Path) -> None:
    """A drive whose 60E4h is a plain INTEGER32 (no sub-index 1): the drive's EDS with 60E4h
    rewritten that way; its sub-index 0 then reads 4 bytes instead of a 1-byte count."""
    text = SIM_EDS.read_text(encoding="utf-8")
    start = text.index("[60E4]")
    end = text.index("[60FF]")
    plain = (
        "[60E4]\nParameterName=Additional position actual value\nObjectType=0x7\n"
        "DataType=0x0004\nAccessType=ro\nDefaultValue=0\nPDOMapping=1\n\n"
    )
    eds = tmp_path / "plain60e4.eds"
    eds.write_text(text[:start] + plain + text[end:], encoding="utf-8")
    with local_rig(eds) as rig:
        plan, _, _ = rig.master.configure()
        assert [rig.stored(2, 0x1A00, i) for i in range(3)] == [
            2,
            entry(0x6064, 0, 32),
            entry(0x60E4, 0, 32),
        ]
    assert plan.load_source is LoadSource.ADDITIONAL_VAR and plan.layout.load_measured


# --- the planner on hand-made facts (values computed by hand from CiA 402's definitions) ----------
def _facts(**objects: bytes) -> DriveFacts:
    base = {
        (0x6040, 0): b"\0\0",
        (0x6041, 0): b"\0\0",
        (0x6060, 0): b"\0",
        (0x6064, 0): bytes(4),
        (0x606C, 0): bytes(4),
        (0x6077, 0): bytes(2),
        (0x60FF, 0): bytes(4),
    }
    for name, raw in objects.items():
        index, sub = name[1:].split("_")
        base[(int(index, 16), int(sub))] = raw
    pdos = tuple(PdoFacts(n, 0x180 + 0x100 * (n - 1) + 2, 1, 8) for n in range(1, 5))
    rpdos = tuple(PdoFacts(n, 0x200 + 0x100 * (n - 1) + 2, 255, 8) for n in range(1, 5))
    return DriveFacts(0x00020192, 1, 2, CSV_BIT, base, pdos, rpdos)


def _u32(value: int) -> bytes:
    return struct.pack("<I", value)


@pytest.mark.parametrize(
    ("objects", "units_per_rev"),
    [
        ({"x608F_1": _u32(4096), "x608F_2": _u32(1)}, 4096.0),  # increments per motor rev
        ({"x608F_1": _u32(10000), "x608F_2": _u32(4)}, 2500.0),
        # feed constant 5000 µm per driving-shaft rev, gear 3 motor revs : 1 shaft rev
        (
            {
                "x6092_1": _u32(5000),
                "x6092_2": _u32(1),
                "x6091_1": _u32(3),
                "x6091_2": _u32(1),
                "x608F_1": _u32(4096),
                "x608F_2": _u32(1),
            },
            5000 / 3,
        ),
    ],
)
def test_position_units_per_motor_revolution_from_the_factor_objects(
    objects: dict[str, bytes], units_per_rev: float
) -> None:
    plan = adapt_plan(_facts(**objects), DriveProfile(rated_torque_mnm=1000), 2, 1e9)
    assert plan.scaling.position_increments_per_rev == pytest.approx(units_per_rev)
    assert plan.scaling.velocity_units_per_rev_s == pytest.approx(units_per_rev)


def test_a_velocity_factor_other_than_one_needs_the_profile() -> None:
    facts = _facts(x608F_1=_u32(4096), x608F_2=_u32(1), x6096_1=_u32(60), x6096_2=_u32(1))
    with pytest.raises(DriveSetupError, match=r"6096h is 60/1: set scaling\.velocity_units"):
        adapt_plan(facts, DriveProfile(), 2, 1e9)
    profile = DriveProfile(velocity_units_per_rev_s=60.0)
    assert adapt_plan(facts, profile, 2, 1e9).scaling.velocity_units_per_rad_s == pytest.approx(
        60 / (2 * math.pi)
    )


def test_packing_follows_the_drives_mapping_entries() -> None:
    """Two entries per TPDO: 6064h+6041h (48 bits), 6077h+606Ch (48 bits)."""
    facts = _facts(x608F_1=_u32(4096), x608F_2=_u32(1))
    plan = adapt_plan(facts, DriveProfile(max_entries=2), 2, 1e9)
    assert [[i.key[0] for i in p.items] for p in plan.tpdos] == [
        [0x6064, 0x6041],
        [0x6077, 0x606C],
    ]
    # one TPDO of one entry: velocity and torque are left out, required ones must fit
    one = DriveProfile(max_entries=2, tpdos=(1,))
    assert [[i.key[0] for i in p.items] for p in adapt_plan(facts, one, 2, 1e9).tpdos] == [
        [0x6064, 0x6041]
    ]
    with pytest.raises(DriveSetupError, match=r"6041h:00 .* does not fit"):
        adapt_plan(facts, DriveProfile(max_entries=1, tpdos=(1,)), 2, 1e9)


def test_the_issue_7_refusal_of_60e4_mapping_leads_to_motor_feedback() -> None:
    """The drive of issue 7 answered 0602 0000 to mapping 60E4h:01 into 1A00h:02: the
    start-up now plans again without it instead of stopping (AUTO load source)."""
    with local_rig(SIM_EDS, DriveProfile()) as rig:

        def refuse(index: int, subindex: int, od: object, data: bytes) -> None:
            if 0x1A00 <= index <= 0x1A03 and subindex and data == struct.pack("<I", 0x60E40120):
                raise SdoAbortedError(0x0602_0000)

        rig.nodes[2].add_write_callback(refuse)
        plan, _, _ = rig.master.configure()
        assert rig.stored(2, 0x1A00, 2) == entry(0x6041, 0, 16)
    assert rig.master.unmappable == frozenset({(0x60E4, 1)})
    assert plan.load_source is LoadSource.MOTOR and not plan.layout.load_measured

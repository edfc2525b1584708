"""One-pass commissioning (issue 18, part 1): ``bridge probe`` names every problem at once,
every load-scale candidate with type and mappability, writes a profile consistent with its own
findings, refuses an implausible scaling; ``config get`` of a record reads every sub-index.

Independent references: python canopen's ``LocalNode`` built from vendor EDS files the bridge
was not written against (Faulhaber MCBL 300x CO and MCBL-CF, shared/vendor_eds/README.md),
besides the Technosoft iPOS and Yiyou EuServo files; every expected value is read off the EDS
by hand, the section named. The LocalNode answers what its EDS says and stores what it is
sent: ``data_store == {}`` proves a probe wrote nothing.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import struct
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import canopen
import pytest
from canopen.sdo import SdoAbortedError

from bridge.__main__ import main
from bridge.adapt import MIN_POSITION_UNITS_PER_REV, VelocityMode
from bridge.errors import DriveSetupError
from bridge.layout import Signal
from tests.adapt_helpers import (
    ENCODER_EDS,
    FAULHABER_CF_EDS,
    FAULHABER_CO_EDS,
    TECHNOSOFT_EDS,
    YIYOU_EDS,
    local_rig,
    mirror_mode,
    require_eds,
)
from tests.paths import CONFIG
from virtual_bus.formats.drive_profile import DriveProfile, LoadSource, load_profile

DRIVES = CONFIG / "drives"
SIM_EDS = CONFIG / "drive.eds"


@contextmanager
def local_nodes(nodes: dict[int, Path]) -> Iterator[tuple[str, dict[int, canopen.LocalNode]]]:
    """LocalNodes of ``nodes`` (node-ID -> EDS) on a fresh virtual channel."""
    channel = f"probe-{uuid.uuid4().hex[:12]}"
    server = canopen.Network()
    server.NOTIFIER_CYCLE = 0.02
    server.connect(interface="virtual", channel=channel)
    made: dict[int, canopen.LocalNode] = {}
    try:
        for node_id, eds in nodes.items():
            node = canopen.LocalNode(node_id, canopen.import_od(str(require_eds(eds)), node_id))
            mirror_mode(node)
            server.add_node(node)
            made[node_id] = node
        yield channel, made
    finally:
        server.disconnect()


def probe(
    eds: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], *extra: str, **more: Path
) -> tuple[str, DriveProfile, dict[int, canopen.LocalNode]]:
    """``bridge probe --eds EDS --out P.toml`` against a LocalNode of ``eds`` (node 2) and
    ``more`` (``n5=ENCODER_EDS``: node 5); the printout, the written profile, the nodes."""
    out = tmp_path / "probed.toml"
    nodes = {2: eds} | {int(k[1:]): v for k, v in more.items()}
    with local_nodes(nodes) as (channel, made):
        argv = ["probe", "--interface", "virtual", "--channel", channel, "--drive-id", "2"]
        code = main([*argv, "--eds", str(eds), "--out", str(out), *extra])
        written = {n: dict(node.data_store) for n, node in made.items()}
    text = capsys.readouterr().out
    # exit 1 exactly when the start-up it plans would stop (the profile is written anyway)
    assert code == (1 if "start-up would stop:" in text else 0), text
    assert written[2] == {}, "a probe only reads"
    return text, load_profile(out), made


def problems(text: str) -> list[str]:
    return re.findall(r"^  \d+\. (.*)$", text, flags=re.MULTILINE)


# --- every problem at once ---------------------------------------------------------------------
def test_static_mapping_drive_is_refused_once_with_every_problem(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Faulhaber MCBL-CF: [OptionalObjects] lists no 6502h; [6064] and [60FF] PDOMapping=0;
    [1A00sub0], [1A01sub0], [1800sub1] and [1600sub0]/[1400sub1] AccessType=ro (a static
    mapping). Five reasons the bridge cannot run it -- all in one printout."""
    text, profile, _ = probe(FAULHABER_CF_EDS, tmp_path, capsys)
    found = problems(text)
    assert len(found) == 5, text
    joined = "\n".join(found)
    for needle in (
        "6064h:00 is not PDO-mappable",
        "60FFh:00 is not PDO-mappable",
        '6502h supported drive modes not readable; set mode.mode = "csv" or "pv"',
        "RPDO1 cannot be configured, the EDS marks 1400h:01, 1600h:00, 1600h:01 read-only",
        "none of the TPDOs [1, 2, 3] can be configured",
    ):
        assert needle in joined, needle
    assert "start-up would stop: 5 problem(s), all of them:" in text
    # [608Fsub1] DefaultValue=2048, [608Fsub2] 1: a plausible encoder, written as found
    assert profile.position_increments_per_rev == 2048
    assert profile.load_source is LoadSource.MOTOR  # no 60E4h, no vendor position object


def test_the_start_up_names_every_problem_before_writing(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The start-up itself (``bridge run``'s path) raises one error listing each problem,
    naming the first one's object; the LocalNode got no write."""
    with local_rig(TECHNOSOFT_EDS) as rig:
        with pytest.raises(DriveSetupError) as info:
            rig.master.configure()
        assert rig.nodes[2].data_store == {}
    exc = info.value
    # no [608F]/[6092] -> resolution unknown; [6094] has no DefaultValue -> factor unknown
    assert [p.index for p in exc.problems] == [0x608F, 0x6094]
    assert exc.index == 0x608F and "\n" not in str(exc)
    assert str(exc).startswith("drive 2: 2 problems, all found before anything was written:")
    assert "position_increments_per_rev" in str(exc) and "velocity_units_per_rev_s" in str(exc)


def test_a_profile_completed_with_the_named_keys_starts_in_one_round(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The probe's profile plus exactly the keys its problems name (values from the shipped
    iPOS profile, which a commissioning engineer would read off the drive) starts up at once:
    one round, not one per missing item."""
    text, probed, _ = probe(TECHNOSOFT_EDS, tmp_path, capsys)
    named = set(re.findall(r"set ([a-z_]+\.[a-z_]+)", "\n".join(problems(text))))
    assert named == {
        "scaling.position_increments_per_rev",
        "scaling.velocity_units_per_rev_s",
        "load.increments_per_unit",
    }
    shipped = load_profile(DRIVES / "technosoft_ipos.toml")
    field = {
        "scaling.position_increments_per_rev": "position_increments_per_rev",
        "scaling.velocity_units_per_rev_s": "velocity_units_per_rev_s",
        "load.increments_per_unit": "load_increments_per_unit",
    }
    completed = dataclasses.replace(probed, **{field[k]: getattr(shipped, field[k]) for k in named})
    with local_rig(TECHNOSOFT_EDS, completed) as rig:
        the_plan, _, mode = rig.master.configure()
    assert mode == VelocityMode.PROFILE_VELOCITY
    # the load position is 208Dh (its [208D] ParameterName=Auxiliary encoder position)
    assert the_plan.tpdos[0].items[1].key == (0x208D, 0)
    assert the_plan.layout.load_measured


# --- load-scale candidates and a consistent profile -------------------------------------------
def test_candidates_are_named_with_type_and_mappability(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Yiyou EuServo ([202A] "first encoder value,", [202B] "second encoder value", both
    INTEGER32 ro PDOMapping=1) and a CiA 406 encoder node 5 found by --scan."""
    text, profile, _ = probe(YIYOU_EDS, tmp_path, capsys, "--scan", "5", n5=ENCODER_EDS)
    lines = text[text.index("load-scale candidates (3):") :].splitlines()[1:4]
    assert "202Ah:00 'first encoder value,' (i32, PDO-mappable)" in lines[0]
    assert lines[1].startswith("  * 202Bh:00 'second encoder value' (i32, PDO-mappable)")
    assert "node 5: CiA 406 encoder, 6004h position value" in lines[2]
    assert 'load.source = "encoder", load.encoder_id = 5' in lines[2]
    assert (profile.load_source, profile.load_object) == (LoadSource.VENDOR, (0x202B, 0))
    assert profile.load_object in (profile.mappable or ())


def _eds_with(tmp_path: Path, replace: dict[str, str], append: str = "") -> Path:
    """The simulated drive's EDS with sections replaced (``[60E4sub1]`` -> text)."""
    text = SIM_EDS.read_text(encoding="utf-8")
    for section, body in replace.items():
        start = text.index(f"[{section}]")
        end = text.index("\n[", start + 1) + 1
        text = text[:start] + body + text[end:]
    path = tmp_path / "drive.eds"
    path.write_text(text + append, encoding="utf-8")
    return path


def test_the_profile_never_uses_an_object_its_own_mappable_list_leaves_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The issue's contradiction: a drive whose EDS has 60E4h:01 but marks it not
    PDO-mappable, and an auxiliary-encoder vendor object that is. The probe lists 60E4h:01 as
    NOT PDO-mappable and writes the vendor object, never ``load.source = "60E4h:01"``."""
    section = SIM_EDS.read_text(encoding="utf-8")
    start = section.index("[60E4sub1]")
    body = section[start : section.index("\n[", start + 1) + 1]
    aux = (
        "\n[2300]\nParameterName=Auxiliary encoder position\nObjectType=0x7\nDataType=0x0004\n"
        "AccessType=ro\nDefaultValue=0\nPDOMapping=1\n"
    )
    eds = _eds_with(tmp_path, {"60E4sub1": body.replace("PDOMapping=1", "PDOMapping=0")}, aux)
    text, profile, _ = probe(eds, tmp_path, capsys)
    assert "60E4h:01 'additional position actual value 1' (i32, NOT PDO-mappable)" in text
    assert (0x60E4, 1) not in (profile.mappable or ())
    assert profile.load_source is LoadSource.VENDOR and profile.load_object == (0x2300, 0)
    assert "the scale of load.object is unknown: set load.increments_per_unit" in text


def test_an_encoder_of_one_increment_per_revolution_is_refused_with_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """6092h feed constant and 6091h gear ratio at their CiA 402 defaults 1/1: 6064h would
    count one unit per motor revolution. Refused, naming where the number came from; the
    profile leaves the value out instead of writing 1."""
    factor = "\n[{i}]\nParameterName={n}\nObjectType=0x9\nSubNumber=3\n" + "".join(
        f"\n[{{i}}sub{s}]\nParameterName={t}\nObjectType=0x7\nDataType={d}\nAccessType={a}\n"
        f"DefaultValue={v}\nPDOMapping=0\n"
        for s, t, d, a, v in (
            (0, "Highest sub-index supported", "0x0005", "ro", 2),
            (1, "Numerator", "0x0007", "rw", 1),
            (2, "Denominator", "0x0007", "rw", 1),
        )
    )
    extra = factor.format(i="6091", n="Gear ratio") + factor.format(i="6092", n="Feed constant")
    eds = _eds_with(tmp_path, {}, extra)
    text, profile, _ = probe(eds, tmp_path, capsys)
    (problem,) = problems(text)
    assert "6064h would count 1 units per motor revolution (6092h feed constant 1/1 x 6091h " in (
        problem
    )
    assert f"at least {MIN_POSITION_UNITS_PER_REV}" in problem
    assert "set scaling.position_increments_per_rev" in problem
    assert profile.position_increments_per_rev is None


def test_a_coarse_encoder_given_in_the_profile_is_refused_too() -> None:
    with local_rig(SIM_EDS, DriveProfile(position_increments_per_rev=4)) as rig:
        with pytest.raises(DriveSetupError, match=r"count 4 units per motor revolution"):
            rig.master.configure()
        assert rig.nodes[2].data_store == {}


def test_a_new_drive_starts_up_on_what_its_eds_offers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Faulhaber MCBL 300x CO, which the bridge was not written against: [6502]
    DefaultValue=37 (bits 0, 2, 5: no CSV) -> profile velocity; [608F] 3000/1, [6092] 3000/1,
    [6091] 1/1 -> 3000 units per revolution; mapping records of 4 entries ([1A00sub4]); no
    6077h (it has [6078] current actual value) and no 60E4h: motor feedback, said so."""
    text, probed, _ = probe(FAULHABER_CO_EDS, tmp_path, capsys)
    assert "start-up plan: 6060h = 3 (PROFILE_VELOCITY)" in text
    assert probed.position_increments_per_rev == 3000 and probed.max_entries == 4
    with local_rig(FAULHABER_CO_EDS, probed) as rig:
        the_plan, facts, mode = rig.master.configure()
        s = rig.stored
        assert mode == 3 and s(2, 0x6060, 0) == 3
        assert facts.supported_modes == 37
        # TPDO1 = 6064h + 6041h (48 bits; 606Ch would make 80), TPDO2 = 606Ch
        assert [s(2, 0x1A00, i) for i in range(3)] == [2, 0x60640020, 0x60410010]
        assert [s(2, 0x1A01, i) for i in range(2)] == [1, 0x606C0020]
        assert s(2, 0x6083, 0) == 0xFFFF_FFFF and s(2, 0x6084, 0) == 0xFFFF_FFFF
    signals = [sig for f in the_plan.layout.frames for sig in f.signals]
    assert Signal.TORQUE not in signals and not the_plan.layout.load_measured
    assert the_plan.scaling.position_increments_per_rev == 3000


# --- messages ----------------------------------------------------------------------------------
def test_unreadable_product_code_is_said_not_shown_as_zero(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The iPOS EDS has no [1018sub2]: the probe says "unreadable", not 0x00000000."""
    text, profile, _ = probe(TECHNOSOFT_EDS, tmp_path, capsys)
    assert "1018h product code    not readable" in text
    assert profile.name == "vendor 0x000001A3 product unreadable"
    assert "0x00000000" not in profile.name and profile.product_code is None


def test_an_unmappable_warning_names_the_drive_once(caplog: pytest.LogCaptureFixture) -> None:
    with local_rig(SIM_EDS, DriveProfile()) as rig:

        def refuse(index: int, subindex: int, od: object, data: bytes) -> None:
            if 0x1A00 <= index <= 0x1A03 and subindex and data == struct.pack("<I", 0x60770010):
                raise SdoAbortedError(0x0604_0041)

        rig.nodes[2].add_write_callback(refuse)
        with caplog.at_level(logging.WARNING, logger="bridge"):
            rig.master.configure()
    (line,) = [r.getMessage() for r in caplog.records if "planning without it" in r.getMessage()]
    assert line.startswith("drive 2 object 1A01h:02") and "drive 2: drive 2" not in line


# --- config get of a record ------------------------------------------------------------------
def test_config_get_of_a_record_reads_every_sub_index(capsys: pytest.CaptureFixture[str]) -> None:
    """Faulhaber MCBL-CO [1018sub4] Serial number has no DefaultValue: the LocalNode answers
    060A 0023 for it. ``config get 1018h`` prints sub-indices 0..3 with their EDS values and
    sub-index 4 with its abort code, and exits 1."""
    eds = require_eds(FAULHABER_CO_EDS)
    with local_nodes({2: eds}) as (channel, _):
        argv = ["config", "get", "--interface", "virtual", "--channel", channel]
        code = main([*argv, "--node-id", "2", "--eds", str(eds), "--timeout", "2", "1018h"])
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert code == 1
    assert lines[:4] == [
        "1018h:00 Number of Entries = 4 (0x04)",
        "1018h:01 Vendor Id = 327 (0x00000147)",
        "1018h:02 Product Code = 3150 (0x00000C4E)",
        "1018h:03 Revision number = 2 (0x00000002)",
    ]
    assert lines[4] == (
        "1018h:04 Serial number: not read, SDO abort 0x060A0023 (resource not available)"
    )
    assert err.count("\n") == 1 and "1 of 5 objects refused" in err

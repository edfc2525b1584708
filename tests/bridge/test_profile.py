"""Drive profiles (virtual_bus.formats.drive_profile), ``bridge probe`` and
``bridge run --drive-profile`` on the
command line, the bus-load check, and the loop with an adapted layout against the simulated
drive (motor feedback, other PDO numbers)."""

from __future__ import annotations

import dataclasses
import uuid
from pathlib import Path

import can
import canopen
import pytest

from bridge.__main__ import COMMANDS, DESCRIPTION, PROG, main
from bridge.cycle import BridgeState, StopReason
from bridge.errors import BridgeConfigError
from bridge.interpolator import Move
from bridge.layout import Signal
from bridge.node import BridgeConfig
from bridge.params import BridgeParams
from bridge.run import check_bus_load
from cmdline import cli
from hil.harness import simulated_axis
from regulator import RegulatorConfig
from tests.adapt_helpers import ENCODER_EDS, TECHNOSOFT_EDS, mirror_mode, require_eds
from tests.paths import ROOT
from virtual_bus import Interface
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.drive_profile import (
    DriveProfile,
    DriveProfileError,
    LoadSource,
    load_profile,
    render_profile,
)

DRIVES = ROOT / "config" / "drives"
AXIS = load_axis(ROOT / "config" / "paper_axis.toml")


@pytest.mark.parametrize("name", ["simdrive", "technosoft_ipos", "yiyou_euservo"])
def test_shipped_profiles_load_and_round_trip(name: str, tmp_path: Path) -> None:
    profile = load_profile(DRIVES / f"{name}.toml")
    out = tmp_path / "p.toml"
    out.write_text(render_profile(profile), encoding="utf-8")
    assert load_profile(out) == profile


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('[mode]\nmode = "turbo"\n', "mode.mode = 'turbo': allowed ['auto', 'csv', 'pv']"),
        ("[pdo]\ntpdos = [0]\n", "pdo.tpdos: tpdos = (0,): a list of distinct TPDO numbers"),
        ("[pdo]\nmax_entries = 65\n", "pdo.max_entries: max_entries = 65: an integer 1..64"),
        ('[load]\nsource = "vendor"\n', "load.object: load_object = None: required with"),
        ('[load]\nobject = "xyz"\n', "load.object = 'xyz': write an object as \"IIIIh:SS\""),
        ("[scaling]\nposition_increments_per_rev = -1\n", "a finite number > 0"),
        ("[scaling]\nspeed = 1\n", "scaling.speed: unknown key; allowed"),
        ("[motor]\nx = 1\n", "[motor]: unknown table; allowed"),
        ("[drive\n", "not valid TOML"),
        ('[load]\nsource = "encoder"\nencoder_id = 200\n', "a CANopen node-ID 1..127"),
    ],
)
def test_bad_profile_is_one_line_naming_key_value_and_allowed(
    text: str, needle: str, tmp_path: Path
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(DriveProfileError) as info:
        load_profile(path)
    message = str(info.value)
    assert needle in message and "\n" not in message and str(path) in message


def test_run_with_a_bad_profile_exits_2_before_opening_the_bus(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[mode]\nmode = "turbo"\n', encoding="utf-8")
    argv = ["run", "--interface", "virtual", "--channel", "x", "--axis"]
    argv += [str(ROOT / "config" / "paper_axis.toml"), "--seconds", "1"]
    assert main([*argv, "--drive-profile", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "mode.mode = 'turbo'" in err


def test_default_bitrate_is_1_mbit_and_an_overfull_bus_is_refused() -> None:
    parser = cli.build_parser(PROG, DESCRIPTION, cli.load_commands("bridge", COMMANDS))
    args = parser.parse_args(["run", "--interface", "i", "--channel", "c", "--axis", "a"])
    assert args.bitrate == 1_000_000
    assert parser.parse_args(["busload"]).bitrate == 1_000_000
    check_bus_load(0.44, 1_000_000, 1e-3)  # one axis at 1 ms and 1 Mbit/s fits
    with pytest.raises(BridgeConfigError, match="does not fit; use --bitrate 1000000"):
        check_bus_load(1.76, 250_000, 1e-3)


def test_probe_command_against_a_localnode_writes_the_profile(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`python -m bridge probe` over a virtual bus to canopen's LocalNode of the iPOS EDS."""
    channel = f"probe-{uuid.uuid4().hex[:12]}"
    server = canopen.Network()
    server.NOTIFIER_CYCLE = 0.02
    server.connect(interface="virtual", channel=channel)
    try:
        node = canopen.LocalNode(2, canopen.import_od(str(require_eds(TECHNOSOFT_EDS)), 2))
        mirror_mode(node)
        server.add_node(node)
        out = tmp_path / "ipos.toml"
        argv = ["probe", "--interface", "virtual", "--channel", channel, "--drive-id", "2"]
        code = main([*argv, "--eds", str(TECHNOSOFT_EDS), "--out", str(out)])
        written = dict(node.data_store)
    finally:
        server.disconnect()
    text = capsys.readouterr().out
    assert code == 1  # the start-up would stop: the profile is written, to be completed
    assert "6502h drive modes     0x001F0065" in text
    assert "start-up would stop: 3 problem(s), all of them:" in text
    assert "1. drive 2: 608Fh position encoder resolution not readable" in text
    probed = load_profile(out)
    shipped = load_profile(DRIVES / "technosoft_ipos.toml")
    assert probed.mappable == shipped.mappable and probed.vendor_id == 0x1A3
    assert written == {}


def _params() -> BridgeParams:
    reg = RegulatorConfig(kv=AXIS.control.kv, cycle_s=AXIS.control.position_cycle)
    return BridgeParams.for_axis(AXIS, reg)


def test_loop_on_motor_feedback_with_other_pdo_numbers_against_the_simulated_drive() -> None:
    """The simulated drive configured like a drive without a load measuring system and with
    TPDO3/TPDO4 instead of 1/2: the loop closes on the motor encoder and reaches the target."""
    profile = dataclasses.replace(
        load_profile(DRIVES / "simdrive.toml"), load_source=LoadSource.MOTOR, tpdos=(3, 4)
    )
    config = BridgeConfig(profile=profile)
    with simulated_axis(AXIS, _params(), interface=Interface.VIRTUAL, bridge_config=config) as sim:
        layout = sim.bridge.layout
        assert [f.can_id for f in layout.frames] == [0x382, 0x482]
        assert layout.frames[0].signals == (Signal.MOTOR_POSITION, Signal.STATUSWORD, Signal.TORQUE)
        assert not layout.load_measured
        c = sim.bridge.controller
        sim.bridge.run(until=lambda b: b.controller.state is not BridgeState.ENABLING)
        assert c.state is BridgeState.RUNNING
        start = c.load_position
        c.queue_move(Move(start + 0.004, 0.02))
        sim.bridge.run(cycles=900)
        assert c.state is BridgeState.RUNNING, c.stop_message
        kr = AXIS.transmission_ratio
        motor_as_load = sim.drive.plant.motor_position_rad / kr
        assert motor_as_load == pytest.approx(start + 0.004, abs=2e-6)
        assert c.load_position == pytest.approx(motor_as_load, abs=1e-6)
        assert sim.bridge.counters.missed == 0


def test_adaptive_start_up_of_the_simulated_drive_is_the_contract_layout() -> None:
    with simulated_axis(AXIS, _params(), interface=Interface.VIRTUAL) as sim:
        info = sim.bridge.drive_info
    assert info is not None
    assert [(f.can_id, f.fmt) for f in info.layout.frames] == [(0x182, "<ii"), (0x282, "<Hhi")]
    assert info.scaling.rated_torque_nm == pytest.approx(50.0)
    assert info.scaling.position_increments_per_rev == 2**20
    assert DriveProfile().load_source is LoadSource.AUTO


@pytest.mark.parametrize("fault", ["heartbeat lost", "emcy"])
def test_loop_with_a_cia406_encoder_node_as_the_load_scale(fault: str) -> None:
    """The simulated drive without its load scale in the PDOs and python canopen's
    LocalNode of a CiA 406 encoder (node 5) on the same bus: the bridge configures the
    encoder's TPDO1 (6004h on SYNC), canopen's PDO code sends the load position from that
    mapping every SYNC, the loop closes on it; when the encoder's heartbeat stops, or the
    encoder sends an EMCY (canopen's own EmcyProducer, 7300h sensor error), the axis stops
    with the encoder named and no set point but 0 after it."""
    channel = f"enc-{uuid.uuid4().hex[:12]}"
    enc_bus = can.Bus(interface="virtual", channel=channel)
    enc_net = canopen.Network(enc_bus)
    notifier = can.Notifier(enc_bus, enc_net.listeners, 0.02)
    encoder = canopen.LocalNode(5, canopen.import_od(str(ENCODER_EDS), 5))
    enc_net.add_node(encoder)
    profile = dataclasses.replace(
        load_profile(DRIVES / "simdrive.toml"),
        load_source=LoadSource.ENCODER,
        encoder_id=5,
        load_increments_per_unit=1e6,  # 1 µm steps
    )
    beats = {"on": True, "syncs": 0}
    try:
        with simulated_axis(
            AXIS, _params(), channel=channel, bridge_config=BridgeConfig(profile=profile)
        ) as sim:
            notifier.stop(2.0)
            encoder.nmt.stop_heartbeat()  # wall clock; below on the loop's SYNC count
            plant = sim.drive.plant
            encoder.tpdo.read(from_od=False)  # the mapping the bridge wrote
            position = encoder.tpdo[1]["Position value"]

            def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
                # sampled at SYNC k, before the drive's physics runs the cycle
                position.raw = round(plant.load_position * 1e6) & 0xFFFF_FFFF
                encoder.tpdo[1].transmit()
                beats["syncs"] += 1
                if beats["on"] and beats["syncs"] % 100 == 0:  # 100 ms heartbeat
                    enc_net.send_message(0x705, b"\x05")

            enc_net.subscribe(0x080, on_sync)
            drive_poll = sim.bridge.peer_poll
            assert drive_poll is not None

            def poll() -> int:
                n = 0
                while (msg := enc_bus.recv(0.0)) is not None:
                    for listener in enc_net.listeners:
                        listener.on_message_received(msg)
                    n += 1
                return n + drive_poll()

            sim.bridge.peer_poll = poll
            layout = sim.bridge.layout
            assert [(f.can_id, f.fmt) for f in layout.frames][-1] == (0x185, "<i")
            c = sim.bridge.controller
            sim.bridge.run(until=lambda b: b.controller.state is not BridgeState.ENABLING)
            assert c.state is BridgeState.RUNNING, c.stop_message
            start = c.load_position
            c.queue_move(Move(start + 0.004, 0.02))
            sim.bridge.run(cycles=900)
            assert c.state is BridgeState.RUNNING, c.stop_message
            assert sim.drive.plant.load_position == pytest.approx(start + 0.004, abs=3e-6)
            assert c.load_position == pytest.approx(plant.load_position, abs=2e-6)
            assert sim.bridge.counters.missed == 0
            if fault == "emcy":
                c.queue_move(Move(start, 0.02))  # moving when the encoder reports its error
                sim.bridge.run(cycles=20)
                encoder.emcy.send(0x7300, 0x01)
                sim.bridge.run(cycles=2)
                assert c.stop_reason is StopReason.ENCODER_EMCY
                assert "encoder node 5 EMCY error code 0x7300" in c.stop_message
                assert c.omega_r == 0.0
            else:
                beats["on"] = False
                sim.bridge.run(until=lambda b: b.controller.state is BridgeState.STOPPED)
                assert c.stop_reason is StopReason.HEARTBEAT_LOST
                assert "encoder node 5" in c.stop_message
    finally:
        notifier.stop(2.0)
        enc_bus.shutdown()

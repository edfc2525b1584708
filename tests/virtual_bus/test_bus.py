"""Bus configuration, AUTO selection, frame passing, vcan setup/CLI and the leak fixture."""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import socket
import subprocess
import threading
import uuid
from collections.abc import Sequence
from pathlib import Path

import can
import pytest

from tests.conftest import LeakAllowance, find_leaks, take_snapshot
from tests.paths import ROOT
from virtual_bus import (
    CIA301_BITRATES,
    BusConfig,
    BusConfigError,
    BusUnavailableError,
    HostProbe,
    Interface,
    LinkKind,
    Missing,
    SetupOutcome,
    VcanProblem,
    VcanSetupError,
    available_modes,
    open_bus,
    resolve,
    setup_vcan,
)
from virtual_bus.__main__ import main
from virtual_bus.open import SOCKETCAN_RCVBUF_BYTES, _driver_messages
from virtual_bus.vcan import check_ifname, run_ip

# --------------------------------------------------------------------------- config


def test_defaults() -> None:
    cfg = BusConfig()
    assert cfg.interface is Interface.AUTO
    assert cfg.channel is None
    assert cfg.bitrate == 500_000
    assert cfg.receive_own_messages is False
    assert cfg.socketcan_channel == "vcan0"
    assert cfg.virtual_channel == "backlash-bridge"


def test_config_is_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        BusConfig().bitrate = 250_000  # type: ignore[misc]


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        ("virtual", Interface.VIRTUAL),
        ("socketcan", Interface.SOCKETCAN),
        ("auto", Interface.AUTO),
        (Interface.VIRTUAL, Interface.VIRTUAL),
        ("pcan", "pcan"),
        ("kvaser", "kvaser"),
    ],
)
def test_interface_names_are_normalised(given: Interface | str, expected: Interface | str) -> None:
    assert BusConfig(interface=given).interface == expected


def test_unknown_interface_is_rejected_with_allowed_list() -> None:
    with pytest.raises(BusConfigError, match=r"unknown interface 'nonsense'.*'virtual'"):
        BusConfig(interface="nonsense")


def test_udp_multicast_is_refused() -> None:
    with pytest.raises(BusConfigError, match=r"udp_multicast.*real network interface"):
        BusConfig(interface="udp_multicast")


@pytest.mark.parametrize("bitrate", CIA301_BITRATES)
def test_cia301_bitrates_are_accepted(bitrate: int) -> None:
    assert BusConfig(bitrate=bitrate).bitrate == bitrate


@pytest.mark.parametrize("bitrate", [100_000, 0, -500_000, 500_001, 2_000_000, True, 500e3])
def test_other_bitrates_are_rejected(bitrate: object) -> None:
    with pytest.raises(BusConfigError, match="bitrate") as info:
        BusConfig(bitrate=bitrate)  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("channel", ["bad name", "x" * 16, "-vcan", "a/b", "eth0:1", ""])
def test_bad_socketcan_channel_is_rejected(channel: str) -> None:
    with pytest.raises(BusConfigError, match=r"channel|interface name"):
        BusConfig(interface=Interface.SOCKETCAN, channel=channel)


def test_virtual_channel_may_be_any_nonempty_name() -> None:
    assert BusConfig(interface=Interface.VIRTUAL, channel="my bus/1").channel == "my bus/1"


@pytest.mark.parametrize("name", ["vcan0", "x" * 15, "can_test-1.2", "_a"])
def test_valid_interface_names(name: str) -> None:
    assert check_ifname(name) == name


# ------------------------------------------------------ python-can's own configuration


@pytest.fixture
def python_can_config(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """An isolated python-can configuration: no environment variables, no can.rc, and a
    config file path that the test fills (the user's ~/can.conf is not read)."""
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(can, "rc", {})
    return tmp_path / "can.ini"


def test_python_can_file_is_honoured(python_can_config: Path) -> None:
    python_can_config.write_text(
        "[default]\ninterface = virtual\nchannel = from-file\nbitrate = 250000\n"
    )
    cfg = BusConfig.from_python_can_config(path=python_can_config)
    assert cfg == BusConfig(interface=Interface.VIRTUAL, channel="from-file", bitrate=250_000)


def test_python_can_environment_is_honoured(
    python_can_config: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CAN_INTERFACE", "socketcan")
    monkeypatch.setenv("CAN_CHANNEL", "vcan1")
    cfg = BusConfig.from_python_can_config(path=python_can_config)
    assert cfg == BusConfig(interface=Interface.SOCKETCAN, channel="vcan1")


def test_nothing_configured_means_auto(python_can_config: Path) -> None:
    assert BusConfig.from_python_can_config(path=python_can_config) == BusConfig()


def test_channel_without_interface_keeps_channel(
    python_can_config: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CAN_CHANNEL", "vcan3")
    cfg = BusConfig.from_python_can_config(path=python_can_config)
    assert cfg == BusConfig(interface=Interface.AUTO, channel="vcan3")


def test_explicit_interface_ignores_python_can_config(python_can_config: Path) -> None:
    python_can_config.write_text("[default]\ninterface = socketcan\nchannel = can0\n")
    cfg = BusConfig.from_python_can_config("virtual", "mine", path=python_can_config)
    assert cfg == BusConfig(interface=Interface.VIRTUAL, channel="mine")


def test_bad_python_can_config_is_named(python_can_config: Path) -> None:
    python_can_config.write_text("[default]\ninterface = bogus\n")
    with pytest.raises(BusConfigError, match=r"python-can configuration.*bogus"):
        BusConfig.from_python_can_config(path=python_can_config)


def test_non_cia301_bitrate_in_python_can_config_is_rejected(python_can_config: Path) -> None:
    python_can_config.write_text("[default]\ninterface = virtual\nbitrate = 100000\n")
    with pytest.raises(BusConfigError, match="100000 bit/s is not a CiA 301 bit rate"):
        BusConfig.from_python_can_config(path=python_can_config)


# ----------------------------------------------------------------- AUTO selection


class FakeProbe(HostProbe):
    """A host whose SocketCAN support is given, not read."""

    def __init__(self, af_can_problem: str | None, links: dict[str, LinkKind]) -> None:
        super().__init__()
        self._problem = af_can_problem
        self._links = links

    def af_can_problem(self) -> str | None:
        return self._problem

    def link_kind(self, name: str) -> LinkKind:
        return self._links.get(name, LinkKind.MISSING)


NO_KERNEL = FakeProbe("the kernel refuses socket(AF_CAN, ...)", {})
VCAN_HOST = FakeProbe(None, {"vcan0": LinkKind.VCAN, "vcan1": LinkKind.VCAN})
KERNEL_NO_VCAN = FakeProbe(None, {"can0": LinkKind.CAN, "eth0": LinkKind.NOT_CAN})


def test_auto_without_kernel_support_picks_virtual() -> None:
    choice = resolve(BusConfig(), NO_KERNEL)
    assert (choice.interface, choice.channel) == (Interface.VIRTUAL, "backlash-bridge")
    assert "AF_CAN" in choice.reason


def test_auto_with_vcan0_picks_socketcan() -> None:
    choice = resolve(BusConfig(), VCAN_HOST)
    assert (choice.interface, choice.channel) == (Interface.SOCKETCAN, "vcan0")
    assert choice.python_can_interface == "socketcan"


def test_auto_honours_configured_channel() -> None:
    choice = resolve(BusConfig(channel="vcan1"), VCAN_HOST)
    assert (choice.interface, choice.channel) == (Interface.SOCKETCAN, "vcan1")
    fallback = resolve(BusConfig(channel="vcan1"), NO_KERNEL)
    assert (fallback.interface, fallback.channel) == (Interface.VIRTUAL, "vcan1")


def test_auto_without_vcan0_picks_virtual_and_says_how_to_create_it() -> None:
    choice = resolve(BusConfig(), KERNEL_NO_VCAN)
    assert choice.interface is Interface.VIRTUAL
    assert "python -m virtual_bus setup vcan0" in choice.reason


def test_auto_never_picks_hardware_can() -> None:
    choice = resolve(BusConfig(channel="can0"), KERNEL_NO_VCAN)
    assert choice.interface is Interface.VIRTUAL
    assert "hardware" in choice.reason


@pytest.mark.parametrize(
    ("probe", "channel", "missing", "text"),
    [
        (NO_KERNEL, "vcan0", Missing.AF_CAN, "AF_CAN"),
        (KERNEL_NO_VCAN, "vcan0", Missing.INTERFACE, "vcan0 does not exist"),
        (KERNEL_NO_VCAN, "eth0", Missing.NOT_CAN, "eth0 is not a CAN interface"),
    ],
)
def test_explicit_socketcan_says_what_is_missing(
    probe: HostProbe, channel: str, missing: Missing, text: str
) -> None:
    config = BusConfig(interface=Interface.SOCKETCAN, channel=channel)
    with pytest.raises(BusUnavailableError, match=text) as info:
        open_bus(config, probe)
    assert info.value.missing is missing
    assert info.value.channel == channel
    assert isinstance(info.value, OSError)


def test_explicit_socketcan_on_hardware_can_is_allowed() -> None:
    choice = resolve(BusConfig(interface=Interface.SOCKETCAN, channel="can0"), KERNEL_NO_VCAN)
    assert (choice.interface, choice.channel) == (Interface.SOCKETCAN, "can0")


def test_other_python_can_interfaces_are_passed_through() -> None:
    choice = resolve(BusConfig(interface="pcan", channel="PCAN_USBBUS1"), NO_KERNEL)
    assert (choice.interface, choice.channel, choice.python_can_interface) == (
        "pcan",
        "PCAN_USBBUS1",
        "pcan",
    )


def test_available_modes_follow_the_probe() -> None:
    assert available_modes(NO_KERNEL) == (Interface.VIRTUAL,)
    assert available_modes(KERNEL_NO_VCAN) == (Interface.VIRTUAL,)
    assert available_modes(VCAN_HOST) == (Interface.VIRTUAL, Interface.SOCKETCAN)


def _fake_sys(tmp_path: Path) -> Path:
    """A /sys tree: vcan0 (virtual, CAN), can0 (device, CAN), eth0 (virtual, ethernet)."""
    net = tmp_path / "class" / "net"
    net.mkdir(parents=True)
    for name, parent, arphrd in [
        ("vcan0", "devices/virtual/net", 280),
        ("can0", "devices/platform/soc/can0/net", 280),
        ("eth0", "devices/virtual/net", 1),
    ]:
        device = tmp_path / parent / name
        device.mkdir(parents=True)
        (device / "type").write_text(f"{arphrd}\n")
        (net / name).symlink_to(device)
    return net


def test_link_kind_reads_sys_class_net(tmp_path: Path) -> None:
    probe = HostProbe(_fake_sys(tmp_path))
    assert probe.link_kind("vcan0") is LinkKind.VCAN
    assert probe.link_kind("can0") is LinkKind.CAN
    assert probe.link_kind("eth0") is LinkKind.NOT_CAN
    assert probe.link_kind("vcan9") is LinkKind.MISSING


def test_this_host_auto_choice_matches_available_modes() -> None:
    """On this machine (no AF_CAN) AUTO opens the virtual bus; where vcan0 exists, SocketCAN."""
    expected = "socketcan" if Interface.SOCKETCAN in available_modes() else "virtual"
    bus = open_bus(BusConfig(channel="vcan0"))
    try:
        kind = "socketcan" if "socketcan" in type(bus).__module__ else "virtual"
        assert kind == expected
    finally:
        bus.shutdown()


def test_explicit_socketcan_fails_cleanly_where_unavailable() -> None:
    if Interface.SOCKETCAN in available_modes():
        pytest.skip("this host has vcan0")
    with pytest.raises(BusUnavailableError):
        open_bus(BusConfig(interface=Interface.SOCKETCAN))


def test_socketcan_choice_reaches_python_can_socketcan_backend() -> None:
    """With a probe that claims vcan0, open_bus hands the request to python-can's socketcan
    backend, which fails with the kernel's OSError (here: no AF_CAN; elsewhere: no vcan0)."""
    if Interface.SOCKETCAN in available_modes():
        pytest.skip("this host has vcan0; the real path is covered by the vcan tests")
    with pytest.raises(OSError) as info:
        open_bus(BusConfig(), VCAN_HOST)
    assert not isinstance(info.value, BusUnavailableError)


@pytest.mark.vcan
def test_a_socketcan_bus_gets_its_receive_buffer_past_rmem_max() -> None:
    """open_bus asks for SOCKETCAN_RCVBUF_BYTES of receive buffer and, as root (the guest),
    gets it although net.core.rmem_max is smaller (SO_RCVBUFFORCE, as candump's -r): the
    kernel reports twice what was set (socket(7)); SO_RCVBUF alone would stop at rmem_max."""
    rmem_max = int(Path("/proc/sys/net/core/rmem_max").read_text())
    assert rmem_max < SOCKETCAN_RCVBUF_BYTES  # else this says nothing of the forcing
    bus = open_bus(BusConfig(interface=Interface.SOCKETCAN, channel="vcan0"))
    try:
        got = bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)  # type: ignore[attr-defined]
    finally:
        bus.shutdown()
    assert got == 2 * SOCKETCAN_RCVBUF_BYTES, (got, rmem_max)


def test_a_driver_note_unrelated_to_the_failure_is_left_out() -> None:
    """pcan logs that it lacks the ``uptime`` package while its bus opens; that says nothing of
    why the bus failed, so the error leaves it out (other driver messages stay)."""
    with _driver_messages() as said:
        logging.getLogger("can.pcan").warning(
            "uptime library not available, timestamps are relative to boot time and not to "
            "Epoch UTC"
        )
        logging.getLogger("can.kvaser").warning("Kvaser canlib is unavailable.")
    assert said == ["Kvaser canlib is unavailable."]


# ---------------------------------------------------------------- frames on the bus


def test_frames_pass_both_ways_in_order(bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
    a, b = bus_pair
    sent = [
        can.Message(arbitration_id=0x181 + i % 4, data=i.to_bytes(2, "big"), is_extended_id=False)
        for i in range(50)
    ]
    sent.append(can.Message(arbitration_id=0x1ABCDE, data=b"\x01", is_extended_id=True))
    sent.append(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1))
    for msg in sent:
        a.send(msg)
    got = [b.recv(timeout=1.0) for _ in sent]
    assert all(m is not None for m in got)
    for s, g in zip(sent, got, strict=True):
        assert g is not None
        assert (g.arbitration_id, g.is_extended_id, g.is_remote_frame, g.dlc, bytes(g.data)) == (
            s.arbitration_id,
            s.is_extended_id,
            s.is_remote_frame,
            s.dlc,
            bytes(s.data),
        )
    assert a.recv(timeout=0) is None  # receive_own_messages is False
    b.send(can.Message(arbitration_id=0x601, data=b"\x40\x00\x10\x00"))
    back = a.recv(timeout=1.0)
    assert back is not None and back.arbitration_id == 0x601


def test_separate_virtual_channels_are_isolated() -> None:
    one = open_bus(BusConfig(interface=Interface.VIRTUAL, channel=f"iso-{uuid.uuid4().hex}"))
    two = open_bus(BusConfig(interface=Interface.VIRTUAL, channel=f"iso-{uuid.uuid4().hex}"))
    try:
        one.send(can.Message(arbitration_id=0x100))
        assert two.recv(timeout=0) is None
    finally:
        one.shutdown()
        two.shutdown()


# ------------------------------------------------------------------- vcan setup


class FakeIp:
    """Stands in for ``ip``: answers each command from a script, records what ran."""

    def __init__(self, answers: dict[str, tuple[int, str, str]]) -> None:
        self.answers = answers  # verb ("add", "show", "up") -> (returncode, stdout, stderr)
        self.commands: list[tuple[str, ...]] = []

    def __call__(self, args: Sequence[str]) -> subprocess.CompletedProcess[str]:
        self.commands.append(tuple(args))
        verb = "show" if "show" in args else "up" if "up" in args else "add"
        rc, out, err = self.answers.get(verb, (0, "", ""))
        return subprocess.CompletedProcess(list(args), rc, out, err)


ADD = ("ip", "link", "add", "dev", "vcan0", "type", "vcan")
UP = ("ip", "link", "set", "up", "vcan0")
SHOW = ("ip", "-details", "-json", "link", "show", "dev", "vcan0")
# ip's real messages (iproute2 6.1 as root on a kernel without vcan printed the first one).
UNKNOWN_TYPE = "Error: Unknown device type.\n"
NOT_SUPPORTED = "RTNETLINK answers: Operation not supported\n"
NOT_PERMITTED = "RTNETLINK answers: Operation not permitted\n"
EXISTS = "RTNETLINK answers: File exists\n"


def _link_json(kind: str | None) -> str:
    link: dict[str, object] = {"ifindex": 5, "ifname": "vcan0", "link_type": "can"}
    if kind is not None:
        link["linkinfo"] = {"info_kind": kind}
    return json.dumps([link])


def test_setup_runs_exactly_the_two_ip_commands() -> None:
    ip = FakeIp({})
    assert setup_vcan("vcan0", ip) is SetupOutcome.CREATED
    assert ip.commands == [ADD, UP]


@pytest.mark.parametrize(
    ("stderr", "problem", "text"),
    [
        (NOT_PERMITTED, VcanProblem.NOT_PERMITTED, "needs root or CAP_NET_ADMIN"),
        (UNKNOWN_TYPE, VcanProblem.NO_VCAN_MODULE, "no vcan module.*modprobe vcan"),
        (NOT_SUPPORTED, VcanProblem.NO_VCAN_MODULE, "no vcan module.*modprobe vcan"),
        ("RTNETLINK answers: No buffer space available\n", VcanProblem.OTHER, "exit status 2"),
    ],
)
def test_setup_failure_says_what_is_missing(stderr: str, problem: VcanProblem, text: str) -> None:
    ip = FakeIp({"add": (2, "", stderr)})
    with pytest.raises(VcanSetupError, match=text) as info:
        setup_vcan("vcan0", ip)
    assert info.value.problem is problem
    assert info.value.returncode == 2
    assert info.value.command == ADD
    assert stderr.strip() in str(info.value)
    assert ip.commands == [ADD]  # nothing else was tried


def test_existing_vcan_is_only_brought_up() -> None:
    ip = FakeIp({"add": (2, "", EXISTS), "show": (0, _link_json("vcan"), "")})
    assert setup_vcan("vcan0", ip) is SetupOutcome.ALREADY_EXISTED
    assert ip.commands == [ADD, SHOW, UP]


@pytest.mark.parametrize("kind", ["veth", None])
def test_existing_non_vcan_interface_is_left_alone(kind: str | None) -> None:
    ip = FakeIp({"add": (2, "", EXISTS), "show": (0, _link_json(kind), "")})
    with pytest.raises(VcanSetupError, match="not a vcan interface") as info:
        setup_vcan("vcan0", ip)
    assert info.value.problem is VcanProblem.NOT_VCAN
    assert UP not in ip.commands


def test_bring_up_without_rights_is_reported() -> None:
    ip = FakeIp(
        {
            "add": (2, "", EXISTS),
            "show": (0, _link_json("vcan"), ""),
            "up": (2, "", NOT_PERMITTED),
        }
    )
    with pytest.raises(VcanSetupError, match="needs root") as info:
        setup_vcan("vcan0", ip)
    assert info.value.command == UP


def test_missing_ip_command_is_reported() -> None:
    def no_ip(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
        raise FileNotFoundError(2, "No such file or directory", "ip")

    with pytest.raises(VcanSetupError, match="iproute2") as info:
        setup_vcan("vcan0", no_ip)
    assert info.value.problem is VcanProblem.NO_IP_COMMAND


@pytest.mark.parametrize("name", ["", "x" * 16, "-dev", "a b", "a/b", "vcan0:1", "ü0"])
def test_invalid_names_never_reach_ip(name: str) -> None:
    ip = FakeIp({})
    with pytest.raises(BusConfigError, match="interface name"):
        setup_vcan(name, ip)
    assert ip.commands == []


@pytest.mark.skipif(shutil.which("ip") is None, reason="no ip command on this host")
def test_real_ip_gives_an_honest_answer() -> None:
    """Runs the real `ip link add` once. Where it cannot succeed (no rights, no vcan module:
    this machine) the message must say which; where it does succeed the link is removed."""
    name = "vbtest0"
    if Path("/sys/class/net", name).exists():
        pytest.skip(f"{name} already exists on this host")
    try:
        outcome = setup_vcan(name)
    except VcanSetupError as exc:
        assert exc.problem in {VcanProblem.NOT_PERMITTED, VcanProblem.NO_VCAN_MODULE}, exc
        assert ("root or CAP_NET_ADMIN" in str(exc)) or ("modprobe vcan" in str(exc))
    else:
        run_ip(["ip", "link", "del", "dev", name])
        assert outcome is SetupOutcome.CREATED


# ---------------------------------------------------------------------------- CLI


def test_cli_setup_ok(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["setup", "vcan0"], runner=FakeIp({})) == 0
    assert capsys.readouterr().out.strip() == "vcan0: created and brought up"


def test_cli_setup_environment_problem_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["setup"], runner=FakeIp({"add": (2, "", UNKNOWN_TYPE)})) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no vcan module" in err and "modprobe vcan" in err


@pytest.mark.parametrize("argv", [["setup", "bad name"], ["setup", "x" * 16], ["frobnicate"], []])
def test_cli_bad_arguments_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    ip = FakeIp({})
    with pytest.raises(SystemExit) as info:
        main(argv, runner=ip)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err
    assert ip.commands == []


def test_cli_probe_reports_choice_and_reason(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["probe"], probe=VCAN_HOST) == 0
    assert capsys.readouterr().out.splitlines()[0] == "bus: SocketCAN on vcan0"
    assert main(["probe", "--channel", "can0"], probe=NO_KERNEL) == 0
    out = capsys.readouterr().out.splitlines()
    # the fallback is the in-process bus, not "virtual on can0"
    assert out[0] == "bus: python-can's in-process virtual bus (SocketCAN can0 not used)"
    assert "AF_CAN" in out[1]


# ------------------------------------------------------------------- leak fixture


def test_leak_check_names_a_leaked_thread() -> None:
    before = take_snapshot()
    stop = threading.Event()
    thread = threading.Thread(target=stop.wait, name="leaky-worker", daemon=True)
    thread.start()
    try:
        problems = find_leaks(before, grace_s=0.01)
        assert problems == ["thread 'leaky-worker' still running"]
        allowance = LeakAllowance()
        allowance.keep(thread)
        assert find_leaks(before, allowance, grace_s=0.01) == []
    finally:
        stop.set()
        thread.join()
    assert find_leaks(before, grace_s=0.01) == []


def test_leak_check_waits_for_finishing_threads() -> None:
    before = take_snapshot()
    go = threading.Event()
    thread = threading.Thread(target=go.wait, name="finishing", daemon=True)
    thread.start()
    go.set()  # the thread is finishing; the grace join must absorb it
    assert find_leaks(before) == []
    assert not thread.is_alive()


def test_leak_check_names_an_open_virtual_bus() -> None:
    before = take_snapshot()
    channel = f"leak-probe-{uuid.uuid4().hex[:8]}"
    bus = can.Bus(channel=channel, interface="virtual", ignore_config=True)
    try:
        problems = find_leaks(before, grace_s=0.01)
        assert problems == [f"python-can virtual channel {channel!r}: 1 bus(es) not shut down"]
        allowance = LeakAllowance()
        allowance.keep(bus)
        assert find_leaks(before, allowance, grace_s=0.01) == []
    finally:
        bus.shutdown()
    assert find_leaks(before, grace_s=0.01) == []


def test_leak_fixture_fails_a_leaking_test(pytester: pytest.Pytester) -> None:
    """Run the project conftest on a test that leaks a thread: the test must fail, naming it;
    a test that keeps its thread via ``leak_allowance`` must pass."""
    source = (ROOT / "tests" / "conftest.py").read_text()
    assert "LEAK_GRACE_S = 1.0" in source
    pytester.makeconftest(source.replace("LEAK_GRACE_S = 1.0", "LEAK_GRACE_S = 0.05"))
    pytester.makepyfile(
        test_inner="""
        import threading

        def _start(name):
            stop = threading.Event()
            t = threading.Thread(target=stop.wait, name=name, daemon=True)
            t.stop_event = stop
            t.start()
            return t

        def test_leaks():
            _start("inner-leaked-thread")

        def test_keeps(leak_allowance):
            leak_allowance.keep(_start("inner-kept-thread"))
        """
    )
    try:
        result = pytester.runpytest("-p", "no:cacheprovider")
        result.assert_outcomes(passed=2, errors=1)
        result.stdout.fnmatch_lines(["*test leaked: thread 'inner-leaked-thread' still running*"])
    finally:
        for t in threading.enumerate():
            if t.name in {"inner-leaked-thread", "inner-kept-thread"}:
                t.stop_event.set()  # type: ignore[attr-defined]
                t.join()

"""The simulated drive as its own process (``python -m plant_sim drive``, ``serve``), read by
python canopen's own master: in-process on ``virtual`` and vcan0, and as a second process over
``udp_multicast`` inside a private network namespace the test creates and removes."""

from __future__ import annotations

import signal
import sys
import threading
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import pytest
from can.interfaces.virtual import VirtualBus

from plant_sim.__main__ import main as plant_sim_main
from plant_sim.drive import State402
from plant_sim.drive.errors import DriveConfigError
from plant_sim.drive.node import NmtState
from plant_sim.drive.process import DriveProcessConfig, ServeResult, SyncWatch, serve
from tests.command_line import refused_in_one_line
from tests.paths import ROOT
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import load_axis
from virtual_bus.framing import MessagePort
from virtual_bus.netns import UDP_GROUP, NetworkNamespace
from virtual_bus.realtime import RealTimeOptions

AXIS_FILE = ROOT / "config" / "paper_axis.toml"
EDS = ROOT / "config" / "drive.eds"
#: Backstop of the wait for the boot-up: a drive compiles before it (minutes on an empty
#: numba cache and a loaded 2-core machine, or in a one-CPU guest), so far beyond that.
BOOT_TIMEOUT_S = 900.0
#: Backstop of an SDO answer (a busy host may hold one longer than canopen's 0.3 s).
SDO_BACKSTOP_S = 10.0


def _one_line_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    return refused_in_one_line(plant_sim_main, argv, capsys)


DRIVE = ["drive", "--axis", str(AXIS_FILE)]


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        ([*DRIVE, "--interface", "kvaser", "--channel", "0"], "cannot open interface 'kvaser'"),
        ([*DRIVE, "--interface", "udp_multicast"], "only inside a private network namespace"),
        ([*DRIVE, "--interface", "nonsense", "--channel", "0"], "unknown interface"),
        ([*DRIVE, "--interface", "virtual", "--channel", "x", "--bitrate", "7"], "CiA 301"),
        (
            [*DRIVE, "--interface", "virtual", "--channel", "x", "--drive-profile", "no.toml"],
            "no such file",
        ),
        (
            [*DRIVE, "--interface", "virtual", "--channel", "x", "--drive-profile", str(AXIS_FILE)],
            "reserved",
        ),
        (["drive", "--interface", "virtual", "--axis", "missing.toml"], "missing.toml"),
        ([*DRIVE, "--interface", "virtual", "--node-id", "0"], "1..127"),
    ],
)
def test_bad_arguments_one_line_exit_2(
    argv: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert fragment in _one_line_exit_2(argv, capsys)


# --- in process: serve() on virtual and vcan0 -------------------------------------------------
def _bus_config(mode: Interface) -> BusConfig:
    if mode is Interface.SOCKETCAN:
        return BusConfig(interface=Interface.SOCKETCAN, channel="vcan0")
    return BusConfig(interface=Interface.VIRTUAL, channel=f"proc-{uuid.uuid4().hex[:10]}")


@pytest.fixture
def served_drive(bus_mode: Interface) -> Iterator[tuple[can.BusABC, threading.Event]]:
    """serve() in a thread on one end of the bus; yields the master's end (opened first, so
    it sees the boot-up) and a flag set once serve() has returned."""
    config = _bus_config(bus_mode)
    master = open_bus(config)
    drive_bus = open_bus(config)
    stop, done = threading.Event(), threading.Event()
    results: list[object] = []

    def body() -> None:
        try:
            results.append(serve(DriveProcessConfig(load_axis(AXIS_FILE)), drive_bus, stop))
        except BaseException as exc:
            results.append(exc)
        finally:
            done.set()

    thread = threading.Thread(target=body, name="serve")
    thread.start()
    try:
        yield master, done
    finally:
        stop.set()
        thread.join(10.0)
        drive_bus.shutdown()
        master.shutdown()
    assert results and not isinstance(results[0], BaseException), results


def _wait_for(
    bus: can.BusABC, can_id: int, timeout_s: float, alive: Callable[[], bool] = lambda: True
) -> can.Message:
    """The first frame with ``can_id``, while ``alive()`` (the sender still runs: a drive
    that died ends the wait at once); ``timeout_s`` is the backstop. No sleep."""
    deadline = threading.Event()
    timer = threading.Timer(timeout_s, deadline.set)
    timer.start()
    try:
        while not deadline.is_set():
            msg = bus.recv(0.5)
            if msg is not None and msg.arbitration_id == can_id:
                return msg
            if not alive():
                raise AssertionError(f"the drive ended before frame 0x{can_id:03X}")
    finally:
        timer.cancel()
    raise TimeoutError(f"no frame 0x{can_id:03X} within {timeout_s} s")


def _read_with_canopen(bus: can.BusABC) -> dict[str, int]:
    """python canopen's own master: SDO uploads, NMT start, one SYNC and TPDO1 received
    through canopen's PDO machinery. That the drive answers at once after its boot-up (no
    compile left) is checked without a clock in test_compiles_before_boot.py; the SDO
    timeout here is a backstop (canopen's 0.3 s default broke on a busy one-CPU guest)."""
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        node = network.add_node(2, str(EDS))
        node.sdo.RESPONSE_TIMEOUT = SDO_BACKSTOP_S
        got = {
            "device_type": node.sdo[0x1000].raw,
            "statusword": node.sdo[0x6041].raw,
            "mode": node.sdo[0x6502].raw,
            "cycle_value": node.sdo[0x60C2][1].raw,
        }
        node.tpdo.read(from_od=True)
        received = threading.Event()
        node.tpdo[1].add_callback(lambda _map: received.set())
        node.nmt.state = "OPERATIONAL"
        network.sync.transmit()
        assert received.wait(5.0), "no TPDO1 after SYNC"
        got["tpdo1_position"] = node.tpdo[1]["Position actual value"].raw
        got["syncs"] = node.sdo[0x2103].raw
        got["heartbeat_operational"] = node.nmt.wait_for_heartbeat(timeout=5.0) == "OPERATIONAL"
        return got
    finally:
        network.disconnect()


def test_serve_answers_python_canopen_and_returns_on_stop(
    served_drive: tuple[can.BusABC, threading.Event],
) -> None:
    master, done = served_drive
    boot = _wait_for(master, 0x702, BOOT_TIMEOUT_S, lambda: not done.is_set())
    assert bytes(boot.data) == b"\x00"
    got = _read_with_canopen(master)
    assert got["device_type"] == 0x00020192
    assert got["statusword"] & 0x4F == 0x40  # switch on disabled
    assert got["mode"] == 0x100 and got["cycle_value"] == 1
    assert got["tpdo1_position"] == 0 and got["syncs"] == 1 and got["heartbeat_operational"]
    assert not done.is_set()


def test_serve_result_names_the_end_state() -> None:
    config = _bus_config(Interface.VIRTUAL)
    bus = open_bus(config)
    stop = threading.Event()
    stop.set()  # stop at once: boot-up, then leave the bus
    try:
        result = serve(DriveProcessConfig(load_axis(AXIS_FILE), node_id=5), bus, stop)
    finally:
        bus.shutdown()
    assert result.state is State402.SWITCH_ON_DISABLED
    assert result.nmt_state is NmtState.PRE_OPERATIONAL and result.sync_count == 0
    assert "switch on disabled" in result.summary()


# --- two processes: udp_multicast in a private network namespace -----------------------------
def _python(*args: str) -> list[str]:
    return [sys.executable, *args]


def test_drive_process_and_canopen_master_over_udp_in_a_namespace(
    private_netns: NetworkNamespace, tmp_path: Path, subprocess_env: dict[str, str]
) -> None:
    """The drive command in one process, python canopen's master in another (a script run
    in the namespace), udp_multicast between them; SIGTERM ends the drive with exit 0 and
    one line. The numba cache is empty, so the drive compiles before its boot-up, and the
    master's first SDO right after the boot-up still gets its answer within 0.3 s."""
    script = tmp_path / "master.py"
    script.write_text(MASTER_SCRIPT)
    env = {**subprocess_env, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    master = private_netns.popen(_python(str(script), str(EDS)), env=subprocess_env)
    try:
        assert master.stdout is not None
        assert master.stdout.readline().strip() == "listening"
        drive = private_netns.popen(
            _python(
                "-m", "plant_sim", "drive", "--interface", "udp_multicast", "--axis", str(AXIS_FILE)
            ),
            env=env,
        )
        try:
            out, err = master.communicate(timeout=BOOT_TIMEOUT_S + 30)
            assert master.returncode == 0, err
            assert out.strip().splitlines()[-1] == (
                "boot 00; 1000h 0x00020192; 6041h 0x0240; sync -> tpdo1 ok; 2103h 1"
            )
        finally:
            drive.send_signal(signal.SIGTERM)
            drive_out, drive_err = drive.communicate(timeout=30)
        assert drive.returncode == 0, drive_err
        lines = drive_out.strip().splitlines()
        assert lines[0].startswith("drive 2: boot-up sent on udp_multicast group " + UDP_GROUP)
        assert lines[-1].startswith("drive 2: stopped on SIGTERM, bus closed; 1 SYNCs served")
        assert len(lines) == 2 and drive_err == ""
    finally:
        if master.poll() is None:
            master.kill()
            master.wait()


MASTER_SCRIPT = """
import sys
import threading

import canopen

from virtual_bus import BusConfig, open_bus

bus = open_bus(BusConfig(interface="udp_multicast"))
print("listening", flush=True)
while True:  # the boot-up of node 2
    msg = bus.recv(150.0)
    if msg is None:
        sys.exit("no boot-up")
    if msg.arbitration_id == 0x702:
        boot = bytes(msg.data).hex()
        break
network = canopen.Network(bus)
network.NOTIFIER_CYCLE = 0.05
network.connect()
try:
    node = network.add_node(2, sys.argv[1])  # SDO timeout: canopen's default 0.3 s
    device = node.sdo[0x1000].raw
    status = node.sdo[0x6041].raw
    node.tpdo.read(from_od=True)
    got = threading.Event()
    node.tpdo[1].add_callback(lambda _map: got.set())
    node.nmt.state = "OPERATIONAL"
    network.sync.transmit()
    tpdo = "ok" if got.wait(5.0) else "missing"
    syncs = node.sdo[0x2103].raw  # answered while the drive runs its first cycle
    print(f"boot {boot}; 1000h 0x{device:08X}; 6041h 0x{status:04X}; sync -> tpdo1 {tpdo}; "
          f"2103h {syncs}")
finally:
    network.disconnect()
"""


# --- the one-thread loop: real-time options, SYNC poll window, receive errors ---------------
RT_ARGS = [*DRIVE, "--interface", "virtual", "--channel", "x"]


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        ([*RT_ARGS, "--rt-priority", "0"], "SCHED_FIFO priority is 1..99"),
        ([*RT_ARGS, "--rt-priority", "top"], "not an integer"),
        ([*RT_ARGS, "--cpu", "-2"], "CPU number is >= 0"),
    ],
)
def test_bad_real_time_arguments_one_line_exit_2(
    argv: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert fragment in _one_line_exit_2(argv, capsys)


def test_a_cpu_the_drive_may_not_use_is_refused_in_one_line_exit_1(
    capsys: pytest.CaptureFixture[str],
) -> None:
    import os

    cpu = max(os.sched_getaffinity(0)) + 64
    assert plant_sim_main([*RT_ARGS, "--cpu", str(cpu)]) == 1
    err = capsys.readouterr().err
    assert f"--cpu {cpu}" in err and "refused" in err and err.count("\n") == 1


def test_sync_watch_polls_only_around_the_due_sync() -> None:
    """Injected instants (s): 1 ms cycle, 0.15 ms lead. Blocks until the window opens,
    polls inside it, never blocks longer than asked."""
    watch = SyncWatch(cycle_s=1e-3, lead_s=150e-6)
    assert watch.wait_s(now=5.0, longest_s=0.2) == 0.2  # no SYNC yet: block
    watch.synced(10.0)
    assert watch.wait_s(10.0001, 0.2) == pytest.approx(1e-3 - 150e-6 - 0.0001)
    assert watch.wait_s(10.0001, 0.0002) == 0.0002
    assert watch.wait_s(10.00085, 0.2) == 0.0  # the window opens at 10.00085
    assert watch.wait_s(10.00114, 0.2) == 0.0  # ... and closes at 10.00115
    watch.synced(10.00102)  # the SYNC came: the next window is one cycle on
    assert watch.wait_s(10.0011, 0.2) == pytest.approx(10.00187 - 10.0011)


def test_sync_watch_follows_one_skipped_slot_then_gives_up() -> None:
    watch = SyncWatch(cycle_s=1e-3, lead_s=100e-6)
    watch.synced(0.0)
    # past the first window: the producer skipped a slot, the next is due at 2 ms
    assert watch.wait_s(0.0012, 1.0) == pytest.approx(0.0019 - 0.0012)
    assert watch.wait_s(0.00195, 1.0) == 0.0
    # the second window passed without a SYNC either: no more polling until one comes
    assert watch.wait_s(0.0022, 1.0) == 1.0
    assert watch.due_s is None
    assert watch.wait_s(0.0029, 1.0) == 1.0
    watch.synced(0.0105)
    assert watch.wait_s(0.0115, 1.0) == 0.0


def test_sync_watch_holds_after_a_sync_until_the_next_frame_or_the_hold_ends() -> None:
    watch = SyncWatch(cycle_s=1e-3, lead_s=100e-6, hold_s=250e-6)
    watch.synced(1.0)
    assert watch.wait_s(1.0001, 0.2) == 0.0  # polling for the set point
    watch.received()  # it came: block until the next window
    assert watch.wait_s(1.00011, 0.2) == pytest.approx(1.0009 - 1.00011)
    watch.synced(1.001)
    assert watch.wait_s(1.00124, 0.2) == 0.0
    # no frame within the hold: block until the next window
    assert watch.wait_s(1.00126, 0.2) == pytest.approx(1.0019 - 1.00126)


class _Clock:
    t = 10.0

    def __call__(self) -> float:
        return self.t


def test_the_next_window_is_dated_from_the_syncs_arrival_not_from_a_late_wake_up() -> None:
    """The loop with injected clocks: a SYNC that waited 300 µs in the socket (its timestamp
    says so) puts the next poll window at arrival + 1 ms - 150 µs, not at wake-up + ..."""
    from plant_sim.drive.process import LoopCounts, _loop

    clock, stop, asked = _Clock(), threading.Event(), []
    sync = can.Message(arbitration_id=0x80, data=b"", timestamp=1000.0 - 300e-6)

    class Bus:  # the drive's end of the bus, as its port reads it
        def recv(self, timeout: float | None) -> can.Message | None:
            asked.append(timeout)
            if len(asked) == 1:
                return sync
            stop.set()
            return None

    class Drive:  # what the loop reads of the drive
        node_id, sync_count = 2, 0
        port = MessagePort(Bus())  # type: ignore[arg-type]
        holding = False  # at rest, power off: its own clock runs nothing

        def check(self) -> None:
            pass

        def watch_master(self, now_s: float) -> float | None:
            return None  # no master watched

        def take(
            self, cob_id: int, port: MessagePort, handle: Callable[[can.Message], None]
        ) -> bool:
            handle(port.message())
            return True

    drive = Drive()

    def handle(msg: can.Message) -> None:
        drive.sync_count += 1

    config = DriveProcessConfig(load_axis(AXIS_FILE), realtime=RealTimeOptions(busy_poll=True))
    _loop(drive, handle, stop, config, None, clock, lambda: 1000.0, LoopCounts())  # type: ignore[arg-type]
    assert asked[0] == config.check_interval_s  # nothing known yet: block
    assert asked[1] == pytest.approx(10.0 - 300e-6 + 1e-3 - 150e-6 - 10.0)


def test_the_poll_lead_is_checked_against_the_cycle() -> None:
    axis = load_axis(AXIS_FILE)  # 1 ms position cycle (the paper's)
    assert DriveProcessConfig(axis).poll_lead_s == pytest.approx(150e-6)
    fast = axis.with_values({"control.position_cycle": 0.0005})
    assert DriveProcessConfig(fast).poll_lead_s == pytest.approx(100e-6)
    with pytest.raises(DriveConfigError, match="sync_poll_lead_s"):
        DriveProcessConfig(axis, sync_poll_lead_s=0.0006)


class _FlakyBus(VirtualBus):
    """python-can's virtual bus whose first receive in the thread named "serve" after the
    boot-up fails as a datagram that is no frame does on udp_multicast
    (can.CanOperationError)."""

    failed = 0
    booted = False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.booted = self.booted or msg.arbitration_id == 0x702
        super().send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        serving = threading.current_thread().name == "serve"
        if self.booted and self.failed == 0 and serving:
            self.failed = 1
            raise can.CanOperationError("could not unpack received message")
        return super()._recv_internal(timeout)


def test_served_with_busy_poll_answers_canopen_and_counts_a_bad_datagram() -> None:
    """serve() with --busy-poll (the window logic polls, blocks outside it) answers python
    canopen's own master; a receive that fails is counted and the loop goes on."""
    channel = f"flaky-{uuid.uuid4().hex[:10]}"
    master = can.Bus(interface="virtual", channel=channel)
    drive_bus = _FlakyBus(channel=channel)
    stop = threading.Event()
    results: list[object] = []
    config = DriveProcessConfig(
        load_axis(AXIS_FILE), realtime=RealTimeOptions(busy_poll=True, freeze_gc=True)
    )

    def body() -> None:
        try:
            results.append(serve(config, drive_bus, stop))
        except BaseException as exc:
            results.append(exc)

    thread = threading.Thread(target=body, name="serve")
    thread.start()
    try:
        _wait_for(master, 0x702, BOOT_TIMEOUT_S, thread.is_alive)
        got = _read_with_canopen(master)
    finally:
        stop.set()
        thread.join(10.0)
        drive_bus.shutdown()
        master.shutdown()
    assert got["tpdo1_position"] == 0 and got["syncs"] == 1
    assert len(results) == 1 and isinstance(results[0], ServeResult), results
    assert results[0].receive_errors == 1 and "1 datagrams ignored" in results[0].summary()

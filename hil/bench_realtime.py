"""The real-time part of ``python -m hil bench``: the bridge alone, the drive elsewhere.

SYNC from the wall clock at ``rate_hz`` for ``seconds``, the axis moving ±20 mm back and
forth. Where the simulated drive runs (:class:`DrivePlacement`):

* ``PROCESS`` (default, needs root): the drive is its own process; both share a python-can
  ``udp_multicast`` bus inside a private network namespace created for the run and removed
  after it (:mod:`virtual_bus.netns`; never on the host's interfaces): ``python -m plant_sim
  drive`` in the namespace, the bench's own thread moved into it (setns) for its bus. The
  drive process gets the loop's real-time options (:func:`drive_options`: one SCHED_FIFO
  priority lower, on ``drive_cpu``). The figures are the bridge's: its loop does not share
  an interpreter with the drive's physics.
* ``THREAD``: the drive in the bridge's process on python-can's virtual bus (what ran before;
  the drive's Python work and threads compete with the loop for the GIL).

Figures (:func:`bridge.loopstats.summary`): SYNC -> set point latency (it includes the drive's
answer), the bridge's own share (both TPDOs in -> RPDO sent), SYNC lateness against its slot
and its jitter, histograms, skipped SYNCs, overruns, cycles without all TPDOs, CPU time of the
loop's thread and of the drive process per cycle, CPU use of both processes, and what the
host took: the gaps of a clock-reading thread before the run (:func:`host_floor`) and the
hypervisor's steal time per CPU during it (:func:`virtual_bus.realtime.steal_s`).

Which floor binds: the loop's CPU per cycle as a fraction of the period (all of it, and its
work alone, without the spin before the SYNC and the wait for the TPDOs), the skipped SYNCs
split into those the loop's own work caused and those after the host kept it off the CPU
(:mod:`bridge.loopstats`), and -- with ``--rt-priority`` and ``--cpu``, where ``cyclictest``
is installed -- the host's own floor measured in the same run, right before the loop, as
long as the loop runs: ``cyclictest`` (rt-tests, :mod:`bridge.host_latency`) on the loop's
CPU at the loop's priority, waking every cycle; beside each figure of it, the wake-ups later
than the loop's slack (its spin before the SYNC plus the lateness its pacer allows): a
wake-up that late is a slot no loop sleeping between cycles can meet. (Run beside the loop,
one priority above it, cyclictest missed most of them: its wake-ups fell while the loop kept
the virtual CPU awake -- measured, 1 against 20 in 20 s.)
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from enum import Enum
from pathlib import Path

import can

from bridge import host_latency
from bridge.cycle import BridgeState
from bridge.errors import BridgeError
from bridge.interpolator import Move
from bridge.loopstats import Timing, summary
from bridge.node import Bridge, BridgeConfig
from bridge.params import BridgeParams
from bridge.scope import Scope
from bridge.timing import RealTimePacer
from regulator import RegulatorConfig
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.contract import heartbeat_cob_id
from virtual_bus.formats.axis import AxisConfig, dump_axis
from virtual_bus.netns import UDP_GROUP, NetworkNamespace
from virtual_bus.realtime import GcBetweenCycles, RealTimeOptions, apply_realtime, host_steal_s

#: Wall time the drive process gets to boot (loading its compiled physics), s.
DRIVE_BOOT_TIMEOUT_S = 120.0


class DrivePlacement(Enum):
    PROCESS = "process"
    THREAD = "thread"


def axis_at_rate(axis: AxisConfig, rate_hz: float | None) -> AxisConfig:
    """``axis`` with its position cycle at ``rate_hz`` (None: as it is)."""
    if rate_hz is None:
        return axis
    return axis.with_values({"control.position_cycle": 1.0 / rate_hz})


def bench_params(axis: AxisConfig) -> BridgeParams:
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    # counted, not acted on: the bench measures; 200Ah = 255 lets a bad run finish
    return dataclasses.replace(BridgeParams.for_axis(axis, reg), pdo_loss_tolerance=255)


CLONE_NEWNET = 0x40000000


@contextlib.contextmanager
def _entered(ns: NetworkNamespace) -> Iterator[None]:
    """The calling thread in the namespace ``ns`` (setns(2)) for the block: the bridge's bus
    socket is opened in it. The thread returns to its own namespace afterwards."""
    libc = ctypes.CDLL(None, use_errno=True)
    own = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    try:
        target = os.open(f"/var/run/netns/{ns.name}", os.O_RDONLY)
        try:
            if libc.setns(target, CLONE_NEWNET) != 0:
                errno = ctypes.get_errno()
                raise OSError(
                    errno, f"setns into network namespace {ns.name}: {os.strerror(errno)}"
                )
        finally:
            os.close(target)
        try:
            yield
        finally:
            libc.setns(own, CLONE_NEWNET)
    finally:
        os.close(own)


def _proc_cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far (from /proc), s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def drive_options(rt: RealTimeOptions, drive_cpu: int | None) -> list[str]:
    """The real-time options of the drive process: the bridge's, one priority below the loop
    (the drive answers the SYNC the loop sends), on ``drive_cpu`` instead of the loop's CPU."""
    priority = None if rt.rt_priority is None else max(1, rt.rt_priority - 1)
    return dataclasses.replace(rt, rt_priority=priority, cpu=drive_cpu).argv()


def _drive_command(
    axis_path: Path,
    rt: RealTimeOptions,
    drive_cpu: int | None,
    ns: NetworkNamespace | None,
    socketcan: str | None,
) -> list[str]:
    """``python -m plant_sim drive`` with :func:`drive_options`: on udp_multicast inside
    ``ns``, or on the SocketCAN interface ``socketcan``."""
    bus = ["socketcan", socketcan] if socketcan is not None else ["udp_multicast", UDP_GROUP]
    argv = [sys.executable, "-m", "plant_sim", "drive", "--interface", bus[0], "--channel"]
    argv += [bus[1], "--axis", str(axis_path), *drive_options(rt, drive_cpu)]
    return argv if ns is None else ns.command(argv)


def _wait_for_boot(bus: can.BusABC, drive_id: int, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + DRIVE_BOOT_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise BridgeError(f"the drive process ended at start-up (exit {proc.returncode})")
        msg = bus.recv(0.1)
        if (
            msg is not None
            and msg.arbitration_id == heartbeat_cob_id(drive_id)
            and msg.data[:1] == b"\0"
        ):
            return
    raise BridgeError(f"the drive process sent no boot-up within {DRIVE_BOOT_TIMEOUT_S:g} s")


@contextlib.contextmanager
def _process_drive(
    axis: AxisConfig,
    rt: RealTimeOptions,
    drive_cpu: int | None,
    drive_id: int,
    socketcan: str | None = None,
) -> Iterator[tuple[can.BusABC, subprocess.Popen[bytes], str]]:
    """The drive process, the bridge's end of the bus and what the bus is: udp_multicast in
    a private network namespace (created for the block, removed after it), or the SocketCAN
    interface ``socketcan`` (e.g. vcan0 in a guest with a CAN stack)."""
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory())
        if socketcan is None:
            ns: NetworkNamespace | None = stack.enter_context(NetworkNamespace.create())
            stack.enter_context(_entered(ns))  # type: ignore[arg-type]
            config = BusConfig(interface="udp_multicast", channel=UDP_GROUP)
            what = f"udp_multicast in the private network namespace {ns.name}"  # type: ignore[union-attr]
        else:
            ns = None
            config = BusConfig(interface=Interface.SOCKETCAN, channel=socketcan)
            what = f"SocketCAN {socketcan}"
        axis_path = Path(tmp) / "axis.toml"
        axis_path.write_text(dump_axis(axis), encoding="utf-8")
        bus = open_bus(config)
        stack.callback(bus.shutdown)
        proc = subprocess.Popen(
            _drive_command(axis_path, rt, drive_cpu, ns, socketcan), stdout=subprocess.DEVNULL
        )
        try:
            _wait_for_boot(bus, drive_id, proc)
            yield bus, proc, what
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _queue_moves(bridge: Bridge, params: BridgeParams, seconds: float) -> None:
    feed = params.feed
    move_s = 0.02 / feed + 0.1 + 0.1  # travel, acceleration ramps, dwell
    for i in range(math.ceil(seconds / move_s) + 2):
        bridge.controller.queue_move(
            Move(0.02 if i % 2 == 0 else 0.0, feed, accel=10 * feed, dwell_s=0.1)
        )


#: The host's own floor is measured this long before the run, s.
HOST_FLOOR_S = 2.0
#: A gap in the clock-reading spin longer than this counts as the host taking the CPU, s.
HOST_GAP_S = 50e-6


def host_floor(seconds: float = HOST_FLOOR_S) -> dict[str, float]:
    """What the host alone does to a thread that only reads the clock (with the real-time
    options already applied), 0.6 ms of every millisecond, sleeping the rest (like the loop;
    a thread at real-time priority that never sleeps is throttled by the kernel): gaps longer
    than :data:`HOST_GAP_S` between two readings, their number and the longest. No bridge
    involved -- a latency maximum of the loop near the longest gap is the host's (interrupts,
    other tasks, the hypervisor), not the loop's."""
    wall = time.monotonic
    end = wall() + seconds
    longest = 0.0
    count = 0
    while wall() < end:
        last = wall()
        spin_end = last + 0.0006
        while last < spin_end:
            now = wall()
            gap = now - last
            if gap > HOST_GAP_S:
                count += 1
                longest = max(longest, gap)
            last = now
        time.sleep(0.0003)
    return {"host_gaps_over_50us": count, "host_gap_us_max": longest * 1e6}


def host_latency_plan(rt: RealTimeOptions) -> tuple[str, int, int] | None:
    """(cyclictest, CPU, priority) for the run's own host floor, or None where it cannot
    run: no ``--rt-priority`` and ``--cpu``, not root, not installed."""
    if rt.rt_priority is None or rt.cpu is None or os.geteuid() != 0:
        return None
    exe = shutil.which("cyclictest")
    return None if exe is None else (exe, rt.cpu, rt.rt_priority)


def host_latency_now(
    plan: tuple[str, int, int], rate_hz: float, seconds: float, slack_s: float
) -> dict[str, object]:
    """cyclictest as :func:`host_latency_plan` says for ``seconds``: its figures, with the
    wake-ups later than ``slack_s``."""
    exe, cpu, priority = plan
    try:
        result = host_latency.measure(
            rate_hz, seconds, cpu, priority, executable=exe, slack_us=round(slack_s * 1e6)
        )
    except host_latency.HostLatencyError as exc:
        return {"host_latency_error": str(exc)}
    return {"host_latency": {**result.as_dict(), "cpu": cpu, "priority": priority}}


def _measure(
    bridge: Bridge, cycles: int, rt: RealTimeOptions, host: tuple[str, int, int] | None
) -> dict[str, object]:
    pacer = bridge.pacer
    rate_hz = 1.0 / pacer.cycle_s
    before: dict[str, object] = {}
    floor: dict[str, float] = {}
    # the bridge serves its heartbeat until its loop starts, as between runs: the drive
    # watches it (1016h, 250 ms) and would otherwise stop the axis (EMCY 8130h) while
    # cyclictest runs or the real-time options are applied (locking the memory takes longer
    # than 250 ms), and the loop would be timed in STOPPED
    with bridge.serving():
        if host is not None:
            print(f"bench: cyclictest first, {cycles / rate_hz:g} s (the host's floor in this run)")
            before = host_latency_now(host, rate_hz, cycles / rate_hz, pacer.spin_s + pacer.late_s)
        applied = apply_realtime(rt)
        for line in applied:
            print(f"bench: {line}")
        if host is None:  # else cyclictest measured the host
            floor = host_floor()
    steal0 = host_steal_s()
    wall0, cpu0, thread0 = time.perf_counter(), time.process_time(), time.thread_time()
    n = bridge.run(until=lambda b: b.cycle_index >= cycles)
    wall = time.perf_counter() - wall0
    cpu, thread = time.process_time() - cpu0, time.thread_time() - thread0
    steal1 = host_steal_s()
    cpu_us = 1e6 * thread / max(1, n)
    return {
        **floor,
        **before,
        "host_steal_ms": {
            name: round(1e3 * (steal1[name] - steal0.get(name, 0.0)), 1) for name in steal1
        },
        "seconds": wall,
        "cycles": n,
        "cpu_us_per_cycle": cpu_us,
        "cpu_fraction_of_period": cpu_us * 1e-6 * rate_hz,
        "cpu_percent_of_one_core": 100.0 * cpu / wall,
    }


#: How often the bench's scope reader polls, s (the page's poll, bridge/scope_page/scope.js).
SCOPE_POLL_S = 0.2


def realtime_run(
    axis: AxisConfig,
    seconds: float,
    *,
    rate_hz: float | None = None,
    rt: RealTimeOptions | None = None,
    placement: DrivePlacement = DrivePlacement.PROCESS,
    drive_cpu: int | None = None,
    spin_s: float | None = None,
    host_beside: bool = True,
    socketcan: str | None = None,
    scope: bool = False,
) -> dict[str, object]:
    """One real-time run (module docstring); returns its figures. ``spin_s``: the pacer's
    clock polling before each SYNC (None: its default). ``host_beside``: cyclictest beside
    the loop where it can run (:func:`host_latency_plan`). ``socketcan``: the drive process and
    the bridge on that SocketCAN interface instead of udp_multicast in a namespace. ``scope``:
    the live scope on (:mod:`bridge.scope`), read by a process that polls it as its page does."""
    rt = rt or RealTimeOptions()
    axis = axis_at_rate(axis, rate_hz)
    params = bench_params(axis)
    cycles = round(seconds / params.cycle_s)
    config = BridgeConfig()
    gc_control = GcBetweenCycles() if rt.freeze_gc else None
    result: dict[str, object] = {
        "rate_hz": 1.0 / params.cycle_s,
        "drive": placement.value,
        "realtime_options": rt.describe(),
    }
    with contextlib.ExitStack() as stack:
        if placement is DrivePlacement.PROCESS:
            bus, proc, what = stack.enter_context(
                _process_drive(axis, rt, drive_cpu, config.drive_id, socketcan)
            )
            drive_pid: int | None = proc.pid
            result["bus"] = what
        else:
            from bridge.timing import TimeMode

            from .harness import simulated_axis

            sim = stack.enter_context(
                simulated_axis(
                    axis, params, time_mode=TimeMode.REAL_TIME, keep_trace=False, keep_timing=True
                )
            )
            bus, drive_pid = sim.bridge_bus, None
            result["bus"] = "python-can virtual (drive in this process)"
        if placement is DrivePlacement.PROCESS:
            bridge = Bridge(
                bus,
                params,
                axis.kind,
                RealTimePacer(params.cycle_s, spin_s=spin_s),
                config=config,
                keep_timing=True,
                overrun_limit=None,
                gc_control=gc_control,
                busy_poll=rt.busy_poll,
            )
            stack.callback(bridge.close)
            bridge.start()
        else:
            bridge = sim.bridge
            bridge.overrun_limit = None
            bridge.gc_control = gc_control
            bridge.busy_poll = rt.busy_poll
        _queue_moves(bridge, params, seconds)
        live = None
        if scope:
            live = Scope(0, stream=sys.stdout)
            live.attach(bridge, None)
            stack.callback(live.close)
            reader = _ScopeReader(live.url)
            stack.callback(reader.stop)
        bridge.timing = Timing(capacity=cycles + 64)  # no array grows during the run
        drive_cpu0 = _proc_cpu_s(drive_pid) if drive_pid is not None else 0.0
        scope_pid = None if live is None else live.server_pid
        scope_cpu0 = _proc_cpu_s(scope_pid) if scope_pid is not None else 0.0
        plan = host_latency_plan(rt) if host_beside else None
        result["cycle_core"] = "compiled (numba)" if bridge.controller.core.compiled else "Python"
        result["frames"] = bridge.frames.kind
        result.update(_measure(bridge, cycles, rt, plan))
        if drive_pid is not None:
            drive_cpu_s = _proc_cpu_s(drive_pid) - drive_cpu0
            result["drive_cpu_percent_of_one_core"] = 100.0 * drive_cpu_s / result["seconds"]  # type: ignore[operator]
            ran = int(result["cycles"])  # type: ignore[call-overload]
            result["drive_cpu_us_per_cycle"] = 1e6 * drive_cpu_s / max(1, ran)
        result["spin_us"] = bridge.pacer.spin_s * 1e6
        result.update(summary(bridge.timing, params.cycle_s))
        result["missed_tpdo_cycles"] = bridge.counters.missed_cycles
        result["late_tpdos"] = bridge.counters.late
        result["stopped"] = bridge.controller.state is BridgeState.STOPPED
        result["stop_message"] = bridge.controller.stop_message
        result["binding_floor"] = binding_floor(result)
        if live is not None:
            # the scope's server is a process of its own: its CPU is not the loop's process's
            server_cpu_s = _proc_cpu_s(scope_pid) - scope_cpu0 if scope_pid is not None else 0.0
            reader.stop()
            result["scope"] = {
                "samples_handed": live.pushed,
                "samples_dropped": live.dropped,
                "reads": reader.reads,
                "samples_read": reader.samples,
                "server_cpu_percent_of_one_core": 100.0 * server_cpu_s / result["seconds"],  # type: ignore[operator]
            }
        if rt.rt_priority is not None:  # back to ordinary scheduling for the tear-down
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return result


#: The bench's scope reader (:class:`_ScopeReader`): polls as the page does until its stdin
#: ends, then prints what it read.
_READER = """
import json, sys, threading, urllib.request
url, poll_s = sys.argv[1], float(sys.argv[2])
done = threading.Event()
threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
after = reads = samples = 0
while not done.wait(poll_s):
    try:
        with opener.open(f"{url}data?after={after}") as answer:
            doc = json.load(answer)
    except OSError:
        break  # the scope has closed
    after = doc["last_seq"]
    reads += 1
    samples += len(doc["samples"]["seq"])
print(json.dumps({"reads": reads, "samples": samples}), flush=True)
"""


class _ScopeReader:
    """A client of the scope doing what its page does: ``GET /data?after=SEQ`` every
    :data:`SCOPE_POLL_S`, in a process of its own as a browser is (a thread here would take
    the loop's interpreter lock: what docs/scope.md measured of the scope's first design)."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.reads = 0
        self.samples = 0
        self._proc: subprocess.Popen[str] | None = subprocess.Popen(
            [sys.executable, "-c", _READER, url, str(SCOPE_POLL_S)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )

    def stop(self) -> None:
        """End the reader (end of file on its stdin) and take its counts."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        out, _ = proc.communicate("")
        if out.strip():
            doc = json.loads(out.strip().splitlines()[-1])
            self.reads, self.samples = int(doc["reads"]), int(doc["samples"])


def binding_floor(r: dict[str, object]) -> str:
    """Which floor the run met: ``"none"`` (no slot skipped), ``"host"`` (every skipped SYNC
    after the host kept the loop off the CPU), ``"loop"`` (its own work skipped more), or
    ``"host and loop"``."""
    own, host = int(r.get("own_skipped_syncs", 0)), int(r.get("host_skipped_syncs", 0))  # type: ignore[call-overload]
    if own == 0 and host == 0:
        return "none"
    if own == 0:
        return "host"
    return "loop" if own > host else "host and loop"


def can_run_process_drive() -> str | None:
    """None when the out-of-process drive can run here, else why not (one sentence)."""
    if os.geteuid() != 0:
        return "not root: a private network namespace for the drive process needs root"
    try:
        import msgpack  # noqa: F401
    except ImportError:
        return "python-can's udp_multicast needs msgpack (pip install msgpack)"
    return None

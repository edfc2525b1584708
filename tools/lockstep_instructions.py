"""Instructions per control cycle, counted by valgrind's callgrind (repeatable on a shared
machine, unlike its clock). Developer tool, not part of the packages.

    python tools/lockstep_instructions.py [--path lockstep|bridge|drive] [--bus virtual|udp|vcan]
                                          [--cycles 2000] [--record] [--python] [--cpu-time]
                                          [--keep FILE]

runs itself under ``valgrind --tool=callgrind --collect-atstart=no
--toggle-collect=functools_reduce --toggle-collect=_operator_call`` on the paper's section
X (``hil bench``'s lockstep scenario) and prints the instructions per cycle of one path;
only what runs inside a ``functools.reduce`` call is counted, and an ``operator.call``
inside it toggles the count off again (a nested ``reduce`` does not: callgrind treats it as
the same activation, so before this tool had --path, its --drive-sync counted the drive's
sends and physics that it meant to leave out):

* ``lockstep`` (default): the whole stack for one cycle (``play_references``: bridge, bus,
  drive, physics; ``--record``: with the trace file and the candump log); start-up
  included, as this figure has always been measured;
* ``bridge``: the bridge's cycle alone (``Bridge.run_cycle``: SYNC sent, TPDOs received and
  decoded, controller, regulator, RPDO sent), the drive's work and the harness's
  disturbance input toggled off;
* ``drive``: the drive's work for one SYNC alone: receiving the RPDO and the SYNC, latch,
  supervision, both TPDOs sent, the physics step (the loop of its process:
  ``SimulatedDrive.take`` on its port);

both after 200 uncounted cycles. ``--bus udp``: the two ends on ``udp_multicast`` in a
private network namespace (root), the bus of ``hil bench``'s real-time runs; ``vcan``: on
SocketCAN vcan0 (a kernel with a CAN stack, e.g. a User-mode Linux guest); ``virtual``:
python-can's in-process bus. ``--python``: the bridge's cycle core as Python (a bridge
installed without numba). The drive of ``--bus udp`` is served by the same code as its
process (``plant_sim drive``), in the bridge's process and thread (lockstep), so that one
callgrind run sees both. For ``bridge`` and ``drive`` the harness's own wrappers are counted
in a second run around a stub that does nothing but call the two hooks, and subtracted (both
figures are printed). ``--cpu-time``: the thread's CPU time of the same sections instead,
without valgrind (where valgrind cannot run, e.g. in a User-mode Linux guest). Needs
valgrind otherwise; run from the checkout (``cd`` there first). Works
on older checkouts too (before the frame ports: the drive's loop then receives messages),
for before/after figures.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import gc
import operator
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
WARM_UP_CYCLES = 200


def _reduced(call: Callable[[], Any]) -> Any:
    """``call()`` inside ``functools.reduce``: callgrind toggles its count at entry and exit."""
    return functools.reduce(lambda _a, _b: call(), [0, 0])


def _called(call: Callable[[], Any]) -> Any:
    """``call()`` inside ``operator.call``: the other function callgrind toggles at, for a
    section left out of a counted one. (A ``reduce`` inside a ``reduce`` does not toggle:
    callgrind counts a recursive entry as the same activation -- measured, the nested work
    was counted; and a common function such as ``sorted`` is called by numba's compiler,
    which runs under valgrind once per function for valgrind's CPU, switching the count on
    there.) Nothing in the project or its dependencies calls ``operator.call``."""
    return operator.call(call)


class CpuMeter:
    """The thread's CPU time in the sections callgrind would count (a call toggles the count
    on, a nested call off again): ``--cpu-time`` instead of instructions."""

    def __init__(self) -> None:
        self.total_s = 0.0
        self._depth = 0
        self._since = 0.0

    def __call__(self, call: Callable[[], Any]) -> Any:
        now = time.thread_time()
        if self._depth % 2 == 0:
            self._since = now
        else:
            self.total_s += now - self._since
        self._depth += 1
        try:
            return call()
        finally:
            self._depth -= 1
            now = time.thread_time()
            if self._depth % 2 == 0:
                self.total_s += now - self._since
            else:
                self._since = now


counted: Callable[[Callable[[], Any]], Any] = _reduced
left_out: Callable[[Callable[[], Any]], Any] = _called


@contextlib.contextmanager
def _two_ends(axis: Any, params: Any, bridge_config: Any, wait_s: float, bus: str) -> Iterator[Any]:
    """Bridge and drive on two ends of udp_multicast (inside a namespace) or of vcan0 in this
    process, the drive answering each SYNC from the bridge's thread as its process's loop
    would."""
    from bridge.node import Bridge
    from bridge.timing import LockstepPacer
    from plant_sim.drive import DriveConfig, SimulatedDrive, TimeMode
    from virtual_bus import BusConfig, Interface, open_bus

    if bus == "udp":
        config = BusConfig(interface="udp_multicast")
    else:
        config = BusConfig(interface=Interface.SOCKETCAN, channel="vcan0")
    drive_bus, bridge_bus = open_bus(config), open_bus(config)
    try:
        drive = SimulatedDrive(drive_bus, 2, axis, DriveConfig(time_mode=TimeMode.LOCKSTEP))
        pacer = LockstepPacer(params.cycle_s, wait_s)
        bridge = Bridge(bridge_bus, params, axis.kind, pacer, config=bridge_config)
        drive.start()
        try:
            bridge.start()
            with drive.receiving_here() as handle:
                port = getattr(drive, "port", None)

                def serve_one() -> bool:  # one pass of the drive process's loop
                    if port is not None:
                        cob_id = port.receive(wait_s)
                        return cob_id >= -1 and drive.take(cob_id, port, handle)  # type: ignore[no-any-return]
                    msg = drive_bus.recv(wait_s)  # a checkout before the frame ports
                    if msg is None:
                        return False
                    syncs = drive.sync_count
                    handle(msg)
                    return drive.sync_count != syncs  # type: ignore[no-any-return]

                def peer_poll() -> int:
                    while not serve_one():
                        pass
                    return 1

                bridge.peer_poll = peer_poll
                yield dataclasses.make_dataclass("Sim", ["bridge", "drive"])(bridge, drive)
        finally:
            bridge.close()
            drive.stop()
    finally:
        bridge_bus.shutdown()
        drive_bus.shutdown()


def _inner(args: argparse.Namespace) -> None:
    global counted, left_out
    sys.path.insert(0, str(ROOT))
    meter = CpuMeter() if args.cpu_time else None
    if meter is not None:
        counted = left_out = meter
    import inspect

    from bridge.master import DriveSetup
    from bridge.node import Bridge, BridgeConfig
    from hil import bench
    from hil.commands.common import simulated_axis_file
    from hil.harness import play_references, simulated_axis
    from plant_sim.paper.scenarios import SectionX
    from virtual_bus.shipped import PAPER_AXIS

    if "compiled" in inspect.signature(Bridge).parameters:  # the cycle core's choice
        original_init = Bridge.__init__

        def init(self: Bridge, *a: Any, **kw: Any) -> None:
            kw.setdefault("compiled", not args.python)
            original_init(self, *a, **kw)

        Bridge.__init__ = init  # type: ignore[method-assign]
    axis = simulated_axis_file(PAPER_AXIS)
    cycles = args.cycles + (0 if args.path == "lockstep" else WARM_UP_CYCLES)
    end_s = cycles * axis.control.position_cycle
    refs = SectionX(end_s=end_s, stop_s=min(SectionX.stop_s, end_s)).references(axis)
    # valgrind runs the start-up some 50 times slower: no SDO timeout may fire
    slow = DriveSetup(sdo_timeout_s=20.0, state_timeout_s=60.0)
    config = BridgeConfig(drive_setup=slow)
    wait_s = 30.0
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        if args.bus != "virtual":
            sim_context = _two_ends(axis, bench._params(axis), config, wait_s, args.bus)
        else:
            sim_context = simulated_axis(
                axis,
                bench._params(axis),
                bridge_config=config,
                lockstep_wait_s=wait_s,
                trace_path=tmp_path / "trace.csv" if args.record else None,
                keep_trace=False,
                disturbance=refs.disturbance_nm if args.record else None,
                bus_log_path=tmp_path / "bus.log" if args.record else None,
            )
        with sim_context as sim:
            # the start-up's objects out of the collector's reach, as --freeze-gc does: a
            # full collection over them (numba, scipy: some 10^7 instructions) would land in
            # a counted cycle now and then
            gc.collect()
            gc.freeze()
            if args.path == "lockstep":
                run = counted(lambda: play_references(sim, refs))
            else:
                bridge = sim.bridge
                run_cycle, peer_poll, quiet = _hooks(bridge, args.path == "bridge")
                bridge.run_cycle = run_cycle  # type: ignore[method-assign]
                bridge.peer_poll = peer_poll
                if args.path == "bridge":
                    run = _play_quiet(sim, refs, quiet)
                else:
                    run = play_references(sim, refs)
    print(f"cycles {run.cycles}, missed TPDOs {run.counters.missed}, {run.state.name}")
    if meter is not None:
        per_cycle_s = meter.total_s / args.cycles
        if args.path != "lockstep":  # less the wrappers' own time, measured apart
            counted = left_out = harness = CpuMeter()
            _harness(args)
            per_cycle_s -= harness.total_s / args.cycles
        print(f"CPU µs per {args.path} cycle: {1e6 * per_cycle_s:.1f}")


def _hooks(bridge: Any, bridge_path: bool) -> tuple[Callable[[], None], Callable[[], int], Any]:
    """The bridge's ``run_cycle`` and ``peer_poll`` wrapped (after the warm-up) so that
    callgrind counts the bridge's cycle without the drive's work (``bridge_path``) or the
    drive's work alone; ``quiet`` wraps the ``before_sync`` hook (left out of the bridge's
    count)."""
    cycle, peer = bridge.run_cycle, bridge.peer_poll

    def run_cycle() -> None:
        if bridge.cycle_index < WARM_UP_CYCLES:
            cycle()
        elif bridge_path:
            counted(cycle)
        else:
            cycle()

    def peer_poll() -> int:
        if bridge.cycle_index < WARM_UP_CYCLES:
            return peer()  # type: ignore[no-any-return]
        if bridge_path:  # inside the counted cycle: left out
            return left_out(peer)  # type: ignore[no-any-return]
        return counted(peer)  # type: ignore[no-any-return]

    def quiet(hook: Callable[[int], None]) -> Callable[[int], None]:
        def run(k: int) -> None:
            if bridge.cycle_index < WARM_UP_CYCLES or not bridge_path:
                hook(k)
            else:
                left_out(lambda: hook(k))

        return run

    return run_cycle, peer_poll, quiet


class _StubBridge:
    """What the harness wraps, doing nothing but the bridge's calls of its two hooks: the
    harness's own instructions per cycle (``--inner --harness``), subtracted from the
    count."""

    def __init__(self) -> None:
        self._k = WARM_UP_CYCLES
        self.before_sync: Callable[[int], None] | None = None
        self.peer_poll: Callable[[], int] | None = lambda: 1

    @property
    def cycle_index(self) -> int:  # a property, as the bridge's, which the wrappers read
        return self._k

    def run_cycle(self) -> None:
        k = self._k
        if self.before_sync is not None:
            self.before_sync(k)
        if self.peer_poll is not None:
            self.peer_poll()
        self._k = k + 1


def _harness(args: argparse.Namespace) -> None:
    """The wrappers of :func:`_hooks` around :class:`_StubBridge`, ``args.cycles`` times."""
    stub = _StubBridge()
    run_cycle, peer_poll, quiet = _hooks(stub, args.path == "bridge")
    stub.run_cycle = run_cycle  # type: ignore[method-assign]
    stub.peer_poll = peer_poll
    if args.path == "bridge":
        stub.before_sync = quiet(lambda k: None)
    gc.collect()
    gc.freeze()
    for _ in range(args.cycles):
        stub.run_cycle()


def _play_quiet(sim: Any, refs: Any, quiet: Callable[[Any], Any]) -> Any:
    """play_references with the bridge's before_sync hook (the harness's disturbance input)
    wrapped in ``quiet`` as soon as play_references has set it."""
    from hil.harness import play_references

    bridge = sim.bridge
    run = bridge.run

    def wrapped_run(*a: Any, **kw: Any) -> int:
        if bridge.before_sync is not None:
            bridge.before_sync = quiet(bridge.before_sync)
        return run(*a, **kw)  # type: ignore[no-any-return]

    bridge.run = wrapped_run
    return play_references(sim, refs)


def _command(args: argparse.Namespace, out: Path, harness: bool = False) -> list[str]:
    command = [
        "valgrind",
        "--tool=callgrind",
        "--fair-sched=yes",
        "--collect-atstart=no",
        "--toggle-collect=functools_reduce",
        "--toggle-collect=_operator_call",
        f"--callgrind-out-file={out}",
        sys.executable,
        __file__,
        "--inner",
        f"--cycles={args.cycles}",
        f"--path={args.path}",
        f"--bus={args.bus}",
        *(["--record"] if args.record else []),
        *(["--python"] if args.python else []),
        *(["--harness"] if harness else []),
    ]
    return command


def _count(args: argparse.Namespace, harness: bool = False) -> tuple[int, str] | None:
    """Instructions callgrind counted in one run of ``--inner`` (None: it failed; its output
    went to stderr) and what the run printed."""
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory())
        out = Path(tmp) / "callgrind.out"
        if args.keep is not None:  # for callgrind_annotate
            keep = args.keep.resolve()
            out = keep.with_name(keep.name + (".harness" if harness else ""))
        command = _command(args, out, harness)
        if args.bus == "udp" and not harness:
            sys.path.insert(0, str(ROOT))
            from virtual_bus.netns import NetworkNamespace

            ns = stack.enter_context(NetworkNamespace.create())
            command = ns.command(command)
        env = dict(os.environ, PYTHONHASHSEED="0")
        done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    collected = re.search(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or collected is None:
        print(done.stdout + done.stderr[-3000:], file=sys.stderr)
        return None
    return int(collected.group(1)), done.stdout.strip()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--path", choices=("lockstep", "bridge", "drive"), default="lockstep")
    parser.add_argument("--bus", choices=("virtual", "udp", "vcan"), default="virtual")
    parser.add_argument("--record", action="store_true")
    parser.add_argument("--python", action="store_true")
    parser.add_argument(
        "--cpu-time",
        action="store_true",
        help="the thread's CPU time of the same sections, without valgrind (µs per cycle)",
    )
    parser.add_argument(
        "--keep",
        type=Path,
        metavar="FILE",
        help="keep callgrind's output in FILE (the harness's run in FILE.harness), "
        "for callgrind_annotate",
    )
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--harness", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.cycles < 1:
        print(f"--cycles {args.cycles}: must be >= 1", file=sys.stderr)
        return 2
    if args.record and (args.bus != "virtual" or args.path != "lockstep"):
        print("--record: only with --path lockstep --bus virtual", file=sys.stderr)
        return 2
    if args.inner and args.harness:
        _harness(args)
        return 0
    if args.inner or (args.cpu_time and args.bus != "udp"):
        _inner(args)
        return 0
    if args.cpu_time:  # udp: in a namespace of its own, without valgrind
        sys.path.insert(0, str(ROOT))
        from virtual_bus.netns import NetworkNamespace

        with NetworkNamespace.create() as ns:
            argv = [sys.executable, __file__, "--inner", *sys.argv[1:]]
            return subprocess.run(ns.command(argv), check=False).returncode
    # a kill ends the run like ^C: the namespace and the temporary files are removed
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    counted_run = _count(args)
    if counted_run is None:
        return 1
    total, printed = counted_run
    print(printed)
    harness = 0
    if args.path != "lockstep":  # the wrappers' own instructions, counted apart
        harness_run = _count(args, harness=True)
        if harness_run is None:
            return 1
        harness = harness_run[0] // args.cycles
    what = {"lockstep": "lockstep cycle", "bridge": "bridge cycle", "drive": "drive SYNC"}
    print(
        f"instructions per {what[args.path]} ({args.bus} bus"
        + (", bridge core in Python" if args.python else "")
        + f"): {total // args.cycles - harness}"
        + (f" (counted {total // args.cycles}, less the harness's {harness})" if harness else "")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

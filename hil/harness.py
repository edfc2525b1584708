"""The bridge and the simulated drive (plant_sim.drive) on one bus: demo, tests, benchmarks.

:func:`simulated_axis` opens two ends of one bus (python-can's in-process virtual bus, or
SocketCAN vcan0), starts a :class:`plant_sim.drive.SimulatedDrive` of the axis on one end and
a :class:`~bridge.node.Bridge` on the other, runs the bridge's start-up (drive configuration
over SDO, CiA 402 to Operation Enabled) and hands both over; everything is stopped and shut
down when the block ends. Faults can be injected on the bridge's end
(:class:`virtual_bus.FaultInjectingBus`, clocked by the bridge's control time).

:func:`run_references` plays a :class:`plant_sim.physics.simulate.References` (e.g. section X) over
the bus: the interpolator plays the reference table, the drive gets the disturbance of
cycle k before SYNC k (its harness input 2100h), one trace row per cycle.
"""

from __future__ import annotations

import contextlib
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from bridge.cycle import BridgeState
from bridge.interpolator import Table
from bridge.node import Bridge, BridgeConfig
from bridge.objects import PdoCounters
from bridge.params import BridgeParams
from bridge.recorder import BusLog, TraceRecorder, log_channel
from bridge.timing import DEFAULT_LOCKSTEP_WAIT_S, LockstepPacer, Pacer, RealTimePacer, TimeMode
from plant_sim.drive import DriveConfig, SimulatedDrive
from plant_sim.physics.simulate import References
from plant_sim.plant import Plant
from virtual_bus import BusConfig, FaultConfig, FaultInjectingBus, Interface, open_bus
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace


@dataclass
class SimulatedAxis:
    """What :func:`simulated_axis` hands over."""

    bridge: Bridge
    drive: SimulatedDrive
    bridge_bus: can.BusABC  # the bridge's end (the FaultInjectingBus when faults are injected)
    drive_bus: can.BusABC
    channel: str


def _channel_name(interface: Interface, channel: str | None) -> str:
    if channel is not None:
        return channel
    if interface is Interface.VIRTUAL:
        return f"sim-{uuid.uuid4().hex[:11]}"  # 15 characters: an interface name
    return "vcan0"


@contextlib.contextmanager
def simulated_axis(
    axis: AxisConfig,
    params: BridgeParams,
    *,
    interface: Interface = Interface.VIRTUAL,
    channel: str | None = None,
    time_mode: TimeMode = TimeMode.LOCKSTEP,
    fault: FaultConfig | None = None,
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S,
    bridge_config: BridgeConfig | None = None,
    drive_config: DriveConfig | None = None,
    trace_path: Path | None = None,
    keep_trace: bool = True,
    disturbance: np.ndarray | None = None,
    bus_log_path: Path | None = None,
    keep_timing: bool = False,
    configure_drive: bool = True,
    wrap_bridge_bus: Callable[[can.BusABC], can.BusABC] | None = None,
    inline_drive: bool = True,
    plant: Plant | None = None,
) -> Iterator[SimulatedAxis]:
    """Bridge + simulated drive of ``axis`` on one bus, started (see the module docstring).

    interface: ``Interface.VIRTUAL`` (default) or ``Interface.SOCKETCAN`` (vcan0).
    time_mode: lockstep (the drive's heartbeat on simulated time too) or real time.
    fault: faults injected on the bridge's end of the bus. trace_path / keep_trace /
    disturbance: the trace recorder; bus_log_path: candump log of the bridge's traffic.
    wrap_bridge_bus: wraps the bridge's end of the bus (outermost; tests tamper with frames).
    inline_drive: lockstep on the in-process virtual bus only: after start-up the drive
    receives in the loop's thread (:meth:`SimulatedDrive.polled`), the frames still going over
    the bus. On vcan0 a frame reaches the other socket asynchronously, so there the drive keeps
    its own thread. plant: what the drive runs (default: the compiled kernel of ``axis``; an
    FMU's :class:`plant_sim.fmu.FmuPlant`), the caller's to close.
    """
    if interface is Interface.AUTO:
        raise ValueError("simulated_axis needs Interface.VIRTUAL or Interface.SOCKETCAN")
    bridge_config = bridge_config or BridgeConfig()
    name = _channel_name(interface, channel)
    bus_config = BusConfig(interface=interface, channel=name)
    cycle_s = params.cycle_s
    pacer: Pacer
    if time_mode is TimeMode.LOCKSTEP:
        pacer = LockstepPacer(cycle_s, lockstep_wait_s)
    else:
        pacer = RealTimePacer(cycle_s)
    drive_config = drive_config or DriveConfig(time_mode=time_mode)
    with contextlib.ExitStack() as stack:
        raw_bridge_bus = open_bus(bus_config)
        stack.callback(raw_bridge_bus.shutdown)
        bridge_bus: can.BusABC = raw_bridge_bus
        if fault is not None:
            bridge_bus = FaultInjectingBus(raw_bridge_bus, fault, clock=pacer.now)
            stack.callback(bridge_bus.shutdown)
        if wrap_bridge_bus is not None:
            bridge_bus = wrap_bridge_bus(bridge_bus)
            stack.callback(bridge_bus.shutdown)
        drive_bus = open_bus(bus_config)
        stack.callback(drive_bus.shutdown)
        recorder = None
        if trace_path is not None or keep_trace:
            recorder = TraceRecorder(trace_path, keep=keep_trace, disturbance=disturbance)
        bus_log = None
        if bus_log_path is not None:
            bus_log = BusLog(bus_log_path, channel=log_channel(bus_config))
        drive = SimulatedDrive(drive_bus, bridge_config.drive_id, axis, drive_config, plant)
        bridge = Bridge(
            bridge_bus,
            params,
            axis.kind,
            pacer,
            config=bridge_config,
            recorder=recorder,
            bus_log=bus_log,
            keep_timing=keep_timing,
            # the drive here is in process and watches on the same (simulated) clock
            wall_heartbeat=time_mode is not TimeMode.LOCKSTEP,
        )
        stack.callback(bridge.close)
        drive.start()
        stack.callback(drive.stop)
        bridge.start(configure_drive=configure_drive)
        if time_mode is TimeMode.LOCKSTEP and inline_drive and interface is Interface.VIRTUAL:
            # configured over SDO with the drive on its own thread; now the loop's thread
            # runs it too: same frames on the same bus, no thread wake-ups per cycle
            bridge.peer_poll = stack.enter_context(drive.polled())
            stack.callback(setattr, bridge, "peer_poll", None)
        yield SimulatedAxis(bridge, drive, bridge_bus, drive_bus, name)


@dataclass(frozen=True)
class ReferenceRun:
    """Result of :func:`run_references`."""

    trace: Trace
    counters: PdoCounters
    state: BridgeState
    stop_message: str
    cycles: int
    wall_s: float


def play_references(sim: SimulatedAxis, refs: References) -> ReferenceRun:
    """Play ``refs`` on a started :class:`SimulatedAxis` (one cycle per reference sample)."""
    bridge, drive = sim.bridge, sim.drive
    dist = refs.disturbance_nm
    current = [drive.disturbance_nm]

    def before_sync(k: int) -> None:
        value = float(dist[k]) if k < dist.size else 0.0
        if value != current[0]:
            drive.set_disturbance_nm(value)
            current[0] = value

    bridge.before_sync = before_sync
    bridge.controller.queue_move(Table.from_references(refs))
    start = time.perf_counter()
    n = bridge.run(cycles=refs.position.size)
    wall_s = time.perf_counter() - start
    drive.check()
    recorder = bridge.recorder
    keeps = recorder is not None and recorder.keeps_rows
    trace = recorder.trace() if keeps else Trace({"time": np.empty(0)})  # type: ignore[union-attr]
    c = bridge.controller
    return ReferenceRun(trace, bridge.counters, c.state, c.stop_message, n, wall_s)


def run_references(
    axis: AxisConfig,
    refs: References,
    params: BridgeParams,
    *,
    interface: Interface = Interface.VIRTUAL,
    trace_path: Path | None = None,
    bus_log_path: Path | None = None,
    fault: FaultConfig | None = None,
    plant: Plant | None = None,
    watch: Callable[[Bridge], None] | None = None,
) -> ReferenceRun:
    """:func:`play_references` in a fresh :func:`simulated_axis` (lockstep). ``watch``:
    called with the bridge before the references play (the live scope, bridge/scope.py)."""
    with simulated_axis(
        axis,
        params,
        interface=interface,
        fault=fault,
        trace_path=trace_path,
        disturbance=refs.disturbance_nm,
        bus_log_path=bus_log_path,
        plant=plant,
    ) as sim:
        if watch is not None:
            watch(sim.bridge)
        return play_references(sim, refs)

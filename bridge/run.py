"""``python -m bridge run``: the bridge against a drive on a CAN interface (real time).

Opens the bus, configures the drive over SDO and brings it to Operation Enabled
(:mod:`bridge.master`), then produces SYNC from the wall clock and closes the loop every cycle
until the moves are done (plus ``--hold`` seconds), ``--seconds`` have passed, the axis was
stopped by a fault, or Ctrl-C. At the end the axis is disabled (controlword "switch on", set
point 0, latched by one more SYNC). Exit status: 0 done, 1 the axis was stopped by a fault (the
reason is printed), 2 bad arguments or files.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import can

from regulator import RegulatorConfig
from virtual_bus import BusConfig, Interface, bus_load, open_bus
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.frame_guard import FrameFault
from virtual_bus.realtime import GcBetweenCycles, RealTimeOptions, apply_realtime

from .busload import layout_load
from .cycle import BridgeState, Command
from .errors import BridgeConfigError
from .interpolator import Move
from .layout import CycleLayout
from .node import DEFAULT_OVERRUN_LIMIT, Bridge, BridgeConfig
from .objects import params_with_store
from .params import BridgeParams
from .recorder import BusLog, TraceRecorder, WireOrderBus, log_channel
from .scaling import LOAD_INCREMENTS_PER_UNIT
from .status import Watch
from .store import ParameterStore
from .timing import LockstepPacer, Pacer, RealTimePacer, TimeMode

log = logging.getLogger("bridge")


@dataclass(frozen=True)
class RunOptions:
    """What ``python -m bridge run`` was asked to do (validated by the CLI parser)."""

    bus: BusConfig
    axis: AxisConfig
    bridge: BridgeConfig
    moves: tuple[Move, ...] = ()
    seconds: float | None = None
    hold_s: float = 1.0
    regulator_enabled: bool = True
    beta_t_rad_s: float | None = None
    trace_path: Path | None = None
    bus_log_path: Path | None = None
    time_mode: TimeMode = TimeMode.REAL_TIME
    realtime: RealTimeOptions = field(default_factory=RealTimeOptions)
    overrun_limit: int | None = DEFAULT_OVERRUN_LIMIT
    #: called with the bridge built and the options, before its start-up (bridge.status:
    #: the plan, the live line, the verdict's figures); None: nothing
    watch: Watch | None = None


@dataclass(frozen=True)
class RunResult:
    cycles: int
    state: BridgeState
    stop_message: str
    missed_tpdos: int
    late_tpdos: int
    skipped_syncs: int
    #: frames the frame guard refused, by kind (2110h; FrameFault order, sub-index 1 first)
    refused_frames: tuple[tuple[FrameFault, int], ...] = ()


def params_for(options: RunOptions) -> BridgeParams:
    axis = options.axis
    base = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    reg = RegulatorConfig(
        kv=base.kv,
        cycle_s=base.cycle_s,
        beta_t_rad_s=options.beta_t_rad_s or base.beta_t_rad_s,
        enabled=options.regulator_enabled,
    )
    return BridgeParams.for_axis(axis, reg)


def check_bus_load(fraction: float, bitrate: int, cycle_s: float, refuse: bool = True) -> None:
    """Refuse a layout that does not fit into the cycle at ``bitrate`` (BridgeConfigError,
    before anything is written to the drive); warn above 80 %. ``refuse=False`` (the check
    of the layout the start-up built, the drive already enabled): warn in both cases."""
    text = (
        f"cyclic PDO traffic is {100 * fraction:.0f} % of the bus at {bitrate} bit/s and "
        f"{cycle_s * 1e3:.3g} ms (python -m bridge busload)"
    )
    if fraction > 1.0:
        message = f"{text}: it does not fit; use --bitrate 1000000 or a longer cycle"
        if refuse:
            raise BridgeConfigError(message)
        log.error("%s", message)
        return
    if fraction > 0.8:
        log.warning("%s; SDO and heartbeats may delay the RPDO", text)


def layout_fraction(layout: CycleLayout, cycle_s: float, bitrate: int) -> float:
    """Bus load of SYNC + the layout's frames + its RPDO (worst-case stuffing)."""
    dlcs = [0, *(f.dlc for f in layout.frames), layout.rpdo_dlc]
    return bus_load(dlcs, cycle_s, bitrate).load_fraction


def run_bridge(options: RunOptions) -> RunResult:
    """Run the bridge as described in the module docstring (blocking)."""
    params = params_for(options)
    store_path = options.bridge.store_path
    if store_path is not None:  # the stored cycle (1006h) sets the pacer
        params = params_with_store(
            params,
            LOAD_INCREMENTS_PER_UNIT[options.axis.kind],
            options.bridge.drive_id,
            ParameterStore(store_path),
        )
    config = options.bus
    if options.bus_log_path is not None and config.interface is Interface.SOCKETCAN:
        # the log in the wire's order: the kernel hands the bridge its own frames back
        config = dataclasses.replace(config, receive_own_messages=True)
    bus = open_bus(config)  # first: a bus that cannot open is the one thing to say
    try:
        return _run_on(bus, options, params)
    finally:
        bus.shutdown()


def _run_on(bus: can.BusABC, options: RunOptions, params: BridgeParams) -> RunResult:
    _, load = layout_load(1, params.cycle_s, options.bus.bitrate)
    check_bus_load(load.load_fraction, options.bus.bitrate, params.cycle_s)
    pacer: Pacer = (
        RealTimePacer(params.cycle_s)
        if options.time_mode is TimeMode.REAL_TIME
        else LockstepPacer(params.cycle_s)
    )
    recorder = TraceRecorder(options.trace_path, keep=False) if options.trace_path else None
    bus_log = None
    if options.bus_log_path is not None:
        bus_log = BusLog(options.bus_log_path, channel=log_channel(options.bus))
        if options.bus.interface is Interface.SOCKETCAN:
            bus = WireOrderBus(bus, bus_log)  # it logs; the bridge does not
            bus_log = None
    bridge = Bridge(
        bus,
        params,
        options.axis.kind,
        pacer,
        config=options.bridge,
        recorder=recorder,
        bus_log=bus_log,
        keep_timing=True,
        overrun_limit=options.overrun_limit,
        gc_control=GcBetweenCycles() if options.realtime.freeze_gc else None,
        busy_poll=options.realtime.busy_poll,
    )
    _command_line_over_store(bridge, options)
    if options.watch is not None:
        options.watch(bridge, options)
    try:
        return _loop(bridge, options, bridge.controller.params)
    finally:
        bridge.close()
        if isinstance(bus, WireOrderBus):  # it wrote the log: the bridge had none to close
            bus.shutdown()
            bus.log.close()


def _command_line_over_store(bridge: Bridge, options: RunOptions) -> None:
    """--no-regulator / --beta-t win over the parameter store (loaded by the bridge)."""
    c = bridge.controller
    p = c.params
    if not options.regulator_enabled:
        p = p.with_value("regulator_enabled", False)
    if options.beta_t_rad_s is not None:
        p = p.with_value("beta_t_rad_s", options.beta_t_rad_s)
    c.set_params(p)


def _loop(bridge: Bridge, options: RunOptions, params: BridgeParams) -> RunResult:
    bridge.start()
    check_bus_load(
        layout_fraction(bridge.layout, params.cycle_s, options.bus.bitrate),
        options.bus.bitrate,
        params.cycle_s,
        refuse=False,
    )
    for line in apply_realtime(options.realtime):  # after the start-up, before the loop
        log.warning("real time: %s", line)
    c = bridge.controller
    for move in options.moves:
        c.queue_move(move)
    limit = math.inf if options.seconds is None else options.seconds / params.cycle_s
    hold_cycles = round(options.hold_s / params.cycle_s)
    idle = [0]

    def done(b: Bridge) -> bool:
        if b.controller.state is BridgeState.STOPPED or b.cycle_index >= limit:
            return True
        if options.moves and not b.controller.moving:
            idle[0] += 1
            return idle[0] > hold_cycles
        return False

    try:
        n = bridge.run(until=done)
    except KeyboardInterrupt:
        n = bridge.counters.cycles
        log.warning("interrupted")
    finally:
        if c.state in (BridgeState.RUNNING, BridgeState.ENABLING):
            c.command(Command.DISABLE)
        # two more cycles: the RPDO "switch on, no motion" and the SYNC that latches it
        bridge.run(cycles=2)
        bridge.drain()  # what came meanwhile passes the frame guard too (counted, logged)
    timing = bridge.timing
    return RunResult(
        cycles=n,
        state=c.state,
        stop_message=c.stop_message,
        missed_tpdos=bridge.counters.missed,
        late_tpdos=bridge.counters.late,
        skipped_syncs=timing.skipped_syncs,
        refused_frames=tuple((fault, bridge.guard.count(fault)) for fault in FrameFault),
    )

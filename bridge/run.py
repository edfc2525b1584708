"""``python -m bridge run``: the bridge against a drive on a CAN interface (real time).

Opens the bus, configures the drive over SDO -- its supervision of the bridge included
(:mod:`bridge.supervision`: heartbeat consumer, 6007h, set-point watchdog) -- and brings it to
Operation Enabled (:mod:`bridge.master`), then produces SYNC from the wall clock and closes the
loop every cycle until the moves are done (plus ``--hold`` seconds), ``--seconds`` have passed,
the axis was stopped by a fault, or SIGINT / SIGTERM (each ends the run at a cycle's end).

At the end the stop reaches the drive (:mod:`bridge.halt`): the quick stop (or, at rest after
the moves, switch on), by SYNC until the drive reports standstill out of Operation Enabled,
else over SDO, else by NMT, and the result says which; then the drive's supervision objects
get back the values they had before the start-up. Exit status: 0 done, 1 the axis was stopped
by a fault or the drive was not confirmed at standstill (the reason is printed), 2 bad
arguments or files.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import signal
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can

from regulator import RegulatorConfig
from virtual_bus import BusConfig, Interface, bus_load, open_bus
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.frame_guard import FrameFault
from virtual_bus.own_frames import EchoSortingBus
from virtual_bus.realtime import GcBetweenCycles, RealTimeOptions, apply_realtime

from .busload import layout_load
from .cycle import BridgeState, Command
from .errors import BridgeConfigError
from .halt import STANDSTILL_RAD_S, HaltResult, HaltWay, halt
from .interpolator import Move
from .layout import CycleLayout
from .master import DriveMaster
from .node import DEFAULT_OVERRUN_LIMIT, Bridge, BridgeConfig
from .objects import params_with_store
from .params import BridgeParams
from .recorder import BusLog, TraceRecorder, log_channel
from .scaling import LOAD_INCREMENTS_PER_UNIT
from .store import ParameterStore
from .timing import DEFAULT_LOCKSTEP_WAIT_S, LockstepPacer, Pacer, RealTimePacer, TimeMode

log = logging.getLogger("bridge")

#: ``RunOptions.watch``: called with the bridge built and the run's options (bridge.status's
#: RunTalk, bridge.scope's Scope).
Watch = Callable[[Bridge, "RunOptions"], None]


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
    #: lockstep: wall time to wait for a TPDO before it counts as missed, s
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
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
    #: how the stop reached the drive at the end (None: the start-up did not finish)
    halt: HaltResult | None = None
    #: the signal that ended the run (SIGINT, SIGTERM), if one did
    interrupted: str | None = None
    #: the drive's supervision objects: configured (lines), given back at the end (lines),
    #: not given back (why), and what the drive lacks for it (notes)
    supervision: tuple[str, ...] = ()
    restored: tuple[str, ...] = ()
    not_restored: tuple[str, ...] = ()
    supervision_notes: tuple[str, ...] = ()

    @property
    def stopped_safely(self) -> bool:
        """The drive was seen out of Operation Enabled at standstill at the end."""
        return self.halt is not None and self.halt.confirmed


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
        with _sigterm_as_interrupt():
            return _run_on(bus, options, params)
    finally:
        bus.shutdown()


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt like SIGINT (the blocking start-up ends the same way
    for both; the loop handles both at a cycle's end, :func:`_signals_end_the_run`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt("SIGTERM")

    before = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


def _run_on(bus: can.BusABC, options: RunOptions, params: BridgeParams) -> RunResult:
    _, load = layout_load(1, params.cycle_s, options.bus.bitrate)
    check_bus_load(load.load_fraction, options.bus.bitrate, params.cycle_s)
    pacer: Pacer = (
        RealTimePacer(params.cycle_s)
        if options.time_mode is TimeMode.REAL_TIME
        else LockstepPacer(params.cycle_s, options.lockstep_wait_s)
    )
    recorder = TraceRecorder(options.trace_path, keep=False) if options.trace_path else None
    bus_log = None
    sorting: tuple[EchoSortingBus, BusLog] | None = None
    if options.bus_log_path is not None:
        bus_log = BusLog(options.bus_log_path, channel=log_channel(options.bus))
        if options.bus.interface is Interface.SOCKETCAN:
            # the kernel hands the bridge its own frames back in the wire's order; the log
            # takes them there, the bridge never sees them (virtual_bus.own_frames)
            writer = bus_log
            bus = EchoSortingBus(
                bus,
                own=lambda m: writer.log(m, received=False),
                other=lambda m: writer.log(m, received=True),
            )
            sorting = (bus, writer)
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
        if sorting is not None:  # it wrote the log: the bridge had none to close
            sorting[0].shutdown()
            sorting[1].close()


def _command_line_over_store(bridge: Bridge, options: RunOptions) -> None:
    """--no-regulator / --beta-t win over the parameter store (loaded by the bridge)."""
    c = bridge.controller
    p = c.params
    if not options.regulator_enabled:
        p = p.with_value("regulator_enabled", False)
    if options.beta_t_rad_s is not None:
        p = p.with_value("beta_t_rad_s", options.beta_t_rad_s)
    c.set_params(p)


@contextlib.contextmanager
def _signals_end_the_run(ended: list[str]) -> Iterator[None]:
    """While the loop runs, SIGINT and SIGTERM end it at the end of a cycle (their name goes
    to ``ended``) instead of raising in the middle of one; elsewhere (the blocking start-up)
    SIGTERM raises KeyboardInterrupt like SIGINT. Only in the main thread (signals go there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handled = (signal.SIGINT, signal.SIGTERM)
    before = {sig: signal.getsignal(sig) for sig in handled}

    def note(signum: int, _frame: object) -> None:
        ended.append(signal.Signals(signum).name)

    for sig in handled:
        signal.signal(sig, note)
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


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
    ended: list[str] = []

    def done(b: Bridge) -> bool:
        if ended or b.controller.state is BridgeState.STOPPED or b.cycle_index >= limit:
            return True
        if options.moves and not b.controller.moving:
            idle[0] += 1
            return idle[0] > hold_cycles
        return False

    with _signals_end_the_run(ended):
        try:
            n = bridge.run(until=done)
        except KeyboardInterrupt:  # not the main thread: Ctrl-C raises in the cycle
            n = bridge.counters.cycles
            ended.append("SIGINT")
        finally:
            if ended:
                log.warning("%s: the run ends", ended[0])
            if c.state in (BridgeState.RUNNING, BridgeState.ENABLING):
                if ended or c.moving or abs(c.motor_speed_rad_s) > STANDSTILL_RAD_S:
                    c.halt()  # the drive's quick stop ramp, not a coasting axis
                else:
                    c.command(Command.DISABLE)  # at rest after the moves: switch on
            stopped = halt(bridge)  # the stop reaches the drive, confirmed (bridge.halt)
            log.log(
                logging.INFO if stopped.confirmed else logging.ERROR,
                "%s",
                stopped.describe(bridge.config.drive_id),
            )
            bridge.drain()  # what came meanwhile passes the frame guard too (counted, logged)
    restored, not_restored = _give_back(bridge, stopped)
    timing = bridge.timing
    info = bridge.drive_info
    supervision = info.supervision if info is not None else None
    return RunResult(
        cycles=n,
        state=c.state,
        stop_message=c.stop_message,
        missed_tpdos=bridge.counters.missed,
        late_tpdos=bridge.counters.late,
        skipped_syncs=timing.skipped_syncs,
        refused_frames=tuple((fault, bridge.guard.count(fault)) for fault in FrameFault),
        halt=stopped,
        interrupted=ended[0] if ended else None,
        supervision=tuple(supervision.describe()) if supervision is not None else (),
        restored=restored,
        not_restored=not_restored,
        supervision_notes=supervision.notes if supervision is not None else (),
    )


def _give_back(bridge: Bridge, stopped: HaltResult) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The drive's supervision objects back to their values before the start-up (the drive
    is at rest and the bridge leaves in order: nothing is to watch it any more); not after
    an NMT Stop (no SDO in Stopped): the drive then goes on watching, and stops again."""
    info = bridge.drive_info
    if info is None or not info.restore:
        return (), ()
    if stopped.way is HaltWay.NMT:
        return (), ("the drive is NMT Stopped: its supervision objects stay as configured",)
    with bridge.serving():
        master = DriveMaster(bridge.drive, bridge.config.drive_setup)
        failed = master.restore(info.restore)
    done = tuple(
        f"{key[0]:04X}h:{key[1]:02X} = 0x{data[::-1].hex().upper()}"
        for key, data in info.restore
        if not any(f"{key[0]:04X}h:{key[1]:02X}" in why for why in failed)
    )
    return done, tuple(failed)

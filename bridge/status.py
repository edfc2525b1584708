"""What ``python -m bridge run`` tells its user (issue 29, "a run that talks").

* **The start-up plan**, on stderr before the drive is touched: the moves (or ``--seconds``),
  the regulator and its parameters, the clock and the bus, and which parameters came from the
  parameter store (1010h/1011h) rather than the axis file and the command line; then, as the
  start-up reports them, the drive's mode, rated torque and the PDO layout it was given
  (:mod:`bridge.master`'s own lines, shown instead of only logged).
* **A live status line** on stderr, only where stderr is a terminal: time, load position,
  following error, β (Fig. 5), λ (eq. 15), the bus load of the frames the bridge sent and
  received, missed TPDOs and skipped SYNCs, and the bridge's state; rewritten in place every
  :data:`LIVE_INTERVAL_S` of the wall clock by a thread of its own. The loop only hands it
  the cycle's values (one tuple per cycle, :meth:`RunTalk.cycle`); it never waits for the
  terminal, whatever the terminal does.
* **A verdict** (:class:`Verdict`): target reached or not, the largest following error while
  running, the vibration episodes (β above β_T, Fig. 5 / eq. 15), the smallest λ, and why the
  run ended; one line on stdout, or with ``--json`` a JSON document of the whole result.

Printed values carry their units in µm / mm (µrad / mrad on a rotary axis) by
:func:`cmdline.quantity.quantity`; the JSON keeps SI (load units), with the unit in each key.

The bridge calls :meth:`RunTalk.attach` with the bridge built, before its start-up
(``RunOptions.watch``), and then :meth:`RunTalk.cycle` after every cycle
(``Bridge.after_cycle``); the command calls :meth:`RunTalk.close` when the run has ended.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TextIO

from cmdline.quantity import number, quantity, resolved
from virtual_bus.busload import frame_bits
from virtual_bus.formats.axis import AxisKind

from .cycle import BridgeState
from .interpolator import Move, Table
from .params import BridgeParams
from .store import ParameterStore
from .timing import TimeMode

if TYPE_CHECKING:
    from .node import Bridge
    from .run import RunOptions

#: How often the live line is rewritten (wall clock), s.
LIVE_INTERVAL_S = 0.25
#: A target counts as reached when the load ends this close to it (load units: 10 µm or
#: 10 µrad; ``--target-tolerance``).
DEFAULT_TARGET_TOLERANCE = 10e-6
#: Prefix of every line on stderr.
PREFIX = "bridge run: "
#: Erase the rest of the terminal's line (ECMA-48 EL).
ERASE_LINE = "\x1b[K"

_RUNNING = BridgeState.RUNNING

#: BridgeParams fields shown where the store set them: (label, object, unit; "load": the
#: axis's load unit, "load/s", "load/s²").
_SHOWN: dict[str, tuple[str, str, str]] = {
    "kv_per_s": ("k_v", "2000h", "1/s"),
    "regulator_enabled": ("regulator", "2001h", ""),
    "beta_t_rad_s": ("β_T", "2002h", "rad/s"),
    "n": ("detector window n", "2003h", ""),
    "tv_s": ("T_v", "2004h", "s"),
    "tf_s": ("T_f", "2005h", "s"),
    "cycle_s": ("position cycle", "1006h", "s"),
    "transmission_ratio": ("k_r", "2006h", "rad/load"),
    "speed_limit_rad_s": ("speed limit", "2007h", "rad/s"),
    "following_error_limit": ("following error limit", "2008h", "load"),
    "discrepancy_limit": ("discrepancy limit", "2009h", "load"),
    "pdo_loss_tolerance": ("PDO loss tolerance", "200Ah", "cycles"),
    "heartbeat_consumer_ms": ("drive heartbeat timeout", "1016h", "ms"),
    "feed": ("feed", "2011h", "load/s"),
    "accel": ("acceleration", "2012h", "load/s²"),
    "position_limit_min": ("travel limit min", "2014h:01", "load"),
    "position_limit_max": ("travel limit max", "2014h:02", "load"),
    "velocity_feedforward": ("k_vff", "200Bh", ""),
}


def load_unit(kind: AxisKind) -> str:
    return "m" if kind is AxisKind.LINEAR else "rad"


def _value(value: object, unit: str, load: str) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if value is None:
        return "default"
    assert isinstance(value, int | float)
    if unit == "rad/load":
        return f"{number(float(value))} rad/{load}"
    if unit.startswith("load"):
        return quantity(float(value), load + unit[4:])
    if unit in ("s",):
        return quantity(float(value), unit)
    return f"{number(float(value))} {unit}".rstrip()


@dataclass(frozen=True)
class Verdict:
    """How a run went. Positions and errors in load units (m, or rad on a rotary axis).

    target: the last move's target (a table's last position); None: no move was given.
    reached: the load ended within ``tolerance`` of it (None: no target).
    max_following_error / at_s: the largest |x_ref - x_l| while the axis ran, and when.
    vibration_episodes: times β rose above β_T while running (Fig. 5, eq. 15); vibrating_s
    their total length. min_lambda: the smallest λ while running (1: never switched).
    stop: why the run ended.
    """

    unit: str
    target: float | None
    final_position: float
    tolerance: float
    reached: bool | None
    max_following_error: float
    max_following_error_at_s: float
    vibration_episodes: int
    vibrating_s: float
    beta_t_rad_s: float
    max_beta_rad_s: float
    min_lambda: float
    stop: str

    def line(self) -> str:
        u = self.unit
        if self.target is None:
            target = f"no target (ended at {quantity(self.final_position, u)})"
        else:
            off = self.final_position - self.target
            where = f"{resolved(abs(off), u)} off"
            ok = "reached" if self.reached else "NOT reached"
            target = (
                f"target {quantity(self.target, u)} {ok} ({where}, tolerance "
                f"{quantity(self.tolerance, u)})"
            )
        if self.vibration_episodes:
            vib = (
                f"{self.vibration_episodes} vibration episode(s), "
                f"{quantity(self.vibrating_s, 's')} in all"
            )
        else:
            vib = "no vibration episode"
        fe = quantity(self.max_following_error, u)
        if math.isfinite(self.max_following_error_at_s):
            fe += f" at {quantity(self.max_following_error_at_s, 's')}"
        return (
            f"verdict: {target}; largest following error {fe}; {vib} (β above β_T "
            f"{number(self.beta_t_rad_s)} rad/s, largest β "
            f"{resolved(self.max_beta_rad_s, 'rad/s', floor=1e-3)}); smallest λ "
            f"{number(self.min_lambda)}; stop: {self.stop}"
        )

    def as_json(self) -> dict[str, Any]:
        """SI values, the unit in each key (``_m`` or ``_rad`` for load units)."""
        u = self.unit
        return {
            "load_unit": u,
            f"target_{u}": self.target,
            f"final_position_{u}": self.final_position,
            f"tolerance_{u}": self.tolerance,
            "target_reached": self.reached,
            f"max_following_error_{u}": self.max_following_error,
            "max_following_error_at_s": _finite(self.max_following_error_at_s),
            "vibration_episodes": self.vibration_episodes,
            "vibrating_s": self.vibrating_s,
            "beta_t_rad_s": self.beta_t_rad_s,
            "max_beta_rad_s": self.max_beta_rad_s,
            "min_lambda": self.min_lambda,
            "stop": self.stop,
        }


def _bitrate(bits_s: int) -> str:
    """'1 Mbit/s', '500 kbit/s'."""
    if bits_s >= 1_000_000:
        return f"{number(bits_s / 1e6)} Mbit/s"
    return f"{number(bits_s / 1e3)} kbit/s"


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def jsonable(value: object) -> Any:
    """A run's result as JSON values: enums by name, dataclasses as objects."""
    if isinstance(value, enum.Enum):
        return value.name
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [jsonable(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class _StartupLines(logging.Filter):
    """On the ``bridge`` logger while the run is attached: the start-up's INFO lines of
    :mod:`bridge.master` (mode, rated torque, layout) go to the stream. ``only_warnings``:
    the logger was lowered to INFO for them, so no other INFO record goes on to the handlers
    (the command's logging shows warnings only)."""

    def __init__(self, write: Callable[[str], None], only_warnings: bool) -> None:
        super().__init__()
        self._write = write
        self._only_warnings = only_warnings

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno == logging.INFO and record.module == "master":
            lines = record.getMessage().splitlines()
            self._write("\n".join([lines[0], *("    " + ln for ln in lines[1:])]))
        return record.levelno >= logging.WARNING or not self._only_warnings


class RunTalk:
    """The start-up plan, the live line and the verdict of one ``bridge run`` (module
    docstring). stream: where the plan and the live line go (stderr). live: the live line
    (None: where ``stream`` is a terminal). target_tolerance: load units."""

    def __init__(
        self,
        stream: TextIO | None = None,
        live: bool | None = None,
        target_tolerance: float = DEFAULT_TARGET_TOLERANCE,
        interval_s: float = LIVE_INTERVAL_S,
        wall: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        if live is None:
            isatty = getattr(self.stream, "isatty", None)
            live = bool(isatty and isatty())
        self.live = live
        self.target_tolerance = target_tolerance
        self.interval_s = interval_s
        self._wall = wall
        self._bridge: Bridge | None = None
        self._options: RunOptions | None = None
        self._handler: _StartupLines | None = None
        self._level = logging.NOTSET
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()  # one writer at a time on the stream
        self._line_shown = False
        # kept by cycle() (the loop's thread)
        self._latest: tuple[float, float, float, float, float, BridgeState] | None = None
        self._reference = math.nan  # x_ref of the last running cycle
        self._max_fe = 0.0
        self._max_fe_at = math.nan
        self._max_beta = 0.0
        self._min_lambda = math.inf
        self._episodes = 0
        self._vibrating_cycles = 0
        self._vibrating = False
        self._cycle_s = math.nan

    # --- output ---------------------------------------------------------------------------
    def say(self, text: str) -> None:
        """A line on the stream (the live line, if shown, is erased first and comes back at
        its next update)."""
        with self._lock:
            erase = "\r" + ERASE_LINE if self._line_shown else ""
            self._line_shown = False
            self.stream.write(f"{erase}{PREFIX}{text}\n")
            self.stream.flush()

    # --- the hooks ------------------------------------------------------------------------
    def attach(self, bridge: Bridge, options: RunOptions) -> None:
        """With the bridge built, before its start-up: the plan; the start-up's own lines
        from here on; the per-cycle hook; the live line's thread."""
        self._bridge, self._options = bridge, options
        self._cycle_s = bridge.controller.params.cycle_s
        for line in self.plan_lines(bridge, options):
            self.say(line)
        logger = logging.getLogger("bridge")
        lower = logger.getEffectiveLevel() > logging.INFO
        self._handler = _StartupLines(self.say, only_warnings=lower)
        self._level = logger.level
        logger.addFilter(self._handler)
        if lower:
            logger.setLevel(logging.INFO)
        bridge.after_cycle = self.cycle
        if self.live:
            self._thread = threading.Thread(target=self._show, name="bridge-status", daemon=True)
            self._thread.start()

    def cycle(self, bridge: Bridge) -> None:
        """After every cycle, in the loop's thread: the extremes and the latest values (a
        few attribute reads; nothing waits)."""
        c = bridge.controller
        state = c.state
        e = c.following_error
        beta = c.vibration_level
        lam = c.switching_factor
        if state is _RUNNING:
            self._reference = c.position_reference
            if abs(e) > self._max_fe:
                self._max_fe = abs(e)
                self._max_fe_at = c.now_s
            if beta > self._max_beta:
                self._max_beta = beta
            if lam < self._min_lambda:
                self._min_lambda = lam
            vibrating = beta > c.regulator_config.beta_t_rad_s
            if vibrating:
                self._vibrating_cycles += 1
                if not self._vibrating:
                    self._episodes += 1
            self._vibrating = vibrating
        self._latest = (c.now_s, c.load_position, e, beta, lam, state)

    def close(self) -> None:
        """The run has ended: the live line stops and is erased, the start-up's lines are
        no longer shown."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with self._lock:
            if self._line_shown:
                self.stream.write("\r" + ERASE_LINE)
                self.stream.flush()
                self._line_shown = False
        if self._handler is not None:
            logger = logging.getLogger("bridge")
            logger.removeFilter(self._handler)
            logger.setLevel(self._level)
            self._handler = None
        if self._bridge is not None:
            self._bridge.after_cycle = None

    # --- the plan ---------------------------------------------------------------------------
    def plan_lines(self, bridge: Bridge, options: RunOptions) -> list[str]:
        from .run import params_for

        unit = load_unit(options.axis.kind)
        p = bridge.controller.params
        lines = []
        if options.moves:
            moves = [self._move_text(m, unit) for m in options.moves]
            then = f", then hold {quantity(options.hold_s, 's')}"
            lines.append(f"plan: {len(moves)} move(s): " + "; ".join(moves) + then)
        if options.seconds is not None:
            lines.append(f"plan: stop after {quantity(options.seconds, 's')}")
        reg = (
            f"regulator on (eq. 15): β_T {number(p.beta_t_rad_s)} rad/s"
            if p.regulator_enabled
            else f"regulator off: ordinary control (Fig. 1), β measured against β_T "
            f"{number(p.beta_t_rad_s)} rad/s"
        )
        lines.append(
            f"{reg}; k_v {number(p.kv_per_s)} 1/s, position cycle {quantity(p.cycle_s, 's')}, "
            f"following error limit {quantity(p.following_error_limit, unit)}, speed limit "
            f"{number(p.speed_limit_rad_s)} rad/s, travel "
            f"{quantity(p.position_limit_min, unit, like=p.position_limit_max)} … "
            f"{quantity(p.position_limit_max, unit, like=p.position_limit_min)}"
        )
        bus = options.bus
        interface = getattr(bus.interface, "value", bus.interface)  # the CLI's string, or enum
        clock = "real time" if options.time_mode is TimeMode.REAL_TIME else "lockstep"
        lines.append(
            f"clock: {clock}; bus: {interface} {bus.channel or ''} at "
            f"{_bitrate(bus.bitrate)}; drive {bridge.config.drive_id}, bridge "
            f"{bridge.config.node_id}".replace("  ", " ")
        )
        lines.append(self._store_line(bridge, params_for(options), p, unit))
        return lines

    @staticmethod
    def _move_text(move: Move | Table, unit: str) -> str:
        if isinstance(move, Table):
            return (
                f"a table of {move.position.size} samples to "
                f"{quantity(float(move.position[-1]), unit)}"
            )
        text = f"to {quantity(move.target, unit)} at {quantity(move.feed, unit + '/s')}"
        if move.accel:
            text += f", {quantity(move.accel, unit + '/s²')}"
        if move.dwell_s:
            text += f", dwell {quantity(move.dwell_s, 's')}"
        return text

    @staticmethod
    def _store_line(bridge: Bridge, given: BridgeParams, used: BridgeParams, unit: str) -> str:
        path = bridge.config.store_path
        if path is None:
            return "parameter store: none (the axis file's and the command line's values)"
        if ParameterStore(path).load() is None:
            return (
                f"parameter store {path}: nothing stored (the axis file's and the command "
                "line's values)"
            )
        changed = [
            f"{label} {_value(getattr(used, name), u, unit)} ({obj})"
            for name, (label, obj, u) in _SHOWN.items()
            if getattr(used, name) != getattr(given, name)
        ]
        what = ", ".join(changed) if changed else "the same values as the axis file's"
        return f"parameters loaded from store {path}: {what}"

    # --- the live line ----------------------------------------------------------------------
    def _show(self) -> None:
        bridge, options = self._bridge, self._options
        assert bridge is not None and options is not None
        unit = load_unit(options.axis.kind)
        last = (self._wall(), bridge.counters.cycles, bridge.guard.accepted)
        while not self._stop.wait(self.interval_s):
            latest = self._latest
            if latest is None:  # the start-up
                continue
            now = (self._wall(), bridge.counters.cycles, bridge.guard.accepted)
            load = self._bus_load(bridge, options, now, last)
            last = now
            t, x, e, beta, lam, state = latest
            line = (
                f"t {number(t)} s  x {quantity(x, unit)}  e {quantity(e, unit)}  "
                f"β {number(beta)} rad/s  λ {number(lam)}  bus {load}  missed "
                f"{bridge.counters.missed}  skipped {bridge.timing.skipped_syncs}  "
                f"{state.name}"
            )
            with self._lock:
                self.stream.write(f"\r{PREFIX}{line}{ERASE_LINE}")
                self.stream.flush()
                self._line_shown = True

    @staticmethod
    def _bus_load(
        bridge: Bridge,
        options: RunOptions,
        now: tuple[float, int, int],
        last: tuple[float, int, int],
    ) -> str:
        """The frames the bridge sent (SYNC, RPDO per cycle) and received since the last
        line, worst-case stuffing, over the wall time at the bitrate; in lockstep there is
        no wall-clock rate to give."""
        if options.time_mode is not TimeMode.REAL_TIME:
            return "– (lockstep)"
        dt = now[0] - last[0]
        if dt <= 0.0:
            return "–"
        layout = bridge.layout
        sent = frame_bits(0) + frame_bits(layout.rpdo_dlc)
        dlcs = [f.dlc for f in layout.frames] or [8]
        received = sum(frame_bits(d) for d in dlcs) / len(dlcs)
        bits = (now[1] - last[1]) * sent + (now[2] - last[2]) * received
        return f"{number(100.0 * bits / (options.bus.bitrate * dt), 2)} %"

    # --- the verdict ------------------------------------------------------------------------
    def verdict(self, result: object) -> Verdict:
        """The verdict of the ended run (``result``: its :class:`~bridge.run.RunResult`)."""
        bridge, options = self._bridge, self._options
        assert bridge is not None and options is not None, "attach() was not called"
        unit = load_unit(options.axis.kind)
        final = bridge.controller.load_position
        target = _target(options.moves)
        reached = None if target is None else abs(final - target) <= self.target_tolerance
        return Verdict(
            unit=unit,
            target=target,
            final_position=final,
            tolerance=self.target_tolerance,
            reached=reached,
            max_following_error=self._max_fe,
            max_following_error_at_s=self._max_fe_at,
            vibration_episodes=self._episodes,
            vibrating_s=self._vibrating_cycles * self._cycle_s,
            beta_t_rad_s=bridge.controller.regulator_config.beta_t_rad_s,
            max_beta_rad_s=self._max_beta,
            min_lambda=self._min_lambda if math.isfinite(self._min_lambda) else 1.0,
            stop=_stop_reason(result, options, self._cycle_s, self._reference, target),
        )

    def document(self, result: object) -> dict[str, Any]:
        """``--json``: the run's result and its verdict."""
        doc = jsonable(result)
        assert isinstance(doc, dict)
        doc["refused_frames"] = {name.lower(): n for name, n in doc.get("refused_frames", [])}
        doc["stopped_safely"] = getattr(result, "stopped_safely", None)
        doc["verdict"] = self.verdict(result).as_json()
        return doc


def _target(moves: tuple[Move | Table, ...]) -> float | None:
    if not moves:
        return None
    last = moves[-1]
    return float(last.position[-1]) if isinstance(last, Table) else last.target


def _stop_reason(
    result: object,
    options: RunOptions,
    cycle_s: float,
    reference: float,
    target: float | None,
) -> str:
    message = getattr(result, "stop_message", "none")
    if message != "none":
        return f"stopped by a fault: {message}"
    interrupted = getattr(result, "interrupted", None)  # the signal, where the run knows it
    if interrupted:
        return f"{interrupted}"
    cycles = int(getattr(result, "cycles", 0))
    if options.seconds is not None and cycles >= math.floor(options.seconds / cycle_s):
        return f"--seconds {quantity(options.seconds, 's')} elapsed"
    if target is not None and reference == target:  # the interpolator ends on the target
        return f"moves done, held {quantity(options.hold_s, 's')}"
    return "interrupted (SIGINT or SIGTERM) before the moves were done"

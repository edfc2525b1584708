"""The per-SYNC controller: pure and stepped (no bus, no clock, no threads).

:meth:`CycleController.step` gets the payloads of the frames of one SYNC in the order of its
:class:`~bridge.layout.CycleLayout` (the contract's: the drive's TPDO1, TPDO2; ``None`` for a
missing one) and the control time, and returns the RPDO1 payload (controlword,
target velocity). Between cycles the I/O layer reports heartbeats and EMCYs
(:meth:`~CycleController.on_heartbeat`, :meth:`~CycleController.on_emcy`), and the SDO server
changes parameters, sends commands and starts moves.

Running, per SYNC k (docs/canopen_layout.md: the set point takes effect at SYNC k+1):

1. measurements at t_k: motor angle theta_m (6064h), load position x_l (60E4h:01), statusword,
   torque, motor speed; a missing TPDO is extrapolated from the last samples;
2. supervision: PDO loss, heartbeat (1016h), EMCY, drive state, following error, encoder
   discrepancy, software position limits (2014h) -- any of them stops the axis (quick stop,
   set point 0) with a :class:`StopReason` and a message until a reset command;
3. interpolator: x_ref and its speed, omega_s = k_r * speed;
4. eq. 7 on the load scale: omega_c = k_r k_v (x_ref - x_l) (``regulator.core``),
   plus k_vff omega_s where the axis has velocity feed-forward (200Bh; the simulator's law);
5. eq. 15: omega_r = omega_s - lambda (omega_s - omega_c) (``regulator.core``: the detector of
   Fig. 5 and the switching factor), clamped to the speed limit, sent as 60FFh.

The arithmetic of steps 1, 4 and 5 is :mod:`bridge.cyclecore` (one source, run as Python or
compiled by numba: ``compiled``); the states, the supervision with its messages and the
interpolator are here. The measurements and outputs live in the core's vector and read as
attributes (``motor_position_rad``, ``omega_r``, ...).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable
from enum import Enum, IntEnum
from typing import Any

from canopen.profiles.p402 import State402

from regulator import core as rcore
from regulator.errors import require_finite_input
from virtual_bus.contract import CW_FAULT_RESET

from . import cyclecore as K
from .consumers import NodeWatch
from .errors import ParameterError, SdoAbort
from .interpolator import Interpolator, Move, Table
from .layout import CycleLayout, Signal, contract_layout
from .params import LOCKED, BridgeParams
from .scaling import Scaling

log = logging.getLogger("bridge")

#: Time the drive gets to reach Operation Enabled after an enable command, s.
ENABLE_TIMEOUT_S = 1.0


class BridgeState(Enum):
    """State of the bridge (2104h)."""

    CONFIGURING = 0  # start-up: the drive is being configured over SDO
    DISABLED = 1  # cycling, commanding no motion; locked parameters may change
    ENABLING = 2  # bringing the drive to Operation Enabled through the controlword
    RUNNING = 3  # closed loop: set points every cycle
    STOPPED = 4  # stopped by a fault (reason in 2105h/2106h); quick stop until reset


class StopReason(Enum):
    """Why the bridge stopped commanding motion (2105h)."""

    NONE = 0
    PDO_LOSS = 1  # more consecutive cycles without a complete TPDO set than 200Ah allows
    DRIVE_FAULT = 2  # statusword shows Fault / Fault reaction active
    DRIVE_EMCY = 3  # the drive sent an EMCY with a non-zero error code
    HEARTBEAT_LOST = 4  # no drive heartbeat within the 1016h consumer time
    FOLLOWING_ERROR = 5  # |x_ref - x_l| above 2008h
    ENCODER_DISCREPANCY = 6  # motor and load scale disagree by more than 2009h
    DRIVE_DISABLED = 7  # the drive left Operation Enabled without a fault
    DRIVE_NMT = 8  # the drive's heartbeat reports boot-up or a non-operational NMT state
    ENABLE_TIMEOUT = 9  # the drive did not reach Operation Enabled within ENABLE_TIMEOUT_S
    POSITION_LIMIT = 10  # the load scale is outside 2014h and no move heads back inside
    CYCLE_OVERRUN = 11  # the loop overran its cycle (SYNC slots skipped) too often in a row
    INTERNAL_ERROR = 12  # the controller's own step failed (a bug; the message names it)
    SYNC_CONFLICT = 13  # a SYNC the bridge did not send: a second SYNC producer on the bus
    ENCODER_EMCY = 14  # the CiA 406 encoder node (load scale) sent an EMCY with a non-zero code
    TEST_LIMIT = 15  # a commissioning test (freqresp, tune) broke its own limit (e.g. torque)
    NMT_COMMAND = 16  # an NMT command took the bridge out of Operational (bridge.nmt)


class Command(IntEnum):
    """Values of the command object 2020h."""

    ENABLE = 1
    DISABLE = 2
    RESET = 3


class Drive402State(Enum):
    """CiA 402 state decoded from the statusword (names as canopen.profiles.p402.State402)."""

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"
    UNKNOWN = "UNKNOWN"


def _decode_table() -> tuple[Drive402State, ...]:
    # Only statusword bits 0-3, 5 and 6 select the state: a 128-entry table of (sw & 0x6F).
    table = []
    for low in range(128):
        state = Drive402State.UNKNOWN
        for name, (mask, value) in State402.SW_MASK.items():
            if low & mask == value:
                state = Drive402State(name)
                break
        table.append(state)
    return tuple(table)


_STATE_OF_LOW_BITS = _decode_table()


def drive_state(statusword: int) -> Drive402State:
    """CiA 402 state of a statusword (6041h)."""
    return _STATE_OF_LOW_BITS[statusword & 0x6F]


def enable_controlword(state: Drive402State, last_controlword: int) -> int:
    """The controlword that moves a drive in ``state`` one step towards Operation Enabled
    (paths of canopen.profiles.p402.State402). A fault reset needs a rising edge of bit 7,
    so after a 0x0080 that did not clear the fault 0x0000 comes first."""
    if state is Drive402State.UNKNOWN:
        return State402.CW_DISABLE_VOLTAGE
    if state is Drive402State.OPERATION_ENABLED:
        return State402.CW_OPERATION_ENABLED
    target = State402.next_state_indirect(state.value)
    cw = State402.TRANSITIONTABLE[(state.value, target)]
    if cw == State402.CW_SWITCH_ON_DISABLED and last_controlword & CW_FAULT_RESET:
        return State402.CW_DISABLE_VOLTAGE
    return cw


#: index of each signal's raw value in the core's vector (bridge.cyclecore)
_RAW = {signal: K.RAW_INDEX[signal.value] for signal in Signal}


def _decoder(
    v: Any, unpack: Callable[[Any, int], tuple[int, ...]], at: tuple[int, ...]
) -> Callable[[Any, int], None]:
    """``decode(buffer, offset)``: the fields ``unpack`` reads at ``offset`` into ``v[at[0]]``,
    ``v[at[1]]``, ... (one unpacking assignment for the usual frame sizes)."""
    if len(at) == 1:
        (a,) = at

        def decode1(buffer: Any, offset: int) -> None:
            (v[a],) = unpack(buffer, offset)

        return decode1
    if len(at) == 2:
        a, b = at

        def decode2(buffer: Any, offset: int) -> None:
            v[a], v[b] = unpack(buffer, offset)

        return decode2
    if len(at) == 3:
        a, b, c = at

        def decode3(buffer: Any, offset: int) -> None:
            v[a], v[b], v[c] = unpack(buffer, offset)

        return decode3

    def decode(buffer: Any, offset: int) -> None:
        for i, value in zip(at, unpack(buffer, offset)):  # noqa: B905 (same length)
            v[i] = value

    return decode


def _value(index: int, doc: str) -> property:
    """A float of the controller's core vector (bridge.cyclecore) as an attribute."""

    def get(self: CycleController) -> float:
        return float(self._vm[index])

    def put(self: CycleController, value: float) -> None:
        self._vm[index] = value

    return property(get, put, doc=doc)


def _count(index: int, doc: str) -> property:
    """An integer kept in the core vector, as an attribute."""

    def get(self: CycleController) -> int:
        return int(self._vm[index])

    def put(self: CycleController, value: int) -> None:
        self._vm[index] = float(value)

    return property(get, put, doc=doc)


# Enum members the per-SYNC code compares with, as module globals: CPython 3.11's EnumType has
# a __getattr__, so reading a member off its class costs ~1,000 instructions, a global ~50
# (callgrind).
_RUNNING, _ENABLING, _STOPPED = BridgeState.RUNNING, BridgeState.ENABLING, BridgeState.STOPPED
_OK = K.OK

CW_STOPPED = State402.CW_QUICK_STOP
CW_DISABLED = State402.CW_SWITCH_ON
CW_RUNNING = State402.CW_OPERATION_ENABLED


class CycleController:
    """The bridge's control cycle; see the module docstring. Not thread-safe: the I/O layer
    calls everything from one thread."""

    def __init__(
        self,
        params: BridgeParams,
        scaling: Scaling,
        state: BridgeState = BridgeState.ENABLING,
        layout: CycleLayout | None = None,
        *,
        compiled: bool | None = False,
    ) -> None:
        #: the cycle's arithmetic (bridge.cyclecore): Python, or compiled by numba
        #: (``compiled`` None: where numba is installed; the loop's choice, docs/bridge.md)
        self.core = K.load(compiled)
        self.scaling = scaling
        self.state = state
        self.stop_reason = StopReason.NONE
        self.stop_message = "none"
        self.params = params
        self._v, self._det = self.core.vectors(params.n)
        #: the vector as Python reads and writes it fastest (a memoryview of the array the
        #: compiled core takes: a float in, a float out, no numpy scalar)
        self._vm = self.core.view(self._v)
        self._build(params)
        self.interpolator = Interpolator(params.cycle_s)
        self._pending: list[Move | Table] = []
        self.set_layout(layout or contract_layout(2))
        self.set_scaling(scaling)
        self.now_s = 0.0
        self.controlword = CW_DISABLED
        #: what DISABLED commands: switch on, no motion (0007h), or the quick stop (0002h)
        #: after :meth:`halt` -- the drive's own ramp to standstill, never a coasting axis
        self.disabled_controlword = CW_DISABLED
        # supervision
        self.cycles = 0
        self.drive_error_code = 0
        self._enable_started_s: float | None = None
        #: the nodes whose heartbeats and EMCYs stop the axis (bridge.consumers), checked in
        #: this order: the drive, then a CiA 406 encoder node supplying the load position
        self.drive_watch = NodeWatch(
            "drive",
            StopReason.DRIVE_EMCY,
            StopReason.HEARTBEAT_LOST,
            StopReason.DRIVE_NMT,
            states_from_operational=True,
        )
        self.encoder_watch: NodeWatch | None = None
        self._watches: tuple[NodeWatch, ...] = (self.drive_watch,)
        self._encoder_id: int | None = None

    # --- configuration ---------------------------------------------------------------------
    def _build(self, params: BridgeParams) -> None:
        reg = params.regulator_config()  # validated by BridgeParams
        #: the regulator's configuration in force (rebuilt only while disabled)
        self.regulator_config = reg
        v = self._v
        v[K.P_KR] = float(params.transmission_ratio)
        v[K.P_KV] = float(params.kv_per_s)
        v[K.P_CYCLE] = float(params.cycle_s)
        v[K.P_REG_ON] = 1.0 if reg.enabled else 0.0
        v[K.P_REG_N] = float(reg.n)
        v[K.P_REG_TV] = float(reg.effective_tv_s)
        v[K.P_REG_TF] = float(reg.tf_s)
        v[K.P_REG_BT] = float(reg.beta_t_rad_s)
        if len(self._det) != rcore.detector_state_size(reg.n):
            self._v, self._det = self.core.vectors(reg.n)
            self._v[:] = v
            self._vm = self.core.view(self._v)
            if hasattr(self, "_formats"):
                self._make_decoders()  # they write into the vector
        self._limits(params)
        self.reset_regulator()
        self._kr = params.transmission_ratio
        self._cycle_s = params.cycle_s

    def _limits(self, params: BridgeParams) -> None:
        """The parameters the running cycle reads that may change at any time."""
        v = self._v
        v[K.P_VFF] = float(params.velocity_feedforward)
        v[K.P_FE_LIMIT] = float(params.following_error_limit)
        v[K.P_DISC_LIMIT] = float(params.discrepancy_limit)
        v[K.P_POS_MIN] = float(params.position_limit_min)
        v[K.P_POS_MAX] = float(params.position_limit_max)
        v[K.P_SPEED_LIMIT] = float(params.speed_limit_rad_s)
        v[K.P_PDO_TOLERANCE] = float(params.pdo_loss_tolerance)

    def reset_regulator(self) -> None:
        """The regulator back to its initial state: detector empty, beta = 0, lambda = 1."""
        rcore.detector_reset(self._det)
        self._vm[K.S_LAMBDA] = 1.0

    def set_scaling(self, scaling: Scaling) -> None:
        """Use ``scaling`` (e.g. the rated torque read from the drive at start-up)."""
        self.scaling = scaling
        v = self._v
        v[K.P_UNIT_PER_INC] = scaling.load_unit_per_increment
        v[K.P_NM_PER_PERMILLE] = scaling.torque_nm_per_permille
        v[K.P_RAD_PER_INC] = scaling.motor_rad_per_increment
        v[K.P_RAD_S_PER_UNIT] = 1.0 / scaling.velocity_units_per_rad_s
        v[K.P_UNITS_PER_RAD_S] = scaling.velocity_units_per_rad_s
        self._units_per_rad_s = scaling.velocity_units_per_rad_s

    def set_layout(self, layout: CycleLayout) -> None:
        """Decode the frames of ``layout`` from the next step on (start-up only)."""
        self.layout = layout
        self._formats = tuple(
            (struct.Struct(f.fmt).unpack_from, tuple(_RAW[s] for s in f.signals))
            for f in layout.frames
        )
        self._make_decoders()
        self._rpdo_struct = struct.Struct(layout.rpdo_fmt)
        self._pack_rpdo = self._rpdo_struct.pack_into
        self.set_rpdo_target(bytearray(self._rpdo_struct.size), 0)
        frame_of = {s: i for i, f in enumerate(layout.frames) for s in f.signals}
        position = frame_of[Signal.MOTOR_POSITION]
        v = self._v
        v[K.P_LOAD_MEASURED] = 1.0 if layout.load_measured else 0.0
        v[K.P_POS_FRAME] = float(1 << position)
        v[K.P_LOAD_FRAME] = float(1 << frame_of.get(Signal.LOAD_POSITION, position))
        v[K.P_STATUS_FRAME] = float(1 << frame_of[Signal.STATUSWORD])
        v[K.P_ALL_FRAMES] = float((1 << len(layout.frames)) - 1)
        for i in range(K.R_MOTOR_POSITION, K.V_SIZE):
            v[i] = 0.0

    def set_rpdo_target(self, buffer: bytearray, offset: int) -> None:
        """Pack the RPDO payload into ``buffer[offset:]`` from now on (the loop's outgoing
        frame, rewritten in place; virtual_bus.framing)."""
        size = self._rpdo_struct.size
        if offset < 0 or offset + size > len(buffer):
            raise ValueError(f"RPDO target: {size} bytes at {offset} do not fit {len(buffer)}")
        self._out = buffer
        self._out_offset = offset
        self._rpdo = memoryview(buffer)[offset : offset + size] if offset else buffer

    @property
    def rpdo_payload(self) -> bytearray | memoryview:
        """The RPDO1 payload; :meth:`step` rewrites it in place every cycle."""
        return self._rpdo

    @property
    def axis_enabled(self) -> bool:
        """Locked parameters may not change (ENABLING or RUNNING)."""
        return self.state in (BridgeState.ENABLING, BridgeState.RUNNING)

    def set_params(self, params: BridgeParams) -> None:
        """Apply validated parameters. Changing a :data:`~bridge.params.LOCKED` one while the
        axis is enabled raises ParameterError 0800 0022 (nothing changed)."""
        changed = {name for name in LOCKED if getattr(params, name) != getattr(self.params, name)}
        if changed and self.axis_enabled:
            name = sorted(changed)[0]
            raise ParameterError(
                f"{name}: may not change while the axis is enabled",
                field=name,
                value=getattr(params, name),
                abort_code=SdoAbort.DEVICE_STATE,
            )
        self.params = params
        self._limits(params)
        if changed:
            self._build(params)
            self.interpolator = Interpolator(params.cycle_s, self.load_position)

    # --- events between cycles -------------------------------------------------------------
    @property
    def encoder_id(self) -> int | None:
        """Node-ID of a CiA 406 encoder supplying the load position (None: none); setting
        it adds the node to the supervised ones."""
        return self._encoder_id

    @encoder_id.setter
    def encoder_id(self, node_id: int | None) -> None:
        self._encoder_id = node_id
        self.encoder_watch = None
        if node_id is not None:
            self.encoder_watch = NodeWatch(
                f"encoder node {node_id}",
                StopReason.ENCODER_EMCY,
                StopReason.HEARTBEAT_LOST,
                StopReason.DRIVE_NMT,
                emcy_consequence=": its position (the load scale) is not trusted",
            )
        self._watches = (self.drive_watch,) + (() if node_id is None else (self.encoder_watch,))

    def on_heartbeat(self, nmt_state: int, now_s: float) -> None:
        """A heartbeat of the drive (NMT state byte without the toggle bit) at ``now_s``;
        its state counts from the first Operational one (bridge.consumers; a drive that
        never becomes Operational sends no TPDO: PDO loss stops the axis)."""
        self.drive_watch.on_heartbeat(nmt_state, now_s)

    def on_encoder_heartbeat(self, nmt_state: int, now_s: float) -> None:
        """A heartbeat of the CiA 406 encoder node (:attr:`encoder_id`) at ``now_s``."""
        if self.encoder_watch is not None:
            self.encoder_watch.on_heartbeat(nmt_state, now_s)

    def on_emcy(self, error_code: int, error_register: int) -> None:
        """An EMCY of the drive; code 0000h (error reset) only clears the stored code."""
        self.drive_error_code = error_code
        self.drive_watch.on_emcy(error_code, error_register)

    def on_encoder_emcy(self, error_code: int, error_register: int) -> None:
        """An EMCY of the CiA 406 encoder node that supplies the load position: a non-zero
        code means its position may be wrong, so the axis stops (0000h: error reset)."""
        if self.encoder_watch is not None:
            self.encoder_watch.on_emcy(error_code, error_register)

    def restart_supervision(self) -> None:
        """Forget heartbeats and EMCYs seen so far (the drive's boot-up and pre-operational
        heartbeats during start-up); monitoring begins with the next heartbeat."""
        for watch in self._watches:
            watch.forget()

    def command(self, command: Command) -> None:
        """Enable, disable or reset; ParameterError 0800 0022 if not possible now."""
        state = self.state
        if command is Command.ENABLE and state is BridgeState.DISABLED:
            self.disabled_controlword = CW_DISABLED
            self._set_enabling()
        elif command is Command.DISABLE and state in (BridgeState.ENABLING, BridgeState.RUNNING):
            self.state = BridgeState.DISABLED
            self._clear_motion()
        elif command is Command.RESET and state is BridgeState.STOPPED:
            self.state = BridgeState.DISABLED
            self.stop_reason = StopReason.NONE
            self.stop_message = "none"
            self.drive_watch.emcy_pending = None
            self.consecutive_missed = 0
        elif (
            command is Command.ENABLE and state in (BridgeState.ENABLING, BridgeState.RUNNING)
        ) or (command is Command.DISABLE and state is BridgeState.DISABLED):
            return  # already there
        else:
            raise ParameterError(
                f"command {command.name} is not possible in state {state.name}"
                + (" (reset the stop first: 2020h = 3)" if state is BridgeState.STOPPED else ""),
                field="command",
                value=int(command),
                abort_code=SdoAbort.DEVICE_STATE,
            )

    def halt(self) -> None:
        """The end of a run while the axis may move (a signal, ``--seconds`` in a move):
        DISABLED with the quick stop (0002h, set point 0), so that the drive ramps the motor
        to standstill (6085h, 605Ah) instead of switching the power stage off and letting it
        coast. A stop in force keeps its reason (it already commands the quick stop)."""
        if self.axis_enabled:
            self.state = BridgeState.DISABLED
            self._clear_motion()
        self.disabled_controlword = CW_STOPPED

    @property
    def status_received(self) -> bool:
        """The drive's statusword came in the last cycle."""
        return self._status_in

    def stop(self, reason: StopReason, message: str) -> None:
        """Stop the axis from outside the controller (the loop: overruns, its own errors);
        only while the axis is enabled -- a stop already in force keeps its reason."""
        if self.axis_enabled:
            self._stop(reason, message)

    def check_path(self, item: Move | Table) -> None:
        """Refuse motion whose path leaves the software position limits (2014h): a move's
        target (its path is the segment from wherever the axis is, so a move from outside
        back inside is allowed), every sample of a table. ParameterError 0609 0031/0032."""
        p = self.params
        if isinstance(item, Move):
            low = high = item.target
            what = f"target {item.target:.9g}"
        else:
            low, high = float(item.position.min()), float(item.position.max())
            what = f"table positions {low:.9g}..{high:.9g}"
        if low < p.position_limit_min or high > p.position_limit_max:
            raise ParameterError(
                f"move refused: {what} load units leaves the software position limits "
                f"2014h [{p.position_limit_min:g}, {p.position_limit_max:g}] load units",
                field="target",
                value=item.target if isinstance(item, Move) else (low, high),
                abort_code=SdoAbort.TOO_LOW if low < p.position_limit_min else SdoAbort.TOO_HIGH,
            )

    def queue_move(self, item: Move | Table) -> None:
        """Queue motion: started now when running, else when the axis becomes running
        (refused if its path leaves the software position limits, :meth:`check_path`)."""
        self.check_path(item)
        if self.state is BridgeState.STOPPED:
            raise ParameterError(
                f"no motion while stopped ({self.stop_reason.name}); reset first",
                field="move",
                value=item,
                abort_code=SdoAbort.DEVICE_STATE,
            )
        if self.state is BridgeState.RUNNING:
            self.interpolator.queue(item)
        else:
            self._pending.append(item)

    def start_move(self, item: Move) -> None:
        """Start a move now (target-position object): only while running and idle."""
        if self.state is not BridgeState.RUNNING or self.interpolator.busy:
            why = "a move is active" if self.state is BridgeState.RUNNING else self.state.name
            raise ParameterError(
                f"target position: no new move now ({why}); allowed while running and idle",
                field="target",
                value=item.target,
                abort_code=SdoAbort.DEVICE_STATE,
            )
        self.check_path(item)
        self.interpolator.queue(item)

    @property
    def moving(self) -> bool:
        return (self.state is BridgeState.RUNNING and self.interpolator.busy) or bool(self._pending)

    # --- the cycle -------------------------------------------------------------------------
    def step(self, now_s: float, *frames: bytes | None) -> bytearray | memoryview:
        """One SYNC: measurements in, RPDO payload (controlword, 60FFh) out.

        ``frames``: one payload of the right length per frame of :attr:`layout` (the
        contract's: TPDO1, TPDO2), or None when missing this cycle. The returned buffer
        is reused by the next call.
        """
        if len(frames) != len(self._decoders):
            raise ValueError(f"{len(frames)} frames for a layout of {len(self._decoders)}")
        present = 0
        for slot, data in enumerate(frames):
            if data is not None:
                self.decode(slot, data, 0)
                present |= 1 << slot
        return self.step_decoded(now_s, present)

    def decode(self, slot: int, buffer: bytes | bytearray | memoryview, offset: int) -> None:
        """The payload of the layout's frame ``slot`` at ``buffer[offset:]`` (its mapping's
        length, checked by the caller) into the raw values of this cycle."""
        self._decoders[slot](buffer, offset)

    def _make_decoders(self) -> None:
        """One function per frame that unpacks its payload straight into the vector."""
        self._decoders = tuple(_decoder(self._vm, unpack, at) for unpack, at in self._formats)
        #: the loop's decoder of each frame (bridge.node; rebuilt with the vector)
        self.decoders = self._decoders

    def step_decoded(self, now_s: float, present: int) -> bytearray | memoryview:
        """:meth:`step` for frames already given to :meth:`decode` (the loop decodes each
        TPDO as it arrives): ``present`` has bit ``i`` set for each frame ``i`` of the layout
        that came this cycle."""
        self.cycles += 1
        self.now_s = now_s
        state = self.state
        # quiet: nothing for _supervise but the checks the core makes (PDO loss, drive state):
        # no EMCY pending, heartbeats (if supervised) in time and operational -- the same
        # conditions as there
        quiet = state is _RUNNING
        if quiet:
            consumer_ms = self.params.heartbeat_consumer_ms
            for watch in self._watches:
                if not watch.quiet(now_s, consumer_ms):
                    quiet = False
                    break
        if quiet:
            # the common case in one call of the core; a stop or an error goes on below
            interp = self.interpolator
            interp.step()  # undone by the stop if the core finds one (_clear_motion)
            # callables of instance attributes from locals: CPython 3.11 specialises no
            # method call of an instance attribute (~300 instructions each, callgrind)
            step_running = self.core.step_running
            code, value = step_running(self._v, self._det, present, interp.position, interp.speed)
            if code == _OK:
                self.controlword = CW_RUNNING
                pack = self._pack_rpdo
                pack(self._out, self._out_offset, CW_RUNNING, value)
            elif code == K.SUPERVISION:
                self._run()  # stops the axis before it steps anything
            else:
                self._finish(code, value)
            return self._rpdo
        self.core.measure(self._v, present)
        if state is _RUNNING:
            self._run()
        elif state is _ENABLING:
            self._enable()
        elif state is _STOPPED:
            self._output(CW_STOPPED, 0.0)
        else:
            self._output(self.disabled_controlword, 0.0)
        return self._rpdo

    def _supervise(self) -> bool:
        """Checks common to ENABLING and RUNNING; True if the axis was stopped."""
        p = self.params
        if self.consecutive_missed > p.pdo_loss_tolerance:
            return self._stop(
                StopReason.PDO_LOSS,
                f"{self.consecutive_missed} consecutive cycles without a complete TPDO set "
                f"(tolerance 200Ah = {p.pdo_loss_tolerance})",
            )
        for watch in self._watches:
            stop = watch.check(self.now_s, p.heartbeat_consumer_ms)
            if stop is not None:
                return self._stop(StopReason(stop[0]), stop[1])
        return False

    def _enable(self) -> None:
        if self._supervise():
            return
        if self._enable_started_s is None:
            self._enable_started_s = self.now_s
        ds = drive_state(self.statusword)
        if ds is Drive402State.OPERATION_ENABLED and self.consecutive_missed == 0:
            # every frame of the layout came this cycle: the positions the move starts from
            # are measured, not a default (on a busy machine the first TPDO1 may come late;
            # holding a position never measured was a following error of the whole travel)
            self._enter_running()
            self._run()
            return
        if self.now_s - self._enable_started_s > ENABLE_TIMEOUT_S:
            self._stop(
                StopReason.ENABLE_TIMEOUT,
                f"drive not in Operation Enabled after {ENABLE_TIMEOUT_S:g} s "
                f"(state {ds.value}, statusword 0x{self.statusword:04X})",
            )
            return
        if not self._status_in:
            # no statusword this cycle: the drive's state is unknown (the first SYNC after the
            # start-up may be answered late); repeat the last controlword rather than command a
            # transition from a state that was never read (0x0000 would disable a drive the
            # start-up already brought to Operation Enabled)
            self._output(self.controlword, 0.0)
            return
        self._output(enable_controlword(ds, self.controlword), 0.0)

    def _enter_running(self) -> None:
        self.state = BridgeState.RUNNING
        self._enable_started_s = None
        self.interpolator.hold(self.load_position)
        for item in self._pending:
            self.interpolator.queue(item)
        self._pending.clear()
        self.reset_regulator()
        self._difference_at_enable = self.motor_position_rad / self._kr - self.load_position

    def _run(self) -> None:
        if self._supervise():
            return
        ds = drive_state(self.statusword)
        if ds is not Drive402State.OPERATION_ENABLED:
            fault = ds in (Drive402State.FAULT, Drive402State.FAULT_REACTION_ACTIVE)
            self._stop(
                StopReason.DRIVE_FAULT if fault else StopReason.DRIVE_DISABLED,
                f"drive left Operation Enabled: {ds.value} (statusword 0x{self.statusword:04X}"
                + (f", error code 0x{self.drive_error_code:04X})" if fault else ")"),
            )
            return
        interp = self.interpolator
        interp.step()
        code, value = self.core.running(self._v, self._det, interp.position, interp.speed)
        self._finish(code, value)

    def _finish(self, code: int, value: int) -> None:
        """What the core's ``code`` asks for at the end of a running cycle (the set point,
        a stop with its reason, the error the regulator's classes raise)."""
        p = self.params
        if code == K.OK:
            self.controlword = CW_RUNNING
            self._pack_rpdo(self._out, self._out_offset, CW_RUNNING, value)
        elif code == K.FOLLOWING_ERROR:
            self._stop(
                StopReason.FOLLOWING_ERROR,
                f"following error {self.following_error:.6g} load units exceeds 2008h = "
                f"{p.following_error_limit:g} load units",
            )
        elif code == K.DISCREPANCY:
            self._stop(
                StopReason.ENCODER_DISCREPANCY,
                f"motor encoder and load scale differ by {self.motor_load_difference:.6g} "
                f"load units since enable, above 2009h = {p.discrepancy_limit:g} load units",
            )
        elif code == K.POSITION_LIMIT:
            low, high = p.position_limit_min, p.position_limit_max
            self._stop(
                StopReason.POSITION_LIMIT,
                f"load position {self.load_position:.9g} load units outside the software "
                f"position limits 2014h [{low:g}, {high:g}] load units and no move heads back "
                "inside",
            )
        elif code == K.NOT_FINITE:  # the regulator package's error, as its classes raise it
            require_finite_input("x_ref", self.interpolator.position)
            require_finite_input("x_fb", self.load_position)
            require_finite_input("omega_s", self.omega_s)
            require_finite_input("omega_c", self.omega_c)
            require_finite_input("u_rad_s", self.omega_s - self.omega_c)
        elif code == K.OUT_OF_RANGE:  # raises struct.error: 60FFh cannot carry it
            self._output(CW_RUNNING, self.omega_r)
        else:
            raise AssertionError(f"cycle core code {code}")

    def _output(self, controlword: int, omega_r: float) -> None:
        self.controlword = controlword
        self.omega_r = omega_r
        self._pack_rpdo(
            self._out, self._out_offset, controlword, round(omega_r * self._units_per_rad_s)
        )

    def _clear_motion(self) -> None:
        self.interpolator.hold(self.load_position)
        self._pending.clear()
        self._enable_started_s = None
        self.omega_s = self.omega_c = 0.0

    def _set_enabling(self) -> None:
        self.state = BridgeState.ENABLING
        self._enable_started_s = None

    def stop_for(self, reason: StopReason, message: str) -> None:
        """Stop the axis from outside the cycle (the I/O layer found a fault on the bus);
        only while it is enabled, like the supervision of the cycle."""
        if self.axis_enabled:
            self._stop(reason, message)

    def _stop(self, reason: StopReason, message: str) -> bool:
        self.state = BridgeState.STOPPED
        self.stop_reason = reason
        self.stop_message = message
        self._clear_motion()
        self._output(CW_STOPPED, 0.0)
        log.error("axis stopped at t = %.4f s: %s: %s", self.now_s, reason.name, message)
        return True

    # --- live values (the core's vector) -------------------------------------------------
    @property
    def vibration_level(self) -> float:
        """beta of the last cycle, rad/s (Fig. 5)."""
        return float(rcore.detector_beta(self._det))

    @property
    def switching_factor(self) -> float:
        """lambda of the last cycle (eq. 15; 1 with the regulator off)."""
        return float(self._vm[K.S_LAMBDA])

    motor_position_rad = _value(K.S_MOTOR_POSITION, "motor angle theta_m, rad (6064h)")
    load_position = _value(K.S_LOAD_POSITION, "load position x_l, load units (60E4h:01)")
    motor_speed_rad_s = _value(K.S_MOTOR_SPEED, "motor speed, rad/s (606Ch)")
    motor_torque_nm = _value(K.S_TORQUE, "motor torque, N·m (6077h)")
    position_reference = _value(K.S_POSITION_REFERENCE, "x_ref of the last cycle, load units")
    omega_s = _value(K.S_OMEGA_S, "interpolator speed k_r·dx_ref/dt, rad/s")
    omega_c = _value(K.S_OMEGA_C, "position controller's output (eq. 7), rad/s")
    omega_r = _value(K.S_OMEGA_R, "the set point sent (eq. 15, clamped), rad/s")
    following_error = _value(K.S_FOLLOWING_ERROR, "x_ref - x_l, load units")
    motor_load_difference = _value(K.S_DIFFERENCE, "theta_m/k_r - x_l since enable")
    _difference_at_enable = _value(K.S_DIFFERENCE_AT_ENABLE, "theta_m/k_r - x_l at enable")
    statusword = _count(K.S_STATUSWORD, "6041h of the last cycle")
    consecutive_missed = _count(K.S_CONSECUTIVE_MISSED, "cycles in a row without all TPDOs")
    missed_cycles = _count(K.S_MISSED_CYCLES, "cycles without all TPDOs")

    @property
    def _status_in(self) -> bool:
        return self._vm[K.S_STATUS_IN] != 0.0

    @property
    def error_register(self) -> int:
        """1001h: bit 0 (generic error) while stopped by a fault."""
        return 1 if self.state is BridgeState.STOPPED else 0

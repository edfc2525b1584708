"""The CiA 402 device behaviour of the drive around one :class:`Plant`, without the bus.

:class:`ServoAxis` owns the state machine and decides, per position cycle, what the power
stage does (paper Fig. 1 below the position controller, section V):

- Operation enabled: the plant's PI speed loop follows 60FFh (``Plant.advance``);
- Quick stop active / Fault reaction active: the speed loop follows a ramp from the speed at
  entry down to zero (6085h quick stop or 6084h slow down deceleration, per 605Ah / 605Eh;
  option code 0 disables the drive at once), completed at standstill;
- every other state: power stage off, the axis coasts (``Plant.advance_torque(0)``; a plant
  that cannot coast, :attr:`Plant.coasts` false, holds a speed set point of zero instead).

A plant that fails while it steps (:class:`plant_sim.errors.PlantFault`: an FMU call that
returned an error) faults the drive: EMCY 6100h with the failed call's first bytes, Fault, and
the plant is not stepped again (a fault reset is refused while it has failed). A plant that
keeps its own torque limit (:attr:`Plant.limits_torque` false) refuses 6072h writes that would
change the limit in force.

Acceleration feed-forward (axis file ``control.acceleration_feedforward``, J_ff in kg·m²):
in CSV mode the drive only sees the speed set point, so it derives the reference
acceleration from it, τ_ff = J_ff·(ω_set[k] − ω_set[k−1])/T_p, and adds it to the speed
controller's output (as drives do with a speed-set-point interface). Velocity feed-forward
(``control.velocity_feedforward``) belongs to the position controller, i.e. the master that
computes 60FFh; the drive does nothing with it. The sensor time offset is physics of the
measuring systems and is applied by the plant (its positions are the readings).

Its supervision runs once per SYNC: the set point watchdog (2102h, reaction 6007h), the
motor encoder vs load scale monitor (2101h, paper section II.B) and the end of the ramps; on
a position cycle of the drive's own clock (real time, no SYNC) the same without the set point
watchdog, which counts SYNCs (:meth:`ServoAxis.supervise_without_sync`). A lost master (its
heartbeat, an NMT command) acts through 6007h as the set point timeout does
(:meth:`ServoAxis.abort_connection`).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from virtual_bus.contract import SdoAbort
from virtual_bus.formats.axis import AxisConfig, AxisKind

from ..errors import PlantFault
from ..plant import Plant
from . import od as O
from .cia402 import (
    SW_FOLLOWS_COMMAND,
    SW_INTERNAL_LIMIT,
    SW_REMOTE,
    SW_VOLTAGE_ENABLED,
    SW_WARNING,
    Command,
    Event,
    State402,
    StateMachine,
    Transition,
    status_bits,
)
from .config import DriveConfig
from .errors import DriveConfigError, DriveSdoAbort
from .protection import (
    EMCY_COMMUNICATION,
    EMCY_HEARTBEAT,
    EMCY_PDO_LENGTH,
    EMCY_RPDO_TIMEOUT,
    EMCY_SENSOR,
    EMCY_SOFTWARE,
    ErrorList,
    SetpointWatchdog,
    apply_torque_limit,
    axis_torque_limit_nm,
    discrepancy,
    emcy_data_int32,
    setpoint_timeout_data,
)

logger = logging.getLogger(__name__)

S = State402
_POWERED = (
    S.READY_TO_SWITCH_ON,
    S.SWITCHED_ON,
    S.OPERATION_ENABLED,
    S.QUICK_STOP_ACTIVE,
    S.FAULT_REACTION_ACTIVE,
)
_DRIVING = (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE, S.FAULT_REACTION_ACTIVE)
# Enum members the per-SYNC code compares with, as module globals: CPython 3.11's EnumType has
# a __getattr__, so reading a member off its class costs ~1,000 instructions, a global ~50
# (callgrind).
_ENABLED, _FAULTED = S.OPERATION_ENABLED, (S.FAULT_REACTION_ACTIVE, S.FAULT)
QUICK_STOP_CODES = (0, 1, 2, 5, 6)  # 605Ah values the drive implements
_FRACTION_AT_LIMIT = 0.999  # |torque| >= this * limit sets statusword bit 11


def _state_word(state: State402) -> int:
    """The statusword bits ``state`` alone sets: its pattern, remote (9), voltage enabled (4),
    drive follows the command value (12)."""
    word = status_bits(state)
    if state is not S.NOT_READY_TO_SWITCH_ON:
        word |= SW_REMOTE
    if state in _POWERED:
        word |= SW_VOLTAGE_ENABLED
    if state is S.OPERATION_ENABLED:
        word |= SW_FOLLOWS_COMMAND
    return word


class ServoAxis:
    """State machine, supervision and power stage of the drive on ``plant``.

    table: the object table (the servo attaches the CiA 402 and manufacturer objects);
    errors: the drive's error list (603Fh / 1001h / EMCY).
    """

    def __init__(
        self,
        axis: AxisConfig,
        plant: Plant,
        table: O.ObjectTable,
        errors: ErrorList,
        config: DriveConfig,
    ) -> None:
        self.axis = axis
        self.plant = plant
        self.config = config
        self._table = table
        self._errors = errors
        self.sm = StateMachine()  # transition 0: Not ready to switch on
        self.watchdog = SetpointWatchdog()
        self._ramp_rad_s = 0.0
        self._ramp_done = False
        self._last_setpoint_rad_s = 0.0  # for the acceleration feed-forward
        self._fault_codes: set[int] = set()
        self.plant_failure: PlantFault | None = None  # the failure that stopped the plant
        #: the plant's readings since its last step (hold_measurements)
        self._held: list[float] | None = None
        self._readings = np.zeros(4)
        self._axis_limit_nm = axis_torque_limit_nm(plant)  # the axis file's, fixed
        self._ratio = plant.axis.transmission_ratio
        self._jff = axis.control.acceleration_feedforward or 0.0  # kg m^2
        self._step = plant.stepper()  # plant.advance for floats
        self._cycle_s = axis.control.position_cycle
        self._word_state: State402 | None = None  # statusword(): state of _state_word
        self._state_word = 0
        self._limit_for: int | None = None  # torque_limit_nm(): the 6072h it was made for
        self._limit_nm = math.inf
        self._set_axis_defaults()
        self._rated_mnm = table.value(O.RATED_TORQUE)  # 6076h, read-only
        self._attach_objects()
        self.apply_torque_limit()

    # --- objects -------------------------------------------------------------------------------
    def _set_axis_defaults(self) -> None:
        """Defaults that come from the axis file and DriveConfig rather than the EDS."""
        t = self._table
        rated_mnm = round(self.config.rated_torque_nm * 1000)
        t.set_default(O.RATED_TORQUE, rated_mnm)
        limit = self.axis.control.torque_limit
        # 6072h is UNSIGNED16: a larger (or no) axis limit leaves 0xFFFF ‰ of 6076h
        permille = math.inf if limit is None else 1e6 * limit / rated_mnm
        max_permille = round(permille) if permille < 0xFFFF else 0xFFFF
        t.set_default(O.MAX_TORQUE, max_permille)
        try:
            value, index = O.interpolation_period(self.axis.control.position_cycle)
        except ValueError as exc:
            raise DriveConfigError(f"60C2h: {exc}") from None
        t.set_default(O.INTERPOLATION_PERIOD_VALUE, value)
        t.set_default(O.INTERPOLATION_PERIOD_INDEX, index)
        scale = O.load_units_per_unit(self.axis.kind)
        if self.axis.kind is AxisKind.LINEAR:
            tolerance = O.PAPER_ENCODER_TOLERANCE_M * scale
        else:
            tolerance = O.PAPER_ENCODER_TOLERANCE_RAD * scale
        t.set_default(O.ENCODER_TOLERANCE, round(tolerance))

    def _attach_objects(self) -> None:
        t, kind, measured = self._table, self.axis.kind, self._measured
        ratio = self.plant.axis.transmission_ratio
        t.on(O.ERROR_REGISTER, read=lambda: self._errors.register)
        t.on(O.ERROR_CODE, read=lambda: self._errors.error_code)
        t.on(O.STATUSWORD, read=self.statusword)
        t.on(O.MODES_OF_OPERATION_DISPLAY, read=lambda: t.value(O.MODES_OF_OPERATION))
        # measured(): motor position (rad), load position, motor speed (rad/s), torque (N·m);
        # the readings held since the last step without the call where they are (every SYNC)
        t.on(
            O.POSITION_ACTUAL,
            read=lambda: O.motor_position_increments((self._held or measured())[0]),
        )
        t.on(
            O.VELOCITY_ACTUAL,
            read=lambda: O.motor_speed_increments_s((self._held or measured())[2]),
        )
        t.on(
            O.TORQUE_ACTUAL,
            read=lambda: O.torque_permille((self._held or measured())[3], self._rated_mnm),
        )
        t.on(
            O.LOAD_POSITION_ACTUAL,
            read=lambda: O.load_position_units((self._held or measured())[1], kind),
        )
        t.on(
            O.LOAD_MINUS_MOTOR,
            read=lambda: O.load_difference_units(discrepancy(*measured()[:2], ratio), kind),
        )
        t.on(O.CONTROLWORD, changed=self._controlword_changed)
        t.on(O.MODES_OF_OPERATION, validate=self._check_mode)
        t.on(O.QUICK_STOP_OPTION, validate=self._check_quick_stop_option)
        t.on(
            O.MAX_TORQUE,
            validate=self._check_max_torque,
            changed=lambda _value: self.apply_torque_limit(),
        )

    def _check_mode(self, value: int) -> None:
        if value != O.MODE_CSV:
            raise DriveSdoAbort(
                SdoAbort.VALUE_RANGE,
                f"mode of operation {value} not supported; allowed {O.MODE_CSV} "
                "(cyclic synchronous velocity)",
                key=O.MODES_OF_OPERATION,
            )

    def _check_max_torque(self, value: int) -> None:
        """A plant with its own torque limit: 6072h may not change the limit in force."""
        if self.plant.limits_torque:
            return
        if value != self._table.stored[O.MAX_TORQUE]:
            raise DriveSdoAbort(
                SdoAbort.VALUE_RANGE,
                f"6072h = {value}: this drive's plant keeps its own torque limit "
                f"({self.plant.torque_limit_nm:g} N·m); 6072h stays "
                f"{self._table.stored[O.MAX_TORQUE]}",
                key=O.MAX_TORQUE,
            )

    def _check_quick_stop_option(self, value: int) -> None:
        if value not in QUICK_STOP_CODES:
            raise DriveSdoAbort(
                SdoAbort.VALUE_RANGE,
                f"quick stop option code {value} not supported; allowed {QUICK_STOP_CODES}",
                key=O.QUICK_STOP_OPTION,
            )

    # --- measurements --------------------------------------------------------------------------
    def _read_plant(self) -> list[float]:
        readings = self._readings
        self.plant.read_measured(readings)  # the properties' values, in one compiled call
        return readings.tolist()  # type: ignore[no-any-return]

    def _measured(self) -> list[float]:
        """Motor position (rad), load position (load units), motor speed (rad/s), torque
        (N·m) of the plant as it stands (see :meth:`hold_measurements`)."""
        held = self._held
        return held if held is not None else self._read_plant()

    def hold_measurements(self) -> None:
        """The plant moves only in :meth:`advance`: its measuring systems are read once after
        each step (each reading a call into the compiled kernel) and these readings serve the
        supervision, the statusword, the TPDOs and SDO reads until the next step -- in real
        time the readings are taken after the SYNC's TPDOs, not between the SYNC and them.
        Called at a SYNC: reads the plant if nothing is held yet (the first SYNC)."""
        if self._held is None:
            self._held = self._read_plant()

    # --- state ---------------------------------------------------------------------------------
    @property
    def state(self) -> State402:
        return self.sm.state

    @property
    def torque_limit_nm(self) -> float:
        """The torque limit in force: min(axis file limit, 6072h · 6076h); 6076h is read-only
        (its value from the drive configuration), kept from the last 6072h read."""
        max_torque = self._table.stored[O.MAX_TORQUE]
        if max_torque != self._limit_for:
            self._limit_for = max_torque
            self._limit_nm = min(
                self._axis_limit_nm, O.torque_limit_nm(max_torque, self._rated_mnm)
            )
        return self._limit_nm

    def apply_torque_limit(self) -> None:
        apply_torque_limit(self.plant, self.torque_limit_nm)

    def statusword(self) -> int:
        """6041h: the state's pattern plus voltage enabled (4), warning (7: an error is
        active outside Fault), remote (9), internal limit active (11: torque at the limit),
        drive follows the command value (12: Operation enabled)."""
        state = self.sm.state
        if state is not self._word_state:  # the bits of the state alone, kept per state
            self._word_state, self._state_word = state, _state_word(state)
        word = self._state_word
        if state in _DRIVING and (
            abs((self._held or self._measured())[3]) >= _FRACTION_AT_LIMIT * self.torque_limit_nm
        ):
            word |= SW_INTERNAL_LIMIT
        if self._errors.codes and state not in (S.FAULT, S.FAULT_REACTION_ACTIVE):
            word |= SW_WARNING
        return word

    # --- life cycle ----------------------------------------------------------------------------
    def initialised(self) -> None:
        """Transition 1 (the drive's initialisation is done)."""
        self._take(self.sm.event(Event.INITIALISED))

    def reset_application(self) -> None:
        """NMT reset node: CiA 402 transitions 0 and 1, errors and faults forgotten (the
        caller restores the object defaults first)."""
        self._take(*self.sm.reset())
        self._errors.forget()
        self._fault_codes.clear()
        self.watchdog.reset()
        self.apply_torque_limit()

    # --- per SYNC ------------------------------------------------------------------------------
    def rpdo_arrived(self) -> None:
        """A complete RPDO is being applied at this SYNC: the set point is back."""
        if self._errors.codes:
            self._errors.clear(EMCY_RPDO_TIMEOUT)
            self._errors.clear(EMCY_PDO_LENGTH)

    def supervise(self, rpdo_received: bool) -> None:
        """After the RPDO latch, before the TPDOs: watchdog, encoders, end of the ramps."""
        t = self._table
        state = self.sm.state
        if state is not _ENABLED or rpdo_received:
            self.watchdog.reset()  # what on_sync does with an RPDO received
        elif self.watchdog.on_sync(False, t.value(O.SETPOINT_TIMEOUT)):
            self._setpoint_timeout()
        if self.sm.state not in _FAULTED and not self._encoder_ok():
            self._fault(EMCY_SENSOR, emcy_data_int32(t.read(O.LOAD_MINUS_MOTOR)))
        if self._ramp_done and abs(self._measured()[2]) <= self.config.standstill_rad_s:
            if self.sm.state is S.QUICK_STOP_ACTIVE and t.value(O.QUICK_STOP_OPTION) in (1, 2):
                self._take(self.sm.event(Event.QUICK_STOP_COMPLETED))
            elif self.sm.state is S.FAULT_REACTION_ACTIVE:
                self._take(self.sm.event(Event.FAULT_REACTION_COMPLETED))

    def supervise_without_sync(self) -> None:
        """A position cycle of the drive's own clock, between SYNCs that did not come (real
        time): the encoder monitor and the end of the ramps, as :meth:`supervise` -- not the
        set point watchdog, which counts SYNCs without a set point."""
        if self.sm.state not in _FAULTED and not self._encoder_ok():
            self._fault(EMCY_SENSOR, emcy_data_int32(self._table.read(O.LOAD_MINUS_MOTOR)))
        if self._ramp_done and abs(self._measured()[2]) <= self.config.standstill_rad_s:
            if self.sm.state is S.QUICK_STOP_ACTIVE and self._table.value(O.QUICK_STOP_OPTION) in (
                1,
                2,
            ):
                self._take(self.sm.event(Event.QUICK_STOP_COMPLETED))
            elif self.sm.state is S.FAULT_REACTION_ACTIVE:
                self._take(self.sm.event(Event.FAULT_REACTION_COMPLETED))

    @property
    def holding(self) -> bool:
        """The power stage holds the axis (Operation enabled, a quick stop or fault reaction
        ramp) or a disturbance acts on it: its physics must go on."""
        return self.sm.state in _DRIVING or self._table.stored[O.DISTURBANCE] != 0

    def abort_connection(self, code: int, data: bytes) -> int:
        """The connection to the master is lost (CiA 402 6007h: heartbeat, NMT Stopped or
        Pre-operational entered, reset communication): error ``code`` (EMCY with ``data``)
        and, in Operation enabled, the 6007h reaction; returns the option code in force."""
        option = self._table.value(O.ABORT_CONNECTION_OPTION)
        self._errors.set(code, data)
        if self.sm.state is not _ENABLED:
            return option
        logger.warning("connection to the master lost (EMCY 0x%04X): 6007h = %d", code, option)
        if option == 1:
            self._fault(code)
        elif option == 2:
            self._take(*self.sm.command(Command.DISABLE_VOLTAGE))
        elif option == 3:
            self._take(*self.sm.command(Command.QUICK_STOP))
        return option

    def connection_restored(self, code: int) -> None:
        """The cause of a lost connection is gone (the master's heartbeat is back, NMT
        Operational again): its error clears (error reset EMCY)."""
        if code in self._errors:
            self._errors.clear(code)

    def advance(self) -> None:
        """Run the plant one position cycle as the state says (see the module docstring),
        then read its measuring systems for the next SYNC (:meth:`hold_measurements`)."""
        self._held = None
        coasting = False
        if self.plant_failure is None:
            try:
                coasting = self._step_plant()
            except PlantFault as exc:
                self._plant_failed(exc)
        self._held = held = self._read_plant()
        if coasting:  # the speed loop follows from where the axis is when it takes over
            self._last_setpoint_rad_s = held[2]

    def _step_plant(self) -> bool:
        """One position cycle of the plant; True when the power stage is off (coasting)."""
        p, t = self.plant, self._table
        stored = t.stored
        disturbance_nm = stored[O.DISTURBANCE] / 1000.0
        state = self.sm.state
        if state is _ENABLED:
            speed = O.increments_to_rad(stored[O.TARGET_VELOCITY])
            self._step(speed, disturbance_nm, self._torque_feedforward_nm(speed))  # floats
            return False
        elif state in (S.QUICK_STOP_ACTIVE, S.FAULT_REACTION_ACTIVE):
            if state is S.QUICK_STOP_ACTIVE:
                slow = t.value(O.QUICK_STOP_OPTION) in (1, 5)
            else:
                slow = t.value(O.FAULT_REACTION_OPTION) == 1
            key = O.PROFILE_DECELERATION if slow else O.QUICK_STOP_DECELERATION
            step = O.increments_to_rad(t.value(key)) * self.axis.control.position_cycle
            if abs(self._ramp_rad_s) <= step:
                self._ramp_rad_s = 0.0
            else:
                self._ramp_rad_s -= math.copysign(step, self._ramp_rad_s)
            p.advance(
                speed_setpoint_rad_s=self._ramp_rad_s,
                disturbance_nm=disturbance_nm,
                torque_feedforward_nm=self._torque_feedforward_nm(self._ramp_rad_s),
            )
            self._ramp_done = self._ramp_rad_s == 0.0
            return False
        p.advance_torque(0.0, disturbance_nm)
        return True

    def _torque_feedforward_nm(self, setpoint_rad_s: float) -> float:
        """J_ff times the speed set point's change over the last position cycle (N·m)."""
        change = setpoint_rad_s - self._last_setpoint_rad_s
        self._last_setpoint_rad_s = setpoint_rad_s
        return self._jff * change / self._cycle_s

    # --- protection ----------------------------------------------------------------------------
    def _encoder_ok(self) -> bool:
        """Paper section II.B: |load scale − motor encoder| within 2101h (2104h's value)."""
        held = self._held or self._measured()
        units = O.load_difference_units(discrepancy(held[0], held[1], self._ratio), self.axis.kind)
        return abs(units) <= self._table.stored[O.ENCODER_TOLERANCE]

    def _setpoint_timeout(self) -> None:
        """No RPDO for 2102h SYNCs: EMCY 0x8250 naming the cause (:func:`setpoint_timeout_data`)
        and the 6007h reaction."""
        option = self._table.value(O.ABORT_CONNECTION_OPTION)
        cycles = self._table.value(O.SETPOINT_TIMEOUT)
        self._errors.set(EMCY_RPDO_TIMEOUT, setpoint_timeout_data(cycles, option))
        if option == 1:
            self._fault(EMCY_RPDO_TIMEOUT)
        elif option == 2:
            self._take(*self.sm.command(Command.DISABLE_VOLTAGE))
        elif option == 3:
            self._take(*self.sm.command(Command.QUICK_STOP))

    def _plant_failed(self, exc: PlantFault) -> None:
        """The plant failed (module docstring): EMCY 6100h, Fault at once (nothing of the
        axis can be moved any more, so there is no fault reaction ramp to run)."""
        logger.error("the plant failed: %s", exc)
        self.plant_failure = exc
        call = getattr(exc, "call", "") or "step"
        self._fault(EMCY_SOFTWARE, call.removeprefix("fmi2").encode("ascii", "replace")[:5])
        if self.sm.state is S.FAULT_REACTION_ACTIVE:
            self._take(self.sm.event(Event.FAULT_REACTION_COMPLETED))

    def _fault(self, code: int, data: bytes = b"") -> None:
        self._errors.set(code, data)
        self._fault_codes.add(code)
        self._take(self.sm.event(Event.FAULT))

    def _fault_cleared(self) -> bool:
        """Fault reset allowed: every cause of the fault is gone."""
        if self.plant_failure is not None:
            return False
        for code in self._fault_codes:
            if code == EMCY_SENSOR and not self._encoder_ok():
                return False
            if code == EMCY_RPDO_TIMEOUT and EMCY_RPDO_TIMEOUT in self._errors:
                return False
            if code in (EMCY_HEARTBEAT, EMCY_COMMUNICATION) and code in self._errors:
                return False
        return True

    # --- state machine glue --------------------------------------------------------------------
    def controlword_unchanged(self, controlword: int) -> bool:
        """Writing ``controlword`` to 6040h changes nothing (the hook below returns at once):
        a master repeats it with every set point."""
        return self._table.changed_hook(O.CONTROLWORD) == self._controlword_changed and (
            self.sm.unchanged_by(controlword)
        )

    def _controlword_changed(self, controlword: int) -> None:
        if self.sm.unchanged_by(controlword):  # the RPDO repeats it every SYNC
            return
        transitions = self.sm.controlword_written(
            controlword,
            quick_stop_stays=self._table.value(O.QUICK_STOP_OPTION) >= 5,
            fault_cleared=self._fault_cleared,
        )
        self._take(*transitions)

    def _take(self, *transitions: Transition | None) -> None:
        """What entering a state does beyond the state machine itself."""
        for tr in transitions:
            if tr is None:
                continue
            logger.info("transition %d -> %s", tr.number, tr.target.value)
            if tr.target is S.OPERATION_ENABLED:
                self.watchdog.reset()
            elif tr.target in (S.QUICK_STOP_ACTIVE, S.FAULT_REACTION_ACTIVE):
                self._ramp_rad_s = self._measured()[2]  # the plant's speed now
                self._ramp_done = False
                if tr.target is S.QUICK_STOP_ACTIVE:
                    immediate = self._table.value(O.QUICK_STOP_OPTION) == 0
                    event = Event.QUICK_STOP_COMPLETED
                else:
                    immediate = self._table.value(O.FAULT_REACTION_OPTION) == 0
                    event = Event.FAULT_REACTION_COMPLETED
                if immediate:  # option code 0: disable the drive function, coast
                    self._take(self.sm.event(event))
            elif tr.number == 15:
                for code in sorted(self._fault_codes):
                    self._errors.clear(code)
                self._fault_codes.clear()

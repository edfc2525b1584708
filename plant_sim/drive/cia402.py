"""The CiA 402 drive state machine (PDS FSA, IEC 61800-7-201): states, commands, transitions.

Pure logic without bus or physics: :class:`StateMachine` takes controlwords (6040h) and
internal events, returns the transitions it took, and gives the statusword (6041h) pattern
of its state. What a state *does* to the motor (speed loop, ramp, coasting) is the drive's
business (:mod:`plant_sim.drive.drive`).

Transitions (numbers as in CiA 402 / IEC 61800-7-201, figure "PDS FSA"):

| no. | from                  | trigger                              | to                    |
| --- | --------------------- | ------------------------------------ | --------------------- |
| 0   | (power on)            | automatic                            | Not ready to switch on|
| 1   | Not ready to switch on| automatic (initialisation done)      | Switch on disabled    |
| 2   | Switch on disabled    | Shutdown                             | Ready to switch on    |
| 3   | Ready to switch on    | Switch on (or Switch on + enable: 3+4)| Switched on          |
| 4   | Switched on           | Enable operation                     | Operation enabled     |
| 5   | Operation enabled     | Disable operation                    | Switched on           |
| 6   | Switched on           | Shutdown                             | Ready to switch on    |
| 7   | Ready to switch on    | Quick stop or Disable voltage        | Switch on disabled    |
| 8   | Operation enabled     | Shutdown                             | Ready to switch on    |
| 9   | Operation enabled     | Disable voltage                      | Switch on disabled    |
| 10  | Switched on           | Disable voltage or Quick stop        | Switch on disabled    |
| 11  | Operation enabled     | Quick stop                           | Quick stop active     |
| 12  | Quick stop active     | Disable voltage, or automatic when   | Switch on disabled    |
|     |                       | the quick stop is completed (605Ah   |                       |
|     |                       | option codes 0..4)                   |                       |
| 13  | any but FRA / Fault   | fault detected                       | Fault reaction active |
| 14  | Fault reaction active | automatic (fault reaction completed) | Fault                 |
| 15  | Fault                 | Fault reset (0->1 edge of bit 7),    | Switch on disabled    |
|     |                       | only when the cause is gone          |                       |
| 16  | Quick stop active     | Enable operation (605Ah codes 5..8)  | Operation enabled     |

Controlword commands (bits 7, 3..0; x = any; all need bit 7 = 0):

| command                         | bits 7 3 2 1 0 | transitions |
| ------------------------------- | -------------- | ----------- |
| Shutdown                        | 0 x 1 1 0      | 2, 6, 8     |
| Switch on / Disable operation   | 0 0 1 1 1      | 3, 5        |
| Enable operation / Switch on +  | 0 1 1 1 1      | 3+4, 4, 16  |
| enable operation                |                |             |
| Disable voltage                 | 0 x x 0 x      | 7, 9, 10, 12|
| Quick stop                      | 0 x 0 1 x      | 7, 10, 11   |
| Fault reset                     | 0->1 x x x x   | 15          |

Any other controlword in a state (e.g. Switch on in Switch on disabled) changes nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

# controlword bits and the statusword bits outside the state pattern: the contract's
from virtual_bus.contract import CW_ENABLE_OPERATION as CW_ENABLE_OPERATION
from virtual_bus.contract import CW_ENABLE_VOLTAGE as CW_ENABLE_VOLTAGE
from virtual_bus.contract import CW_FAULT_RESET as CW_FAULT_RESET
from virtual_bus.contract import CW_QUICK_STOP as CW_QUICK_STOP
from virtual_bus.contract import CW_SWITCH_ON as CW_SWITCH_ON
from virtual_bus.contract import SW_FOLLOWS_COMMAND as SW_FOLLOWS_COMMAND
from virtual_bus.contract import SW_INTERNAL_LIMIT as SW_INTERNAL_LIMIT
from virtual_bus.contract import SW_REMOTE as SW_REMOTE
from virtual_bus.contract import SW_VOLTAGE_ENABLED as SW_VOLTAGE_ENABLED
from virtual_bus.contract import SW_WARNING as SW_WARNING


class State402(Enum):
    """States of the CiA 402 power drive system finite state automaton."""

    NOT_READY_TO_SWITCH_ON = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"


S = State402

#: Statusword (6041h) bit pattern per state: (mask, value) over bits 0..3, 5, 6.
STATUS_PATTERNS: dict[State402, tuple[int, int]] = {
    S.NOT_READY_TO_SWITCH_ON: (0x004F, 0x0000),  # x0xx 0000
    S.SWITCH_ON_DISABLED: (0x004F, 0x0040),  # x1xx 0000
    S.READY_TO_SWITCH_ON: (0x006F, 0x0021),  # x01x 0001
    S.SWITCHED_ON: (0x006F, 0x0023),  # x01x 0011
    S.OPERATION_ENABLED: (0x006F, 0x0027),  # x01x 0111
    S.QUICK_STOP_ACTIVE: (0x006F, 0x0007),  # x00x 0111
    S.FAULT_REACTION_ACTIVE: (0x004F, 0x000F),  # x0xx 1111
    S.FAULT: (0x004F, 0x0008),  # x0xx 1000
}


class Command(Enum):
    """Device control commands coded in controlword bits 7, 3..0."""

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on / disable operation"
    ENABLE_OPERATION = "enable operation / switch on + enable operation"
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    FAULT_RESET = "fault reset"


class Event(Enum):
    """Internal triggers of the automatic transitions."""

    POWER_ON = "power on"  # 0
    INITIALISED = "initialisation done"  # 1
    QUICK_STOP_COMPLETED = "quick stop completed"  # 12
    FAULT = "fault detected"  # 13
    FAULT_REACTION_COMPLETED = "fault reaction completed"  # 14


Trigger = Command | Event


@dataclass(frozen=True)
class Transition:
    """One numbered CiA 402 transition; ``source`` None is the power-on pseudo state."""

    number: int
    source: State402 | None
    trigger: Trigger
    target: State402


_ALL_BUT_FAULT = (
    S.NOT_READY_TO_SWITCH_ON,
    S.SWITCH_ON_DISABLED,
    S.READY_TO_SWITCH_ON,
    S.SWITCHED_ON,
    S.OPERATION_ENABLED,
    S.QUICK_STOP_ACTIVE,
)

C, E = Command, Event
#: The transition table (see the module docstring).
TRANSITIONS: tuple[Transition, ...] = (
    Transition(0, None, E.POWER_ON, S.NOT_READY_TO_SWITCH_ON),
    Transition(1, S.NOT_READY_TO_SWITCH_ON, E.INITIALISED, S.SWITCH_ON_DISABLED),
    Transition(2, S.SWITCH_ON_DISABLED, C.SHUTDOWN, S.READY_TO_SWITCH_ON),
    Transition(3, S.READY_TO_SWITCH_ON, C.SWITCH_ON, S.SWITCHED_ON),
    Transition(3, S.READY_TO_SWITCH_ON, C.ENABLE_OPERATION, S.SWITCHED_ON),  # then 4
    Transition(4, S.SWITCHED_ON, C.ENABLE_OPERATION, S.OPERATION_ENABLED),
    Transition(5, S.OPERATION_ENABLED, C.SWITCH_ON, S.SWITCHED_ON),
    Transition(6, S.SWITCHED_ON, C.SHUTDOWN, S.READY_TO_SWITCH_ON),
    Transition(7, S.READY_TO_SWITCH_ON, C.QUICK_STOP, S.SWITCH_ON_DISABLED),
    Transition(7, S.READY_TO_SWITCH_ON, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    Transition(8, S.OPERATION_ENABLED, C.SHUTDOWN, S.READY_TO_SWITCH_ON),
    Transition(9, S.OPERATION_ENABLED, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    Transition(10, S.SWITCHED_ON, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    Transition(10, S.SWITCHED_ON, C.QUICK_STOP, S.SWITCH_ON_DISABLED),
    Transition(11, S.OPERATION_ENABLED, C.QUICK_STOP, S.QUICK_STOP_ACTIVE),
    Transition(12, S.QUICK_STOP_ACTIVE, C.DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    Transition(12, S.QUICK_STOP_ACTIVE, E.QUICK_STOP_COMPLETED, S.SWITCH_ON_DISABLED),
    *(Transition(13, src, E.FAULT, S.FAULT_REACTION_ACTIVE) for src in _ALL_BUT_FAULT),
    Transition(14, S.FAULT_REACTION_ACTIVE, E.FAULT_REACTION_COMPLETED, S.FAULT),
    Transition(15, S.FAULT, C.FAULT_RESET, S.SWITCH_ON_DISABLED),
    Transition(16, S.QUICK_STOP_ACTIVE, C.ENABLE_OPERATION, S.OPERATION_ENABLED),
)

_TABLE: dict[tuple[State402 | None, Trigger], Transition] = {
    (t.source, t.trigger): t for t in TRANSITIONS
}


def decode_command(controlword: int, previous_controlword: int) -> Command | None:
    """The command in ``controlword`` (bits 7, 3..0); a fault reset is the 0->1 edge of bit 7
    against ``previous_controlword``. None: no command (bit 7 held at 1)."""
    if controlword & CW_FAULT_RESET:
        return None if previous_controlword & CW_FAULT_RESET else Command.FAULT_RESET
    if not controlword & CW_ENABLE_VOLTAGE:
        return Command.DISABLE_VOLTAGE
    if not controlword & CW_QUICK_STOP:
        return Command.QUICK_STOP
    if not controlword & CW_SWITCH_ON:
        return Command.SHUTDOWN
    if controlword & CW_ENABLE_OPERATION:
        return Command.ENABLE_OPERATION
    return Command.SWITCH_ON


def status_bits(state: State402) -> int:
    """The statusword bits that code ``state`` (value of its pattern)."""
    return STATUS_PATTERNS[state][1]


def state_from_statusword(statusword: int) -> State402:
    """Decode the state from a statusword (raises ValueError for no valid pattern)."""
    for state, (mask, value) in STATUS_PATTERNS.items():
        if statusword & mask == value:
            return state
    raise ValueError(f"statusword 0x{statusword:04X} codes no CiA 402 state")


class StateMachine:
    """The PDS FSA of one axis. Starts in Not ready to switch on (transition 0); call
    :meth:`event` with ``Event.INITIALISED`` to reach Switch on disabled (transition 1)."""

    def __init__(self) -> None:
        self.state = _TABLE[(None, Event.POWER_ON)].target
        self.controlword = 0
        # unchanged_by's last answer (a master repeats one controlword in one state)
        self._steady_state: State402 | None = None
        self._steady_word = -1
        self._steady = False

    def controlword_written(
        self,
        controlword: int,
        *,
        quick_stop_stays: bool,
        fault_cleared: Callable[[], bool],
    ) -> tuple[Transition, ...]:
        """Apply a new controlword; returns the transitions taken (empty: no change).

        quick_stop_stays: 605Ah is 5..8, so transition 16 is allowed from Quick stop active.
        fault_cleared: asked on a fault reset in Fault; transition 15 only if it returns True.
        """
        if not 0 <= controlword <= 0xFFFF:
            raise ValueError(f"controlword {controlword}: allowed 0..0xFFFF")
        command = decode_command(controlword, self.controlword)
        self.controlword = controlword
        if command is None:
            return ()
        return self.command(command, quick_stop_stays=quick_stop_stays, fault_cleared=fault_cleared)

    def unchanged_by(self, controlword: int) -> bool:
        """Writing ``controlword`` again changes nothing: it is the last one written and its
        command (if any) has no transition from the present state (a master repeats its
        controlword with every set point)."""
        if controlword != self.controlword:
            return False
        state = self.state
        if state is self._steady_state and controlword == self._steady_word:
            return self._steady  # the last answer: the same controlword in the same state
        command = decode_command(controlword, controlword)
        steady = command is None or (state, command) not in _TABLE
        self._steady_state, self._steady_word, self._steady = state, controlword, steady
        return steady

    def command(
        self,
        command: Command,
        *,
        quick_stop_stays: bool = False,
        fault_cleared: Callable[[], bool] = lambda: False,
    ) -> tuple[Transition, ...]:
        """Apply a device control command (also the drive's own, e.g. a quick stop on a set
        point timeout); returns the transitions taken."""
        transition = _TABLE.get((self.state, command))
        if transition is None:
            return ()
        if transition.number == 16 and not quick_stop_stays:
            return ()
        if transition.number == 15 and not fault_cleared():
            return ()
        self.state = transition.target
        if transition.number == 3 and command is Command.ENABLE_OPERATION:
            second = _TABLE[(S.SWITCHED_ON, Command.ENABLE_OPERATION)]
            self.state = second.target
            return (transition, second)
        return (transition,)

    def event(self, event: Event) -> Transition | None:
        """Apply an internal event; None if it means nothing in the current state."""
        transition = _TABLE.get((self.state, event))
        if transition is None:
            return None
        self.state = transition.target
        return transition

    def reset(self) -> tuple[Transition, ...]:
        """Application reset (NMT reset node): back through transitions 0 and 1."""
        first = _TABLE[(None, Event.POWER_ON)]
        self.state = first.target
        self.controlword = 0
        second = self.event(Event.INITIALISED)
        assert second is not None
        return (first, second)

"""The arithmetic of the bridge's cycle as plain functions on one vector: one source, run as
Python or compiled.

:class:`~bridge.cycle.CycleController` keeps its measurements, its controller outputs, the
parameters the cycle reads and the raw values of the received TPDOs in one vector of floats
(the ``V_*`` layout below; the detector state of :mod:`regulator.core` apart), and these
functions do the per-SYNC arithmetic on it:

* :func:`measure`: the raw TPDO values -> SI measurements, extrapolation over a missing
  frame with the drive's measured motor speed, the count of cycles without a complete set
  (docs/bridge.md, "The cycle", step 1);
* :func:`running`: steps 4 and 5 of a running axis: eq. 7 (plus the velocity feed-forward),
  the following-error / encoder-discrepancy / software-limit checks, the vibration detector
  (Fig. 5) and eq. 15 from :mod:`regulator.core`, the clamp to 2007h and the set point in
  drive units;
* :func:`step_running`: both, with the two checks of step 2 that depend on this cycle's
  frames (PDO loss, drive state), for a cycle in which nothing else needs the controller's
  Python (the common case).

They return a code (:data:`OK` or why the controller's Python has to finish the cycle: a
stop, a non-finite value) and the set point in drive units. Everything here uses only
floats, ints and :mod:`math`, like :mod:`regulator.core`, so that :func:`load` can compile it
with numba (nopython, no fastmath: the same IEEE operations in the same order, bit for bit
the Python result, ``tests/bridge/test_cycle_core.py``); without numba the same functions run
as Python (on a list, faster than a numpy array element by element). Compiled, a running
cycle's arithmetic is one call of a few thousand instructions instead of some 900 bytecodes
(docs/bridge.md, "Hot path").
"""

from __future__ import annotations

import importlib.util
import types
from collections.abc import Callable
from typing import Any

from regulator import core as rcore
from regulator import cycle as rcycle
from virtual_bus.contract import Cia402

# --- the vector: the cycle block, parameters, state, the raw values of the frames ------------
# The cycle block of regulator.cycle first (its parameters and results are the cycle's own):
P_KR = rcycle.C_KR  # k_r, motor rad per load unit
P_KV = rcycle.C_KV  # k_v, 1/s
P_VFF = rcycle.C_VFF  # k_vff (200Bh)
P_REG_ON = rcycle.C_REG_ON  # 2001h: 1.0 eq. 15 in the loop
P_REG_N = rcycle.C_REG_N  # detector window n (n + 1 samples)
P_CYCLE = rcycle.C_CYCLE  # s, the position cycle
P_REG_TV = rcycle.C_REG_TV  # s, T_v
P_REG_TF = rcycle.C_REG_TF  # s, T_f
P_REG_BT = rcycle.C_REG_BT  # rad/s, beta_T
P_SPEED_LIMIT = rcycle.C_SPEED_LIMIT  # 2007h, rad/s
P_FE_LIMIT = rcycle.C_FE_LIMIT  # 2008h, load units
P_DISC_LIMIT = rcycle.C_DISC_LIMIT  # 2009h, load units
P_POS_MIN = rcycle.C_POS_MIN  # 2014h:01
P_POS_MAX = rcycle.C_POS_MAX  # 2014h:02
S_OMEGA_S = rcycle.Y_OMEGA_S  # rad/s
S_OMEGA_C = rcycle.Y_OMEGA_C  # rad/s
S_OMEGA_R = rcycle.Y_OMEGA_R  # rad/s, the set point
S_LAMBDA = rcycle.Y_LAMBDA  # eq. 15
S_FOLLOWING_ERROR = rcycle.Y_ERROR  # load units
(
    P_RAD_PER_INC,  # motor rad per 6064h increment
    P_UNIT_PER_INC,  # load units per load-position increment
    P_NM_PER_PERMILLE,  # N·m per 6077h unit
    P_RAD_S_PER_UNIT,  # rad/s per 606Ch unit
    P_UNITS_PER_RAD_S,  # 60FFh units per rad/s
    P_LOAD_MEASURED,  # 1.0: the layout carries a load position, 0.0: feedback = motor / k_r
    P_PDO_TOLERANCE,  # 200Ah, cycles
    P_POS_FRAME,  # bit of the frame carrying the motor position
    P_LOAD_FRAME,  # bit of the frame carrying the load position (the position frame's if none)
    P_STATUS_FRAME,  # bit of the frame carrying the statusword
    P_ALL_FRAMES,  # all frame bits
    S_MOTOR_POSITION,  # rad
    S_LOAD_POSITION,  # load units
    S_MOTOR_SPEED,  # rad/s
    S_TORQUE,  # N·m (or per mille, see bridge.scaling)
    S_STATUSWORD,
    S_HAVE_SAMPLE,  # 1.0 once a load sample came
    S_STATUS_IN,  # 1.0: the statusword came with this cycle's frames
    S_CONSECUTIVE_MISSED,  # cycles in a row without a complete set
    S_MISSED_CYCLES,  # cycles without a complete set
    S_POSITION_REFERENCE,  # x_ref, load units
    S_DIFFERENCE,  # motor - load since enable, load units
    S_DIFFERENCE_AT_ENABLE,  # load units
    R_MOTOR_POSITION,  # the raw values of the frames (integers)
    R_LOAD_POSITION,
    R_STATUSWORD,
    R_TORQUE,
    R_MOTOR_VELOCITY,
    V_SIZE,
) = range(rcycle.BLOCK_SIZE, rcycle.BLOCK_SIZE + 29)

#: Raw value index of each :class:`bridge.layout.Signal` value (the CiA 402 object).
RAW_INDEX = {
    Cia402.POSITION_ACTUAL_VALUE: R_MOTOR_POSITION,
    Cia402.ADDITIONAL_POSITION_ACTUAL_VALUE: R_LOAD_POSITION,
    Cia402.STATUSWORD: R_STATUSWORD,
}
RAW_INDEX |= {Cia402.TORQUE_ACTUAL_VALUE: R_TORQUE, Cia402.VELOCITY_ACTUAL_VALUE: R_MOTOR_VELOCITY}

#: Statusword bits 0-3, 5, 6 of Operation Enabled (canopen's State402.SW_MASK).
OPERATION_ENABLED_MASK = 0x6F
OPERATION_ENABLED_BITS = 0x27

# --- codes (regulator.cycle's, and the bridge's own two) ------------------------------------
OK = rcycle.OK  # the set point is computed (value returned)
SUPERVISION = 1  # PDO loss or the drive left Operation Enabled: the controller stops the axis
FOLLOWING_ERROR = rcycle.FOLLOWING_ERROR  # 2008h exceeded (values stored)
DISCREPANCY = rcycle.DISCREPANCY  # 2009h exceeded
POSITION_LIMIT = rcycle.POSITION_LIMIT  # outside 2014h and not heading back
NOT_FINITE = rcycle.NOT_FINITE  # a non-finite input of eq. 7 or eq. 15: the controller raises
OUT_OF_RANGE = 6  # the set point does not fit 60FFh (INTEGER32): the controller's pack raises

INT32_LIMIT = 2.0**31


def measure(v: Any, frames: int) -> None:
    """Step 1 of the cycle: the raw values in ``v`` -> measurements (``frames``: a bit per
    frame of the layout that came this cycle)."""
    position_in = frames & int(v[P_POS_FRAME]) != 0
    load_in = frames & int(v[P_LOAD_FRAME]) != 0
    v[S_STATUS_IN] = 1.0 if frames & int(v[P_STATUS_FRAME]) != 0 else 0.0
    v[S_STATUSWORD] = v[R_STATUSWORD]
    v[S_TORQUE] = v[R_TORQUE] * v[P_NM_PER_PERMILLE]
    speed = v[R_MOTOR_VELOCITY] * v[P_RAD_S_PER_UNIT]
    v[S_MOTOR_SPEED] = speed
    have = v[S_HAVE_SAMPLE] != 0.0
    if position_in:
        v[S_MOTOR_POSITION] = v[R_MOTOR_POSITION] * v[P_RAD_PER_INC]
    elif have:  # extrapolate over the lost sample
        v[S_MOTOR_POSITION] += speed * v[P_CYCLE]
    if v[P_LOAD_MEASURED] == 0.0:  # position feedback = motor
        load_in = position_in
        v[R_LOAD_POSITION] = 0.0
        load = v[S_MOTOR_POSITION] / v[P_KR]
    else:
        load = v[R_LOAD_POSITION] * v[P_UNIT_PER_INC]
    if load_in:
        v[S_LOAD_POSITION] = load
        v[S_HAVE_SAMPLE] = 1.0
    elif have:  # the drive's measured motor speed, never a difference of two samples: those
        # may lie many cycles apart (SYNC slots skipped), and one cycle's worth of that
        # difference, extrapolated, was a speed the axis never had (docs/bridge.md, step 1)
        v[S_LOAD_POSITION] += speed / v[P_KR] * v[P_CYCLE]
    if frames != int(v[P_ALL_FRAMES]):
        v[S_CONSECUTIVE_MISSED] += 1.0
        v[S_MISSED_CYCLES] += 1.0
    else:
        v[S_CONSECUTIVE_MISSED] = 0.0


def running(v: Any, det: Any, x_ref: float, speed: float) -> tuple[int, int]:
    """Steps 4 and 5 of a running axis with the interpolator's ``x_ref`` and ``speed`` (load
    units, load units/s): the cycle of :func:`regulator.cycle.position_cycle` on the load
    feedback, its limits checked on measured cycles only; (code, set point in 60FFh units).
    A code other than :data:`OK` leaves the regulator untouched."""
    x_l = v[S_LOAD_POSITION]
    difference = v[S_MOTOR_POSITION] / v[P_KR] - x_l - v[S_DIFFERENCE_AT_ENABLE]
    v[S_POSITION_REFERENCE] = x_ref
    v[S_DIFFERENCE] = difference
    measured = v[S_CONSECUTIVE_MISSED] == 0.0  # limits are checked on measured values only
    code = rcycle.position_cycle(v, det, x_ref, speed, x_l, difference, measured)
    if code != OK:
        return code, 0
    units = v[S_OMEGA_R] * v[P_UNITS_PER_RAD_S]
    if not abs(units) < INT32_LIMIT:
        return OUT_OF_RANGE, 0
    return OK, round(units)


def step_running(v: Any, det: Any, frames: int, x_ref: float, speed: float) -> tuple[int, int]:
    """One cycle of a running axis whose other supervision is quiet: :func:`measure`, the
    PDO-loss and drive-state checks (:data:`SUPERVISION` if one fails; the controller then
    stops the axis with its reason), :func:`running`."""
    measure(v, frames)
    if v[S_CONSECUTIVE_MISSED] > v[P_PDO_TOLERANCE]:
        return SUPERVISION, 0
    if int(v[S_STATUSWORD]) & OPERATION_ENABLED_MASK != OPERATION_ENABLED_BITS:
        return SUPERVISION, 0
    return running(v, det, x_ref, speed)


class Functions:
    """The three functions as Python (``compiled`` False) or compiled by numba."""

    def __init__(
        self,
        measure: Callable[[Any, int], None],
        running: Callable[[Any, Any, float, float], tuple[int, int]],
        step_running: Callable[[Any, Any, int, float, float], tuple[int, int]],
        compiled: bool,
    ) -> None:
        self.measure = measure
        self.running = running
        self.step_running = step_running
        self.compiled = compiled

    def view(self, v: Any) -> Any:
        """``v`` as Python code reads and writes it fastest: a memoryview of a numpy vector
        (a float in and out, no numpy scalar), a list as it is."""
        return memoryview(v) if self.compiled else v

    def vectors(self, n: int) -> tuple[Any, Any]:
        """A zero vector and a detector state (window ``n + 1``) of the kind these functions
        run fastest on: numpy arrays compiled, lists of floats as Python."""
        size = rcore.detector_state_size(n)
        if self.compiled:
            import numpy as np

            return np.zeros(V_SIZE), np.zeros(size)
        return [0.0] * V_SIZE, [0.0] * size


PYTHON = Functions(measure, running, step_running, compiled=False)
_compiled: Functions | None = None


def numba_available() -> bool:
    """Whether numba is installed (found without importing it)."""
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):  # refused by an import hook, or blocked in sys.modules
        return False


def load(compiled: bool | None = None) -> Functions:
    """The functions to run: ``compiled`` True: numba's (raises ImportError without numba),
    False: Python's, None: numba's where it is installed (``pip install .[fast]``), else
    Python's. The first compiled load compiles (or loads numba's cache of) all three and
    runs them once, so no cycle ever compiles."""
    global _compiled
    if compiled is False or (compiled is None and not numba_available()):
        return PYTHON
    if _compiled is None:
        try:
            _compiled = _compile()
        except ImportError:
            if compiled:
                raise
            return PYTHON
    return _compiled


def _compile() -> Functions:
    import numba
    import numpy as np

    from regulator import compiled

    jit = numba.njit(cache=True, nogil=True)  # no fastmath: bit for bit the Python result
    names = dict(globals())
    shared = compiled.load()  # regulator's core and cycle, compiled once for every caller
    names["rcore"] = shared.core
    names["rcycle"] = shared.cycle

    def rebuilt(f: types.FunctionType) -> Any:
        return jit(types.FunctionType(f.__code__, names, f.__name__))

    names["measure"] = m = rebuilt(measure)
    names["running"] = r = rebuilt(running)
    s = rebuilt(step_running)
    v, det = np.zeros(V_SIZE), np.zeros(rcore.detector_state_size(4))
    v[P_KR] = v[P_CYCLE] = v[P_REG_TV] = v[P_REG_TF] = v[P_REG_BT] = 1.0
    v[P_REG_N] = 4.0
    m(v, 0)
    r(v, det, 0.0, 0.0)
    s(v, det, 0, 0.0, 0.0)
    return Functions(_entry(m), _entry(r), _entry(s), compiled=True)


def _entry(dispatcher: Any) -> Any:
    """The compiled function's own entry point, without numba's dispatcher: the dispatcher
    works out the types of the arguments at every call to pick a compiled version (callgrind:
    ~3,700 instructions a call of ``step_running``, of which the call of the machine code and
    the conversions of its arguments are ~2,400); here there is one version, and the
    controller always passes the float64 vectors of :meth:`Functions.vectors`, ints and
    floats. A wrong argument is still refused by the entry point's own conversions (an array
    of another type: ``TypeError``; a string for an int: ``ValueError``)."""
    (signature,) = dispatcher.signatures
    return dispatcher.overloads[signature].entry_point

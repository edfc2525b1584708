"""The paper's beta_T procedure over the bus (section VIII), on any drive the bridge runs.

Each trial goes through what a tool could do over SDO: disable (2020h = 2), write beta_T and
the regulator switch (2002h, 2001h; locked while enabled), enable (2020h = 1), then the test
motion from wherever the axis stood when the tuning began, back to the same place, recorded
every cycle. Which motion provokes the limit cycle, the search and the verdicts are
:mod:`regulator.tuning`'s, the same as offline; the motions are sized here from what the
bridge knows (k_v, the cycle, 2008h, 2014h, the torque limit, the torque it measures). The
cycle's supervision stays in force (2008h, 2009h, 2014h, heartbeats, EMCY, the drive's state)
and the test's torque limit on top; any stop ends the run.

Only an outcome FOUND changes the bridge: beta_T (2002h) and the regulator on (2001h) are
written through the object dictionary like an SDO write and stored with 1010h:01 = "save"
(the parameter store, docs/bridge.md). Otherwise the axis is disabled (or left stopped, with
its stop reason), the parameters the bridge started with are restored and nothing is stored.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from regulator.tuning import (
    Ladder,
    MotionProfile,
    Outcome,
    Record,
    Runner,
    SearchConfig,
    SearchResult,
    TorqueModel,
    TrialResult,
    TuningError,
    TuningInputError,
    TuningMotion,
    motion_from_samples,
    search,
)
from virtual_bus.formats.axis import AxisConfig

from .. import od as objdict
from ..cycle import BridgeState
from ..errors import BridgeConfigError
from ..interpolator import Table
from ..node import Bridge
from .session import disable, enable, play

log = logging.getLogger("bridge")

#: Why a load pulse is not among the motions over the bus: the bridge maps no torque offset.
NO_PULSE_ON_THE_BUS = "the bridge's PDO layout carries no torque offset (60B2h) to push with"


@dataclass(frozen=True)
class MotionSamples:
    """The user's own test motion (``--motion FILE``): time (s) and reference position (load
    units) as read from the file, and its name."""

    time_s: np.ndarray
    position: np.ndarray
    name: str

    def profile(self, cycle_s: float, kv: float, dwell_s: float | None) -> MotionProfile:
        return motion_from_samples(self.time_s, self.position, cycle_s, kv, dwell_s, self.name)


@dataclass(frozen=True)
class TuneOptions:
    """motion_changes: fields of the default test motion the user set (the rest:
    :meth:`TuningMotion.for_axis`, adapted to k_v and 2008h); user_motion: the user's own,
    tried first; repeats: runs per trial (the
    verdict takes the worst); search: the beta_T schedule and margin; standstill_limit: load
    units the result must reach at rest within the dwell; torque_limit: the test's own limit
    (N m, or per mille without 6076h)."""

    motion_changes: tuple[tuple[str, float], ...] = ()
    user_motion: MotionSamples | None = None
    repeats: int = 2
    search: SearchConfig = SearchConfig()
    standstill_limit: float = 1e-6
    torque_limit: float = math.inf

    def __post_init__(self) -> None:
        if isinstance(self.repeats, bool) or not isinstance(self.repeats, int):
            raise BridgeConfigError(f"repeats = {self.repeats!r}: an integer 1..10")
        if not 1 <= self.repeats <= 10:
            raise BridgeConfigError(f"repeats = {self.repeats!r}: an integer 1..10")
        if not (math.isfinite(self.standstill_limit) and self.standstill_limit > 0.0):
            raise BridgeConfigError(f"standstill_limit = {self.standstill_limit!r}: > 0")
        if not self.torque_limit > 0.0:
            raise BridgeConfigError(f"torque_limit = {self.torque_limit!r}: > 0")

    def base_motion(self, kv: float, following_error_limit: float) -> TuningMotion:
        return TuningMotion.for_axis(kv, following_error_limit, **dict(self.motion_changes))


@dataclass(frozen=True)
class AxisLimits:
    """What sizes the test motions of one axis: k_v (1/s), the cycle (s), 2008h and the
    travel 2014h (load units), the load unit ("m" or "rad"), the friction torque a motion at
    the feed needs by the axis file (N m; 0: unknown), and the axis file's torque model (None:
    none, or the drive's torque is not in N m)."""

    kv: float
    cycle_s: float
    following_error_limit: float
    position_min: float
    position_max: float
    unit: str = "m"
    friction_nm: float = 0.0
    model: TorqueModel | None = None
    drive_torque_limit: float = math.inf


def make_ladder(
    options: TuneOptions,
    limits: AxisLimits,
    here: float,
    pulse: bool,
    no_pulse: str = NO_PULSE_ON_THE_BUS,
) -> Ladder:
    """The provoking motions (:mod:`regulator.tuning.ladder`) for an axis standing at
    ``here``; TuningInputError for a torque limit below the friction of the
    default motion or a user's motion that leaves the travel."""
    base = options.base_motion(limits.kv, limits.following_error_limit)
    if limits.friction_nm > 0.0 and options.torque_limit <= limits.friction_nm:
        raise TuningInputError(
            f"torque limit {options.torque_limit:g} N·m is below the friction "
            f"{limits.friction_nm:.3g} N·m the axis file gives at the feed of the test motion: "
            "the axis could not move; allowed: a limit above the friction"
        )
    travel = (limits.position_min - here, limits.position_max - here)
    user = None
    if options.user_motion is not None:
        _, _, dwell_s, _ = base.times(limits.kv)
        user = options.user_motion.profile(limits.cycle_s, limits.kv, dwell_s)
        lo, hi = user.excursion()
        if here + lo < limits.position_min or here + hi > limits.position_max:
            from regulator.units import length

            u = limits.unit
            raise TuningInputError(
                f"{user.name} reaches {length(here + lo, u)}..{length(here + hi, u)} from the "
                f"axis at {length(here, u)}: outside the travel limits 2014h "
                f"[{length(limits.position_min, u)}, {length(limits.position_max, u)}]"
            )
    return Ladder(
        base,
        limits.cycle_s,
        limits.kv,
        options.repeats,
        min(options.torque_limit, limits.drive_torque_limit),
        travel,
        limits.unit,
        pulse=pulse,
        no_pulse=no_pulse,
        user=user,
        model=limits.model,
    )


@dataclass(frozen=True)
class TuneReport:
    """The search's result and whether the bridge stored it."""

    result: SearchResult
    stored: bool
    store_path: str | None

    @property
    def beta_t_rad_s(self) -> float | None:
        return self.result.beta_t_rad_s


def bus_runner(bridge: Bridge, options: TuneOptions) -> Runner:
    """A :data:`regulator.tuning.Runner` that plays a profile on ``bridge`` from where the
    axis stood at the first trial."""
    c = bridge.controller
    kept = c.params
    state = {"start": math.nan}

    def run(profile: MotionProfile, beta_t: float | None) -> Record:
        if profile.disturbance_nm is not None:
            raise TuningError(f"{profile.name}: {NO_PULSE_ON_THE_BUS}")
        params = kept.with_value("regulator_enabled", beta_t is not None)
        if beta_t is not None:
            params = params.with_value("beta_t_rad_s", beta_t)
        what = "tuning trial " + ("(regulator off)" if beta_t is None else f"beta_T {beta_t:.4g}")
        enable(bridge, params, what)
        if math.isnan(state["start"]):
            state["start"] = c.position_reference
        table = Table(profile.position + state["start"], profile.speed)
        rec = play(bridge, table, options.torque_limit, what)
        stopped = None
        if c.state is not BridgeState.RUNNING:
            stopped = f"{c.stop_reason.name}: {c.stop_message}"
        return rec.record(stopped)

    return run


def store_beta_t(bridge: Bridge, beta_t_rad_s: float) -> bool:
    """2001h = 1, 2002h = beta_T through the object dictionary (the checks of an SDO write),
    then 1010h:01 = "save" when the bridge has a parameter store; whether it stored."""
    objects = bridge.objects
    objects.write(objdict.REG_ENABLE, 0, b"\x01")
    objects.write(objdict.BETA_T, 0, struct.pack("<f", beta_t_rad_s))
    if objects.store is None:
        return False
    objects.write(objdict.STORE_PARAMETERS, 1, struct.pack("<I", objdict.SAVE_SIGNATURE))
    return True


def axis_limits(
    axis: AxisConfig,
    options: TuneOptions,
    following_error_limit: float,
    travel: tuple[float, float],
    torque_in_nm: bool = True,
) -> AxisLimits:
    """What sizes the tuning's motions on an axis: its axis file (k_v, the cycle, the
    friction and inertia, the drive's torque limit -- the latter three only where the drive's
    torque is in N m), 2008h and the travel 2014h."""
    c, f = axis.control, axis.friction
    base = options.base_motion(c.kv, following_error_limit)
    coulomb, viscous = f.coulomb or 0.0, f.viscous or 0.0
    model = TorqueModel(
        axis.motor_side_inertia + axis.load_inertia_reflected,
        axis.transmission_ratio,
        coulomb,
        viscous,
    )
    return AxisLimits(
        c.kv,
        c.position_cycle,
        following_error_limit,
        travel[0],
        travel[1],
        axis.load_unit,
        coulomb + viscous * base.feed if torque_in_nm else 0.0,
        model if torque_in_nm else None,
        (c.torque_limit or math.inf) if torque_in_nm else math.inf,
    )


def tune(
    bridge: Bridge,
    options: TuneOptions,
    axis: AxisConfig,
    on_trial: Callable[[TrialResult], None] | None = None,
) -> TuneReport:
    """The procedure on a started bridge (module docstring) on the axis of ``axis`` (the
    file it was started with). Raises :class:`regulator.tuning.TuningInputError` before
    anything moves (a torque limit below friction, a user's motion outside 2014h),
    :class:`regulator.tuning.TuningError` when no motion provokes a limit cycle."""
    c = bridge.controller
    kept = c.params
    limits = axis_limits(
        axis,
        options,
        kept.following_error_limit,
        (kept.position_limit_min, kept.position_limit_max),
        c.scaling.torque_unit == "N·m",
    )
    ladder = make_ladder(options, limits, c.load_position, False)
    run = bus_runner(bridge, options)
    try:
        result: SearchResult = search(
            run,
            ladder,
            options.search,
            kept.cycle_s,
            kept.kv_per_s,
            options.standstill_limit,
            velocity_feedforward=kept.velocity_feedforward,
            on_trial=on_trial,
            unit=limits.unit,
        )
    finally:
        disable(bridge)
        if c.state is not BridgeState.STOPPED:
            c.set_params(kept)
    stored = False
    if result.outcome is Outcome.FOUND and c.state is not BridgeState.STOPPED:
        assert result.beta_t_rad_s is not None
        stored = store_beta_t(bridge, result.beta_t_rad_s)
        log.info(
            "beta_T = %.4g rad/s written (2002h)%s",
            result.beta_t_rad_s,
            " and stored (1010h)" if stored else "; no parameter store configured",
        )
    store = bridge.objects.store
    return TuneReport(result, stored, None if store is None else str(store.path))

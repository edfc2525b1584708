"""The paper's beta_T procedure over the bus (section VIII), on any drive the bridge runs.

Each trial goes through what a tool could do over SDO: disable (2020h = 2), write beta_T and
the regulator switch (2002h, 2001h; locked while enabled), enable (2020h = 1), then the test
motion (:class:`regulator.tuning.TuningMotion`) from wherever the axis stands, back to the same
place, recorded every cycle. The search and the verdicts are :func:`regulator.tuning.search`'s,
the same as offline. The cycle's supervision stays in force (2008h, 2009h, 2014h, heartbeats,
EMCY, the drive's state) and the test's torque limit on top; any stop ends the run.

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

from regulator.tuning import (
    Outcome,
    Record,
    SearchConfig,
    SearchResult,
    TrialResult,
    TuningMotion,
    search,
)

from .. import od as objdict
from ..cycle import BridgeState
from ..errors import BridgeConfigError
from ..interpolator import Table
from ..node import Bridge
from .session import disable, enable, play

log = logging.getLogger("bridge")


@dataclass(frozen=True)
class TuneOptions:
    """motion: the test motion; repeats: runs per trial (the verdict takes the worst);
    search: the beta_T schedule and margin; standstill_limit: load units the result must
    hold at rest; torque_limit: the test's own limit (N m, or per mille without 6076h)."""

    motion: TuningMotion = TuningMotion()
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


@dataclass(frozen=True)
class TuneReport:
    """The search's result and whether the bridge stored it."""

    result: SearchResult
    stored: bool
    store_path: str | None

    @property
    def beta_t_rad_s(self) -> float | None:
        return self.result.beta_t_rad_s


def bus_runner(
    bridge: Bridge, options: TuneOptions, profile_len: int
) -> tuple[Callable[[float | None], Record], Callable[[], float]]:
    """A :data:`regulator.tuning.Runner` that plays the motion on ``bridge``; the second
    function gives the start position the profile was built for."""
    c = bridge.controller
    kept = c.params
    state = {"start": math.nan}

    def run(beta_t: float | None) -> Record:
        params = kept.with_value("regulator_enabled", beta_t is not None)
        if beta_t is not None:
            params = params.with_value("beta_t_rad_s", beta_t)
        what = "tuning trial " + ("(regulator off)" if beta_t is None else f"beta_T {beta_t:.4g}")
        enable(bridge, params, what)
        if math.isnan(state["start"]):
            state["start"] = c.position_reference
        start = state["start"]
        profile = options.motion.profile(kept.cycle_s, kept.kv_per_s, start).repeated(
            options.repeats
        )
        assert profile.position.size == profile_len
        rec = play(bridge, Table(profile.position, profile.speed), options.torque_limit, what)
        stopped = None
        if c.state is not BridgeState.RUNNING:
            stopped = f"{c.stop_reason.name}: {c.stop_message}"
        return rec.record(stopped)

    return run, lambda: state["start"]


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


def tune(
    bridge: Bridge,
    options: TuneOptions,
    on_trial: Callable[[TrialResult], None] | None = None,
) -> TuneReport:
    """The procedure on a started bridge (module docstring). Raises
    :class:`regulator.tuning.TuningError` when the test motion provokes nothing, a
    ParameterError (0609 0031/32) when its path leaves 2014h -- nothing moved then."""
    c = bridge.controller
    kept = c.params
    probe = options.motion.profile(kept.cycle_s, kept.kv_per_s).repeated(options.repeats)
    # the whole path from here must lie inside 2014h, refused before anything moves
    here = c.load_position
    c.check_path(Table(probe.position + here, probe.speed))
    run, _start = bus_runner(bridge, options, probe.position.size)
    try:
        result: SearchResult = search(
            run,
            probe,
            options.search,
            kept.cycle_s,
            kept.kv_per_s,
            options.standstill_limit,
            velocity_feedforward=kept.velocity_feedforward,
            on_trial=on_trial,
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

"""Commissioning on the simulated axis, offline: the beta_T procedure and the frequency
response on a plant (the compiled kernel's or an FMU's) with the cycle the bridge runs over
the bus.

* :func:`plant_runner` -- a :data:`regulator.tuning.Runner`: each trial on a fresh plant
  through the bridge's loop without a bus (:func:`hil.loop.trial_runner`: the cycle of
  :mod:`regulator.cycle` with the bridge's clamp and supervision, the one-cycle PDO delay);
* :func:`frequency_response` -- the bridge's excitation (:class:`bridge.commission.freqresp.
  ExcitationPlan`) through :func:`hil.loop.run_loop` on any steppable plant, estimated like
  the bus command.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from bridge.commission.freqresp import ExcitationPlan, FrequencyResponse
from bridge.commission.tune import TuneOptions, axis_limits, make_ladder
from bridge.params import BridgeParams
from plant_sim.fmu.arguments import AxisSource
from plant_sim.physics.model import AxisPlant
from regulator import RegulatorConfig
from regulator.frequency_response import antiresonance, bandwidth
from regulator.tuning import (
    Runner,
    SafetyLimits,
    SearchResult,
    TrialResult,
    TuningError,
    search,
)
from virtual_bus.formats.axis import AxisConfig

from .loop import Plant, run_loop, trial_runner


def base_regulator(axis: AxisConfig) -> RegulatorConfig:
    return RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)


def safety_of(
    axis: AxisConfig, following_error: float, torque_nm: float = math.inf
) -> SafetyLimits:
    """The bridge's limits for ``axis``: 2008h, its default 2014h, a torque limit."""
    from bridge.params import BridgeParams

    p = BridgeParams.for_axis(axis, base_regulator(axis))
    return SafetyLimits(following_error, p.position_limit_min, p.position_limit_max, torque_nm)


def frequency_response(
    plant: Plant, plan: ExcitationPlan, kr: float, kv: float, torque_unit: str = "N·m"
) -> FrequencyResponse:
    """The bus command's test on a steppable plant (the bridge's loop of :mod:`hil.loop`
    with the regulator off and full velocity feed-forward)."""
    table = plan.table(plant.load_position, kr)
    config = RegulatorConfig(kv=kv, cycle_s=plan.cycle_s, enabled=False)
    trace = run_loop(plant, table.position, table.speed, kr, config, velocity_feedforward=1.0)
    if np.max(np.abs(trace.torque)) > plan.torque_limit:
        raise TuningError(
            f"torque {np.max(np.abs(trace.torque)):.4g} N m beyond the test's limit "
            f"{plan.torque_limit:g}: lower the amplitude (the drive would have been stopped)"
        )
    loop = plan.estimate(trace.omega_r, trace.motor_speed)
    adm = plan.estimate(trace.torque, trace.motor_speed)
    band = plan.notch_band_hz or (
        max(plan.multisine.f_min_hz, 4.0 * plan.multisine.resolution_hz),
        plan.multisine.f_max_hz,
    )
    return FrequencyResponse(
        loop,
        adm,
        antiresonance(loop, band[0], band[1], adm, plan.sheet_damping),
        bandwidth(loop),
        trace,
        torque_unit,
        plan,
    )


def kernel_plant(axis: AxisConfig) -> Callable[[float], AxisPlant]:
    return lambda start: AxisPlant(axis, position=start)


def plant_runner(source: AxisSource, safety: SafetyLimits) -> Runner:
    """Trials on a fresh plant of the source each (the compiled kernel's ``AxisPlant`` or an
    FMU's) at rest at 0: the bridge's loop (:func:`hil.loop.trial_runner`, the cycle of
    :mod:`regulator.cycle` with the bridge's 2007h clamp and its 2008h (the test's following
    error limit), 2009h and 2014h supervision), the one-cycle PDO delay; a profile's load
    pulse on the plant's disturbance input."""
    axis = source.axis
    base = base_regulator(axis)
    return trial_runner(
        source.plant,
        axis.transmission_ratio,
        base,
        safety,
        axis.control.velocity_feedforward or 0.0,
        replace(BridgeParams.for_axis(axis, base), following_error_limit=safety.following_error),
    )


def tune_offline(
    source: AxisSource,
    options: TuneOptions,
    following_error_limit: float,
    travel: tuple[float, float] | None = None,
    on_trial: Callable[[TrialResult], None] | None = None,
) -> SearchResult:
    """``hil tune``'s procedure: the ladder sized from the axis file, the trials on fresh
    plants at rest at 0 (:func:`plant_runner`, a load pulse on the plant's disturbance input).
    TuningInputError before anything runs (a torque limit below friction, a motion outside
    the travel); TuningError when no motion provokes a limit cycle."""
    axis = source.axis
    default = safety_of(axis, following_error_limit)
    limits = axis_limits(
        axis,
        options,
        following_error_limit,
        travel or (default.position_min, default.position_max),
    )
    ladder = make_ladder(options, limits, 0.0, True, "")
    safety = SafetyLimits(
        following_error_limit, limits.position_min, limits.position_max, options.torque_limit
    )
    return search(
        plant_runner(source, safety),
        ladder,
        options.search,
        limits.cycle_s,
        limits.kv,
        options.standstill_limit,
        velocity_feedforward=axis.control.velocity_feedforward or 0.0,
        on_trial=on_trial,
        unit=limits.unit,
    )


def analytic_loop(axis: AxisConfig, frequency_hz: np.ndarray) -> np.ndarray | None:
    """Eq. 6a of the axis' linearised two-mass model (backlash closed, friction left out),
    with its current lag and the delays of the sampled loop: the cycle the set point waits for
    the next SYNC, half a cycle of its zero-order hold, half a speed cycle of the drive's
    backward-difference speed; None for a rigid axis or one without PI speed loop."""
    from regulator.twomass import TwoMass

    m, c = axis.mechanics, axis.control
    if m.antiresonance is None or c.tsi is None:
        return None
    model = TwoMass(
        axis.motor_side_inertia,
        axis.load_inertia_reflected,
        m.antiresonance,
        m.damping_ratio or 0.0,
    )
    return model.speed_loop(
        frequency_hz,
        c.ksp,
        c.tsi,
        c.current_lag or 0.0,
        delay_s=1.5 * c.position_cycle + 0.5 * c.speed_cycle,
    )

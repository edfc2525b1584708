"""Commissioning on the simulated axis, offline: the beta_T procedure and the frequency
response run on the compiled kernel with the same logic the bridge runs over the bus.

* :func:`kernel_runner` -- a :data:`regulator.tuning.Runner` on
  :func:`plant_sim.physics.simulate.simulate` (the regulator compiled into the loop, the
  one-cycle PDO delay of ``KernelOptions(setpoint_delay_cycles=1)``): fast, the section X
  loop the bridge reproduces to 10 nm (docs/bridge.md);
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
from plant_sim.fmu.arguments import AxisSource
from plant_sim.physics.model import AxisPlant, KernelOptions
from plant_sim.physics.simulate import References, simulate
from regulator import RegulatorConfig
from regulator.frequency_response import antiresonance, bandwidth
from regulator.tuning import MotionProfile, Record, SafetyLimits, TuningError, safety_stop
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


def kernel_runner(
    axis: AxisConfig,
    profile: MotionProfile,
    safety: SafetyLimits,
    disturbance_nm: np.ndarray | None = None,
) -> Callable[[float | None], Record]:
    """Trials on the compiled kernel (module docstring)."""
    base = base_regulator(axis)
    dist = np.zeros_like(profile.speed) if disturbance_nm is None else disturbance_nm
    refs = References(profile.position, profile.speed, dist)
    options = KernelOptions(setpoint_delay_cycles=1)

    def run(beta_t: float | None) -> Record:
        reg = RegulatorConfig(
            kv=base.kv,
            cycle_s=base.cycle_s,
            beta_t_rad_s=beta_t if beta_t is not None else base.beta_t_rad_s,
            enabled=beta_t is not None,
        )
        tr = simulate(axis, refs, reg, options)
        record = Record(
            tr["position_reference"],
            tr["load_position"],
            tr["beta"],
            tr["lambda"],
            None,
            tr["motor_torque"],
        )
        return replace(record, stopped=safety_stop(record, safety))

    return run


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
        antiresonance(loop, band[0], band[1], adm),
        bandwidth(loop),
        trace,
        torque_unit,
        plan,
    )


def kernel_plant(axis: AxisConfig) -> Callable[[float], AxisPlant]:
    return lambda start: AxisPlant(axis, position=start)


def plant_runner(
    source: AxisSource,
    profile: MotionProfile,
    safety: SafetyLimits,
    disturbance_nm: np.ndarray | None = None,
) -> Callable[[float | None], Record]:
    """Trials on the source's plant: the compiled kernel's closed loop
    (:func:`kernel_runner`), or the bridge's loop (:func:`hil.loop.trial_runner`) around a
    fresh instance of the FMU per trial."""
    axis = source.axis
    if source.model is None:
        return kernel_runner(axis, profile, safety, disturbance_nm)
    return trial_runner(
        source.plant,
        profile.position,
        profile.speed,
        axis.transmission_ratio,
        base_regulator(axis),
        safety,
        axis.control.velocity_feedforward or 0.0,
        disturbance_nm,
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

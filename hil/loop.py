"""The bridge's loop without a bus, around any steppable plant (offline commissioning, proofs).

Per position cycle k, as the bridge over CANopen (docs/canopen_layout.md): the sensors are
read at t_k; :func:`regulator.cycle.position_cycle` (eq. 7 on the load scale with the velocity
feed-forward, the bridge's limits, the detector, eq. 15, the clamp: the one composition the
bridge and the kernel run); the set point computed at SYNC k takes effect at SYNC k+1 (the PDO
delay). The plant is anything with
``advance(speed_setpoint_rad_s, disturbance_nm)`` and the readings ``motor_position_rad``,
``motor_speed_rad_s``, ``load_position``, ``motor_torque_nm``
(:class:`regulator.loop.SteppedAxis`): the compiled kernel's
:class:`plant_sim.physics.model.AxisPlant`, an FMU's :class:`plant_sim.fmu.FmuPlant`, or the
tests' independent plant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from bridge.commission.session import Recording
from bridge.params import BridgeParams
from regulator import RegulatorConfig, cycle
from regulator.loop import SteppedAxis, play
from regulator.tuning import MotionProfile, Record, Runner, SafetyLimits, safety_stop

#: What the loop closes around (:class:`regulator.loop.SteppedAxis`).
Plant = SteppedAxis


def run_loop(
    plant: Plant,
    position: np.ndarray,
    speed: np.ndarray,
    kr: float,
    regulator: RegulatorConfig,
    velocity_feedforward: float = 0.0,
    disturbance_nm: np.ndarray | None = None,
    params: BridgeParams | None = None,
) -> Recording:
    """Play the reference (load units, load units/s per cycle) on ``plant`` (module doc).

    Each cycle is :func:`regulator.cycle.position_cycle`, the one composition the bridge's
    core and the kernel run. ``params``: the bridge's limits in the cycle (2007h clamp, 2008h,
    2009h, 2014h; None: no limits, as the kernel runs the law); a limit the axis breaks stops
    it as the bridge does (the set point 0 from then on, ``Recording.stop_reason`` says why)."""
    limits = {}
    if params is not None:
        limits = {
            "speed_limit_rad_s": params.speed_limit_rad_s,
            "following_error_limit": params.following_error_limit,
            "discrepancy_limit": params.discrepancy_limit,
            "position_min": params.position_limit_min,
            "position_max": params.position_limit_max,
        }
    c = cycle.block(
        kr,
        regulator.kv,
        regulator.cycle_s,
        velocity_feedforward=velocity_feedforward,
        regulator_on=regulator.enabled,
        n=regulator.n,
        tv_s=regulator.effective_tv_s,
        tf_s=regulator.tf_s,
        beta_t_rad_s=regulator.beta_t_rad_s,
        **limits,
    )
    run = play(plant, position, speed, c, disturbance_nm)
    stop = None
    if run.stop_cycle is not None:
        why = _stop_reason(run.stop_code, c, run.stop_feedback, run.stop_difference, params)
        stop = f"cycle {run.stop_cycle}: {why}"
    return Recording(
        run["position_reference"],
        run["load_position"],
        run["speed_setpoint"],
        run["motor_speed"],
        run["motor_torque"],
        run["beta"],
        run["lambda"],
        cycles=position.size,
        stop_reason=stop,
    )


def _stop_reason(
    code: int, c: list[float], x_l: float, difference: float, params: BridgeParams | None
) -> str:
    """The bridge's words for a stop of the cycle (bridge/cycle.py)."""
    if code == cycle.FOLLOWING_ERROR and params is not None:
        return (
            f"following error {c[cycle.Y_ERROR]:.6g} load units exceeds 2008h = "
            f"{params.following_error_limit:g} load units"
        )
    if code == cycle.DISCREPANCY and params is not None:
        return (
            f"motor encoder and load scale differ by {difference:.6g} load units since "
            f"enable, above 2009h = {params.discrepancy_limit:g} load units"
        )
    if code == cycle.POSITION_LIMIT and params is not None:
        return (
            f"load position {x_l:.9g} load units outside the software position limits 2014h "
            f"[{params.position_limit_min:g}, {params.position_limit_max:g}] load units and no "
            "move heads back inside"
        )
    return "a non-finite position or speed (the plant diverged)"


def trial_runner(
    make_plant: Callable[[float], Plant],
    kr: float,
    base: RegulatorConfig,
    safety: SafetyLimits,
    velocity_feedforward: float = 0.0,
    params: BridgeParams | None = None,
    start: float = 0.0,
) -> Runner:
    """A :data:`regulator.tuning.Runner` on fresh plants (``make_plant(start)``): each trial
    from the same state at ``start``, the profile's load pulse on the plant's disturbance
    input, the bridge's cycle with its limits (``params``) in the loop and the test's safety
    limits applied to what it recorded."""

    def run(profile: MotionProfile, beta_t: float | None) -> Record:
        config = RegulatorConfig(
            kv=base.kv,
            cycle_s=base.cycle_s,
            n=base.n,
            beta_t_rad_s=beta_t if beta_t is not None else base.beta_t_rad_s,
            tv_s=base.tv_s,
            tf_s=base.tf_s,
            enabled=beta_t is not None,
        )
        plant = make_plant(start)
        try:
            trace = run_loop(
                plant,
                profile.position + start,
                profile.speed,
                kr,
                config,
                velocity_feedforward,
                profile.disturbance_nm,
                params,
            )
        finally:
            close = getattr(plant, "close", None)
            if close is not None:
                close()
        record = trace.record()
        return replace(record, stopped=trace.stop_reason or safety_stop(record, safety))

    return run

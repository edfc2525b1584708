"""The bridge's loop without a bus, around any steppable plant (offline commissioning, proofs).

Per position cycle k, as the bridge over CANopen (docs/canopen_layout.md): the sensors are
read at t_k; eq. 7 on the load scale with the velocity feed-forward, ``omega_c = k_r (k_v
(x_ref - x_l) + k_vff v_ref)`` (:class:`regulator.PositionController`); eq. 15 through
:class:`regulator.BacklashRegulator` (or omega_c unchanged with the regulator off); the set
point computed at SYNC k takes effect at SYNC k+1 (the PDO delay). The plant is anything with
``advance(speed_setpoint_rad_s, disturbance_nm)`` and the readings ``motor_position_rad``,
``motor_speed_rad_s``, ``load_position``, ``motor_torque_nm``
(:class:`plant_sim.plant.SteppedAxis`): the compiled kernel's
:class:`plant_sim.physics.model.AxisPlant`, an FMU's :class:`plant_sim.fmu.FmuPlant`, or the
tests' independent plant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from bridge.commission.session import Recording
from plant_sim.plant import SteppedAxis
from regulator import BacklashRegulator, PositionController, RegulatorConfig
from regulator.tuning import Record, SafetyLimits, safety_stop

#: What the loop closes around (:class:`plant_sim.plant.SteppedAxis`).
Plant = SteppedAxis


def run_loop(
    plant: Plant,
    position: np.ndarray,
    speed: np.ndarray,
    kr: float,
    regulator: RegulatorConfig,
    velocity_feedforward: float = 0.0,
    disturbance_nm: np.ndarray | None = None,
) -> Recording:
    """Play the reference (load units, load units/s per cycle) on ``plant`` (module doc)."""
    n = position.size
    controller = PositionController(regulator.kv, kr)
    reg = BacklashRegulator.from_config(regulator)
    dist = np.zeros(n) if disturbance_nm is None else disturbance_nm
    out = np.empty((7, n))
    latched = 0.0  # the set point in force during this cycle (sent at the previous SYNC)
    for k in range(n):
        x_l = plant.load_position
        omega_s = kr * speed[k]
        omega_c = controller.step(position[k], x_l) + velocity_feedforward * omega_s
        omega_r = reg.step(omega_s, omega_c)
        out[:, k] = (
            position[k],
            x_l,
            omega_r,
            plant.motor_speed_rad_s,
            plant.motor_torque_nm,
            reg.vibration_level,
            reg.switching_factor,
        )
        plant.advance(latched, float(dist[k]))
        latched = omega_r
    return Recording(*out, cycles=n)


def trial_runner(
    make_plant: Callable[[float], Plant],
    position: np.ndarray,
    speed: np.ndarray,
    kr: float,
    base: RegulatorConfig,
    safety: SafetyLimits,
    velocity_feedforward: float = 0.0,
    disturbance_nm: np.ndarray | None = None,
) -> Callable[[float | None], Record]:
    """A :data:`regulator.tuning.Runner` on fresh plants (``make_plant(start)``): each trial
    from the same state, the bridge's safety limits applied to what it recorded."""

    def run(beta_t: float | None) -> Record:
        config = RegulatorConfig(
            kv=base.kv,
            cycle_s=base.cycle_s,
            n=base.n,
            beta_t_rad_s=beta_t if beta_t is not None else base.beta_t_rad_s,
            tv_s=base.tv_s,
            tf_s=base.tf_s,
            enabled=beta_t is not None,
        )
        plant = make_plant(float(position[0]))
        try:
            trace = run_loop(
                plant, position, speed, kr, config, velocity_feedforward, disturbance_nm
            )
        finally:
            close = getattr(plant, "close", None)
            if close is not None:
                close()
        record = trace.record()
        return replace(record, stopped=safety_stop(record, safety))

    return run

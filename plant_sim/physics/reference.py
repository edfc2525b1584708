"""Reference implementation of the same closed loop with ``scipy.integrate.solve_ivp``.

Written independently of the compiled kernel: the mechanics are the continuous ODE of
:mod:`plant_sim.physics.kernel`'s docstring, integrated by an adaptive Runge-Kutta method (RK45)
between the speed controller's sampling instants; the controllers are plain Python
(the PI speed controller here, :class:`regulator.PositionController` and
:class:`regulator.BacklashRegulator` for the position loop and eq. 15).

Two deliberate differences, both for runs in which the load does not stick:
- Coulomb friction is ``coulomb·sign(v)`` (no stiction logic: an ODE solver cannot hold a
  set-valued force); while the load moves both models are the same equations.
- Dead time is not modelled (``control.delay`` must be absent or 0), nor a late set point or
  reading or a scale error (``control.setpoint_delay``, ``measurement_delay``,
  ``scale_error_*``).

The speed filter (``control.speed_filter``) is its ODE, integrated by solve_ivp over each
speed cycle with the cycle's encoder difference as input.

It is the benchmark's baseline (``python -m plant_sim bench``) and the second implementation
the kernel is tested against (tests/plant_sim/physics/test_convergence.py).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from regulator import BacklashRegulator, PositionController, RegulatorConfig
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from ..errors import ScenarioError
from .simulate import SIM_COLUMNS, References


def _rhs_factory(axis: AxisConfig):
    kr = axis.transmission_ratio
    j1 = axis.motor_side_inertia
    m = axis.mechanics.load_mass
    k = axis.stiffness or 0.0
    c = axis.damping_coefficient
    half = 0.5 * (axis.mechanics.backlash or 0.0)
    fr = axis.friction
    fc_pos = kr * (fr.coulomb or 0.0)
    fv_pos = kr * (fr.viscous or 0.0)
    fc_neg = kr * (fr.coulomb_negative if fr.coulomb_negative is not None else fr.coulomb or 0.0)
    fv_neg = kr * (fr.viscous_negative if fr.viscous_negative is not None else fr.viscous or 0.0)
    f_const = -kr * (axis.disturbance.constant_torque or 0.0)
    if axis.is_rigid:
        raise ScenarioError("the reference implementation models the elastic axis only")
    if axis.friction.stribeck or axis.disturbance.periodic_amplitude:
        raise ScenarioError("the reference implementation has no Stribeck or periodic terms")

    def rhs(_t: float, y: np.ndarray, tau: float, f_ext: float) -> list[float]:
        th, om, x, v = y
        d = th / kr - x
        ddot = om / kr - v
        if half <= 0.0:
            fs = k * d + c * ddot
        elif d > half:
            fs = max(0.0, k * (d - half) + c * ddot)
        elif d < -half:
            fs = min(0.0, k * (d + half) + c * ddot)
        else:
            fs = 0.0
        friction = (fc_pos + fv_pos * v) if v > 0 else (-fc_neg + fv_neg * v) if v < 0 else 0.0
        return [om, (tau - fs / kr) / j1, v, (fs + f_ext + f_const - friction) / m]

    return rhs


def simulate_reference(
    axis: AxisConfig,
    refs: References,
    regulator: RegulatorConfig | None = None,
    rtol: float = 1e-7,
) -> Trace:
    """Closed loop of Fig. 1 / Fig. 6 with solve_ivp; same trace columns as
    :func:`plant_sim.physics.simulate.simulate` (one row per position cycle)."""
    c = axis.control
    if c.delay:
        raise ScenarioError("the reference implementation has no dead time (control.delay)")
    for key in (
        "velocity_feedforward",
        "acceleration_feedforward",
        "sensor_time_offset",
        "setpoint_delay",
        "setpoint_delay_rate",
        "measurement_delay",
        "scale_error_amplitude",
    ):
        if getattr(c, key):
            raise ScenarioError(f"the reference implementation has no control.{key}")
    kr = axis.transmission_ratio
    rhs = _rhs_factory(axis)
    reg = BacklashRegulator.from_config(
        regulator or RegulatorConfig(kv=c.kv, cycle_s=c.position_cycle, enabled=False)
    )
    position = PositionController(kv_per_s=c.kv, transmission_ratio=kr)
    lim = math.inf if c.torque_limit is None else c.torque_limit
    ki = 0.0 if c.tsi is None else c.ksp / c.tsi
    tsc = c.speed_cycle
    n_sc = c.speed_cycles_per_position_cycle
    y = np.array([kr * refs.position[0], 0.0, refs.position[0], 0.0])
    th_prev, integ, tau, t = y[0], 0.0, 0.0, 0.0
    omega_meas = 0.0
    rows = []
    for k in range(len(refs.position)):
        x_fb = y[2] if c.position_feedback.value == "load" else y[0] / kr
        omega_c = position.step(refs.position[k], x_fb)
        omega_s = kr * refs.speed[k]
        omega_r = reg.step(omega_s, omega_c)
        f_ext = kr * refs.disturbance_nm[k]
        rows.append(
            (
                t,
                refs.position[k],
                omega_r,
                y[0],
                omega_meas,
                y[2],
                tau,
                refs.disturbance_nm[k],
                reg.vibration_level,
                reg.switching_factor,
                omega_s,
                omega_c,
            )
        )
        for _ in range(n_sc):
            raw = (y[0] - th_prev) / tsc
            th_prev = y[0]
            if c.speed_filter:
                # the speed filter's ODE, T_f·dw/dt = u − w, integrated over the cycle whose
                # mean speed u the encoder difference is
                filt = solve_ivp(
                    lambda _tt, w, u=raw: [(u - w[0]) / c.speed_filter],
                    (0.0, tsc),
                    [omega_meas],
                    rtol=rtol,
                    atol=1e-12,
                )
                omega_meas = float(filt.y[0, -1])
            else:
                omega_meas = raw
            err = omega_r - omega_meas
            if ki:
                integ = integ + ki * err * tsc
                integ = min(max(integ, -lim - c.ksp * err), lim - c.ksp * err)
            cmd = min(lim, max(-lim, c.ksp * err + integ))
            if c.current_lag:
                # first-order current loop as an extra state integrated with the mechanics
                sol = solve_ivp(
                    lambda tt, z, cmd=cmd, f_ext=f_ext: [
                        *rhs(tt, z[:4], z[4], f_ext),
                        (cmd - z[4]) / c.current_lag,
                    ],
                    (t, t + tsc),
                    [*y, tau],
                    rtol=rtol,
                    atol=1e-12,
                )
                y, tau = sol.y[:4, -1], float(sol.y[4, -1])
            else:
                sol = solve_ivp(rhs, (t, t + tsc), y, args=(cmd, f_ext), rtol=rtol, atol=1e-12)
                y, tau = sol.y[:, -1], cmd
            t += tsc
    data = np.array(rows)
    return Trace({name: data[:, i] for i, name in enumerate(SIM_COLUMNS)})

"""Relative force error of an axis model on a recording (shared/data/emps/README.md).

    error = 100 * ||F_measured - F_simulated|| / ||F_measured||   (percent)

F is the force (torque) acting on the axis: the motor's plus the known external one. The
model is simulated *in the loop* of the recording: the axis file's controller follows the
recording's ``position_reference`` while the recording's ``disturbance`` acts on the load,
and the simulated torque is compared with the recorded one. This is the one piece of code by
which the published EMPS reference model and any fitted model are scored, so both are
simulated and compared the same way.

Row timing is the simulator's (:func:`plant_sim.physics.simulate.simulate`, and the EMPS importer
writes recordings that way, :mod:`plant_sim.datasets.emps`): ``motor_torque[k]`` acted over
the cycle that ends at row k, ``disturbance[k]`` acts over the cycle that starts there. The
force over the cycle ending at row k is therefore ``motor_torque[k] + disturbance[k-1]``.

Comparison window: as in the authors' own script (``n_border = 50``: samples 50..N, 1-based,
at 1 kHz) the first ``SETTLE_S`` = 0.049 s are left out: the simulation starts at rest while
the recording starts in motion.

Integration: a rigid axis gets one mechanics step per speed cycle from
:func:`plant_sim.physics.model.default_substeps`, which is first-order accurate in the closed speed
loop. For scoring, :func:`replay_substeps` refines the step until the speed loop's rate times
the step is at most ``LOOP_RATE_DT`` (EMPS: 45 steps per 1 ms cycle; the force error is then
within ~0.02 percentage points of the converged value, against 1.9 points with one step).

Run as ``python -m plant_sim force_error --axis AXIS.toml TRACE.csv ...``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from regulator import RegulatorConfig
from regulator.errors import RegulatorConfigError
from virtual_bus.formats.axis import AxisConfig, PositionFeedback
from virtual_bus.formats.errors import TraceFileError
from virtual_bus.formats.trace import Trace, check_time_base, uniform_step

from ..errors import ScenarioError
from ..physics.model import KernelOptions, default_substeps
from ..physics.simulate import References, simulate

#: s, start of the comparison window (the authors' n_border = 50 samples at 1 kHz).
SETTLE_S = 0.049
#: Largest (speed-loop rate x mechanics step) used for scoring (see module docstring).
LOOP_RATE_DT = 0.002
#: Relative tolerance between the trace's sample time and the axis' position cycle.
CYCLE_REL_TOL = 1e-3


def passive_regulator(axis: AxisConfig) -> RegulatorConfig:
    """A disabled speed regulator (ordinary control of Fig. 1) valid for any axis.

    ``simulate(regulator=None)`` builds the detector with n = 4, which section VII's sampling
    rule refuses when kv * position_cycle >= 0.1 (EMPS: 160.18 1/s at 1 ms). Disabled, the
    regulator only fills the ``beta`` column; n = 1 and, if needed, a lower detector kv keep
    it valid without touching the control.
    """
    c = axis.control
    try:
        return RegulatorConfig(kv=c.kv, cycle_s=c.position_cycle, enabled=False)
    except RegulatorConfigError:
        kv = min(c.kv, 0.5 / (4.0 * c.position_cycle))  # max_cycle_s(kv, 1) = 1 / (4 kv)
        return RegulatorConfig(kv=kv, cycle_s=c.position_cycle, n=1, enabled=False)


def replay_substeps(axis: AxisConfig) -> int:
    """Mechanics steps per speed cycle for scoring: at least the kernel's default, and enough
    that (ksp / total inertia) * step <= LOOP_RATE_DT."""
    c = axis.control
    rate_per_s = c.ksp / axis.total_inertia
    return max(default_substeps(axis), math.ceil(rate_per_s * c.speed_cycle / LOOP_RATE_DT))


def check_replay_input(axis: AxisConfig, trace: Trace, source: str = "trace") -> None:
    """Refuse (ScenarioError or TraceFileError naming ``source``) a trace :func:`replay`
    cannot step through: no ``position_reference``, or not one row per position cycle of
    ``axis``."""
    if "position_reference" not in trace:
        raise TraceFileError(
            f"{source}: no column 'position_reference'; a replay in the loop needs the "
            f"interpolator output (columns: {', '.join(trace.names)})",
            column="position_reference",
        )
    cycle = axis.control.position_cycle
    check_time_base(trace, cycle, source)
    step = uniform_step(trace)
    if step is None:
        raise ScenarioError(
            f"{source}: time is not uniformly sampled; replay needs one row per position cycle"
        )
    if abs(step - cycle) > CYCLE_REL_TOL * cycle:
        raise ScenarioError(
            f"{source}: sampled every {step:.4g} s, the axis' control.position_cycle is "
            f"{cycle:g} s; replay needs one trace row per position cycle"
        )


def replay(axis: AxisConfig, trace: Trace, options: KernelOptions | None = None) -> Trace:
    """Simulate ``axis`` in the loop of a recording: same position reference and disturbance,
    starting at rest at the recording's first position. One row per recording row.

    ``options``: None uses :func:`replay_substeps`. Raises ScenarioError (trace sampled at
    another cycle than the axis' position_cycle) or TraceFileError (missing column).
    """
    check_replay_input(axis, trace)
    x_ref = trace["position_reference"]
    dist = trace["disturbance"] if "disturbance" in trace else np.zeros(len(trace))
    refs = References.from_position(x_ref, axis.control.position_cycle, dist)
    if axis.control.position_feedback is PositionFeedback.LOAD and "load_position" in trace:
        start = float(trace["load_position"][0])
    else:
        start = float(trace["motor_position"][0]) / axis.transmission_ratio
    opts = options or KernelOptions(substeps=replay_substeps(axis))
    sim = simulate(axis, refs, passive_regulator(axis), opts, start_position=start)
    return sim.with_columns({"time": trace.time})


@dataclass(frozen=True)
class ForceError:
    """Relative force error (percent) over ``rows`` rows, with the two RMS values (N·m, or N
    for a load-side trace) it is the ratio of."""

    percent: float
    rows: int
    measured_rms: float
    error_rms: float


def _applied_force(trace: Trace) -> np.ndarray:
    """Force over the cycle ending at each row k >= 1: motor_torque[k] + disturbance[k-1]."""
    torque = trace["motor_torque"][1:]
    if "disturbance" in trace:
        return torque + trace["disturbance"][:-1]
    return torque


def compare_force(measured: Trace, simulated: Trace, settle_s: float = SETTLE_S) -> ForceError:
    """The relative force error of two traces of equal length (rows paired by index)."""
    if len(measured) != len(simulated):
        raise ScenarioError(f"traces differ in length: {len(measured)} and {len(simulated)} rows")
    f_meas = _applied_force(measured)
    f_sim = simulated["motor_torque"][1:]
    if "disturbance" in measured:
        f_sim = f_sim + measured["disturbance"][:-1]
    keep = (measured.time[1:] - measured.time[0]) >= settle_s
    if keep.sum() < 2:
        raise ScenarioError(f"no rows left after the first {settle_s} s")
    meas, err = f_meas[keep], (f_meas - f_sim)[keep]
    norm = float(np.linalg.norm(meas))
    if norm == 0.0:
        raise ScenarioError("the measured force is zero throughout; relative error undefined")
    return ForceError(
        percent=100.0 * float(np.linalg.norm(err)) / norm,
        rows=int(keep.sum()),
        measured_rms=norm / math.sqrt(keep.sum()),
        error_rms=float(np.linalg.norm(err)) / math.sqrt(keep.sum()),
    )


def relative_force_error(
    axis: AxisConfig,
    trace: Trace,
    settle_s: float = SETTLE_S,
    options: KernelOptions | None = None,
) -> ForceError:
    """Simulate ``axis`` in the loop of ``trace`` (:func:`replay`) and score the force."""
    return compare_force(trace, replay(axis, trace, options), settle_s)

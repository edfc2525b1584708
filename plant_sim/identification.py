"""Section IX of the paper: identify unknown mechanical parameters from a servo trace.

"Unknown mechanical parameters (load mass moment of inertia, reflected friction torque on
motor) were optimized by Nelder-Mead simplex algorithm. Total number of 1600 points from
experimental servo trace at 2.5 ms sampling time are used" -- result M_l = 6554.2 kg,
tau_f = 1.2 sign(v_l) + 57.3 v_l (N m at the motor).

Here: the axis file supplies everything known (controller, J_m, J_screw, k_r, elasticity);
the unknowns -- by default ``mechanics.load_mass``, ``friction.coulomb`` and
``friction.viscous`` -- are found by :func:`scipy.optimize.minimize` (``method="Nelder-Mead"``)
on the *simulation error*: the axis is simulated in the loop of the recording
(:func:`plant_sim.datasets.force_error.replay`: same position reference and disturbance) and
compared with it, as the paper's Fig. 7 compares axis speed and motor torque::

    J(p) = sum_c ||c_sim(p) - c_meas||^2 / ||c_meas||^2,   c in (motor_torque, motor_speed)

(``motor_speed`` only when the trace has it; rows after ``force_error.SETTLE_S``). The search
runs on p_i / p_i,start (each parameter scaled by its start value; bounded at 0 except the
signed ``SIGNED_KEYS``), so one simplex size fits all parameters.

:func:`section_ix_trace` builds the synthetic 1600-point, 2.5 ms trace the test and
:func:`bench_identify` use (speed steps and reversals of the interpolator, measurement noise),
on :func:`section_ix_axis`: the paper's axis as section IX models it -- elastic (omega_a =
600 rad/s), but without the backlash, which the paper adds only in section X. With the
0.1 mm backlash and the position loop on the load, the axis limit-cycles under these speed
steps (the paper's very subject), and the simulation error then depends on the parameters
too erratically for a simplex search (docs/emps.md).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from virtual_bus.formats.axis import AxisConfig, load_axis
from virtual_bus.formats.errors import AxisFileError
from virtual_bus.formats.trace import Trace
from virtual_bus.shipped import PAPER_AXIS

from .datasets.force_error import SETTLE_S, passive_regulator, replay
from .errors import ScenarioError
from .physics.model import KernelOptions
from .physics.simulate import References, simulate

#: The unknowns of section IX (dotted axis-file keys).
SECTION_IX_PARAMETERS = ("mechanics.load_mass", "friction.coulomb", "friction.viscous")
#: Keys that may take either sign (all others are bounded at 0 from below).
SIGNED_KEYS = frozenset({"disturbance.constant_torque", "disturbance.periodic_phase"})
#: Trace columns compared, in order of preference (motor_torque is required).
COST_CHANNELS = ("motor_torque", "motor_speed")

#: Synthetic section IX trace: 1600 points at 2.5 ms (the paper's numbers).
SECTION_IX_POINTS = 1600
SECTION_IX_CYCLE_S = 0.0025
#: Interpolator speed profile (load units/s) as (start time s, speed): steps and reversals at
#: two speed levels (Coulomb and viscous friction separate only with more than one speed).
SECTION_IX_PROFILE = (
    (0.0, 0.0),
    (0.1, 0.04),
    (1.0, -0.04),
    (1.9, 0.015),
    (2.7, -0.015),
    (3.5, 0.0),
)
#: Relative measurement noise (std / RMS of the channel) of the synthetic trace.
SECTION_IX_NOISE = 0.005
#: Start of the benchmark: every unknown 25 % off its true value (mass high, friction low).
BENCH_START_FACTORS = {
    "mechanics.load_mass": 1.25,
    "friction.coulomb": 0.75,
    "friction.viscous": 0.75,
}


@dataclass(frozen=True)
class IdentifyOptions:
    """Search settings. ``xatol``: simplex size at convergence, relative to the start values;
    ``fatol``: spread of the cost at convergence; ``initial_step``: relative size of the first
    simplex; ``max_evaluations``: simulations at most; ``kernel``: integration options for
    the replay (None: :func:`plant_sim.datasets.force_error.replay_substeps`)."""

    parameters: tuple[str, ...] = SECTION_IX_PARAMETERS
    xatol: float = 2e-4
    fatol: float = 1e-9
    initial_step: float = 0.1
    max_evaluations: int = 600
    kernel: KernelOptions | None = None

    def __post_init__(self) -> None:
        if not self.parameters:
            raise ScenarioError("parameters: at least one axis key to identify")
        if len(set(self.parameters)) != len(self.parameters):
            raise ScenarioError(f"parameters: {list(self.parameters)} has duplicates")
        for name, value, low, high in (
            ("xatol", self.xatol, 0.0, 0.1),
            ("fatol", self.fatol, 0.0, 1.0),
            ("initial_step", self.initial_step, 1e-4, 0.9),
        ):
            if not (math.isfinite(value) and low < value <= high):
                raise ScenarioError(f"{name} = {float(value):g}: allowed range ({low:g}, {high:g}]")
        if not 10 <= self.max_evaluations <= 100_000:
            raise ScenarioError(f"max_evaluations = {self.max_evaluations}: allowed 10..100000")


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of :func:`identify`: the fitted axis, start and identified values, the cost
    at both, the per-channel relative errors (percent) at the optimum, and the effort."""

    axis: AxisConfig
    start: Mapping[str, float]
    values: Mapping[str, float]
    cost_start: float
    cost: float
    channel_errors_percent: Mapping[str, float]
    evaluations: int
    iterations: int
    converged: bool
    message: str
    elapsed_s: float

    def summary(self) -> dict[str, object]:
        """JSON-ready summary."""
        return {
            "parameters": {
                k: {"start": self.start[k], "identified": self.values[k]} for k in self.values
            },
            "cost_start": self.cost_start,
            "cost": self.cost,
            "relative_error_percent": dict(self.channel_errors_percent),
            "evaluations": self.evaluations,
            "iterations": self.iterations,
            "converged": self.converged,
            "message": self.message,
            "elapsed_s": self.elapsed_s,
        }


def _channels(trace: Trace) -> tuple[str, ...]:
    if "motor_torque" not in trace:
        raise ScenarioError("trace has no 'motor_torque' column; identification compares it")
    return tuple(c for c in COST_CHANNELS if c in trace)


def channel_errors(
    measured: Trace, simulated: Trace, settle_s: float = SETTLE_S
) -> dict[str, float]:
    """||sim - meas|| / ||meas|| per compared column, rows after ``settle_s``."""
    keep = (measured.time - measured.time[0]) >= settle_s
    out = {}
    for c in _channels(measured):
        meas = measured[c][keep]
        norm = float(np.linalg.norm(meas))
        if norm == 0.0:
            raise ScenarioError(f"trace column {c!r} is zero throughout; nothing to compare")
        out[c] = float(np.linalg.norm(simulated[c][keep] - meas)) / norm
    return out


def simulation_cost(axis: AxisConfig, trace: Trace, kernel: KernelOptions | None = None) -> float:
    """J of the module docstring for one axis (one closed-loop simulation)."""
    return sum(e * e for e in channel_errors(trace, replay(axis, trace, kernel)).values())


def _start_values(
    axis: AxisConfig, parameters: tuple[str, ...], start: Mapping[str, float] | None
) -> dict[str, float]:
    given = dict(start or {})
    unknown = sorted(set(given) - set(parameters))
    if unknown:
        raise ScenarioError(
            f"start value(s) for {unknown}, which are not identified ({list(parameters)})"
        )
    values = {}
    for key in parameters:
        try:
            value = given[key] if key in given else axis.value(key)
        except AttributeError:
            raise AxisFileError(f"unknown axis key {key!r}", key=key) from None
        signed = key in SIGNED_KEYS
        if value is None or not math.isfinite(value) or value == 0.0 or (value < 0 and not signed):
            allowed = "!= 0" if signed else "> 0"
            shown = "none" if value is None else f"{float(value):g}"
            raise ScenarioError(
                f"{key}: start value {shown}; identification needs a start {allowed} (set it "
                f"in the axis file or give --start {key}=VALUE)"
            )
        values[key] = float(value)
    axis.with_values(values)  # validates the keys and the start values
    return values


def identify(
    trace: Trace,
    axis: AxisConfig,
    start: Mapping[str, float] | None = None,
    options: IdentifyOptions = IdentifyOptions(),
    clock: Callable[[], float] = time.perf_counter,
    on_evaluation: Callable[[], None] | None = None,
) -> IdentificationResult:
    """Section IX: Nelder-Mead on the simulation error (module docstring).

    ``start`` overrides the axis file's values as starting point; ``clock`` measures
    ``elapsed_s`` (injectable); ``on_evaluation`` is called after each simulation (progress).
    Raises ScenarioError / AxisFileError / TraceFileError on bad input.
    """
    keys = options.parameters
    x0 = _start_values(axis, keys, start)
    scale = np.array([x0[k] for k in keys])

    def axis_at(x: np.ndarray) -> AxisConfig:
        return axis.with_values({k: float(v) for k, v in zip(keys, x * scale, strict=True)})

    def cost(x: np.ndarray) -> float:
        if on_evaluation is not None:
            on_evaluation()
        try:
            return simulation_cost(axis_at(x), trace, options.kernel)
        except AxisFileError:
            return math.inf  # outside an axis-file range: not a candidate

    _channels(trace)
    t0 = clock()
    ones = np.ones(len(keys))
    simplex = np.vstack([ones, ones + options.initial_step * np.eye(len(keys))])
    cost_start = cost(ones)
    res = minimize(
        cost,
        ones,
        method="Nelder-Mead",
        bounds=[(None, None) if k in SIGNED_KEYS else (1e-9, None) for k in keys],
        options={
            "initial_simplex": simplex,
            "xatol": options.xatol,
            "fatol": options.fatol,
            "maxfev": options.max_evaluations,
        },
    )
    elapsed = clock() - t0
    fitted = axis_at(res.x)
    values = {k: float(fitted.value(k)) for k in keys}  # type: ignore[arg-type]
    errors = channel_errors(trace, replay(fitted, trace, options.kernel))
    return IdentificationResult(
        axis=fitted,
        start=x0,
        values=values,
        cost_start=cost_start,
        cost=float(res.fun),
        channel_errors_percent={c: 100.0 * e for c, e in errors.items()},
        evaluations=int(res.nfev) + 1,
        iterations=int(res.nit),
        converged=bool(res.success),
        message=str(res.message),
        elapsed_s=elapsed,
    )


# --------------------------------------------------------------------------------------------
# the synthetic section IX trace and the benchmark
# --------------------------------------------------------------------------------------------
def section_ix_axis(path: str | Path = PAPER_AXIS) -> AxisConfig:
    """The paper's axis as section IX models it: position cycle 2.5 ms, no backlash."""
    return load_axis(path).with_values(
        {"control.position_cycle": SECTION_IX_CYCLE_S, "mechanics.backlash": None}
    )


def section_ix_references(
    cycle_s: float = SECTION_IX_CYCLE_S, points: int = SECTION_IX_POINTS
) -> References:
    """Interpolator output of :data:`SECTION_IX_PROFILE`, one value per position cycle."""
    t = np.arange(points) * cycle_s
    speed = np.zeros(points)
    for start_s, value in SECTION_IX_PROFILE:
        speed[t >= start_s] = value
    position = np.concatenate([[0.0], np.cumsum(speed[:-1]) * cycle_s])
    return References(position, speed, np.zeros(points))


def section_ix_trace(
    axis: AxisConfig,
    noise: float = SECTION_IX_NOISE,
    seed: int = 0,
    kernel: KernelOptions = KernelOptions(),
) -> Trace:
    """A servo trace of ``axis`` under :func:`section_ix_references` at the axis' position
    cycle, with Gaussian noise of ``noise`` x RMS on motor_torque and motor_speed."""
    refs = section_ix_references(axis.control.position_cycle)
    sim = simulate(axis, refs, passive_regulator(axis), kernel)
    rng = np.random.default_rng(seed)
    noisy = {}
    for c in COST_CHANNELS:
        rms = float(np.sqrt(np.mean(sim[c] ** 2)))
        noisy[c] = sim[c] + noise * rms * rng.standard_normal(len(sim))
    return sim.with_columns(noisy)


@dataclass(frozen=True)
class IdentifyBench:
    """Timing of the section IX identification (:func:`bench_identify`)."""

    elapsed_s: float
    evaluations: int
    seconds_per_simulation: float
    relative_errors: Mapping[str, float] = field(default_factory=dict)

    def __str__(self) -> str:
        errors = ", ".join(f"{k} {100 * v:+.2f} %" for k, v in self.relative_errors.items())
        return (
            f"{self.elapsed_s:.3g} s ({self.evaluations} simulations, "
            f"{1e3 * self.seconds_per_simulation:.3g} ms each; {errors})"
        )


def bench_identify(
    axis_path: str | Path = PAPER_AXIS, clock: Callable[[], float] = time.perf_counter
) -> IdentifyBench:
    """Section IX on :func:`section_ix_axis`: 1600-point synthetic trace at 2.5 ms, start
    25 % off (:data:`BENCH_START_FACTORS`), the kernel's default integration step for data and
    model (the same step for both, so the step does not bias the fit)."""
    axis = section_ix_axis(axis_path)
    trace = section_ix_trace(axis)
    options = IdentifyOptions(kernel=KernelOptions())
    simulation_cost(axis, trace, options.kernel)  # compile outside the timing
    start = {k: f * float(axis.value(k)) for k, f in BENCH_START_FACTORS.items()}  # type: ignore[arg-type]
    result = identify(trace, axis, start, options, clock)
    return IdentifyBench(
        elapsed_s=result.elapsed_s,
        evaluations=result.evaluations,
        seconds_per_simulation=result.elapsed_s / result.evaluations,
        relative_errors={
            k: v / float(axis.value(k)) - 1.0  # type: ignore[arg-type]
            for k, v in result.values.items()
        },
    )

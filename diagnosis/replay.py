"""Replay an axis file like a recording: the closed loop of Fig. 1 driven by the recording.

The diagnosis compares a model with a recording by *simulation* (output error), never by
one-step prediction: the whole cascade of the axis file (P position controller, PI/P speed
controller, current loop, dead time, mechanics) runs in the compiled kernel of
:mod:`plant_sim.physics.kernel`, driven only by what the recording says was commanded — its
``position_reference`` and, when present, its ``disturbance`` column — on the recording's own
time base. Why closed-loop replay and not the mechanics driven by the recorded torque:
``docs/diagnosis.md`` ("Closed-loop replay").

Time bases. The kernel samples the position loop at ``control.position_cycle`` (and the speed
loop at ``control.speed_cycle``); a recording may use any, even non-uniform, sample time. The
reference is resampled onto the position-cycle grid with a cubic spline (a linear interpolation
of a 2 ms trace of a 2 m/s² move is off by a·h²/8 = 1 µm, as large as the effects looked for)
and the disturbance by sample-and-hold; the simulated outputs go back onto the recording's
sample times by linear interpolation (exact where a sample time is a whole number of position
cycles).

Start. The simulated axis starts at rest at the recorded feedback position (averaged over the
first samples while the reference rests) with the PI integral empty. The other measuring
system's zero is a nuisance parameter: a motor encoder and a linear scale have unrelated zeros
on a real machine, so the simulated one is shifted by the median difference to the recording.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from plant_sim.physics.model import KernelOptions
from plant_sim.physics.simulate import References, simulate, simulate_plant
from regulator.loop import SteppedAxis
from virtual_bus.formats.axis import AxisConfig, PositionFeedback
from virtual_bus.formats.errors import TraceWarning
from virtual_bus.formats.trace import Trace, check_time_base

from .errors import DiagnosisInputError

#: Signals the diagnosis compares, as trace columns. Positions are scored on their following
#: error (position_reference - position), see :func:`compared_quantity`.
SIGNALS = ("motor_position", "load_position", "motor_speed", "motor_torque")

#: Simulated columns that replace the recording's in a replayed trace.
SIMULATED_COLUMNS = (
    "speed_setpoint",
    "motor_position",
    "motor_speed",
    "load_position",
    "motor_torque",
    "beta",
    "lambda",
)

DEFAULT_OPTIONS = KernelOptions()

#: Most samples over which the starting position is averaged (while the reference rests).
ALIGN_SAMPLES = 10
#: Largest relative difference between the recorded motor/reference travel ratio and k_r.
RATIO_TOLERANCE = 0.2
#: When a soft loop lags its reference (travel ratio below k_r by more than RATIO_TOLERANCE):
#: largest factor between the recorded ratio and the axis file's own replayed ratio. A unit
#: mistake is a factor >= 2*pi (rev/rad, rpm, deg, mm); a nominal model that is off is not.
SOFT_LOOP_FACTOR = 2.0


@dataclass(frozen=True)
class ReplayInput:
    """A recording prepared for closed-loop replay of axes with one control configuration.

    time_s: recording sample times (s); references: per position cycle from time_s[0];
    start_position: load units, where the simulated axis starts at rest; recorded: the
    recording's columns (all of them, kept for writing simulated traces with the same columns).
    """

    time_s: np.ndarray
    cycle_s: float
    transmission_ratio: float
    feedback: PositionFeedback
    references: References
    start_position: float
    signals: tuple[str, ...]
    recorded: Mapping[str, np.ndarray]

    @property
    def n_samples(self) -> int:
        return len(self.time_s)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    def compared(self, signal: str) -> np.ndarray:
        """The recorded quantity that ``signal`` is scored on (see :func:`compared_quantity`)."""
        return compared_quantity(self, signal, self.recorded[signal])


def compared_quantity(inp: ReplayInput, signal: str, values: np.ndarray) -> np.ndarray:
    """What a signal is scored on: following error for positions (k_r·x_ref − θ_m in rad for
    the motor, x_ref − x_l in load units for the load), the value itself for speed and torque.
    A position itself would score ~100 % for any model that follows its reference."""
    ref = inp.recorded["position_reference"]
    if signal == "motor_position":
        return inp.transmission_ratio * ref - values
    if signal == "load_position":
        return ref - values
    return values


def _fail_ratio(
    name: str, ratio: float, expected: float, what: str, simulated: float | None = None
) -> DiagnosisInputError:
    model = "" if simulated is None else f", its closed loop replayed travels {simulated:.6g}"
    soft = "" if simulated is None else f", or of the replay within a factor {SOFT_LOOP_FACTOR:g}"
    return DiagnosisInputError(
        f"recording column {name!r} travels {ratio:.6g} {what} per load unit of "
        f"position_reference, the axis file says {expected:.6g}{model} "
        f"(allowed within {RATIO_TOLERANCE:.0%}{soft}); the axis file and the recording do not fit "
        "together (transmission_ratio or units; or the axis sticks or lags far more than its "
        "loop in the axis file does: a friction or load it lacks that the loop cannot "
        "overcome — diagnose a recording in which the axis follows its reference)",
        column=name,
        key="axis.transmission_ratio" if name == "motor_position" else None,
    )


def _travel_ratio(position: np.ndarray, reference: np.ndarray) -> float | None:
    """Least-squares slope of a position against the reference, None if the reference rests."""
    ref = reference - reference.mean()
    denom = float(ref @ ref)
    if denom <= 0.0 or np.ptp(reference) <= 0.0:
        return None
    return float(ref @ (position - position.mean())) / denom


def check_units(trace: Trace, source: str = "recording") -> None:
    """Warn (never rescale) when motor_speed does not look like the derivative of
    motor_position in rad/s (rpm, or a speed in load units)."""
    if "motor_speed" not in trace or len(trace) < 3:
        return
    derivative = np.gradient(trace["motor_position"], trace.time)
    denom = float(derivative @ derivative)
    if denom <= 0.0:
        return
    slope = float(derivative @ trace["motor_speed"]) / denom
    if abs(slope - 1.0) > 0.3:
        hint = " (rpm instead of rad/s?)" if abs(slope - 60.0 / (2.0 * math.pi)) < 1.0 else ""
        warnings.warn(
            f"{source}: column 'motor_speed' is {slope:.3g} times the derivative of "
            f"'motor_position'; expected rad/s at the motor{hint}; used as it is",
            TraceWarning,
            stacklevel=2,
        )


def prepare_replay(trace: Trace, axis: AxisConfig, source: str = "recording") -> ReplayInput:
    """Check that ``trace`` and ``axis`` fit together and resample the commanded inputs.

    Raises DiagnosisInputError when the recording lacks position_reference (closed-loop replay
    needs it), lacks the feedback column the axis closes its loop on, or moves its motor by a
    ratio to the reference that contradicts ``axis.transmission_ratio``; TraceFileError when
    the time column cannot be seconds for this axis (:func:`check_time_base`: a replay of
    years is refused before it starts, whoever calls).
    """
    check_time_base(trace, axis.control.position_cycle, source)
    if "position_reference" not in trace:
        raise DiagnosisInputError(
            f"{source}: no column 'position_reference'; closed-loop replay of the axis file "
            "needs the interpolator output (columns: " + ", ".join(trace.names) + ")",
            column="position_reference",
        )
    feedback = axis.control.position_feedback
    if feedback is PositionFeedback.LOAD and "load_position" not in trace:
        raise DiagnosisInputError(
            f"{source}: the axis file closes the position loop on the load (control."
            f'position_feedback = "load") but the recording has no load_position column; '
            f'use position_feedback = "motor" or a recording with load_position',
            column="load_position",
            key="control.position_feedback",
        )
    kr = axis.transmission_ratio
    ref = trace["position_reference"]
    # (column, recorded travel per reference travel, what a stiff loop travels, unit)
    off_ratio = []
    for name, expected, unit in (("motor_position", kr, "rad"), ("load_position", 1.0, "")):
        ratio = _travel_ratio(trace[name], ref) if name in trace else None
        if ratio is not None and abs(ratio / expected - 1.0) > RATIO_TOLERANCE:
            off_ratio.append((name, ratio, expected, unit or "load units"))
    check_units(trace, source)
    cycle = axis.control.position_cycle
    time = trace.time
    dt_median = float(np.median(np.diff(time)))
    if dt_median > 10.0 * cycle:
        warnings.warn(
            f"{source}: sample time {dt_median:g} s is more than 10 position cycles "
            f"({cycle:g} s); the reference between samples is a spline guess",
            TraceWarning,
            stacklevel=2,
        )
    n_cycles = math.floor((time[-1] - time[0]) / cycle + 1e-9) + 2
    grid = time[0] + np.arange(n_cycles) * cycle
    position = CubicSpline(time, ref)(grid)
    if "disturbance" in trace:
        # sample and hold: a recorded value holds until the next sample (a step between two
        # samples lands on the later one, as a drive's trace records it)
        idx = np.clip(
            np.searchsorted(time, grid + 1e-9 * cycle, side="right") - 1, 0, len(time) - 1
        )
        dist = trace["disturbance"][idx]
    else:
        dist = np.zeros(n_cycles)
    refs = References.from_position(position, cycle, dist)
    fb = (
        trace["load_position"]
        if feedback is PositionFeedback.LOAD
        else trace["motor_position"] / kr
    )
    # at rest before the reference moves: average the first samples (measurement noise)
    still = np.nonzero(np.abs(ref[:ALIGN_SAMPLES] - ref[0]) > 0.0)[0]
    m = int(still[0]) if len(still) else min(ALIGN_SAMPLES, len(fb))
    start = float(np.median(fb[:m])) if m >= 2 else float(fb[0])
    signals = tuple(s for s in SIGNALS if s in trace)
    inp = ReplayInput(
        time_s=time.copy(),
        cycle_s=cycle,
        transmission_ratio=kr,
        feedback=feedback,
        references=refs,
        start_position=start,
        signals=signals,
        recorded={name: trace[name].copy() for name in trace.names},
    )
    if off_ratio:
        _check_soft_loop(axis, inp, off_ratio)
    return inp


def _check_soft_loop(
    axis: AxisConfig, inp: ReplayInput, off_ratio: Sequence[tuple[str, float, float, str]]
) -> None:
    """A travel ratio off by more than RATIO_TOLERANCE is a unit or transmission-ratio error
    for a stiff position loop, but a soft loop under load (a hobby servo lifting a pendulum)
    lags its reference by design. Accept it when the axis file's own closed loop, replayed
    like the recording, lags too (its ratio is off k_r by more than RATIO_TOLERANCE as well)
    and travels a ratio within SOFT_LOOP_FACTOR of the recorded one (the nominal model may
    well be off; a unit mistake is a larger factor); else refuse. A model that follows its
    reference stiffly never excuses a recording that does not."""
    simulated = replay(axis, inp, columns=("motor_position", "load_position"))
    ref = inp.recorded["position_reference"]
    for name, ratio, expected, unit in off_ratio:
        model = _travel_ratio(simulated[name], ref)
        if (
            model is None
            or not np.isfinite(model)
            or model == 0.0  # the model does not move at all: no soft loop excuses that
            or abs(model / expected - 1.0) <= RATIO_TOLERANCE
            or not 1.0 / SOFT_LOOP_FACTOR <= ratio / model <= SOFT_LOOP_FACTOR
        ):
            raise _fail_ratio(name, ratio, expected, unit, model)


def _check_compatible(axis: AxisConfig, inp: ReplayInput) -> None:
    if axis.control.position_cycle != inp.cycle_s or axis.transmission_ratio != (
        inp.transmission_ratio
    ):
        raise DiagnosisInputError(
            "replay input was prepared for another position cycle or transmission ratio; "
            "call prepare_replay again"
        )


def replay(
    axis: AxisConfig,
    inp: ReplayInput,
    options: KernelOptions = DEFAULT_OPTIONS,
    columns: Sequence[str] = SIMULATED_COLUMNS,
    plant: Callable[[float], SteppedAxis] | None = None,
) -> Trace:
    """Simulate ``axis`` in closed loop like the recording of ``inp``.

    Returns the simulated ``columns`` (default :data:`SIMULATED_COLUMNS`) plus ``time`` (the
    recording's sample times), ``position_reference`` and ``disturbance`` (the inputs, as
    recorded). Non-finite outputs (an unstable parameter set) are kept as they are.
    ``plant``: a plant other than the kernel's (an FMU's) at rest at a start position, made by
    ``plant(start)``; ``axis`` is then the controller around it (k_r, k_v, the feedback).
    """
    _check_compatible(axis, inp)
    if plant is not None:
        with contextlib.closing(plant(inp.start_position)) as p:  # type: ignore[type-var]
            sim = simulate_plant(p, axis, inp.references, None, options.setpoint_delay_cycles)
    else:
        sim = simulate(axis, inp.references, None, options, start_position=inp.start_position)
    rel = inp.time_s - inp.time_s[0]
    grid = np.arange(len(sim)) * inp.cycle_s
    out: dict[str, np.ndarray] = {"time": inp.time_s.copy()}
    for name in columns:
        out[name] = np.interp(rel, grid, sim[name])
    aligned = "motor_position" if inp.feedback is PositionFeedback.LOAD else "load_position"
    if aligned in inp.recorded and aligned in out:
        offset = np.median(inp.recorded[aligned] - out[aligned])
        out[aligned] = out[aligned] + (float(offset) if np.isfinite(offset) else 0.0)
    out["position_reference"] = inp.recorded["position_reference"].copy()
    if "disturbance" in inp.recorded:
        out["disturbance"] = inp.recorded["disturbance"].copy()
    return Trace(out)


def like_recording(inp: ReplayInput, simulated: Trace) -> Trace:
    """The simulated trace with exactly the recording's columns and time base: simulated
    values where the simulation produces the column, the recording's values for its inputs
    (position_reference, disturbance) and for columns the simulation does not produce."""
    cols = {name: simulated.columns.get(name, values) for name, values in inp.recorded.items()}
    return Trace(cols)


def simulate_like(
    axis: AxisConfig, recording: Trace, options: KernelOptions = DEFAULT_OPTIONS
) -> Trace:
    """``python -m diagnosis simulate --like``: the axis's closed loop driven by the
    recording's position_reference (and disturbance), with the recording's columns and times."""
    inp = prepare_replay(recording, axis)
    return like_recording(inp, replay(axis, inp, options))

"""Effects of the control path, tested through the loop: a dead time between the speed
controller and the torque, a set point applied late (bus, drive input stage), readings taken
late, a torque limit, and (with one measuring system, where no
deflection is measured) free play.

These act on the relation between the commanded and the measured signals, not on the torque
balance (the recorded torque is the torque that acted, after the dead time and the limit),
and the drive's speed controller cannot be rebuilt from samples taken once per position
cycle (the set point steps at every cycle and the speed loop answers within it). So the
regressor of such an effect is its *signature in the closed loop*: the change of the replay
(:mod:`.replay`) of the current model when the effect is added at a value of a scan (dead
times of whole speed cycles, torque limits at the top quantiles of the recorded torque), a
scan of time shifts between set point and torque. The test regresses the recording's
residual against the current model on that signature, linear in its gain (1: the effect at
that value), with the signatures of the model's own uncertain parameters as base regressors
(the load mass, whose estimate a dead time biases, the friction, the elastic element), on
the torque, the speed and the following error, each pre-whitened by its own residual's AR
filter and scaled by its whitened noise, with the null of :mod:`.randomization`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np

from plant_sim.errors import ScenarioError
from plant_sim.physics.kernel import MAX_DELAY
from plant_sim.physics.model import KernelOptions, default_substeps
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.errors import AxisFileError

from .effects import RATE_KEY, Effect
from .parameters import UNCERTAIN_KEYS
from .randomization import Whitener, face_value_test, fit_whitener, time_blocks
from .regression import EffectTest
from .replay import ReplayInput, compared_quantity, replay

NAME = "closed loop"
#: Dead times tried, in speed cycles.
DELAY_CYCLES = (1, 2, 3, 4, 6, 8, 12, 16)
#: Set-point and reading dead times tried, in speed cycles (continuous in the kernel: linear
#: interpolation between the speed cycles' history; 0.25-4 ms at 125 µs).
LATE_CYCLES = (2, 4, 8, 16, 32)
#: Torque limits tried, as percentiles of the recorded |torque|.
LIMIT_PERCENTILES = (99.0, 99.8, 100.0)
#: Free play tried (one measuring system), as multiples of the following error's spread.
BACKLASH_FRACTIONS = (0.02, 0.1, 0.5)
#: Relative step of the base sensitivities.
BASE_STEP = {
    "mechanics.load_mass": 0.05,
    "mechanics.antiresonance": 0.05,
    "mechanics.damping_ratio": 0.3,
}
GAIN_KEY = "gain"
#: Substeps of the loop tests' replays, times the kernel's default for the model.
REFINE = 2
#: A signature larger than this many noise σ somewhere is a variant that destabilised the loop.
UNSTABLE = 1e8


@dataclass(frozen=True)
class LoopCandidate:
    """One loop effect's scan: the variants of the model, the scanned value of each (``key``)
    and, where a variant sets more than ``key``, the axis values it sets (the estimate)."""

    effect: Effect
    key: str
    values: tuple[float, ...]
    variants: tuple[AxisConfig, ...]
    settings: tuple[dict[str, float], ...] = ()

    def estimate(self, i: int) -> dict[str, float]:
        return dict(self.settings[i]) if self.settings else {self.key: float(self.values[i])}


def _signals(inp: ReplayInput) -> tuple[str, ...]:
    fb = "load_position" if inp.feedback.value == "load" else "motor_position"
    return tuple(s for s in ("motor_torque", "motor_speed", fb) if s in inp.signals)


def loop_candidates(
    model: AxisConfig,
    inp: ReplayInput,
    effects: frozenset[Effect],
    one_system: bool,
    following_error: float,
    contact: Callable[[AxisConfig], AxisConfig | None],
) -> list[LoopCandidate]:
    """The variants of ``model`` each loop effect in ``effects`` is scanned over; ``contact``
    gives the model a contact stiffness for free play (None where it cannot have one)."""
    out = []
    c = model.control
    if Effect.TIME_DELAY in effects:
        vals = tuple(
            n * c.speed_cycle for n in DELAY_CYCLES if n <= MAX_DELAY and n * c.speed_cycle <= 0.1
        )
        if vals:
            out.append(
                LoopCandidate(
                    Effect.TIME_DELAY,
                    "control.delay",
                    vals,
                    tuple(model.with_values({"control.delay": v}) for v in vals),
                )
            )
    if Effect.SETPOINT_DELAY in effects:
        out += _setpoint_delay(model, inp.duration_s)
    if Effect.MEASUREMENT_DELAY in effects:
        key = "control.measurement_delay"
        vals = tuple(n * c.speed_cycle for n in LATE_CYCLES if n * c.speed_cycle <= 0.05)
        if vals:
            out.append(
                LoopCandidate(
                    Effect.MEASUREMENT_DELAY,
                    key,
                    vals,
                    tuple(model.with_values({key: v}) for v in vals),
                )
            )
    if Effect.TORQUE_SATURATION in effects:
        tau = np.abs(inp.recorded["motor_torque"])
        vals = tuple(
            sorted(
                {
                    float(np.percentile(tau, q))
                    for q in LIMIT_PERCENTILES
                    if np.percentile(tau, q) > 0
                }
            )
        )
        if vals:
            out.append(
                LoopCandidate(
                    Effect.TORQUE_SATURATION,
                    "control.torque_limit",
                    vals,
                    tuple(model.with_values({"control.torque_limit": v}) for v in vals),
                )
            )
    if Effect.BACKLASH in effects and one_system:
        on = contact(model)
        if on is not None:
            vals = tuple(f * following_error for f in BACKLASH_FRACTIONS)
            vals = tuple(v for v in vals if 0.0 < v <= 0.1)
            if vals:
                out.append(
                    LoopCandidate(
                        Effect.BACKLASH,
                        "mechanics.backlash",
                        vals,
                        tuple(on.with_values({"mechanics.backlash": v}) for v in vals),
                    )
                )
    return out


def _setpoint_delay(model: AxisConfig, duration_s: float) -> list[LoopCandidate]:
    """The set point applied late: constant dead times of :data:`LATE_CYCLES` speed cycles,
    and dead times growing from none to as much at the recording's end (a bus whose jitter
    grows, a drive's input stage filling up: a constant one misses such a delay, which is
    short in the first half of the run and long in the second)."""
    cyc = model.control.speed_cycle
    ends = [n * cyc for n in LATE_CYCLES if n * cyc <= 0.1]
    settings = [{"control.setpoint_delay": d, RATE_KEY: 0.0} for d in ends]
    if duration_s > 0.0:
        settings += [
            {"control.setpoint_delay": 0.0, RATE_KEY: d / duration_s}
            for d in ends
            if d / duration_s <= 0.01
        ]
    variants, kept = [], []
    for v in settings:
        try:
            variants.append(model.with_values(v))
        except AxisFileError:
            continue
        kept.append(v)
    if not variants:
        return []
    values = tuple(v["control.setpoint_delay"] + v[RATE_KEY] * duration_s for v in kept)
    return [
        LoopCandidate(
            Effect.SETPOINT_DELAY,
            "control.setpoint_delay",
            values,
            tuple(variants),
            tuple(kept),
        )
    ]


def refined(model: AxisConfig, options: KernelOptions) -> KernelOptions:
    """``options`` with REFINE times its substeps (the model's default when it has none)."""
    base = options.substeps or default_substeps(model)
    return KernelOptions(
        substeps=REFINE * base, setpoint_delay_cycles=options.setpoint_delay_cycles
    )


def _base_variants(model: AxisConfig) -> list[tuple[str, AxisConfig]]:
    """The model with each of its uncertain parameters moved (BASE_STEP, 5 % else): their
    signatures are the base regressors, so that what is left of a parameter's error after the
    torque balance's estimate (a Coulomb level a few per cent off changes every reversal) is
    not taken for a dead time."""
    out = []
    for key in UNCERTAIN_KEYS:
        v = model.value(key)
        if v is None or v == 0.0 or key in ("friction.creep_speed", "disturbance.periodic_period"):
            continue
        step = BASE_STEP.get(key, 0.05)
        try:
            out.append((key, model.with_values({key: float(v) * (1.0 + step)})))
        except AxisFileError:
            continue
    return out


def loop_tests(
    inp: ReplayInput,
    model: AxisConfig,
    options: KernelOptions,
    candidates: Sequence[LoopCandidate],
    rng: np.random.Generator,
    pool: Executor | None = None,
) -> tuple[dict[Effect, EffectTest], int]:
    """Test every loop candidate against the replay of ``model``; also the number of replays
    it took. The replays here take REFINE times the substeps of ``options``: the residual is
    the recording less the model itself, and a stick-slip decision taken a substep early or
    late (set-valued friction decides at substep instants) makes a signature like a dead
    time of a fraction of a speed cycle (on the test set's slide, at the default substep
    of one speed cycle, a dead-time test at p < 0.001 on 4 of 30 recordings with nothing
    left out; at two substeps none)."""
    if not candidates:
        return {}, 0
    signals = _signals(inp)
    options = refined(model, options)
    base_sim = replay(model, inp, options, signals)
    resid = {s: inp.compared(s) - compared_quantity(inp, s, base_sim[s]) for s in signals}  # type: ignore[index]
    ok = {s: np.isfinite(r) for s, r in resid.items()}
    whiten: dict[str, Whitener] = {
        s: fit_whitener(np.where(ok[s], r, 0.0), ok[s]) for s, r in resid.items()
    }
    scale: dict[str, float] = {}
    for s, r in resid.items():
        rw = whiten[s].apply(np.where(ok[s], r, 0.0))
        sd = float(np.std(rw[whiten[s].order :]))
        scale[s] = sd if sd > 0.0 else 1.0
    order = max(w.order for w in whiten.values())
    n = inp.n_samples
    valid = np.ones(n, dtype=bool)
    valid[:order] = False
    for s in signals:
        valid &= whiten[s].valid(ok[s])

    def stacked(values: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([whiten[s].apply(values[s]) / scale[s] for s in signals])

    y = stacked({s: np.where(ok[s], resid[s], 0.0) for s in signals})
    blocks_t, _ = time_blocks(valid, y[:n])
    blocks = np.tile(blocks_t, len(signals))

    def sensitivity(axis: AxisConfig) -> np.ndarray | None:
        try:
            sim = replay(axis, inp, options, signals)
        except (ScenarioError, AxisFileError):
            return None
        diff = {
            s: compared_quantity(inp, s, sim[s]) - compared_quantity(inp, s, base_sim[s])
            for s in signals
        }  # type: ignore[index]
        if not all(np.all(np.isfinite(d)) for d in diff.values()):
            return None
        z = stacked(diff)
        # a variant that made the loop unstable (a long dead time) grows without bound
        return z if float(np.max(np.abs(z))) < UNSTABLE else None

    jobs: list[AxisConfig] = [a for _, a in _base_variants(model)]
    for cand in candidates:
        jobs += list(cand.variants)
    results = (
        list(pool.map(sensitivity, jobs)) if pool is not None else [sensitivity(a) for a in jobs]
    )
    n_base = len(_base_variants(model))
    base_cols = [z for z in results[:n_base] if z is not None and np.any(z)]
    base = np.column_stack(base_cols) if base_cols else np.zeros((len(y), 0))
    out: dict[Effect, EffectTest] = {}
    i = n_base
    for cand in candidates:
        zs = results[i : i + len(cand.variants)]
        i += len(cand.variants)
        usable = [(j, z) for j, z in enumerate(zs) if z is not None and np.any(z)]
        if not usable:
            continue
        result = face_value_test(y, base, [z for _, z in usable], blocks, rng)
        gain = float(result.coefficients[0]) if len(result.coefficients) else 0.0
        est = {**cand.estimate(usable[result.best][0]), GAIN_KEY: gain}
        out[cand.effect] = EffectTest(cand.effect, NAME, result, est, {})
    return out, len(jobs) + 1

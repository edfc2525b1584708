"""The physical effects of the axis-file table as objects: one class per effect knows its
axis-file keys, when a model has it, how to take it out of an axis, how to add it to a model
(its free parameters, their bounds and data-derived starting values), when a fitted value is
"absent" after all, and how to describe it with the axis's units.

Names and keys are the table of ``docs/axis-file.md`` plus ``sensor_time_offset``
(``control.sensor_time_offset``, docs/diagnosis.md). An effect is *in* a model when one of its
keys is present; the diagnosis (:mod:`.engine`) loops over :data:`MODELS` and tries every
effect the model lacks. Bounds come from :func:`.parameters.parameter_for`; :mod:`.fit` only
searches.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

import numpy as np

from virtual_bus.formats.axis import AxisConfig

from ..physics.kernel import MAX_DELAY
from .evidence import DataScales, Evidence, direction_offset, inverse_dynamics, periodic_peaks
from .fit import PERIODIC_COS, PERIODIC_SIN, DiscreteParameter, FitSpec, Parameter
from .parameters import (
    CONTACT_DAMPING,
    contact_antiresonance,
    format_value,
    max_antiresonance,
    options_for,
    parameter_for,
    rounded,
    speed_loop_bandwidth,
)
from .replay import replay


class Effect(Enum):
    """Physical effects a model can leave out (axis-file.md, "Names of physical effects")."""

    BACKLASH = "backlash"
    COMPLIANCE = "compliance"
    COULOMB_FRICTION = "coulomb_friction"
    VISCOUS_FRICTION = "viscous_friction"
    ASYMMETRIC_FRICTION = "asymmetric_friction"
    STRIBECK_FRICTION = "stribeck_friction"
    CONSTANT_LOAD_TORQUE = "constant_load_torque"
    PERIODIC_DISTURBANCE = "periodic_disturbance"
    TORQUE_SATURATION = "torque_saturation"
    TIME_DELAY = "time_delay"
    SENSOR_TIME_OFFSET = "sensor_time_offset"


@dataclass(frozen=True)
class Candidate:
    """How to add an effect to a model: alternative fit specifications (the best wins) and
    notes for the report (a stiff contact added with it, why it was not tried)."""

    specs: list[FitSpec]
    notes: list[str] = field(default_factory=list)


def _spec(
    on: AxisConfig,
    params: Sequence[Parameter],
    starts: Sequence[Mapping[str, float]] = (),
    n_global: int = 4,
    discrete: DiscreteParameter | None = None,
) -> FitSpec:
    wa = next((p.high for p in params if p.key == "mechanics.antiresonance"), None)
    return FitSpec(
        base=on,
        parameters=tuple(params),
        extra_starts=tuple(starts),
        discrete=discrete,
        options=options_for(wa if wa is not None else on.mechanics.antiresonance, on),
        n_global=n_global if params else 0,
    )


class EffectModel:
    """One effect of the table. Subclasses set the class attributes and :meth:`candidate`."""

    effect: ClassVar[Effect]
    keys: ClassVar[tuple[str, ...]]
    description: ClassVar[str]
    #: keys re-fitted with the model's uncertain parameters once the diagnosis added the
    #: effect (control keys are machine data otherwise)
    refit_keys: ClassVar[tuple[str, ...]] = ()

    def present(self, axis: AxisConfig) -> bool:
        """The model has the effect: one of its keys is present (0 included)."""
        return any(axis.value(k) is not None for k in self.keys)

    def strip(self, axis: AxisConfig) -> AxisConfig:
        """``axis`` without the effect (its keys absent)."""
        return axis.with_values(dict.fromkeys(self.keys))

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        """False when the fitted effect sits at its "absent" value (zero backlash, zero load
        torque, ...): a held-out gain then came from the re-fitted model parameters, not from
        the effect. Thresholds: 0.1 % of the recording's peak torque."""
        return True

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        raise NotImplementedError

    def fixed_after_naming(self, before: AxisConfig) -> tuple[str, ...]:
        """Keys the candidate added without fitting them (held fixed afterwards)."""
        return ()

    def describe(self, axis: AxisConfig) -> str:
        """'mechanics.backlash = 0.00028 m' for the keys ``axis`` has."""
        vals = [
            f"{k} = {format_value(k, float(v), axis)}"
            for k in self.keys
            if (v := axis.value(k)) is not None
        ]
        return ", ".join(vals)


def _tiny(scales: DataScales) -> float:
    return 1e-3 * scales.torque_peak


class Backlash(EffectModel):
    effect = Effect.BACKLASH
    keys = ("mechanics.backlash",)
    description = "free play between motor and load (the motor crosses a gap at reversals)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.mechanics.backlash or 0.0) > 1e-3 * scales.following_error

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Backlash on a rigid model needs a contact stiffness: a stiff antiresonance (ten
        times the speed-loop bandwidth, damping 0.1) is added with it and not fitted."""
        sc, rec, sim = ev.scales, ev.inp.recorded, ev.simulated
        notes: list[str] = []
        on = model
        if model.is_rigid:
            wa = contact_antiresonance(model)
            on = model.with_values(
                {"mechanics.antiresonance": wa, "mechanics.damping_ratio": CONTACT_DAMPING}
            )
            notes.append(
                f"backlash needs a contact stiffness: a stiff mechanics.antiresonance = "
                f"{rounded(wa)!r} rad/s (ten times the speed-loop bandwidth) with "
                f"damping_ratio = {CONTACT_DAMPING} was added with it and not fitted"
            )
        guesses = [0.002 * sc.following_error, 0.02 * sc.following_error]
        if "motor_position" in rec and "load_position" in rec:
            kr = model.transmission_ratio
            defl_rec = rec["motor_position"] / kr - rec["load_position"]
            defl_sim = sim["motor_position"] / kr - sim["load_position"]
            d = direction_offset(defl_rec - defl_sim, sc.speed, sc.speed_max)
            if d is not None and d > 0.0:
                guesses.insert(0, d)
        b = parameter_for("mechanics.backlash", guesses[0], sc, nominal, on)
        starts = [{"mechanics.backlash": g} for g in guesses[1:]]
        return Candidate([_spec(on, [b], starts, n_global)], notes)

    def fixed_after_naming(self, before: AxisConfig) -> tuple[str, ...]:
        if before.is_rigid:
            return ("mechanics.antiresonance", "mechanics.damping_ratio")
        return ()


class Compliance(EffectModel):
    effect = Effect.COMPLIANCE
    keys = ("mechanics.antiresonance", "mechanics.damping_ratio")
    description = "an elastic transmission (motor and load positions differ with the force)"

    def strip(self, axis: AxisConfig) -> AxisConfig:
        # backlash needs the contact stiffness of the elastic element: it goes with it
        return axis.with_values({**dict.fromkeys(self.keys), "mechanics.backlash": None})

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Starts: 1.5 and 4 times the speed-loop bandwidth, and the stiffness from the
        deflection against the transmitted force when both positions are recorded."""
        sc, rec = ev.scales, ev.inp.recorded
        kr = model.transmission_ratio
        wmax = max_antiresonance(model)
        bw = speed_loop_bandwidth(model)
        guesses = [min(wmax, f * bw) for f in (1.5, 4.0)]
        if "motor_position" in rec and "load_position" in rec:
            defl = rec["motor_position"] / kr - rec["load_position"]
            force = kr * (rec["motor_torque"] - model.motor_side_inertia * kr * sc.accel)
            f0 = force - force.mean()
            denom = float(f0 @ f0)
            slope = float(f0 @ (defl - defl.mean())) / denom if denom > 0 else 0.0
            if slope > 0.0:
                wa = math.sqrt(1.0 / slope / model.mechanics.load_mass)
                guesses.insert(0, min(wmax * 0.99, max(wa, 2.0 * model.control.kv)))
        lo = max(2.0 * model.control.kv, 0.1 * bw)
        if not lo < wmax:
            # e.g. all inertia lumped into the load (motor_inertia a placeholder): an elastic
            # element would resonate beyond what the kernel integrates at this speed cycle
            return Candidate(
                [],
                [
                    f"compliance not tried: with this inertia split an elastic element needs "
                    f"omega_a in [{lo:.3g}, {wmax:.3g}] rad/s, an empty range (give "
                    f"mechanics.motor_inertia its real value to test compliance)"
                ],
            )
        wa_p = Parameter("mechanics.antiresonance", lo, wmax, guesses[0], guesses[0], log=True)
        xi_p = Parameter("mechanics.damping_ratio", 0.005, 0.7, 0.05, 0.05, log=True)
        on = model.with_values(
            {"mechanics.antiresonance": guesses[0], "mechanics.damping_ratio": 0.05}
        )
        starts = [{"mechanics.antiresonance": g} for g in guesses[1:]]
        return Candidate([_spec(on, [wa_p, xi_p], starts, n_global)])


class _SingleTorque(EffectModel):
    """An effect with one torque-law key started from the inverse-dynamics regression."""

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        sc = ev.scales
        key = self.keys[0]
        guess = inverse_dynamics(ev.inp, model, sc).get(key, 0.0)
        guess = self._start(guess, ev)
        par = parameter_for(key, guess, sc, nominal, model)
        return Candidate([_spec(model, [par], [{key: 0.0}], n_global)])

    def _start(self, guess: float, ev: Evidence) -> float:
        return guess if guess > 0.0 else 0.02 * ev.scales.torque_peak


class CoulombFriction(_SingleTorque):
    effect = Effect.COULOMB_FRICTION
    keys = ("friction.coulomb",)
    description = "a friction torque of constant size opposing the motion"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.coulomb or 0.0) > _tiny(scales)


class ViscousFriction(_SingleTorque):
    effect = Effect.VISCOUS_FRICTION
    keys = ("friction.viscous",)
    description = "a friction torque growing with speed"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.viscous or 0.0) * scales.speed_max > _tiny(scales)

    def _start(self, guess: float, ev: Evidence) -> float:
        sc = ev.scales
        return guess if guess > 0.0 else 0.02 * sc.torque_peak / sc.speed_max


class ConstantLoadTorque(_SingleTorque):
    effect = Effect.CONSTANT_LOAD_TORQUE
    keys = ("disturbance.constant_torque",)
    description = (
        "a constant load torque (gravity, counterweight error) that the motor must hold even "
        "at rest"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return abs(fitted.disturbance.constant_torque or 0.0) > _tiny(scales)

    def _start(self, guess: float, ev: Evidence) -> float:
        """The median torque residual while moving (signed)."""
        sc = ev.scales
        res = ev.inp.recorded["motor_torque"] - ev.simulated["motor_torque"]
        moving = res[np.abs(sc.speed) > 0.05 * sc.speed_max]
        return float(np.median(moving)) if len(moving) else guess


class AsymmetricFriction(EffectModel):
    effect = Effect.ASYMMETRIC_FRICTION
    keys = ("friction.coulomb_negative", "friction.viscous_negative")
    description = "friction that differs between the two directions of motion"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        f = fitted.friction
        dc = abs((f.coulomb_negative or 0.0) - (f.coulomb or 0.0))
        dv = abs((f.viscous_negative or 0.0) - (f.viscous or 0.0)) * scales.speed_max
        return max(dc, dv) > _tiny(scales)

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Start: the negative direction's friction lowered by the direction offset of the
        torque residual (residual higher moving + than moving −)."""
        sc = ev.scales
        res = ev.inp.recorded["motor_torque"] - ev.simulated["motor_torque"]
        c = model.friction.coulomb or 0.0
        b = model.friction.viscous or 0.0
        d = direction_offset(res, sc.speed, sc.speed_max) or 0.0
        pc = parameter_for("friction.coulomb_negative", max(0.0, c - d), sc, nominal, model)
        pv = parameter_for("friction.viscous_negative", b, sc, nominal, model)
        starts = [{"friction.coulomb_negative": c, "friction.viscous_negative": b}]
        return Candidate([_spec(model, [pc, pv], starts, n_global)])


class StribeckFriction(EffectModel):
    effect = Effect.STRIBECK_FRICTION
    keys = ("friction.stribeck", "friction.stribeck_speed")
    description = "extra static friction near zero speed (break-away peak)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.stribeck or 0.0) > _tiny(scales)

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Starts: half the Coulomb friction, Stribeck speed on a log grid of the top speed."""
        sc = ev.scales
        c = model.friction.coulomb or 0.0
        ps = parameter_for(
            "friction.stribeck", max(0.5 * c, 0.02 * sc.torque_peak), sc, nominal, model
        )
        pv = parameter_for("friction.stribeck_speed", 0.02 * sc.speed_max, sc, nominal, model)
        starts = [{"friction.stribeck_speed": f * sc.speed_max} for f in (0.005, 0.1)]
        return Candidate([_spec(model, [ps, pv], starts, n_global)])


class PeriodicDisturbance(EffectModel):
    effect = Effect.PERIODIC_DISTURBANCE
    keys = (
        "disturbance.periodic_amplitude",
        "disturbance.periodic_period",
        "disturbance.periodic_phase",
    )
    description = "a torque that repeats with position (cogging, screw lead error)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.disturbance.periodic_amplitude or 0.0) > _tiny(scales)

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """One alternative per peak of the torque residual's spectrum over position."""
        sc = ev.scales
        res = ev.inp.recorded["motor_torque"] - ev.simulated["motor_torque"]
        specs = []
        for period, a, b in periodic_peaks(res, sc):
            on = model.with_values(
                {
                    "disturbance.periodic_amplitude": 0.0,
                    "disturbance.periodic_period": period,
                    "disturbance.periodic_phase": 0.0,
                }
            )
            params = [
                parameter_for(PERIODIC_COS, a, sc, nominal, on),
                parameter_for(PERIODIC_SIN, b, sc, nominal, on),
                parameter_for("disturbance.periodic_period", period, sc, nominal, on),
            ]
            specs.append(_spec(on, params, [], n_global))
        notes = [] if specs else ["periodic_disturbance not tried: too little travel"]
        return Candidate(specs, notes)


class TorqueSaturation(EffectModel):
    effect = Effect.TORQUE_SATURATION
    keys = ("control.torque_limit",)
    description = "a torque limit that clips the fastest accelerations"
    refit_keys = ("control.torque_limit",)

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Starts: the recorded peak torque and its 99.9th percentile."""
        sc = ev.scales
        par = parameter_for("control.torque_limit", sc.torque_max, sc, nominal, model)
        pct = float(np.percentile(np.abs(ev.inp.recorded["motor_torque"]), 99.9))
        return Candidate([_spec(model, [par], [{"control.torque_limit": pct}], n_global)])


class TimeDelay(EffectModel):
    effect = Effect.TIME_DELAY
    keys = ("control.delay",)
    description = "a dead time between the speed controller and the torque"

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Discrete in the kernel (whole speed cycles): profiled over a grid up to 0.1 s."""
        cyc = model.control.speed_cycle
        grid = [n * cyc for n in (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32) if n <= MAX_DELAY]
        grid = [g for g in grid if g <= 0.1]
        if not grid:
            return Candidate([], [f"time_delay not tried: speed cycle {cyc:g} s > 0.1 s"])
        disc = DiscreteParameter("control.delay", tuple(grid), grid[0])
        return Candidate([_spec(model, [], [], 0, disc)])


#: Largest sensor time offset tried, in position cycles (the key allows ±0.05 s).
MAX_OFFSET_CYCLES = 20


class SensorTimeOffset(EffectModel):
    effect = Effect.SENSOR_TIME_OFFSET
    keys = ("control.sensor_time_offset",)
    description = (
        "the load measuring system samples at another time than the motor's (positive: the "
        "load position is older)"
    )
    refit_keys = ("control.sensor_time_offset",)

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        value = fitted.value("control.sensor_time_offset") or 0.0
        return abs(value) > 0.05 * scales.sample_time_s

    def candidate(
        self, model: AxisConfig, nominal: AxisConfig, ev: Evidence, n_global: int
    ) -> Candidate:
        """Needs both positions recorded; bounded to ±20 position cycles; starts at ±1 and
        ±3 cycles."""
        rec = ev.inp.recorded
        if "motor_position" not in rec or "load_position" not in rec:
            return Candidate(
                [], ["sensor_time_offset not tried: needs motor_position and load_position"]
            )
        cyc = model.control.position_cycle
        lim = min(0.05, MAX_OFFSET_CYCLES * cyc)
        key = "control.sensor_time_offset"
        on = model.with_values({key: 0.0})
        opts = options_for(model.mechanics.antiresonance, model)
        probe = replay(model.with_values({key: 3.0 * cyc}), ev.inp, opts, ("load_position",))
        if np.array_equal(probe["load_position"], replay(on, ev.inp, opts)["load_position"]):
            return Candidate(
                [],
                ["sensor_time_offset not tried: the simulator ignores control.sensor_time_offset"],
            )
        par = Parameter(key, -lim, lim, cyc, cyc)
        starts = [{key: f * cyc} for f in (-1.0, 3.0, -3.0)]
        return Candidate([_spec(on, [par], starts, 0)])


#: Every effect of the table, in the table's order.
MODELS: dict[Effect, EffectModel] = {
    m.effect: m
    for m in (
        Backlash(),
        Compliance(),
        CoulombFriction(),
        ViscousFriction(),
        AsymmetricFriction(),
        StribeckFriction(),
        ConstantLoadTorque(),
        PeriodicDisturbance(),
        TorqueSaturation(),
        TimeDelay(),
        SensorTimeOffset(),
    )
}

#: Keys of every effect (axis-file.md's table).
EFFECT_KEYS: dict[Effect, tuple[str, ...]] = {e: m.keys for e, m in MODELS.items()}


def model_of(effect: Effect) -> EffectModel:
    return MODELS[effect]


def effects_in(axis: AxisConfig) -> frozenset[Effect]:
    """Effects the model has (a key present, 0 included)."""
    return frozenset(e for e, m in MODELS.items() if m.present(axis))


#: Experiments that tell two effects apart when a recording fits both equally well.
EXPERIMENTS: dict[frozenset[Effect], str] = {
    frozenset({Effect.CONSTANT_LOAD_TORQUE, Effect.ASYMMETRIC_FRICTION}): (
        "with Coulomb friction above the load torque the two are the same torque law; change "
        "the load torque and not the friction (add or remove a payload on a vertical axis, "
        "tilt it) or move at several speeds in both directions: a direction difference that "
        "grows with speed is asymmetric viscous friction"
    ),
    frozenset({Effect.COULOMB_FRICTION, Effect.STRIBECK_FRICTION}): (
        "slow constant-speed moves at several speeds below and above the Stribeck speed: "
        "Coulomb friction is flat in speed, Stribeck friction falls off"
    ),
    frozenset({Effect.BACKLASH, Effect.COMPLIANCE}): (
        "reversals at very low speed with a linear scale recorded: backlash shows a motor "
        "travel without load travel of a fixed size, compliance a deflection proportional "
        "to the force"
    ),
    frozenset({Effect.TIME_DELAY, Effect.COMPLIANCE}): (
        "a speed-loop frequency response (or a small speed step): a dead time adds phase "
        "lag growing linearly with frequency, an elastic element a resonance/antiresonance pair"
    ),
    frozenset({Effect.TIME_DELAY, Effect.TORQUE_SATURATION}): (
        "small speed steps (far from the torque limit) and one large step: a dead time "
        "shows in both, saturation only in the large one"
    ),
    frozenset({Effect.COULOMB_FRICTION, Effect.VISCOUS_FRICTION}): (
        "constant-speed moves at several feeds: Coulomb friction is the same torque at every "
        "speed, viscous friction grows with speed"
    ),
    frozenset({Effect.PERIODIC_DISTURBANCE, Effect.CONSTANT_LOAD_TORQUE}): (
        "a slow move over several screw pitches: a periodic torque varies with position, a "
        "load torque does not"
    ),
    frozenset({Effect.SENSOR_TIME_OFFSET, Effect.COMPLIANCE}): (
        "moves at several constant speeds: a sensor time offset shifts the load position by "
        "speed x offset (no force needed), a compliance deflects with the force"
    ),
}

GENERIC_EXPERIMENT = (
    "a recording that excites the two differently: slow and fast moves, reversals with and "
    "without dwell, a dwell at standstill, and a second recording to validate on"
)


def experiment_for(a: Effect, b: Effect) -> str:
    return EXPERIMENTS.get(frozenset({a, b}), GENERIC_EXPERIMENT)

"""The physical effects of the axis-file table as objects: one class per effect knows its
axis-file keys, when a model has it, how to take it out of an axis (the concealed test set),
the axis-file values of the evidence stage's estimate (:meth:`EffectModel.values`), when a
value is its "absent" value after all, and how to describe it with the axis's units; and
which experiment tells two effects apart that explain the same signature. The pseudo-keys of
the estimates that are not axis-file keys are defined here too, for the regressors that name
their coefficients with them (:mod:`.idim`, :mod:`.deflection`).

Names and keys are the table of ``docs/axis-file.md`` plus ``sensor_time_offset``
(``control.sensor_time_offset``, docs/diagnosis.md). An effect is *in* a model when one of its
keys is present; the evidence stage (:mod:`.screen`) tests every effect the model lacks, with
the regressors of :mod:`.idim`, :mod:`.deflection` and :mod:`.loop_tests`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from enum import Enum
from typing import ClassVar

from cmdline.quantity import quantity
from virtual_bus.formats.axis import AxisConfig

from .evidence import DataScales
from .fit import PERIODIC_COS, PERIODIC_SIN
from .parameters import format_value, key_unit, max_antiresonance, with_contact

#: Axis values an estimate adds to a model ({} and the reason when it is not physical).
Values = tuple[dict[str, float | None], str]

# Pseudo-keys of the evidence stage's estimates that are not axis-file keys (the regressors of
# :mod:`.idim` and :mod:`.deflection` name their coefficients with them):
#: the compliance coefficient M/ω_a² (torque balance, one measuring system)
COMPLIANCE_KEY = "mechanics.load_mass/antiresonance^2"
#: asymmetric friction: the negative direction's friction minus the model's
DELTA_COULOMB_NEG = "friction.coulomb_negative-coulomb"
DELTA_VISCOUS_NEG = "friction.viscous_negative-viscous"
#: the deflection between the two measuring systems: 1/k (load units per N) and c/k (s)
FLEXIBILITY = "mechanics.flexibility"
DAMPING = "mechanics.damping/stiffness"
#: The set point's dead-time growth (s/s), freed in the closed-loop fit once it is named.
RATE_KEY = "control.setpoint_delay_rate"
#: the load scale's periodic error A·sin(2πx/P + φ) as the deflection's two coefficients:
#: A·cos φ (of −sin 2πx/P) and A·sin φ (of −cos 2πx/P), :func:`.deflection.scale_columns`
SCALE_COS = "control.scale_error_amplitude*cos(phase)"
SCALE_SIN = "control.scale_error_amplitude*sin(phase)"
SCALE_PERIOD = "control.scale_error_period"


def model_values(axis: AxisConfig) -> dict[str, float]:
    """What ``axis`` already has, in the deflection's terms (:data:`FLEXIBILITY`,
    :data:`DAMPING`), with its free play and sensor time offset."""
    m = axis.mechanics
    out = {
        "mechanics.backlash": float(m.backlash or 0.0),
        "control.sensor_time_offset": float(axis.control.sensor_time_offset or 0.0),
    }
    if m.antiresonance:
        out[FLEXIBILITY] = 1.0 / (m.load_mass * m.antiresonance**2)
        out[DAMPING] = 2.0 * (m.damping_ratio or 0.0) / m.antiresonance
    c = axis.control
    if c.scale_error_amplitude is not None:
        phase = c.scale_error_phase or 0.0
        out[SCALE_COS] = c.scale_error_amplitude * math.cos(phase)
        out[SCALE_SIN] = c.scale_error_amplitude * math.sin(phase)
    return out


def scale_error_values(a_cos: float, a_sin: float) -> dict[str, float]:
    """Amplitude and phase of the scale's periodic error from its two coefficients (the phase
    in (−π, π])."""
    return {
        "control.scale_error_amplitude": math.hypot(a_cos, a_sin),
        "control.scale_error_phase": math.atan2(a_sin, a_cos),
    }


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
    SETPOINT_DELAY = "setpoint_delay"
    MEASUREMENT_DELAY = "measurement_delay"
    SCALE_ERROR = "scale_error"


class EffectModel:
    """One effect of the table. Subclasses set the class attributes and, where the effect has
    an "absent" value, :meth:`significant`."""

    effect: ClassVar[Effect]
    keys: ClassVar[tuple[str, ...]]
    description: ClassVar[str]
    #: the effect in a column of the confusion matrix (docs/matrix-results.md)
    short: ClassVar[str]
    #: the evidence stage tests it through the closed loop (:mod:`.loop_tests`), after the
    #: plant effects (:mod:`.idim`, :mod:`.deflection`)
    tested_in_loop: ClassVar[bool] = False
    #: why the evidence stage has no test for it yet ("" when it has one; the report says so)
    untested: ClassVar[str] = ""

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

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        """The axis-file values that add the effect at the evidence stage's estimate ``est``
        (:mod:`.screen`) to ``model`` ({} and why when the estimate is not physical); none
        for an effect the evidence stage does not estimate in axis-file terms."""
        return {}, "no estimate"

    def at_rest(self, est: Mapping[str, float]) -> float | None:
        """The motor torque the effect at the evidence's estimate ``est`` makes at rest before
        the axis has first moved, which the position loop holds (:mod:`.standstill`); None
        when it predicts nothing there. Friction acts only with motion: 0."""
        return None

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
    short = "bl"
    keys = ("mechanics.backlash",)
    description = "free play between motor and load (the motor crosses a gap at reversals)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.mechanics.backlash or 0.0) > 1e-3 * scales.following_error

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        d = est.get("mechanics.backlash", 0.0)
        if not 0.0 < d <= 0.1:
            return {}, f"free play {d:.3g} outside (0, 0.1]"
        values: dict[str, float | None] = {"mechanics.backlash": d}
        if model.is_rigid:
            on = with_contact(model)
            if on is None:
                return (
                    {},
                    "free play needs a contact stiffness: the model has no motor-side inertia",
                )
            values["mechanics.antiresonance"] = on.mechanics.antiresonance
            values["mechanics.damping_ratio"] = on.mechanics.damping_ratio
        return values, ""


class Compliance(EffectModel):
    effect = Effect.COMPLIANCE
    short = "cmp"
    keys = ("mechanics.antiresonance", "mechanics.damping_ratio")
    description = "an elastic transmission (motor and load positions differ with the force)"

    def strip(self, axis: AxisConfig) -> AxisConfig:
        # backlash needs the contact stiffness of the elastic element: it goes with it
        return axis.with_values({**dict.fromkeys(self.keys), "mechanics.backlash": None})

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        mass = model.mechanics.load_mass
        wmax = max_antiresonance(model, 50)
        if not wmax > 0.0:
            return (
                {},
                "an elastic element needs motor-side inertia; the model lumps it all in the load",
            )
        if FLEXIBILITY in est:
            flex = est[FLEXIBILITY]
            damping = est.get(DAMPING, 0.0)
            if model.mechanics.antiresonance is not None:
                # on top of the stiff contact that came with free play (a known term there)
                known = model_values(model)
                flex += known[FLEXIBILITY]
                damping += known[DAMPING]
            if not flex > 0.0:
                return {}, f"negative flexibility {flex:.3g}"
            wa = math.sqrt(1.0 / (flex * mass))
            xi = 0.5 * damping * wa
        else:
            kappa = est.get(COMPLIANCE_KEY, 0.0)
            if not kappa > 0.0:
                return {}, f"M/ω_a² = {kappa:.3g} <= 0"
            wa = math.sqrt(mass / kappa)
            xi = 0.05
        wa = min(wa, 0.99 * wmax)
        xi = min(0.7, max(0.005, xi))
        return {"mechanics.antiresonance": wa, "mechanics.damping_ratio": xi}, ""


class CoulombFriction(EffectModel):
    effect = Effect.COULOMB_FRICTION
    short = "coul"
    keys = ("friction.coulomb",)
    description = "a friction torque of constant size opposing the motion"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.coulomb or 0.0) > _tiny(scales)

    def at_rest(self, est: Mapping[str, float]) -> float | None:
        return 0.0

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        c = est.get("friction.coulomb", 0.0)
        return ({"friction.coulomb": c}, "") if c > 0.0 else ({}, f"Coulomb friction {c:.3g} < 0")


class ViscousFriction(EffectModel):
    effect = Effect.VISCOUS_FRICTION
    short = "visc"
    keys = ("friction.viscous",)
    description = "a friction torque growing with speed"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.viscous or 0.0) * scales.speed_max > _tiny(scales)

    def at_rest(self, est: Mapping[str, float]) -> float | None:
        return 0.0

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        b = est.get("friction.viscous", 0.0)
        return ({"friction.viscous": b}, "") if b > 0.0 else ({}, f"viscous friction {b:.3g} < 0")


class ConstantLoadTorque(EffectModel):
    effect = Effect.CONSTANT_LOAD_TORQUE
    short = "load"
    keys = ("disturbance.constant_torque",)
    description = (
        "a constant load torque (gravity, counterweight error) that the motor must hold even "
        "at rest"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return abs(fitted.disturbance.constant_torque or 0.0) > _tiny(scales)

    def at_rest(self, est: Mapping[str, float]) -> float | None:
        return est.get("disturbance.constant_torque")

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        return {"disturbance.constant_torque": est.get("disturbance.constant_torque", 0.0)}, ""


class AsymmetricFriction(EffectModel):
    effect = Effect.ASYMMETRIC_FRICTION
    short = "asym"
    keys = ("friction.coulomb_negative", "friction.viscous_negative")
    description = "friction that differs between the two directions of motion"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        f = fitted.friction
        dc = abs((f.coulomb_negative or 0.0) - (f.coulomb or 0.0))
        dv = abs((f.viscous_negative or 0.0) - (f.viscous or 0.0)) * scales.speed_max
        return max(dc, dv) > _tiny(scales)

    def at_rest(self, est: Mapping[str, float]) -> float | None:
        return 0.0

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        fr = model.friction
        cn = (fr.coulomb or 0.0) + est.get(DELTA_COULOMB_NEG, 0.0)
        vn = (fr.viscous or 0.0) + est.get(DELTA_VISCOUS_NEG, 0.0)
        if cn < 0.0 or vn < 0.0:
            return {}, f"negative friction in the negative direction ({cn:.3g}, {vn:.3g})"
        return {"friction.coulomb_negative": cn, "friction.viscous_negative": vn}, ""


class StribeckFriction(EffectModel):
    effect = Effect.STRIBECK_FRICTION
    short = "strb"
    keys = ("friction.stribeck", "friction.stribeck_speed")
    description = "extra static friction near zero speed (break-away peak)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.stribeck or 0.0) > _tiny(scales)

    def at_rest(self, est: Mapping[str, float]) -> float | None:
        return 0.0

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        s, vs = est.get("friction.stribeck", 0.0), est.get("friction.stribeck_speed", 0.0)
        if not (s > 0.0 and vs > 0.0):
            return {}, f"Stribeck excess {s:.3g} <= 0 (friction falling towards zero speed)"
        return {"friction.stribeck": s, "friction.stribeck_speed": vs}, ""


class PeriodicDisturbance(EffectModel):
    effect = Effect.PERIODIC_DISTURBANCE
    short = "per"
    keys = (
        "disturbance.periodic_amplitude",
        "disturbance.periodic_period",
        "disturbance.periodic_phase",
    )
    description = "a torque that repeats with position (cogging, screw lead error)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.disturbance.periodic_amplitude or 0.0) > _tiny(scales)

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        c, s = est.get(PERIODIC_COS, 0.0), est.get(PERIODIC_SIN, 0.0)
        return {
            "disturbance.periodic_amplitude": math.hypot(c, s),
            "disturbance.periodic_period": est["disturbance.periodic_period"],
            "disturbance.periodic_phase": math.atan2(s, c),
        }, ""


class TorqueSaturation(EffectModel):
    effect = Effect.TORQUE_SATURATION
    short = "sat"
    keys = ("control.torque_limit",)
    tested_in_loop = True
    description = "a torque limit that clips the fastest accelerations"

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        return {"control.torque_limit": est["control.torque_limit"]}, ""


class TimeDelay(EffectModel):
    effect = Effect.TIME_DELAY
    short = "dly"
    keys = ("control.delay",)
    tested_in_loop = True
    description = "a dead time between the speed controller and the torque"

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        return {"control.delay": est["control.delay"]}, ""


class SensorTimeOffset(EffectModel):
    effect = Effect.SENSOR_TIME_OFFSET
    short = "sto"
    keys = ("control.sensor_time_offset",)
    description = (
        "the load measuring system samples at another time than the motor's (positive: the "
        "load position is older)"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        value = fitted.value("control.sensor_time_offset") or 0.0
        return abs(value) > 0.05 * scales.sample_time_s

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        o = est.get("control.sensor_time_offset", 0.0)
        if not abs(o) <= 0.05:
            return {}, f"sensor time offset {o:.3g} s outside ±0.05 s"
        return {"control.sensor_time_offset": o}, ""


class SetpointDelay(EffectModel):
    effect = Effect.SETPOINT_DELAY
    short = "spd"
    keys = ("control.setpoint_delay", "control.setpoint_delay_rate")
    tested_in_loop = True
    description = (
        "the drive applies the speed set point late (bus, the drive's input stage), by a "
        "dead time that may grow slowly during the run"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        d0 = fitted.value("control.setpoint_delay") or 0.0
        rate = fitted.value("control.setpoint_delay_rate") or 0.0
        duration = len(scales.position) * scales.sample_time_s
        return max(abs(d0), abs(d0 + rate * duration)) > 0.05 * scales.sample_time_s

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        # the scan's variant (constant, or growing from none); the closed-loop fit frees both
        return {
            "control.setpoint_delay": est["control.setpoint_delay"],
            RATE_KEY: est.get(RATE_KEY, 0.0),
        }, ""

    def headline(self, fitted: AxisConfig, nominal: AxisConfig) -> str | None:
        """'the drive applies the speed set point 2.1 ms late', or with its growth."""
        d0 = fitted.control.setpoint_delay
        if d0 is None:
            return None
        rate = fitted.control.setpoint_delay_rate or 0.0
        text = f"the drive applies the speed set point {quantity(d0, 's')} late"
        if rate:
            grows = "growing" if rate > 0 else "shrinking"
            text += f" at the start, {grows} by {quantity(abs(rate), 's')} per second of the run"
        return text + " (bus, the drive's input stage)"


class MeasurementDelay(EffectModel):
    effect = Effect.MEASUREMENT_DELAY
    short = "msd"
    keys = ("control.measurement_delay",)
    untested = (
        "the loop test does not tell a late reading from a late set point yet (on an FMU axis "
        "with a 2 ms set-point dead time, development seed 9, it scored higher than the set "
        "point's); a trace of the set point as the drive received it decides"
    )
    description = "every reading the position loop and the recording see is taken late"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        value = fitted.value("control.measurement_delay") or 0.0
        return abs(value) > 0.05 * scales.sample_time_s

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        return {"control.measurement_delay": est["control.measurement_delay"]}, ""


class ScaleError(EffectModel):
    effect = Effect.SCALE_ERROR
    short = "scl"
    keys = (
        "control.scale_error_amplitude",
        "control.scale_error_period",
        "control.scale_error_phase",
    )
    description = (
        "a periodic error of the load measuring system (a reading error, not a force: it "
        "shows in the deflection between the two measuring systems, not in the torque)"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.control.scale_error_amplitude or 0.0) > 1e-3 * scales.following_error

    def values(self, est: Mapping[str, float], model: AxisConfig) -> Values:
        period = est.get(SCALE_PERIOD, 0.0)
        vals = scale_error_values(est.get(SCALE_COS, 0.0), est.get(SCALE_SIN, 0.0))
        amp = vals["control.scale_error_amplitude"]
        if not (0.0 < amp <= 0.01 and period > 0.0):
            return {}, f"amplitude {amp:.3g} outside (0, 0.01] or period {period:.3g} <= 0"
        return {**vals, SCALE_PERIOD: period}, ""

    def headline(self, fitted: AxisConfig, nominal: AxisConfig) -> str | None:
        """'the load scale reads up to 5.77 µm wrong, periodically every 30.7 mm of travel'."""
        c = fitted.control
        if not (c.scale_error_amplitude and c.scale_error_period):
            return None
        unit = key_unit("control.scale_error_amplitude", fitted)
        return (
            f"the load scale reads up to {quantity(c.scale_error_amplitude, unit)} wrong, "
            f"periodically every {quantity(c.scale_error_period, unit)} of travel (a reading "
            "error: where the loop holds the scale, the load stands off by as much)"
        )


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
        SetpointDelay(),
        MeasurementDelay(),
        ScaleError(),
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
        "while the axis moves the two are the same torque law; record a rest of a second "
        "before the first move (a load is held there by the loop, friction is not), or "
        "change the load torque and not the friction (add or remove a payload on a vertical axis, "
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
    frozenset({Effect.SETPOINT_DELAY, Effect.TIME_DELAY}): (
        "a speed-loop step or frequency response driven from the drive's own signal "
        "generator (not over the bus): a set point that arrives late shifts the whole "
        "response, a dead time inside the speed loop changes its damping"
    ),
    frozenset({Effect.SETPOINT_DELAY, Effect.MEASUREMENT_DELAY}): (
        "record the set point as the drive received it (its own trace): a late set point "
        "shows between the bus and the drive, a late reading between the drive's actual "
        "values and the recording"
    ),
    frozenset({Effect.SCALE_ERROR, Effect.PERIODIC_DISTURBANCE}): (
        "a slow constant-speed pass over several periods with both measuring systems "
        "recorded: a scale error moves the load reading against the motor's at no torque, "
        "a periodic force moves the torque"
    ),
}

GENERIC_EXPERIMENT = (
    "a recording that excites the two differently: slow and fast moves, reversals with and "
    "without dwell, a dwell at standstill, and a second recording to validate on"
)


def experiment_for(a: Effect, b: Effect) -> str:
    return EXPERIMENTS.get(frozenset({a, b}), GENERIC_EXPERIMENT)

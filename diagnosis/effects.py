"""The physical effects of the axis-file table as objects: one class per effect knows its
axis-file keys, when a model has it, how to take it out of an axis (the concealed test set),
when a value is its "absent" value after all, and how to describe it with the axis's units;
and which experiment tells two effects apart that explain the same signature.

Names and keys are the table of ``docs/axis-file.md`` plus ``sensor_time_offset``
(``control.sensor_time_offset``, docs/diagnosis.md). An effect is *in* a model when one of its
keys is present; the evidence stage (:mod:`.screen`) tests every effect the model lacks, with
the regressors of :mod:`.idim`, :mod:`.deflection` and :mod:`.loop_tests`.
"""

from __future__ import annotations

from enum import Enum
from typing import ClassVar

from virtual_bus.formats.axis import AxisConfig

from .evidence import DataScales
from .parameters import (
    format_value,
)


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


class Compliance(EffectModel):
    effect = Effect.COMPLIANCE
    keys = ("mechanics.antiresonance", "mechanics.damping_ratio")
    description = "an elastic transmission (motor and load positions differ with the force)"

    def strip(self, axis: AxisConfig) -> AxisConfig:
        # backlash needs the contact stiffness of the elastic element: it goes with it
        return axis.with_values({**dict.fromkeys(self.keys), "mechanics.backlash": None})


class CoulombFriction(EffectModel):
    effect = Effect.COULOMB_FRICTION
    keys = ("friction.coulomb",)
    description = "a friction torque of constant size opposing the motion"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.coulomb or 0.0) > _tiny(scales)


class ViscousFriction(EffectModel):
    effect = Effect.VISCOUS_FRICTION
    keys = ("friction.viscous",)
    description = "a friction torque growing with speed"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.viscous or 0.0) * scales.speed_max > _tiny(scales)


class ConstantLoadTorque(EffectModel):
    effect = Effect.CONSTANT_LOAD_TORQUE
    keys = ("disturbance.constant_torque",)
    description = (
        "a constant load torque (gravity, counterweight error) that the motor must hold even "
        "at rest"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return abs(fitted.disturbance.constant_torque or 0.0) > _tiny(scales)


class AsymmetricFriction(EffectModel):
    effect = Effect.ASYMMETRIC_FRICTION
    keys = ("friction.coulomb_negative", "friction.viscous_negative")
    description = "friction that differs between the two directions of motion"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        f = fitted.friction
        dc = abs((f.coulomb_negative or 0.0) - (f.coulomb or 0.0))
        dv = abs((f.viscous_negative or 0.0) - (f.viscous or 0.0)) * scales.speed_max
        return max(dc, dv) > _tiny(scales)


class StribeckFriction(EffectModel):
    effect = Effect.STRIBECK_FRICTION
    keys = ("friction.stribeck", "friction.stribeck_speed")
    description = "extra static friction near zero speed (break-away peak)"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        return (fitted.friction.stribeck or 0.0) > _tiny(scales)


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


class TorqueSaturation(EffectModel):
    effect = Effect.TORQUE_SATURATION
    keys = ("control.torque_limit",)
    description = "a torque limit that clips the fastest accelerations"


class TimeDelay(EffectModel):
    effect = Effect.TIME_DELAY
    keys = ("control.delay",)
    description = "a dead time between the speed controller and the torque"


class SensorTimeOffset(EffectModel):
    effect = Effect.SENSOR_TIME_OFFSET
    keys = ("control.sensor_time_offset",)
    description = (
        "the load measuring system samples at another time than the motor's (positive: the "
        "load position is older)"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        value = fitted.value("control.sensor_time_offset") or 0.0
        return abs(value) > 0.05 * scales.sample_time_s


class SetpointDelay(EffectModel):
    effect = Effect.SETPOINT_DELAY
    keys = ("control.setpoint_delay", "control.setpoint_delay_rate")
    description = (
        "the drive applies the speed set point late (bus, the drive's input stage), by a "
        "dead time that may grow slowly during the run"
    )

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        d0 = fitted.value("control.setpoint_delay") or 0.0
        rate = fitted.value("control.setpoint_delay_rate") or 0.0
        duration = len(scales.position) * scales.sample_time_s
        return max(abs(d0), abs(d0 + rate * duration)) > 0.05 * scales.sample_time_s


class MeasurementDelay(EffectModel):
    effect = Effect.MEASUREMENT_DELAY
    keys = ("control.measurement_delay",)
    description = "every reading the position loop and the recording see is taken late"

    def significant(self, fitted: AxisConfig, scales: DataScales) -> bool:
        value = fitted.value("control.measurement_delay") or 0.0
        return abs(value) > 0.05 * scales.sample_time_s


class ScaleError(EffectModel):
    effect = Effect.SCALE_ERROR
    keys = (
        "control.scale_error_amplitude",
        "control.scale_error_period",
        "control.scale_error_phase",
    )
    description = (
        "a periodic error of the load measuring system (a reading error, not a force: it "
        "shows in the deflection between the two measuring systems, not in the torque)"
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

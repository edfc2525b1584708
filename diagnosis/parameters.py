"""The fitted parameters of an axis file: bounds, normalisation, data-sheet uncertainty and
units of every key the diagnosis may fit, and the kernel substeps a fit needs.

Every bound rule is here (:mod:`.closed_loop` chooses which keys are free, :mod:`.fit` only
searches). Bounds scale with the recording (peak torque, top speed, following error) so that
one rule serves a 6.5 t milling axis and a 25 kg slide; the nominal axis anchors relative
bounds.

Data-sheet uncertainty (:data:`UNCERTAINTY`, :func:`uncertainty_box`): how far the closed-loop
fit may move a nominal parameter — unless the evidence stage's estimate lies beyond it by more
than its standard errors, which says the data sheet is wrong (:mod:`.screen`).
"""

from __future__ import annotations

import math
from dataclasses import replace

from plant_sim.physics.model import MAX_OMEGA_DT, KernelOptions
from virtual_bus.formats.axis import RANGES, AxisConfig, AxisKind

from .evidence import DataScales
from .fit import PERIODIC_COS, PERIODIC_SIN, Parameter

#: Relative uncertainty of a data-sheet value (1 sigma-ish; a move beyond it is a finding).
#: Mass from the drawing/weighing: 15 %; stiffness (antiresonance) from a frequency response
#: or FE model: 20 %; damping ratio is guessed: 100 %; friction and load torques change with
#: lubrication, temperature and wear: 50 %; a periodic disturbance's period is the screw lead
#: or pole pitch: 5 %; a torque limit from the drive's parameters: 20 %.
UNCERTAINTY: dict[str, float] = {
    "mechanics.load_mass": 0.15,
    "mechanics.antiresonance": 0.2,
    "mechanics.damping_ratio": 1.0,
    "mechanics.backlash": 1.0,
    "friction.coulomb": 0.5,
    "friction.viscous": 0.5,
    "friction.coulomb_negative": 0.5,
    "friction.viscous_negative": 0.5,
    "friction.stribeck": 0.5,
    "friction.stribeck_speed": 1.0,
    "disturbance.constant_torque": 0.5,
    "disturbance.periodic_amplitude": 0.5,
    PERIODIC_COS: 0.5,
    PERIODIC_SIN: 0.5,
    "disturbance.periodic_period": 0.05,
    "control.torque_limit": 0.2,
    "control.delay": 1.0,
    "control.sensor_time_offset": 1.0,
    "control.setpoint_delay": 1.0,
    "control.setpoint_delay_rate": 1.0,
    "control.measurement_delay": 1.0,
}


def units(axis: AxisConfig) -> dict[str, str]:
    """Units of the quantities for this axis: torque (N for a linear axis at transmission
    ratio 1, where the "motor" moves in m; N·m otherwise), load position and load speed."""
    linear = axis.kind is AxisKind.LINEAR
    torque = "N" if linear and axis.transmission_ratio == 1.0 else "N·m"
    pos = "m" if linear else "rad"
    return {"torque": torque, "position": pos, "speed": f"{pos}/s"}


def key_unit(key: str, axis: AxisConfig) -> str:
    """Unit of an axis-file key on this axis (load units follow ``axis.kind``)."""
    u = units(axis)
    table = {
        "mechanics.load_mass": "kg" if axis.kind is AxisKind.LINEAR else "kg·m²",
        "mechanics.antiresonance": "rad/s",
        "mechanics.damping_ratio": "",
        "mechanics.backlash": u["position"],
        "friction.viscous": f"{u['torque']}·s/{u['position']}",
        "friction.viscous_negative": f"{u['torque']}·s/{u['position']}",
        "friction.stribeck_speed": u["speed"],
        "disturbance.periodic_period": u["position"],
        "disturbance.periodic_phase": "rad",
        "control.delay": "s",
        "control.sensor_time_offset": "s",
        "control.setpoint_delay": "s",
        "control.setpoint_delay_rate": "s/s",
        "control.measurement_delay": "s",
        "control.scale_error_amplitude": u["position"],
        "control.scale_error_period": u["position"],
        "control.scale_error_phase": "rad",
    }
    if key in table:
        return table[key]
    if key.startswith(("friction.", "disturbance.")) or key == "control.torque_limit":
        return u["torque"]
    return ""


def format_value(key: str, value: float, axis: AxisConfig) -> str:
    """``value`` with its unit, as written in axis_fitted.toml (:func:`rounded`)."""
    unit = key_unit(key, axis)
    return f"{value!r} {unit}".rstrip()


#: Significant digits of fitted values (the explanation prints exactly the file's numbers).
DIGITS = 6


def rounded(value: float) -> float:
    """``value`` to :data:`DIGITS` significant digits (what axis_fitted.toml holds)."""
    if value == 0.0 or not math.isfinite(value):
        return float(value)
    return float(f"{value:.{DIGITS}g}")


def speed_loop_bandwidth(axis: AxisConfig) -> float:
    """rad/s: k_sp / J_total, the crossover of the speed loop (rigid approximation)."""
    return axis.control.ksp / axis.total_inertia


def max_antiresonance(axis: AxisConfig, max_substeps: int = 5) -> float:
    """Largest ω_a fitted: the resonance ω_r = ω_a·√(1+R) must keep ω_r·dt <= MAX_OMEGA_DT
    with at most ``max_substeps`` mechanics substeps per speed cycle (cost of a simulation).
    0 for a lumped rigid model (no motor-side inertia: no elastic element can be added; the
    axis-file rules need motor_inertia + screw_inertia > 0 with an antiresonance)."""
    if not axis.motor_side_inertia > 0.0:
        return 0.0
    r = axis.inertia_ratio
    return max_substeps * MAX_OMEGA_DT / axis.control.speed_cycle / math.sqrt(1.0 + r)


def contact_antiresonance(axis: AxisConfig) -> float:
    """ω_a of the stiff contact added with backlash to a rigid model: ten times the speed
    loop's bandwidth, at most what 3 substeps per speed cycle integrate (0: none possible,
    a lumped rigid model)."""
    return min(10.0 * speed_loop_bandwidth(axis), 0.99 * max_antiresonance(axis, 3))


#: Damping ratio of that contact (a steel flank contact; only sets the impact loss).
CONTACT_DAMPING = 0.1


def with_contact(model: AxisConfig) -> AxisConfig | None:
    """``model`` with a stiff contact for free play when it is rigid (None: a lumped rigid
    model has no motor-side inertia for one)."""
    if not model.is_rigid:
        return model
    wa = contact_antiresonance(model)
    if not wa > 0.0:
        return None
    return model.with_values(
        {"mechanics.antiresonance": wa, "mechanics.damping_ratio": CONTACT_DAMPING}
    )


def options_for(axis_max_wa: float | None, axis: AxisConfig) -> KernelOptions:
    """Kernel substeps fixed for a whole fit, from the largest ω_a it may visit."""
    if axis_max_wa is None or not axis.motor_side_inertia > 0.0:
        return KernelOptions(substeps=1)
    wr = axis_max_wa * math.sqrt(1.0 + axis.inertia_ratio)
    return KernelOptions(substeps=max(1, math.ceil(wr * axis.control.speed_cycle / MAX_OMEGA_DT)))


#: Keys whose value must be positive, and those that may be zero but not negative: an
#: estimate outside is not physical (it says nothing about the data sheet).
POSITIVE_KEYS = frozenset(
    {
        "mechanics.load_mass",
        "mechanics.antiresonance",
        "control.torque_limit",
        "friction.stribeck_speed",
        "disturbance.periodic_period",
    }
)


def physical(key: str, value: float) -> bool:
    """Whether ``value`` is a possible value of ``key`` (signed keys: any finite value)."""
    if not math.isfinite(value):
        return False
    if key in POSITIVE_KEYS:
        return value > 0.0
    if key.startswith(("mechanics.", "friction.")) or key in (
        "disturbance.periodic_amplitude",
        "control.delay",
        "control.setpoint_delay",
        "control.measurement_delay",
    ):
        return value >= 0.0
    return True


#: The axis-file format's own range of each fitted key (virtual_bus.formats.axis.RANGES),
#: the periodic pseudo-keys' from the amplitude's: a fitting bound beyond it would let the
#: fit try a value no axis file may hold (a viscous friction of 3e6 on an axis of huge
#: torques).
_AMPLITUDE_MAX = RANGES["disturbance.periodic_amplitude"].high / math.sqrt(2.0)
FORMAT_RANGE: dict[str, tuple[float, float]] = {
    **{key: (r.low, r.high) for key, r in RANGES.items()},
    PERIODIC_COS: (-_AMPLITUDE_MAX, _AMPLITUDE_MAX),
    PERIODIC_SIN: (-_AMPLITUDE_MAX, _AMPLITUDE_MAX),
}


def within_format(p: Parameter) -> Parameter:
    """``p`` with its bounds cut to the format's range of its key (:data:`FORMAT_RANGE`)."""
    if p.key not in FORMAT_RANGE:
        return p
    lo, hi = FORMAT_RANGE[p.key]
    low, high = max(p.low, lo), min(p.high, hi)
    if (low, high) == (p.low, p.high):
        return p
    if not low < high:  # the whole box beyond the range (an evidence box): its edge
        width = min(p.high - p.low, 0.5 * (hi - lo))
        low, high = (hi - width, hi) if p.low >= hi else (lo, lo + width)
    return replace(p, low=low, high=high, scale=p.scale if p.log else min(p.scale, high - low))


def parameter_for(
    key: str,
    value: float,
    scales: DataScales,
    nominal: AxisConfig,
    axis: AxisConfig,
) -> Parameter:
    """Bounds and scale of one fitted key around its current ``value``; the nominal axis
    anchors the relative bounds of mass, antiresonance and damping (a data sheet is within a
    factor 2), the recording the absolute ones of torques and speeds. The fit cuts them to
    the format's range of the key (:func:`within_format`)."""
    tp, vmax = scales.torque_peak, scales.speed_max
    ref = nominal.value(key) if key.startswith("mechanics.") else None
    if key == "mechanics.load_mass":
        n = ref or value
        return Parameter(key, n / 2.0, 2.0 * n, value, n, log=True)
    if key == "mechanics.antiresonance":
        n = ref or value
        hi = max(max_antiresonance(axis), value * 1.01)
        lo = min(max(n / 2.0, 2.0 * axis.control.kv), value * 0.99)
        return Parameter(key, lo, min(2.0 * n, hi) if 2.0 * n > lo else hi, value, n, log=True)
    if key == "mechanics.damping_ratio":
        n = ref or value
        if n > 0.0:
            lo, hi = max(0.002, n / 5.0), min(1.0, 5.0 * n)
            if not lo < hi:  # below the usual floor (an evidence estimate): its own factor 5
                lo, hi = n / 5.0, 5.0 * n
            return Parameter(key, lo, hi, value, n, log=True)
        return Parameter(key, 0.0, 0.5, value, 0.05)
    if key == "mechanics.backlash":
        b = max(0.01 * scales.following_error, 1e-9)
        hi = min(0.1, max(0.5 * scales.following_error, 3.0 * value))
        return Parameter(key, 0.0, hi, value, max(value, b))
    if key in ("friction.coulomb", "friction.coulomb_negative", "friction.stribeck"):
        hi = max(0.5 * tp, 2.0 * value)
        return Parameter(key, 0.0, hi, value, max(value, 0.02 * tp))
    if key in ("friction.viscous", "friction.viscous_negative"):
        hi = max(0.5 * tp / vmax, 2.0 * value)
        return Parameter(key, 0.0, hi, value, max(value, 0.02 * tp / vmax))
    if key == "friction.stribeck_speed":
        lo, hi = vmax * 1e-4, vmax
        return Parameter(key, min(lo, value), max(hi, value), value, value, log=True)
    if key == "friction.creep_speed":
        lo, hi = vmax * CREEP_RANGE[0], vmax * CREEP_RANGE[1]
        return Parameter(key, min(lo, value), max(hi, value), value, value, log=True)
    if key == "disturbance.constant_torque":
        lim = max(0.5 * tp, 2.0 * abs(value))
        return Parameter(key, -lim, lim, value, max(abs(value), 0.02 * tp))
    if key in (PERIODIC_COS, PERIODIC_SIN):
        lim = max(0.25 * tp, 2.0 * abs(value))
        return Parameter(key, -lim, lim, value, 0.02 * tp)
    if key == "disturbance.periodic_period":
        return Parameter(key, value / 1.25, value * 1.25, value, value, log=True)
    if key == "control.torque_limit":
        hi = max(3.0 * scales.torque_max, 1.5 * value)
        return Parameter(key, 0.3 * scales.torque_max, hi, value, scales.torque_max)
    if key == "control.sensor_time_offset":
        # as the candidate in effects.SensorTimeOffset: within ±20 position cycles
        cyc = axis.control.position_cycle
        lim = max(min(0.05, 20.0 * cyc), 1.01 * abs(value))
        return Parameter(key, -lim, lim, value, cyc)
    if key in ("control.setpoint_delay", "control.measurement_delay"):
        # from none to twice the loop scan's estimate, at least 8 speed cycles
        cyc = axis.control.speed_cycle
        hi = max(2.0 * value, 8.0 * cyc)
        return Parameter(key, 0.0, hi, value, max(cyc, 0.25 * value))
    if key == "control.setpoint_delay_rate":
        # a growth over the recording of at most 5 ms (scale: a position cycle over it)
        duration = max(len(scales.position) * scales.sample_time_s, scales.sample_time_s)
        lim = max(min(0.005 / duration, 0.01), 1.01 * abs(value))
        return Parameter(key, -lim, lim, value, axis.control.position_cycle / duration)
    raise KeyError(f"no fitting rule for {key!r}")


#: Keys refitted whenever present (the "uncertain" parameters of a data sheet); control keys
#: are machine data and stay fixed unless the diagnosis added them itself.
UNCERTAIN_KEYS = (
    "mechanics.load_mass",
    "mechanics.antiresonance",
    "mechanics.damping_ratio",
    "mechanics.backlash",
    "friction.coulomb",
    "friction.viscous",
    "friction.coulomb_negative",
    "friction.viscous_negative",
    "friction.stribeck",
    "friction.stribeck_speed",
    "disturbance.constant_torque",
    "disturbance.periodic_amplitude",
    "disturbance.periodic_period",
    "friction.creep_speed",
)

#: Creep speed of the regularised friction law, as fractions of the recording's top speed:
#: from practically set-valued (1e-5) to a linear zone over 5 % of the top speed.
CREEP_RANGE = (1e-5, 0.05)

#: Keys of the model's form that no data sheet states (the friction law's creep speed): they
#: are fitted, but a value on a bound or far from a nominal is no sign of missing physics.
MODEL_FORM_KEYS = ("friction.creep_speed",)


def current_value(axis: AxisConfig, key: str) -> float:
    if key in (PERIODIC_COS, PERIODIC_SIN):
        amp = axis.disturbance.periodic_amplitude or 0.0
        phase = axis.disturbance.periodic_phase or 0.0
        return amp * (math.cos(phase) if key == PERIODIC_COS else math.sin(phase))
    value = axis.value(key)
    return 0.0 if value is None else float(value)


def uncertainty_box(key: str, nominal: AxisConfig) -> tuple[float, float] | None:
    """The values a data sheet allows for ``key``: the nominal value within its relative
    :data:`UNCERTAINTY` (None: the nominal has no value for it)."""
    if key in (PERIODIC_COS, PERIODIC_SIN):
        amp = nominal.disturbance.periodic_amplitude
        if not amp:
            return None
        n = current_value(nominal, key)
        u = UNCERTAINTY[key] * amp
        return n - u, n + u
    n = nominal.value(key)
    if n is None or n == 0.0:
        return None
    u = UNCERTAINTY.get(key, 1.0)
    lo, hi = sorted((n * (1.0 - u), n * (1.0 + u)))
    return lo, hi

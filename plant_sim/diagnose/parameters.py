"""The fitted parameters of an axis file: bounds, normalisation, data-sheet uncertainty and
units of every key the diagnosis may fit, the keys re-fitted for a model, and the kernel
substeps a fit needs.

Every bound rule is here (:mod:`.effects` only chooses starts, :mod:`.fit` only searches).
Bounds scale with the recording (peak torque, top speed, following error) so that one rule
serves a 6.5 t milling axis and a 25 kg slide; the nominal axis anchors relative bounds.

Data-sheet uncertainty (:data:`UNCERTAINTY`): how far a re-fit may move a parameter from the
nominal value before the move itself is a finding. A parameter that ends on a bound of its
search box, or moves further than its uncertainty, is reported as a sign of missing physics
(:func:`suspects`): small differences of model form (a dead time, a cogging torque) are
otherwise soaked up by the elastic parameters, and the diagnosis then compares every effect,
fitted with those parameters held within their uncertainty (:func:`within_uncertainty`),
against the re-fit that moved them further.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ..axis import AxisConfig, AxisKind
from ..model import MAX_OMEGA_DT, KernelOptions
from .evidence import DataScales
from .fit import PERIODIC_COS, PERIODIC_SIN, FitResult, FitSpec, Parameter

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


def options_for(axis_max_wa: float | None, axis: AxisConfig) -> KernelOptions:
    """Kernel substeps fixed for a whole fit, from the largest ω_a it may visit."""
    if axis_max_wa is None or not axis.motor_side_inertia > 0.0:
        return KernelOptions(substeps=1)
    wr = axis_max_wa * math.sqrt(1.0 + axis.inertia_ratio)
    return KernelOptions(substeps=max(1, math.ceil(wr * axis.control.speed_cycle / MAX_OMEGA_DT)))


def parameter_for(
    key: str,
    value: float,
    scales: DataScales,
    nominal: AxisConfig,
    axis: AxisConfig,
) -> Parameter:
    """Bounds and scale of one fitted key around its current ``value``; the nominal axis
    anchors the relative bounds of mass, antiresonance and damping (a data sheet is within a
    factor 2), the recording the absolute ones of torques and speeds."""
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
            return Parameter(key, max(0.002, n / 5.0), min(1.0, 5.0 * n), value, n, log=True)
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


def free_keys(
    axis: AxisConfig, added_keys: Sequence[str] = (), fixed: Sequence[str] = ()
) -> list[str]:
    """Keys refitted for a model: the uncertain keys present, plus ``added_keys`` (continuous
    keys of effects the diagnosis added, a torque limit), minus ``fixed`` (a backlash
    contact, parameters held at nominal). A key whose every change would make the axis
    invalid is not free: a backlash present with 0 on a rigid axis (it needs an
    antiresonance) stays 0."""
    keys = [k for k in UNCERTAIN_KEYS if axis.value(k) is not None and k not in fixed]
    keys += [k for k in added_keys if k not in fixed and k not in keys]
    if axis.is_rigid and "mechanics.backlash" in keys:
        keys.remove("mechanics.backlash")
    out: list[str] = []
    for k in keys:
        if k == "disturbance.periodic_amplitude":
            out += [PERIODIC_COS, PERIODIC_SIN]
        elif k != "disturbance.periodic_phase":
            out.append(k)
    return out


def current_value(axis: AxisConfig, key: str) -> float:
    if key in (PERIODIC_COS, PERIODIC_SIN):
        amp = axis.disturbance.periodic_amplitude or 0.0
        phase = axis.disturbance.periodic_phase or 0.0
        return amp * (math.cos(phase) if key == PERIODIC_COS else math.sin(phase))
    value = axis.value(key)
    return 0.0 if value is None else float(value)


def base_parameters(
    axis: AxisConfig,
    keys: Sequence[str],
    scales: DataScales,
    nominal: AxisConfig,
    hold: Sequence[str] = (),
) -> tuple[Parameter, ...]:
    """The fitted parameters of ``keys`` around their values in ``axis``; the ``hold`` ones
    (suspects of a re-fit, while effects are compared) only within their data-sheet
    uncertainty (:func:`within_uncertainty`)."""
    params = (parameter_for(k, current_value(axis, k), scales, nominal, axis) for k in keys)
    return tuple(within_uncertainty(p, nominal) if p.key in hold else p for p in params)


def _max_wa(parameters: Sequence[Parameter], axis: AxisConfig) -> float | None:
    for p in parameters:
        if p.key == "mechanics.antiresonance":
            return p.high
    return axis.mechanics.antiresonance


def nominal_spec(
    axis: AxisConfig, scales: DataScales, idim: Mapping[str, float], n_global: int = 12
) -> FitSpec:
    """Re-fit of the nominal model's uncertain parameters: starts at the nominal values, at
    the inverse-dynamics estimates, and at the best points of a Sobol sample of the box."""
    params = base_parameters(axis, free_keys(axis), scales, axis)
    idim_start = {k: v for k, v in idim.items() if any(p.key == k for p in params)}
    return FitSpec(
        base=axis,
        parameters=params,
        extra_starts=(idim_start,) if idim_start else (),
        options=options_for(_max_wa(params, axis), axis),
        n_global=n_global,
    )


@dataclass(frozen=True)
class Suspect:
    """A re-fitted parameter that ended on a bound of its search box or moved further from
    the nominal value than its data-sheet uncertainty: a sign of missing physics."""

    key: str
    nominal: float
    fitted: float
    uncertainty: float  # relative
    on_bound: str  # "", "lower" or "upper"

    @property
    def change_percent(self) -> float:
        return 100.0 * (self.fitted / self.nominal - 1.0) if self.nominal else math.inf


def suspects(
    result: FitResult, parameters: Sequence[Parameter], nominal: AxisConfig
) -> list[Suspect]:
    """Parameters of a re-fit that ended on a bound (within 1 % of the box in normalised
    units; a friction or torque ending at zero counts) or moved beyond :data:`UNCERTAINTY`
    from their nominal value (only keys the nominal has with a non-zero value)."""
    out = []
    for p in parameters:
        if p.key not in result.values or p.key in MODEL_FORM_KEYS:
            continue
        value = result.values[p.key]
        lo, hi = p.u_bounds
        u = p.to_u(value)
        tol = 0.01 * (hi - lo)
        bound = "lower" if u <= lo + tol else "upper" if u >= hi - tol else ""
        nom = nominal.value(p.key) if p.key not in (PERIODIC_COS, PERIODIC_SIN) else None
        rel = UNCERTAINTY.get(p.key, 1.0)
        moved = nom is not None and beyond_uncertainty(p.key, value, nominal)
        if bound and p.low == 0.0 and (nom is None or nom == 0.0):
            bound = ""  # an absent/zero value staying at zero is no finding
        if bound or moved:
            out.append(Suspect(p.key, float(nom or 0.0), float(value), rel, bound))
    return out


def uncertainty_box(key: str, nominal: AxisConfig) -> tuple[float, float] | None:
    """The values a data sheet allows for ``key``: the nominal value within its relative
    :data:`UNCERTAINTY` (None: the nominal has no value for it)."""
    n = nominal.value(key)
    if n is None or n == 0.0:
        return None
    u = UNCERTAINTY.get(key, 1.0)
    lo, hi = sorted((n * (1.0 - u), n * (1.0 + u)))
    return lo, hi


def beyond_uncertainty(key: str, value: float, nominal: AxisConfig) -> bool:
    """Whether ``value`` lies outside the data sheet's :func:`uncertainty_box` (False when
    the nominal has no value for ``key``)."""
    box = uncertainty_box(key, nominal)
    return box is not None and not box[0] <= value <= box[1]


def within_uncertainty(p: Parameter, nominal: AxisConfig) -> Parameter:
    """``p`` with its bounds cut to the data sheet's :func:`uncertainty_box`."""
    box = uncertainty_box(p.key, nominal)
    if box is None:
        return p
    lo, hi = max(p.low, box[0]), min(p.high, box[1])
    if not lo < hi:
        return p
    return Parameter(p.key, lo, hi, p.start, p.scale, p.log)


def held_within(axis: AxisConfig, nominal: AxisConfig, keys: Sequence[str]) -> AxisConfig:
    """``axis`` with ``keys`` moved to the nearest value its data sheet allows."""
    values = {}
    for k in keys:
        box, v = uncertainty_box(k, nominal), axis.value(k)
        if box is not None and v is not None:
            values[k] = min(box[1], max(box[0], float(v)))
    return axis.with_values(values) if values else axis


def held_at_nominal(axis: AxisConfig, nominal: AxisConfig, keys: Sequence[str]) -> AxisConfig:
    """``axis`` with ``keys`` set back to their nominal values (keys the nominal has)."""
    values = {k: nominal.value(k) for k in keys if nominal.value(k) is not None}
    return axis.with_values(values) if values else axis

"""The candidate effects of the axis-file table: which keys model them, their bounds and
their starting values (from the recording where the data tell them).

Names and keys are the table of ``shared/spec/axis-file.md``. An effect is *in* a model when
its keys are present; the diagnosis tries every effect that is not. Bounds scale with the
recording (peak torque, top speed, following error) so that one rule serves a 6.5 t milling
axis and a 25 kg slide. Every bound and starting rule is here; :mod:`.fit` only searches.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
from scipy import signal as sps

from ..axis import AxisConfig
from ..kernel import MAX_DELAY
from ..model import MAX_OMEGA_DT, KernelOptions
from ..trace import Trace
from .fit import PERIODIC_COS, PERIODIC_SIN, DiscreteParameter, FitSpec, Parameter
from .replay import ReplayInput


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


EFFECT_KEYS: dict[Effect, tuple[str, ...]] = {
    Effect.BACKLASH: ("mechanics.backlash",),
    Effect.COMPLIANCE: ("mechanics.antiresonance", "mechanics.damping_ratio"),
    Effect.COULOMB_FRICTION: ("friction.coulomb",),
    Effect.VISCOUS_FRICTION: ("friction.viscous",),
    Effect.ASYMMETRIC_FRICTION: ("friction.coulomb_negative", "friction.viscous_negative"),
    Effect.STRIBECK_FRICTION: ("friction.stribeck", "friction.stribeck_speed"),
    Effect.CONSTANT_LOAD_TORQUE: ("disturbance.constant_torque",),
    Effect.PERIODIC_DISTURBANCE: (
        "disturbance.periodic_amplitude",
        "disturbance.periodic_period",
        "disturbance.periodic_phase",
    ),
    Effect.TORQUE_SATURATION: ("control.torque_limit",),
    Effect.TIME_DELAY: ("control.delay",),
}

#: What each effect does, for the explanation paragraph.
DESCRIPTION: dict[Effect, str] = {
    Effect.BACKLASH: "free play between motor and load (the motor crosses a gap at reversals)",
    Effect.COMPLIANCE: "an elastic transmission (motor and load positions differ with the force)",
    Effect.COULOMB_FRICTION: "a friction torque of constant size opposing the motion",
    Effect.VISCOUS_FRICTION: "a friction torque growing with speed",
    Effect.ASYMMETRIC_FRICTION: "friction that differs between the two directions of motion",
    Effect.STRIBECK_FRICTION: "extra static friction near zero speed (break-away peak)",
    Effect.CONSTANT_LOAD_TORQUE: "a constant load torque (gravity, counterweight error) "
    "that the motor must hold even at rest",
    Effect.PERIODIC_DISTURBANCE: "a torque that repeats with position (cogging, screw lead error)",
    Effect.TORQUE_SATURATION: "a torque limit that clips the fastest accelerations",
    Effect.TIME_DELAY: "a dead time between the speed controller and the torque",
}

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
}

GENERIC_EXPERIMENT = (
    "a recording that excites the two differently: slow and fast moves, reversals with and "
    "without dwell, a dwell at standstill, and a second recording to validate on"
)


def experiment_for(a: Effect, b: Effect) -> str:
    return EXPERIMENTS.get(frozenset({a, b}), GENERIC_EXPERIMENT)


def effects_in(axis: AxisConfig) -> frozenset[Effect]:
    """Effects whose (first) key is present in ``axis``."""
    present = set()
    for effect, keys in EFFECT_KEYS.items():
        if any(axis.value(k) is not None for k in keys):
            present.add(effect)
    return frozenset(present)


# ----------------------------------------------------------------------------------------
# what the recording says about scales
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DataScales:
    """Scales of one recording: torques N·m, speeds/positions in load units."""

    torque_peak: float  # 99.5th percentile of |motor_torque|
    torque_max: float  # max |motor_torque|
    speed_max: float  # max |reference speed|
    span: float  # travel of the reference
    following_error: float  # std of the feedback following error
    sample_time_s: float
    speed: np.ndarray  # actual load speed at the recording samples (smoothed derivative)
    accel: np.ndarray  # actual load acceleration
    position: np.ndarray  # feedback position (load units)


def _derivatives(x: np.ndarray, dt: float, window_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    win = max(5, 2 * round(window_s / dt / 2) + 1)
    win = min(win, len(x) - (1 - len(x) % 2))
    v = sps.savgol_filter(x, win, 3, deriv=1, delta=dt)
    a = sps.savgol_filter(x, win, 3, deriv=2, delta=dt)
    return v, a


def data_scales(inp: ReplayInput) -> DataScales:
    rec = inp.recorded
    tau = np.abs(rec["motor_torque"])
    ref = rec["position_reference"]
    dt = float(np.median(np.diff(inp.time_s)))
    if "load_position" in rec and inp.feedback.value == "load":
        pos = rec["load_position"]
    else:
        pos = rec["motor_position"] / inp.transmission_ratio
    v, a = _derivatives(pos, dt)
    v_ref = np.gradient(ref, inp.time_s)
    return DataScales(
        torque_peak=max(float(np.percentile(tau, 99.5)), 1e-12),
        torque_max=max(float(tau.max()), 1e-12),
        speed_max=max(float(np.max(np.abs(v_ref))), 1e-12),
        span=max(float(np.ptp(ref)), 1e-12),
        following_error=max(float(np.std(ref - pos)), 1e-12),
        sample_time_s=dt,
        speed=v,
        accel=a,
        position=pos,
    )


def inverse_dynamics(inp: ReplayInput, axis: AxisConfig, scales: DataScales) -> dict[str, float]:
    """Least-squares starting values from the rigid-body torque balance on moving samples:

        τ = J·k_r·a + c·sign(v) + b·v + τ_0            (symmetric)
        τ = J·k_r·a + c₊·[v>0] − c₋·[v<0] + b₊·v⁺ + b₋·v⁻   (direction-dependent)

    with v, a the measured load speed/acceleration (Savitzky-Golay). Returns estimates keyed
    by axis keys (load_mass from J − J_motor_side); only a start for the simulation fit."""
    v, a = scales.speed, scales.accel
    tau = inp.recorded["motor_torque"]
    moving = np.abs(v) > 0.02 * scales.speed_max
    if moving.sum() < 20:
        return {}
    kr = axis.transmission_ratio
    s = np.sign(v[moving])
    vm, am, tm = v[moving], a[moving], tau[moving]
    sym = np.column_stack([kr * am, s, vm, np.ones_like(vm)])
    coef, *_ = np.linalg.lstsq(sym, tm, rcond=None)
    pos = (s > 0).astype(float)
    neg = (s < 0).astype(float)
    asym = np.column_stack([kr * am, pos, -neg, vm * pos, vm * neg])
    coef2, *_ = np.linalg.lstsq(asym, tm, rcond=None)
    j_load = coef[0] - axis.motor_side_inertia
    out = {
        "friction.coulomb": float(coef[1]),
        "friction.viscous": float(coef[2]),
        "disturbance.constant_torque": float(coef[3]),
        "friction.coulomb_positive": float(coef2[1]),
        "friction.coulomb_negative": float(coef2[2]),
        "friction.viscous_positive": float(coef2[3]),
        "friction.viscous_negative": float(coef2[4]),
    }
    if j_load > 0.0:
        out["mechanics.load_mass"] = float(j_load * kr**2)
    return out


def effect_present(effect: Effect, fitted: AxisConfig, scales: DataScales) -> bool:
    """False when the fitted effect sits at its "absent" value (zero backlash, zero load
    torque, a direction-independent friction, ...) — then a held-out gain of that candidate
    came from the re-fitted model parameters, not from the effect, and it is not named.
    Thresholds: 0.1 % of the recording's peak torque (0.1 % of the following error's spread
    for backlash)."""
    tiny = 1e-3 * scales.torque_peak
    f = fitted.friction
    if effect is Effect.BACKLASH:
        return (fitted.mechanics.backlash or 0.0) > 1e-3 * scales.following_error
    if effect is Effect.COULOMB_FRICTION:
        return (f.coulomb or 0.0) > tiny
    if effect is Effect.VISCOUS_FRICTION:
        return (f.viscous or 0.0) * scales.speed_max > tiny
    if effect is Effect.ASYMMETRIC_FRICTION:
        dc = abs((f.coulomb_negative or 0.0) - (f.coulomb or 0.0))
        dv = abs((f.viscous_negative or 0.0) - (f.viscous or 0.0)) * scales.speed_max
        return max(dc, dv) > tiny
    if effect is Effect.STRIBECK_FRICTION:
        return (f.stribeck or 0.0) > tiny
    if effect is Effect.CONSTANT_LOAD_TORQUE:
        return abs(fitted.disturbance.constant_torque or 0.0) > tiny
    if effect is Effect.PERIODIC_DISTURBANCE:
        return (fitted.disturbance.periodic_amplitude or 0.0) > tiny
    return True


# ----------------------------------------------------------------------------------------
# parameters
# ----------------------------------------------------------------------------------------
def speed_loop_bandwidth(axis: AxisConfig) -> float:
    """rad/s: k_sp / J_total, the crossover of the speed loop (rigid approximation)."""
    return axis.control.ksp / axis.total_inertia


def max_antiresonance(axis: AxisConfig, max_substeps: int = 5) -> float:
    """Largest ω_a fitted: the resonance ω_r = ω_a·√(1+R) must keep ω_r·dt <= MAX_OMEGA_DT
    with at most ``max_substeps`` mechanics substeps per speed cycle (cost of a simulation)."""
    r = axis.load_inertia_reflected / axis.motor_side_inertia
    return max_substeps * MAX_OMEGA_DT / axis.control.speed_cycle / math.sqrt(1.0 + r)


def contact_antiresonance(axis: AxisConfig) -> float:
    """ω_a of the stiff contact added with backlash to a rigid model: ten times the speed
    loop's bandwidth, at most what 3 substeps per speed cycle integrate."""
    return min(10.0 * speed_loop_bandwidth(axis), 0.99 * max_antiresonance(axis, 3))


#: Damping ratio of that contact (a steel flank contact; only sets the impact loss).
CONTACT_DAMPING = 0.1


def options_for(axis_max_wa: float | None, axis: AxisConfig) -> KernelOptions:
    """Kernel substeps fixed for a whole fit, from the largest ω_a it may visit."""
    if axis_max_wa is None:
        return KernelOptions(substeps=1)
    r = axis.load_inertia_reflected / axis.motor_side_inertia
    wr = axis_max_wa * math.sqrt(1.0 + r)
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
)


def free_keys(
    axis: AxisConfig, added: Sequence[Effect] = (), fixed: Sequence[str] = ()
) -> list[str]:
    """Keys refitted for a model: the uncertain keys present, plus the continuous keys of
    effects the diagnosis added (torque limit), minus ``fixed`` (a backlash contact)."""
    keys = [k for k in UNCERTAIN_KEYS if axis.value(k) is not None and k not in fixed]
    if Effect.TORQUE_SATURATION in added and "control.torque_limit" not in fixed:
        keys.append("control.torque_limit")
    out: list[str] = []
    for k in keys:
        if k == "disturbance.periodic_amplitude":
            out += [PERIODIC_COS, PERIODIC_SIN]
        else:
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
    axis: AxisConfig, keys: Sequence[str], scales: DataScales, nominal: AxisConfig
) -> tuple[Parameter, ...]:
    return tuple(parameter_for(k, current_value(axis, k), scales, nominal, axis) for k in keys)


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


# ----------------------------------------------------------------------------------------
# starting values of effects from the residual of the current model
# ----------------------------------------------------------------------------------------
def _direction_offset(r: np.ndarray, v: np.ndarray, vmax: float) -> float | None:
    pos, neg = v > 0.05 * vmax, v < -0.05 * vmax
    if pos.sum() < 10 or neg.sum() < 10:
        return None
    return float(np.median(r[pos]) - np.median(r[neg]))


def periodic_peaks(
    residual_torque: np.ndarray, scales: DataScales, n_peaks: int = 2
) -> list[tuple[float, float, float]]:
    """Top peaks (period, A·cos φ, A·sin φ) of the torque residual against position: the
    moving samples are averaged in position bins (a quarter of the shortest period looked
    for), the binned residual's spectrum over position (FFT, zero-padded four times) gives
    the candidate periods, and a least-squares sine fit on the samples their amplitude and
    phase. The starts of the periodic disturbance."""
    v, x = scales.speed, scales.position
    moving = np.abs(v) > 0.05 * scales.speed_max
    if moving.sum() < 50:
        return []
    xm, rm = x[moving], residual_torque[moving] - np.mean(residual_torque[moving])
    step = float(np.median(np.abs(v[moving]))) * scales.sample_time_s
    p_lo = max(8.0 * step, scales.span / 2000.0)
    p_hi = scales.span / 3.0
    if not p_hi > p_lo:
        return []
    width = p_lo / 4.0
    edges_lo = float(xm.min())
    idx = np.floor((xm - edges_lo) / width).astype(int)
    n_bins = int(idx.max()) + 1
    sums = np.bincount(idx, rm, n_bins)
    counts = np.bincount(idx, None, n_bins)
    binned = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    size = 4 * (1 << (n_bins - 1).bit_length())
    power = np.abs(np.fft.rfft(binned, size)) ** 2
    freqs = np.fft.rfftfreq(size, width)  # cycles per load unit
    with np.errstate(divide="ignore"):
        periods = np.where(freqs > 0, 1.0 / freqs, np.inf)
    band = (periods >= p_lo) & (periods <= p_hi)
    peaks = sps.argrelmax(np.where(band, power, 0.0))[0]
    peaks = peaks[band[peaks]]
    peaks = peaks[np.argsort(power[peaks])[::-1]][:n_peaks]
    out = []
    for i in peaks:
        per = float(periods[i])
        phase = 2.0 * np.pi * xm / per
        basis = np.column_stack([np.sin(phase), np.cos(phase)])
        (a, b), *_ = np.linalg.lstsq(basis, rm, rcond=None)
        out.append((per, float(a), float(b)))
    return out


@dataclass(frozen=True)
class Evidence:
    """What the current model leaves in the residual: the recording and its simulation."""

    inp: ReplayInput
    simulated: Trace
    scales: DataScales


def candidate_specs(
    effect: Effect,
    model: AxisConfig,
    nominal: AxisConfig,
    evidence: Evidence,
    n_global: int = 4,
) -> tuple[list[FitSpec], list[str]]:
    """Fit specifications of ``effect``'s own parameters added to ``model`` (alternatives;
    the best wins), and notes for the report (e.g. a stiff contact that was added)."""
    sc = evidence.scales
    inp, sim = evidence.inp, evidence.simulated
    rec = inp.recorded
    kr = model.transmission_ratio
    tp, vmax = sc.torque_peak, sc.speed_max
    base: tuple[Parameter, ...] = ()
    notes: list[str] = []
    res_tau = rec["motor_torque"] - sim["motor_torque"]

    def spec(
        extra: Sequence[Parameter],
        starts: Sequence[Mapping[str, float]] = (),
        on: AxisConfig = model,
        discrete: DiscreteParameter | None = None,
    ) -> FitSpec:
        params = (*base, *extra)
        return FitSpec(
            base=on,
            parameters=params,
            extra_starts=tuple(starts),
            discrete=discrete,
            options=options_for(_max_wa(params, on), on),
            n_global=n_global if extra else 0,
        )

    def p(key: str, value: float, on: AxisConfig = model) -> Parameter:
        return parameter_for(key, value, sc, nominal, on)

    both = "motor_position" in rec and "load_position" in rec
    if effect is Effect.BACKLASH:
        on = model
        if model.is_rigid:
            wa = contact_antiresonance(model)
            on = model.with_values(
                {"mechanics.antiresonance": wa, "mechanics.damping_ratio": CONTACT_DAMPING}
            )
            notes.append(
                f"backlash needs a contact stiffness: a stiff mechanics.antiresonance = "
                f"{wa:.4g} rad/s (ten times the speed-loop bandwidth) with damping_ratio = "
                f"{CONTACT_DAMPING} was added with it and not fitted"
            )
        guesses = [0.002 * sc.following_error, 0.02 * sc.following_error]
        if both:
            defl_rec = rec["motor_position"] / kr - rec["load_position"]
            defl_sim = sim["motor_position"] / kr - sim["load_position"]
            d = _direction_offset(defl_rec - defl_sim, sc.speed, vmax)
            if d is not None and d > 0.0:
                guesses.insert(0, d)
        b = p("mechanics.backlash", guesses[0], on)
        starts = [{"mechanics.backlash": g} for g in guesses[1:]]
        return [spec([b], starts, on)], notes
    if effect is Effect.COMPLIANCE:
        wmax = max_antiresonance(model)
        bw = speed_loop_bandwidth(model)
        guesses = [min(wmax, f * bw) for f in (1.5, 4.0)]
        if both:
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
            notes.append(
                f"compliance not tried: with this inertia split an elastic element needs "
                f"omega_a in [{lo:.3g}, {wmax:.3g}] rad/s, an empty range (give "
                f"mechanics.motor_inertia its real value to test compliance)"
            )
            return [], notes
        wa_p = Parameter("mechanics.antiresonance", lo, wmax, guesses[0], guesses[0], log=True)
        xi_p = Parameter("mechanics.damping_ratio", 0.005, 0.7, 0.05, 0.05, log=True)
        on = model.with_values(
            {"mechanics.antiresonance": guesses[0], "mechanics.damping_ratio": 0.05}
        )
        starts = [{"mechanics.antiresonance": g} for g in guesses[1:]]
        return [spec([wa_p, xi_p], starts, on)], notes
    if effect in (Effect.COULOMB_FRICTION, Effect.VISCOUS_FRICTION, Effect.CONSTANT_LOAD_TORQUE):
        key = EFFECT_KEYS[effect][0]
        idim = inverse_dynamics(inp, model, sc)
        guess = idim.get(key, 0.0)
        if effect is Effect.CONSTANT_LOAD_TORQUE:
            moving_res = res_tau[np.abs(sc.speed) > 0.05 * vmax]
            guess = float(np.median(moving_res)) if len(moving_res) else guess
        default = 0.02 * tp if effect is not Effect.VISCOUS_FRICTION else 0.02 * tp / vmax
        if effect is not Effect.CONSTANT_LOAD_TORQUE and guess <= 0.0:
            guess = default
        par = p(key, guess)
        return [spec([par], [{key: 0.0}])], notes
    if effect is Effect.ASYMMETRIC_FRICTION:
        c = model.friction.coulomb or 0.0
        b = model.friction.viscous or 0.0
        d = _direction_offset(res_tau, sc.speed, vmax) or 0.0
        # residual higher moving + than moving -: negative direction needs less friction
        c_neg = max(0.0, c - d)
        pc = p("friction.coulomb_negative", c_neg)
        pv = p("friction.viscous_negative", b)
        starts = [{"friction.coulomb_negative": c, "friction.viscous_negative": b}]
        return [spec([pc, pv], starts)], notes
    if effect is Effect.STRIBECK_FRICTION:
        c = model.friction.coulomb or 0.0
        fs = max(0.5 * c, 0.02 * tp)
        ps = p("friction.stribeck", fs)
        pv = p("friction.stribeck_speed", 0.02 * vmax)
        starts = [{"friction.stribeck_speed": f * vmax} for f in (0.005, 0.1)]
        return [spec([ps, pv], starts)], notes
    if effect is Effect.PERIODIC_DISTURBANCE:
        specs = []
        for period, a, b in periodic_peaks(res_tau, sc):
            on = model.with_values(
                {
                    "disturbance.periodic_amplitude": 0.0,
                    "disturbance.periodic_period": period,
                    "disturbance.periodic_phase": 0.0,
                }
            )
            params = [
                p(PERIODIC_COS, a, on),
                p(PERIODIC_SIN, b, on),
                parameter_for("disturbance.periodic_period", period, sc, nominal, on),
            ]
            specs.append(spec(params, [], on))
        return specs, notes
    if effect is Effect.TORQUE_SATURATION:
        peak = sc.torque_max
        par = p("control.torque_limit", peak)
        pct = float(np.percentile(np.abs(rec["motor_torque"]), 99.9))
        return [spec([par], [{"control.torque_limit": pct}])], notes
    if effect is Effect.TIME_DELAY:
        cyc = model.control.speed_cycle
        grid = [n * cyc for n in (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32) if n <= MAX_DELAY]
        grid = [g for g in grid if g <= 0.1]
        disc = DiscreteParameter("control.delay", tuple(grid), grid[0])
        return [spec([], [], model, disc)], notes
    raise KeyError(effect)

"""The third plant's concealed-effect test set: its own families, excitation, effects,
noise and nominal files (nothing taken from ``diagnosis.synthetic`` but the
:class:`~diagnosis.synthetic.Case` / ``GeneratedCase`` records the matrix reads).

Families (both elastic in their data sheets, so the nominal files have an antiresonance):

* ``rotary`` — a rotary table behind a 1:90 gear, position loop on the table's encoder, a
  torsional coupling mode at 900 Hz the format cannot state, LuGre friction;
* ``vertical`` — a Z axis, 16 mm ball screw, 60 kg head with a counterweight that leaves
  35 N of gravity to the motor, position loop on the motor encoder with a linear scale
  recorded, coupling mode at 1.1 kHz.

Each effect of the table is concealed once per family (its truth has it, its nominal file
not), at a size comparable to the torque noise; two recordings per family with nothing left
out. Modelling choices of this plant that no axis file states, present in every recording:
the coupling's torsion, LuGre pre-sliding (bristle) friction, the PI current loop on an R-L
winding with back-EMF and its PWM delay, the encoder's interpolation error, the trace's
anti-alias filter on the torque, a dead time placed in the speed set-point path (a field-bus
stage) when the dead time is the concealed effect, a position cycle of 1 ms recorded at
every cycle (not every second one).

Excitation (:func:`program`): an NC program of rapids without jerk limit (acceleration
steps), feeds with cosine-shaped (jerk-limited) acceleration at five feed rates down to a
creep feed, back-and-forth arcs, and dwells. Unrecorded process load: random load steps
through a 30 ms lag plus a slow cable-chain force.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from diagnosis.effects import MODELS, Effect
from diagnosis.synthetic import Case, GeneratedCase, case_list, trapezoid
from plant_sim.physics.simulate import References
from reference_plants.third.plant import Physics, axis_of, simulate
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import MOTION_COLUMNS, Trace

#: Seeds of this set are offset from the others' (no shared random streams).
SEED_SHIFT = 104_729


@dataclass(frozen=True)
class Motion:
    """NC-program limits (load units, s)."""

    position_range: tuple[float, float]
    feeds: tuple[float, ...]  # the slowest is a creep feed
    rapid: float
    accel: float


@dataclass(frozen=True)
class NoiseLevels:
    torque: float  # N m, white on the traced torque
    torque_quantum: float  # N m, the current ADC's step
    speed: float  # rad/s on the traced speed actual value
    scale_error: float  # load units, graduation error amplitude of the load scale
    scale_period: float  # load units
    process: float  # N m at the motor, unrecorded load steps


@dataclass(frozen=True)
class Family:
    name: str
    base: Physics
    motion: Motion
    noise: NoiseLevels
    effects: dict[Effect, Callable[[Physics], Physics]] = field(default_factory=dict)


def _drive_train(
    kr: float, jm: float, js: float, mass: float, coupling_hz: float, kn: float, zeta_kn_wa: float
) -> dict[str, float]:
    """Motor, coupling (2 % damped, at ``coupling_hz`` against the reduced inertia), screw,
    nut (stiffness ``kn``, damping 2·ζ·kn/ω_a given as ``zeta_kn_wa`` = ζ·kn/ω_a) and load."""
    jred = 1.0 / (1.0 / jm + 1.0 / js)
    kc = (2.0 * math.pi * coupling_hz) ** 2 * jred
    return {
        "transmission_ratio": kr,
        "motor_inertia": jm,
        "screw_inertia": js,
        "coupling_stiffness": kc,
        "coupling_damping": 2.0 * 0.02 * math.sqrt(kc * jred),
        "load_mass": mass,
        "nut_stiffness": kn,
        "nut_damping": 2.0 * zeta_kn_wa,
        "backlash": 0.0,
    }


def _lugre(
    coulomb: float, stribeck_speed: float, sig0: float, mass: float, viscous: float
) -> dict[str, float]:
    """Symmetric LuGre friction without a Stribeck peak (static = Coulomb), bristle damping
    0.2·sqrt(σ0·m)."""
    return {
        "coulomb_pos": coulomb,
        "coulomb_neg": coulomb,
        "static_pos": coulomb,
        "static_neg": coulomb,
        "stribeck_speed": stribeck_speed,
        "bristle_stiffness": sig0,
        "bristle_damping": 0.2 * math.sqrt(sig0 * mass),
        "viscous_pos": viscous,
        "viscous_neg": viscous,
    }


def _rotary() -> Family:
    kr, jm, js, mass = 90.0, 1.2e-3, 4.0e-4, 3.0
    wa = 2.0 * math.pi * 55.0
    kn = mass * wa**2
    sig0 = 9.0 / 5e-5
    base = Physics(
        kind="rotary",
        **_drive_train(kr, jm, js, mass, 900.0, kn, 0.05 * kn / wa),
        **_lugre(9.0, 0.02, sig0, mass, 25.0),
        load_force=0.0,
        periodic_force=0.0,
        periodic_period=2.0 * math.pi / 40.0,
        periodic_phase=0.0,
        kv=30.0,
        ksp=0.69,
        tsi=0.012,
        torque_limit=math.inf,
        position_cycle=0.001,
        speed_cycle=0.00025,
        current_per_speed_cycle=4,
        load_feedback=True,
        speed_filter=0.0001,
        setpoint_delay_cycles=0,
        sensor_offset=0.0,
        winding_resistance=1.2,
        winding_inductance=0.003,
        torque_constant=0.6,
        bus_voltage=320.0,
        current_lag=0.0003,
        encoder_lines=2048,
        encoder_error=2.0 * math.pi / 2048 / 300.0,
        encoder_quantum=2.0 * math.pi / 2**22,
        scale_quantum=2.0 * math.pi / 2**24,
        trace_filter=5e-5,
    )
    effects: dict[Effect, Callable[[Physics], Physics]] = {
        Effect.BACKLASH: lambda p: p.with_(backlash=2e-5),
        Effect.COMPLIANCE: lambda p: p,  # the nominal drops the table's elasticity
        Effect.COULOMB_FRICTION: lambda p: p.with_(
            coulomb_pos=3.0, coulomb_neg=3.0, static_pos=3.0, static_neg=3.0
        ),
        Effect.VISCOUS_FRICTION: lambda p: p.with_(viscous_pos=8.0, viscous_neg=8.0),
        Effect.ASYMMETRIC_FRICTION: lambda p: p.with_(
            coulomb_neg=11.0, static_neg=11.0, viscous_neg=28.0
        ),
        Effect.STRIBECK_FRICTION: lambda p: p.with_(static_pos=14.0, static_neg=14.0),
        Effect.CONSTANT_LOAD_TORQUE: lambda p: p.with_(load_force=2.5),
        Effect.PERIODIC_DISTURBANCE: lambda p: p.with_(periodic_force=2.0, periodic_phase=0.4),
        Effect.TORQUE_SATURATION: lambda p: p,  # set from the peak demand (generate)
        Effect.TIME_DELAY: lambda p: p.with_(setpoint_delay_cycles=1),
        Effect.SENSOR_TIME_OFFSET: lambda p: p.with_(sensor_offset=0.0004),
    }
    return Family(
        "rotary",
        base,
        Motion((0.0, 2.0), (0.004, 0.05, 0.2, 0.8, 1.5), 1.5, 8.0),
        NoiseLevels(0.015, 0.6 * 10.0 / 2048, 0.1, 5e-7, 2.0 * math.pi / 8192, 0.01),
        effects,
    )


def _vertical() -> Family:
    kr, jm, js, mass = 2.0 * math.pi / 0.016, 6.0e-4, 2.5e-4, 60.0
    kn = 1.2e8
    wa = math.sqrt(kn / mass)
    sig0 = 70.0 / 1e-6
    base = Physics(
        kind="linear",
        **_drive_train(kr, jm, js, mass, 1100.0, kn, 0.06 * kn / wa),
        **_lugre(70.0, 0.005, sig0, mass, 400.0),
        load_force=35.0,
        periodic_force=0.0,
        periodic_period=0.016,
        periodic_phase=0.0,
        kv=40.0,
        ksp=0.5,
        tsi=0.008,
        torque_limit=math.inf,
        position_cycle=0.001,
        speed_cycle=0.000125,
        current_per_speed_cycle=2,
        load_feedback=False,
        speed_filter=0.00015,
        setpoint_delay_cycles=0,
        sensor_offset=0.0,
        winding_resistance=0.9,
        winding_inductance=0.0025,
        torque_constant=0.45,
        bus_voltage=560.0,
        current_lag=0.00025,
        encoder_lines=1024,
        encoder_error=2.0 * math.pi / 1024 / 200.0,
        encoder_quantum=2.0 * math.pi / 2**20,
        scale_quantum=1e-9,
        trace_filter=5e-5,
    )
    effects: dict[Effect, Callable[[Physics], Physics]] = {
        Effect.BACKLASH: lambda p: p.with_(backlash=1e-5),
        Effect.COMPLIANCE: lambda p: p,
        Effect.COULOMB_FRICTION: lambda p: p.with_(
            coulomb_pos=20.0, coulomb_neg=20.0, static_pos=20.0, static_neg=20.0
        ),
        Effect.VISCOUS_FRICTION: lambda p: p.with_(viscous_pos=150.0, viscous_neg=150.0),
        Effect.ASYMMETRIC_FRICTION: lambda p: p.with_(
            coulomb_neg=85.0, static_neg=85.0, viscous_neg=450.0
        ),
        Effect.STRIBECK_FRICTION: lambda p: p.with_(static_pos=110.0, static_neg=110.0),
        Effect.CONSTANT_LOAD_TORQUE: lambda p: p,  # the nominal drops the gravity residual
        Effect.PERIODIC_DISTURBANCE: lambda p: p.with_(periodic_force=12.0, periodic_phase=-0.9),
        Effect.TORQUE_SATURATION: lambda p: p,
        Effect.TIME_DELAY: lambda p: p.with_(setpoint_delay_cycles=2),
        Effect.SENSOR_TIME_OFFSET: lambda p: p.with_(sensor_offset=0.0006),
    }
    return Family(
        "vertical",
        base,
        Motion((0.0, 0.25), (0.003, 0.02, 0.08, 0.25, 0.5), 0.5, 5.0),
        NoiseLevels(0.02, 0.45 * 10.0 / 2048, 0.2, 2e-8, 4e-5, 0.01),
        effects,
    )


FAMILIES: dict[str, Family] = {f.name: f for f in (_rotary(), _vertical())}

#: Fraction of the peak torque demand at which the concealed torque limit sits.
LIMIT_FRACTION = {"rotary": 0.95, "vertical": 0.93}
#: Parameters of a nominal file that are off like a data sheet's (5-10 %, random sign).
PERTURBED = (
    "mechanics.load_mass",
    "mechanics.antiresonance",
    "mechanics.damping_ratio",
    "friction.coulomb",
    "friction.viscous",
    "disturbance.constant_torque",
)


# ----------------------------------------------------------------------------------------
# the NC program
# ----------------------------------------------------------------------------------------
def _feed(distance: float, speed: float, accel: float, dt: float) -> np.ndarray:
    """Speed samples of a feed move: acceleration a raised cosine (jerk-limited)."""
    d = abs(distance)
    v = min(speed, math.sqrt(d * accel / 2.0))
    t_acc = 2.0 * v / accel  # mean acceleration of the raised cosine is accel/2
    t_const = max(0.0, d / v - t_acc)
    ramp_t = np.arange(0.0, t_acc, dt)
    ramp = v * (ramp_t / t_acc - np.sin(2.0 * math.pi * ramp_t / t_acc) / (2.0 * math.pi))
    prof = np.concatenate([ramp, np.full(round(t_const / dt), v), ramp[::-1]])
    travel = prof.sum() * dt
    if travel > 0.0:
        prof *= d / travel
    return math.copysign(1.0, distance) * prof


def program(
    motion: Motion, duration_s: float, cycle_s: float, rng: np.random.Generator
) -> np.ndarray:
    """Position reference, one value per position cycle: rapids, feeds, arcs and dwells in
    random order (a third rapids, a third feeds, a sixth arcs, the rest creep feeds)."""
    lo, hi = motion.position_range
    margin = 0.05 * (hi - lo)
    n_total = round(duration_s / cycle_s)
    pieces = [np.zeros(round(0.25 / cycle_s))]
    n = len(pieces[0])
    x = 0.5 * (lo + hi)
    while n < n_total:
        kind = rng.choice(["rapid", "feed", "arc", "creep"], p=[0.33, 0.33, 0.17, 0.17])
        target = float(rng.uniform(lo + margin, hi - margin))
        if kind == "arc":
            speed = float(rng.choice(motion.feeds[1:-1]))
            amp = min(0.08 * (hi - lo), hi - margin - x, x - lo - margin)
            amp = max(amp, 1e-9)
            freq = min(
                speed / (2.0 * math.pi * amp), math.sqrt(motion.accel / amp) / (2.0 * math.pi)
            )
            t = np.arange(0.0, float(rng.integers(1, 4)) / freq, cycle_s)
            prof = amp * 2.0 * math.pi * freq * np.sin(2.0 * math.pi * freq * t)
        elif kind == "rapid":
            prof = trapezoid(target - x, motion.rapid, motion.accel, cycle_s)
        elif kind == "feed":
            speed = float(rng.choice(motion.feeds[1:-1]))
            prof = _feed(target - x, speed, motion.accel * float(rng.uniform(0.3, 1.0)), cycle_s)
        else:
            speed = motion.feeds[0]
            dist = math.copysign(speed * float(rng.uniform(0.5, 1.5)), target - x)
            prof = _feed(dist, speed, motion.accel * 0.2, cycle_s)
        dwell = np.zeros(round(float(rng.uniform(0.05, 0.4)) / cycle_s))
        x += float(prof.sum() * cycle_s)
        pieces += [prof, dwell]
        n += len(prof) + len(dwell)
    speed_profile = np.concatenate(pieces)[:n_total]
    steps = np.cumsum(speed_profile[:-1]) * cycle_s
    return 0.5 * (lo + hi) + np.concatenate([[0.0], steps])


def process_load(level: float, n: int, cycle_s: float, rng: np.random.Generator) -> np.ndarray:
    """Unrecorded load torque (N·m at the motor): random steps (0.5 per second) through a
    30 ms lag, plus a slow cable-chain force; standard deviation about ``level``."""
    steps = np.zeros(n)
    events = rng.random(n) < 0.5 * cycle_s
    steps[events] = rng.normal(0.0, 1.0, int(events.sum()))
    level_path = np.cumsum(steps)
    level_path -= np.linspace(level_path[0], level_path[-1], n) * 0.5  # keep it bounded-ish
    a = math.exp(-cycle_s / 0.03)
    lagged = np.empty(n)
    acc = 0.0
    for i in range(n):
        acc = a * acc + (1.0 - a) * level_path[i]
        lagged[i] = acc
    t = np.arange(n) * cycle_s
    chain = 0.5 * np.sin(2.0 * math.pi * 0.7 * t + rng.uniform(0.0, 2.0 * math.pi))
    total = lagged / max(float(np.std(lagged)), 1e-12) + chain
    return level * total / max(float(np.std(total)), 1e-12)


# ----------------------------------------------------------------------------------------
# cases
# ----------------------------------------------------------------------------------------
def test_set(seed: int = 1, duration_s: float = 25.0, none_per_family: int = 2) -> list[Case]:
    """Every effect once per family and ``none_per_family`` recordings with nothing left out
    (the bookkeeping of any plant's test set: :func:`diagnosis.synthetic.case_list`)."""
    return case_list(
        {f.name: f.effects for f in FAMILIES.values()}, seed, duration_s, none_per_family
    )


@dataclass(frozen=True)
class Truth:
    """A case's physics with and without its concealed effect, and its inputs."""

    with_effect: Physics
    without: Physics
    references: References


def _family(case: Case) -> Family:
    if case.family not in FAMILIES:
        raise ValueError(f"case {case.name}: family {case.family!r}, allowed {sorted(FAMILIES)}")
    return FAMILIES[case.family]


def _nominal_of(truth: Physics, effect: Effect | None) -> AxisConfig:
    """The axis file of ``truth`` without the concealed effect's keys."""
    axis = axis_of(truth)
    if effect is None:
        return axis
    out = MODELS[effect].strip(axis)
    if effect is Effect.COMPLIANCE and axis.mechanics.backlash is not None:
        out = out.with_values({"mechanics.backlash": None})
    return out


def _inputs(fam: Family, duration_s: float, rng: np.random.Generator) -> References:
    """An NC program's position and speed references and the unrecorded process load."""
    cycle = fam.base.position_cycle
    position = program(fam.motion, duration_s, cycle, rng)
    speed = np.empty_like(position)
    speed[:-1] = np.diff(position) / cycle
    speed[-1] = speed[-2]
    load = process_load(fam.noise.process, len(position), cycle, rng)
    return References(position, speed, load)


def truth_of(case: Case) -> Truth:
    """The physics of ``case`` (deterministic in its seed)."""
    fam = _family(case)
    refs = _inputs(fam, case.duration_s, np.random.default_rng(case.seed + SEED_SHIFT))
    without = fam.base
    truth = fam.base if case.effect is None else fam.effects[case.effect](fam.base)
    if case.effect is Effect.TORQUE_SATURATION:
        free = simulate(truth, refs.position, refs.speed, refs.disturbance_nm)
        peak = float(np.max(np.abs(free["motor_torque"])))
        truth = truth.with_(torque_limit=LIMIT_FRACTION[fam.name] * peak)
    return Truth(truth, without, refs)


def _perturbed(axis: AxisConfig, rng: np.random.Generator) -> AxisConfig:
    changes: dict[str, float | None] = {}
    for key in PERTURBED:
        value = axis.value(key)
        if value:
            sign = 1.0 if rng.random() < 0.5 else -1.0
            changes[key] = float(value) * (1.0 + sign * float(rng.uniform(0.05, 0.10)))
    return axis.with_values(changes)


def _recorded(sim: Trace, noise: NoiseLevels, rng: np.random.Generator) -> dict[str, np.ndarray]:
    n = len(sim)
    cols = {name: sim[name].copy() for name in MOTION_COLUMNS}
    tq = cols["motor_torque"] + noise.torque * rng.standard_normal(n)
    cols["motor_torque"] = np.round(tq / noise.torque_quantum) * noise.torque_quantum
    cols["motor_speed"] = cols["motor_speed"] + noise.speed * rng.standard_normal(n)
    x = cols["load_position"]
    cols["load_position"] = x + noise.scale_error * np.sin(2.0 * math.pi * x / noise.scale_period)
    return cols


def generate(case: Case) -> GeneratedCase:
    """The recording of ``case`` on the third plant, its nominal file and truths."""
    fam = _family(case)
    truth = truth_of(case)
    rng = np.random.default_rng(case.seed + 2 * SEED_SHIFT)
    sim = simulate(
        truth.with_effect,
        truth.references.position,
        truth.references.speed,
        truth.references.disturbance_nm,
    )
    nominal = _perturbed(_nominal_of(truth.with_effect, case.effect), rng)
    return GeneratedCase(
        case=case,
        recording=Trace(_recorded(sim, fam.noise, rng)),
        nominal=nominal,
        truth=axis_of(truth.with_effect),
        truth_without=_nominal_of(truth.with_effect, case.effect),
        references=truth.references,
        process_nm=truth.references.disturbance_nm,
    )


def another_recording(gen: GeneratedCase, take: int) -> Trace:
    """A second recording of ``gen``'s hidden truth at another time (``take`` >= 1): the same
    axis (a concealed torque limit stays where the first recording's peak demand put it),
    another NC program, another unrecorded load, new noise."""
    if take < 1:
        raise ValueError(f"take = {take!r}: a second recording is take 1 or more")
    fam = _family(gen.case)
    truth = truth_of(gen.case).with_effect
    rng = np.random.default_rng([gen.case.seed + SEED_SHIFT, take])
    refs = _inputs(fam, gen.case.duration_s, rng)
    sim = simulate(truth, refs.position, refs.speed, refs.disturbance_nm)
    return Trace(_recorded(sim, fam.noise, rng))


def concealment(gen: GeneratedCase) -> dict[str, float]:
    """How hidden the effect is: RMS of (with − without the effect), noise-free, over the
    torque noise (``snr_motor_torque``) and over the torque's spread (``share_...``)."""
    if gen.case.effect is None:
        return {}
    truth = truth_of(gen.case)
    fam = _family(gen.case)
    refs = truth.references
    if gen.case.effect is Effect.COMPLIANCE:
        stiff = truth.with_effect.with_(
            nut_stiffness=truth.with_effect.nut_stiffness * 100.0,
            nut_damping=truth.with_effect.nut_damping * 10.0,
        )
        without = stiff
    elif gen.case.effect is Effect.CONSTANT_LOAD_TORQUE:
        without = truth.with_effect.with_(load_force=0.0)
    else:
        without = truth.without
    a = simulate(truth.with_effect, refs.position, refs.speed, refs.disturbance_nm)
    b = simulate(without, refs.position, refs.speed, refs.disturbance_nm)
    out = {}
    for name in ("motor_torque", "motor_speed"):
        diff = a[name] - b[name]
        rms = float(np.sqrt(np.mean(diff**2)))
        level = fam.noise.torque if name == "motor_torque" else fam.noise.speed
        out[f"snr_{name}"] = rms / level
        out[f"share_{name}"] = rms / max(float(np.std(a[name])), 1e-300)
    return out

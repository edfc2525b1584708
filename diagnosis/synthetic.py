"""The concealed test set: recordings of hidden "true" axes, each hiding one effect (or none).

Every case has a hidden truth axis and a nominal axis file, the one the diagnosis is given:
the truth minus the concealed effect, with the uncertain parameters (load mass, friction,
antiresonance, damping) off by 5-10 % as a data sheet would be. The recording is simulated
from the truth with a configuration the diagnosis is not told about:

* finer integration (twice the default mechanics substeps);
* an unrecorded process disturbance: low-pass filtered random torque on the load (cable
  drag, way covers, cutting noise) that no axis-file key models;
* measurement noise on every recorded column (white, per-signal levels of the family);
* sampling every second position cycle (2 ms for a 1 ms position cycle), so the diagnosis has to
  resample its reference onto the control grid;
* realistic excitation: jerk-limited point-to-point moves at slow to fast feeds, dwells at
  standstill, direct reversals (sinusoidal back-and-forth) and reversals after a dwell.

Concealed: each effect is scaled so that its footprint in every recorded signal is small
against the rest of the dynamics (a few per cent of the signal's spread) and comparable to
the measurement noise; :func:`concealment` measures both for the README table.

Two families of axes: ``mill`` (the paper's 6.5 t milling axis: elastic, position loop on the
linear scale) and ``slide`` (a light ball-screw slide: rigid nominal model, position loop on
the motor encoder, a linear scale recorded alongside).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import signal as sps

from plant_sim.physics.model import KernelOptions, default_substeps
from plant_sim.physics.simulate import References, simulate
from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import (
    AxisConfig,
    AxisKind,
    Control,
    Friction,
    Mechanics,
    PositionFeedback,
)
from virtual_bus.formats.trace import MOTION_COLUMNS, Trace

from .effects import MODELS, Effect
from .errors import DiagnosisOptionError

#: Recording sample time in position cycles.
DECIMATION = 2


@dataclass(frozen=True)
class Excitation:
    """Reference generator limits (load units, s)."""

    position_range: tuple[float, float]
    speeds: tuple[float, ...]  # feeds drawn for the moves, load units/s
    accel: float  # largest acceleration, load units/s^2
    jerk_time_s: float = 0.02  # moving-average smoothing of the speed profile
    dwell_s: tuple[float, float] = (0.1, 0.5)


@dataclass(frozen=True)
class Noise:
    """Standard deviations of the white measurement noise per column, and of the unrecorded
    process disturbance (N·m at the motor, low-pass filtered at ``process_band_hz``)."""

    motor_torque: float
    motor_speed: float
    motor_position: float
    load_position: float
    process_nm: float
    process_band_hz: float = 2.0


@dataclass(frozen=True)
class Family:
    """A hidden base axis, its excitation and its noise."""

    name: str
    truth: AxisConfig
    excitation: Excitation
    noise: Noise
    #: effect -> changes to the truth that conceal it (dotted key -> value), per variant
    effects: dict[Effect, tuple[dict[str, float | None], ...]] = field(default_factory=dict)


def _add_sensor_offset(
    effects: dict[Effect, tuple[dict[str, float | None], ...]], offset_s: float
) -> None:
    """The sensor time offset as a concealed effect, once the diagnosis knows the effect
    (``Effect.SENSOR_TIME_OFFSET``): a fraction of a position cycle (0.3 ms on the mill,
    0.5 ms on the slide), about what a drive's and a scale's sampling instants differ by;
    invisible in the torque, a few µm between the two position columns at the feeds.
    Positive: the load scale is read late (on the mill it is in the position loop, on the
    slide only recorded)."""
    effect = getattr(Effect, "SENSOR_TIME_OFFSET", None)
    if effect is not None:
        effects[effect] = ({"control.sensor_time_offset": offset_s},)


def _mill() -> Family:
    truth = AxisConfig(
        kind=AxisKind.LINEAR,
        transmission_ratio=100.0 * math.pi,
        mechanics=Mechanics(
            motor_inertia=0.0625,
            screw_inertia=0.0784,
            load_mass=6554.2,
            antiresonance=600.0,
            damping_ratio=0.04,
        ),
        friction=Friction(coulomb=1.2, viscous=57.3),
        control=Control(
            kv=25.0,
            ksp=52.0,
            tsi=0.0075,
            torque_limit=150.0,
            current_lag=0.0003,
            position_feedback=PositionFeedback.LOAD,
        ),
    )
    effects: dict[Effect, tuple[dict[str, float | None], ...]] = {
        Effect.BACKLASH: ({"mechanics.backlash": 4e-6},),
        Effect.COMPLIANCE: ({"mechanics.antiresonance": 900.0, "mechanics.damping_ratio": 0.05},),
        Effect.COULOMB_FRICTION: ({"friction.coulomb": 0.6},),
        Effect.VISCOUS_FRICTION: ({"friction.viscous": 15.0},),
        Effect.ASYMMETRIC_FRICTION: (
            {"friction.coulomb_negative": 1.5, "friction.viscous_negative": 63.0},
        ),
        Effect.STRIBECK_FRICTION: ({"friction.stribeck": 0.6, "friction.stribeck_speed": 0.003},),
        Effect.CONSTANT_LOAD_TORQUE: ({"disturbance.constant_torque": 0.5},),
        Effect.PERIODIC_DISTURBANCE: (
            {
                "disturbance.periodic_amplitude": 0.4,
                "disturbance.periodic_period": 0.02,
                "disturbance.periodic_phase": 0.7,
            },
        ),
        # times the peak torque demand: clips the fast moves' accelerations
        Effect.TORQUE_SATURATION: ({"control.torque_limit": 0.95},),
        Effect.TIME_DELAY: ({"control.delay": 0.0005},),
    }
    _add_sensor_offset(effects, 3e-4)
    return Family(
        name="mill",
        truth=truth,
        excitation=Excitation(
            position_range=(0.0, 0.4),
            speeds=(0.003, 0.01, 0.03, 0.08, 0.15),
            accel=1.0,
        ),
        noise=Noise(
            motor_torque=0.4,
            motor_speed=0.2,
            motor_position=3e-6,
            load_position=1e-7,
            process_nm=0.3,
        ),
        effects=effects,
    )


def slide_axis() -> AxisConfig:
    """A light rigid slide (10 mm screw pitch, 25 kg), PI speed loop, position loop on the
    motor encoder, no torque limit: small and fast to simulate (the "slide" family's truth
    without its saturation; also the tests' small axis)."""
    return AxisConfig(
        kind=AxisKind.LINEAR,
        transmission_ratio=2.0 * math.pi / 0.01,
        mechanics=Mechanics(motor_inertia=1.2e-4, screw_inertia=0.8e-4, load_mass=25.0),
        friction=Friction(coulomb=0.08, viscous=0.4),
        control=Control(
            kv=30.0,
            ksp=0.1,
            tsi=0.008,
            current_lag=0.0002,
            position_feedback=PositionFeedback.MOTOR,
        ),
    )


def _slide() -> Family:
    truth = slide_axis().with_values({"control.torque_limit": 3.0})
    effects: dict[Effect, tuple[dict[str, float | None], ...]] = {
        Effect.BACKLASH: (
            {
                "mechanics.backlash": 8e-6,
                "mechanics.antiresonance": 3000.0,
                "mechanics.damping_ratio": 0.15,
            },
        ),
        Effect.COMPLIANCE: ({"mechanics.antiresonance": 800.0, "mechanics.damping_ratio": 0.05},),
        Effect.COULOMB_FRICTION: ({"friction.coulomb": 0.015},),
        Effect.VISCOUS_FRICTION: ({"friction.viscous": 0.1},),
        Effect.ASYMMETRIC_FRICTION: (
            {"friction.coulomb_negative": 0.092, "friction.viscous_negative": 0.45},
        ),
        Effect.STRIBECK_FRICTION: ({"friction.stribeck": 0.03, "friction.stribeck_speed": 0.005},),
        Effect.CONSTANT_LOAD_TORQUE: ({"disturbance.constant_torque": 0.012},),
        Effect.PERIODIC_DISTURBANCE: (
            {
                "disturbance.periodic_amplitude": 0.012,
                "disturbance.periodic_period": 0.01,
                "disturbance.periodic_phase": -1.2,
            },
        ),
        # times the peak torque demand: clips the fast moves' accelerations
        Effect.TORQUE_SATURATION: ({"control.torque_limit": 0.93},),
        Effect.TIME_DELAY: ({"control.delay": 0.000375},),
    }
    _add_sensor_offset(effects, 5e-4)
    return Family(
        name="slide",
        truth=truth,
        excitation=Excitation(
            position_range=(0.0, 0.3),
            speeds=(0.005, 0.02, 0.1, 0.3),
            accel=4.0,
        ),
        noise=Noise(
            motor_torque=0.01,
            motor_speed=0.1,
            motor_position=6e-6,
            load_position=5e-7,
            process_nm=0.005,
        ),
        effects=effects,
    )


FAMILIES: dict[str, Family] = {f.name: f for f in (_mill(), _slide())}

#: Uncertain parameters perturbed by 5-10 % in the nominal axis (when present).
UNCERTAIN_KEYS = (
    "mechanics.load_mass",
    "mechanics.antiresonance",
    "mechanics.damping_ratio",
    "friction.coulomb",
    "friction.viscous",
)


# ----------------------------------------------------------------------------------------
# excitation
# ----------------------------------------------------------------------------------------
def trapezoid(distance: float, speed: float, accel: float, dt: float) -> np.ndarray:
    """Speed samples of a point-to-point move (trapezoid or triangle), sign of distance:
    acceleration steps, no jerk limit (also the third test set's rapids)."""
    d = abs(distance)
    v = min(speed, math.sqrt(d * accel))
    t_acc = v / accel
    t_total = d / v + t_acc
    t = np.arange(0.0, t_total, dt)
    prof = np.minimum.reduce([t / t_acc * v, np.full_like(t, v), (t_total - t) / t_acc * v])
    prof = np.clip(prof, 0.0, None)
    # scale so that the samples travel exactly the distance
    travel = prof.sum() * dt
    if travel > 0:
        prof *= d / travel
    return math.copysign(1.0, distance) * prof


def reference_profile(
    exc: Excitation, duration_s: float, cycle_s: float, rng: np.random.Generator
) -> np.ndarray:
    """Position reference (load units), one value per position cycle.

    Point-to-point moves cycle through the feeds in shuffled order (so every few seconds
    hold a slow and a fast move), each 0.4-1 s at its feed (the two fastest feeds at the full
    acceleration, the others at 40-100 % of it), mostly (70 %) reversing the
    previous direction, separated by dwells (a quarter of them only 30 ms: reversals without
    a rest); one segment in five is a sinusoidal back-and-forth (reversals at speed).
    The speed profile is smoothed over ``jerk_time_s`` (jerk limit)."""
    lo, hi = exc.position_range
    margin = 0.05 * (hi - lo)
    n_total = round(duration_s / cycle_s)
    pieces: list[np.ndarray] = [np.zeros(round(0.3 / cycle_s))]  # start at rest
    x = 0.5 * (lo + hi)
    n = len(pieces[0])
    direction = 1.0
    queue: list[float] = []
    while n < n_total:
        if rng.random() < 0.2:
            speed = float(rng.choice(exc.speeds[1:]))
            amp = min(0.1 * (hi - lo), speed / (2.0 * math.pi * 0.5), hi - x, x - lo)
            amp = max(amp, 1e-9)
            freq = min(speed / (2.0 * math.pi * amp), math.sqrt(exc.accel / amp) / (2.0 * math.pi))
            t = np.arange(0.0, int(rng.integers(1, 4)) / freq, cycle_s)
            prof = amp * 2.0 * math.pi * freq * np.sin(2.0 * math.pi * freq * t)
        else:
            if not queue:
                queue = [float(v) for v in rng.permutation(np.asarray(exc.speeds))]
            speed = queue.pop()
            # rapid moves use the axis's acceleration (as an NC does), feeds a gentler one
            fast = speed >= sorted(exc.speeds)[-2]
            accel = exc.accel if fast else exc.accel * rng.uniform(0.4, 1.0)
            if rng.random() < 0.7:
                direction = -direction
            dist = speed * rng.uniform(0.4, 1.0) + speed**2 / accel
            room = (hi - margin - x) if direction > 0 else (x - lo - margin)
            if room < 0.5 * dist:
                direction = -direction
                room = (hi - margin - x) if direction > 0 else (x - lo - margin)
            dist = min(dist, max(room, 1e-6))
            prof = trapezoid(direction * dist, speed, accel, cycle_s)
        dwell = np.zeros(round(rng.uniform(*exc.dwell_s) / cycle_s))
        if rng.random() < 0.25:
            dwell = dwell[: round(0.03 / cycle_s)]
        x += float(prof.sum() * cycle_s)
        pieces += [prof, dwell]
        n += len(prof) + len(dwell)
    speed_profile = np.concatenate(pieces)[:n_total]
    width = max(1, round(exc.jerk_time_s / cycle_s))
    speed_profile = np.convolve(speed_profile, np.ones(width) / width, mode="same")
    steps = np.cumsum(speed_profile[:-1]) * cycle_s
    return 0.5 * (lo + hi) + np.concatenate([[0.0], steps])


def process_disturbance(
    noise: Noise, n: int, cycle_s: float, rng: np.random.Generator
) -> np.ndarray:
    """Unrecorded random load torque (N·m at the motor): filtered white noise of std process_nm."""
    if noise.process_nm <= 0.0:
        return np.zeros(n)
    b, a = sps.butter(2, noise.process_band_hz, fs=1.0 / cycle_s)
    raw = sps.lfilter(b, a, rng.standard_normal(n + 2000))[2000:]
    return noise.process_nm * raw / max(float(np.std(raw)), 1e-300)


# ----------------------------------------------------------------------------------------
# cases
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """One recording of a test set: ``effect`` None means nothing is left out. ``family``
    names one of the plant's families (:data:`FAMILIES` here; a plant with its own families
    checks them when it generates the case)."""

    name: str
    family: str
    effect: Effect | None
    seed: int
    duration_s: float = 25.0

    def __post_init__(self) -> None:
        if not self.family:
            raise DiagnosisOptionError(f"case {self.name}: no family")
        if not 2.0 <= self.duration_s <= 3600.0:
            raise DiagnosisOptionError(
                f"case {self.name}: duration_s = {self.duration_s!r}, allowed [2, 3600] s"
            )


@dataclass(frozen=True)
class GeneratedCase:
    case: Case
    recording: Trace
    nominal: AxisConfig
    truth: AxisConfig
    #: truth without the concealed effect (same hidden parameters) - for :func:`concealment`
    truth_without: AxisConfig
    references: References
    process_nm: np.ndarray
    #: what the diagnosis should name, when the truth is no axis file (an FMU's inside):
    #: the effects left out (None: those of ``truth`` the nominal lacks) and the names that
    #: count as a correct first naming (empty: ``case.effect`` alone)
    expected: list[str] | None = None
    accepted: tuple[str, ...] = ()


def _peak_demand(axis: AxisConfig, refs: References, plant: Simulator) -> float:
    """Peak |motor torque| without a limit (the fast moves all accelerate at the axis's
    largest acceleration, so a limit just below it clips each of them a little)."""
    free = axis.with_values({"control.torque_limit": None})
    return float(np.max(np.abs(plant(free, refs)["motor_torque"])))


def _perturb(axis: AxisConfig, rng: np.random.Generator) -> AxisConfig:
    changes: dict[str, float | None] = {}
    for key in UNCERTAIN_KEYS:
        value = axis.value(key)
        if value:
            factor = 1.0 + float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.05, 0.10))
            changes[key] = float(value) * factor
    return axis.with_values(changes)


def _strip(axis: AxisConfig, effect: Effect, truth_base: AxisConfig) -> AxisConfig:
    """The axis without ``effect``; backlash on a rigid family also takes its contact
    stiffness (the truth's compliance) out."""
    out = MODELS[effect].strip(axis)
    if effect is Effect.BACKLASH and truth_base.is_rigid:
        out = MODELS[Effect.COMPLIANCE].strip(out)
    return out


#: A plant as a function: noise-free closed loop of an axis on references (the recording's
#: hidden truth): the columns time, position_reference, motor_position, load_position,
#: motor_speed and motor_torque at every position cycle. :func:`truth_simulator` is the
#: compiled kernel's; the test suite has an independent one (reference_plants/independent).
Simulator = Callable[[AxisConfig, References], Trace]


def truth_simulator(axis: AxisConfig, refs: References) -> Trace:
    """The kernel with twice the default mechanics substeps (what :func:`generate` uses)."""
    return simulate(axis, refs, None, KernelOptions(substeps=2 * default_substeps(axis)))


def hidden_axes(case: Case, refs: References, plant: Simulator) -> tuple[AxisConfig, AxisConfig]:
    """The hidden truth of ``case`` and the truth without its concealed effect (a torque
    limit is set relative to ``plant``'s peak demand on ``refs``)."""
    fam = family_of(case)
    base = fam.truth
    truth = base
    if case.effect is not None:
        variant = fam.effects[case.effect][case.seed % len(fam.effects[case.effect])]
        changes = dict(variant)
        if case.effect is Effect.TORQUE_SATURATION:
            peak = _peak_demand(base, refs, plant)
            changes["control.torque_limit"] = float(variant["control.torque_limit"] or 1.0) * peak
        truth = base.with_values(changes)
    truth_without = truth if case.effect is None else _strip(truth, case.effect, base)
    return truth, truth_without


def recorded_columns(sim: Trace) -> dict[str, np.ndarray]:
    """The columns a recording keeps, every :data:`DECIMATION`-th position cycle."""
    keep = slice(0, None, DECIMATION)
    return {name: sim[name][keep] for name in MOTION_COLUMNS}


def family_of(case: Case) -> Family:
    """The family of ``case`` (refused with the allowed names when unknown)."""
    if case.family not in FAMILIES:
        raise DiagnosisOptionError(
            f"case {case.name}: family {case.family!r}, allowed {sorted(FAMILIES)}"
        )
    return FAMILIES[case.family]


def _references(case: Case, rng: np.random.Generator) -> References:
    """The inputs of a recording of ``case``: the excitation's position and speed references
    and the unrecorded process load (drawn from ``rng`` in that order)."""
    fam = family_of(case)
    cycle = fam.truth.control.position_cycle
    position = reference_profile(fam.excitation, case.duration_s, cycle, rng)
    refs0 = References.from_position(position, cycle)
    process = process_disturbance(fam.noise, len(position), cycle, rng)
    return References(refs0.position, refs0.speed, process)


def generate(case: Case, plant: Simulator = truth_simulator) -> GeneratedCase:
    """Simulate the recording of ``case`` with ``plant`` (deterministic in its seed)."""
    fam = family_of(case)
    rng = np.random.default_rng(case.seed)
    refs = _references(case, rng)
    truth, truth_without = hidden_axes(case, refs, plant)
    nominal = _perturb(truth_without, rng)
    return GeneratedCase(
        case=case,
        recording=_recorded(plant(truth, refs), fam.noise, rng),
        nominal=nominal,
        truth=truth,
        truth_without=truth_without,
        references=refs,
        process_nm=refs.disturbance_nm,
    )


def _recorded(sim: Trace, noise: Noise, rng: np.random.Generator) -> Trace:
    """What a recording keeps of the noise-free ``sim``, with the measurement noise."""
    cols = recorded_columns(sim)
    m = len(cols["time"])
    for name in ("motor_position", "load_position", "motor_speed", "motor_torque"):
        cols[name] = cols[name] + getattr(noise, name) * rng.standard_normal(m)
    return Trace(cols)


def another_recording(gen: GeneratedCase, take: int, plant: Simulator = truth_simulator) -> Trace:
    """A second recording of ``gen``'s hidden truth made at another time (``take`` >= 1): the
    same axis, new moves, a new unrecorded load and new noise (what ``--validate`` is for)."""
    if take < 1:
        raise DiagnosisOptionError(f"take = {take!r}: a second recording is take 1 or more")
    fam = family_of(gen.case)
    rng = np.random.default_rng([gen.case.seed, take])
    refs = _references(gen.case, rng)
    return _recorded(plant(gen.truth, refs), fam.noise, rng)


def concealment(gen: GeneratedCase, simulator: Simulator | None = None) -> dict[str, float]:
    """How hidden the effect is: per recorded signal, RMS of (truth − truth without the
    effect), noise-free and on the same inputs, divided by the measurement-noise std
    (``snr_<signal>``) and by the signal's spread (``share_<signal>``; for positions the spread
    of the following error). An empty dict for a case with nothing left out. ``simulator``:
    the plant that made the recording (default :func:`truth_simulator`)."""
    if gen.case.effect is None:
        return {}
    fam = family_of(gen.case)
    sim = simulator or truth_simulator
    with_e = sim(gen.truth, gen.references)
    without = sim(gen.truth_without, gen.references)
    out: dict[str, float] = {}
    ref = with_e["position_reference"]
    kr = gen.truth.transmission_ratio
    for name in ("motor_position", "load_position", "motor_speed", "motor_torque"):
        diff = with_e[name] - without[name]
        if name == "motor_position":
            spread_sig = kr * ref - with_e[name]
        elif name == "load_position":
            spread_sig = ref - with_e[name]
        else:
            spread_sig = with_e[name]
        rms = float(np.sqrt(np.mean(diff**2)))
        out[f"snr_{name}"] = rms / getattr(fam.noise, name)
        out[f"share_{name}"] = rms / max(float(np.std(spread_sig)), 1e-300)
    return out


def test_set(
    seed: int = 1,
    families: Sequence[str] = ("mill", "slide"),
    none_per_family: int = 2,
    duration_s: float = 25.0,
) -> list[Case]:
    """Every effect once per family (so >= 2 recordings per effect) and ``none_per_family``
    recordings with nothing left out per family; seeds derived from ``seed``."""
    return case_list({f: FAMILIES[f].effects for f in families}, seed, duration_s, none_per_family)


def case_list(
    families: Mapping[str, Iterable[Effect]],
    seed: int,
    duration_s: float,
    none_per_family: int = 2,
) -> list[Case]:
    """A test set's cases: per family (name -> its effects) each effect once, then
    ``none_per_family`` with nothing left out, named ``FAMILY-EFFECT`` / ``FAMILY-none-I``,
    case seeds ``seed * 1000 + k`` in that order (any plant's test set)."""
    cases: list[Case] = []
    k = 0
    for fam, effects in families.items():
        for effect in effects:
            cases.append(Case(f"{fam}-{effect.value}", fam, effect, seed * 1000 + k, duration_s))
            k += 1
        for i in range(none_per_family):
            cases.append(Case(f"{fam}-none-{i + 1}", fam, None, seed * 1000 + k, duration_s))
            k += 1
    return cases


def write_case(gen: GeneratedCase, directory: str | Path) -> tuple[Path, Path]:
    """Write ``<name>.csv`` and ``<name>_nominal.toml`` (the truth stays hidden)."""
    from virtual_bus.formats.axis import dump_axis

    from .fit import plain_floats

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    csv_path = directory / f"{gen.case.name}.csv"
    toml_path = directory / f"{gen.case.name}_nominal.toml"
    gen.recording.to_csv(csv_path)
    write_atomic(
        toml_path,
        dump_axis(plain_floats(gen.nominal), header=f"nominal axis of test case {gen.case.name}"),
    )
    return csv_path, toml_path

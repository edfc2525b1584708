"""The FMU family's concealed-effect test set: recordings of the axes of
``shared/plants/axis_family.fmu`` (written apart from this project, a binary only), each family
concealing one effect or none, made as a user makes them.

* **The nominal axis file** is the FMU's data sheet (:func:`plant_sim.fmu.nominal_axis`): the
  axis as built, nothing about the hidden effect, the data-sheet values as the FMU states them.
* **The motion** is a test plan a user runs on an axis he knows from its data sheet
  (:func:`plan`): from rest, jerk-limited moves between points of the travel at five feeds up to
  a rapid (each feed in both directions), short reversals with and without a dwell (free play,
  pre-sliding), creep moves (static friction), a slow pass over the travel (position-dependent
  effects). The acceleration is a share of what the data sheet's torque limit allows.
* **The loop** is the project's position cycle around the FMU (:func:`plant_sim.physics.
  simulate.simulate_plant`, :mod:`regulator.loop`), on the data-sheet loop (k_v, cycles), the
  set point applied at once (as the diagnosis's replay does).
* **The noise** is the FMU's own (``noise = 1``, a ``noise_seed`` per recording); every
  position cycle is recorded; no unrecorded process force.

The families the set draws from (:data:`FAMILIES`) and what each should be called are the
FMU's README; the matrix and the sweep score against them. ``truth_*`` is never read here
except in :func:`truth_values` (the scoring step).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from diagnosis.effects import Effect
from diagnosis.synthetic import Case, GeneratedCase
from plant_sim.fmu import FmuPlant, FmuSpec, nominal_axis
from plant_sim.fmu.model import FmuModel
from plant_sim.physics.simulate import References, simulate_plant
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import MOTION_COLUMNS, Trace


@dataclass(frozen=True)
class FmuFamily:
    """One family of the FMU: its code, what it conceals (the README's words) and the effect
    the diagnosis should name first (None: nothing left out)."""

    code: int
    label: str
    effect: Effect | None
    #: other names that count as correct (a more general effect of the table)
    also: tuple[Effect, ...] = ()

    @property
    def accepted_names(self) -> tuple[str, ...]:
        """Effect names that count as a correct first naming ("none" for a clean axis)."""
        if self.effect is None:
            return ("none",)
        return (self.effect.value, *(e.value for e in self.also))


def _families() -> dict[int, FmuFamily]:
    e = Effect
    rows = [
        FmuFamily(0, "clean", None),
        FmuFamily(1, "uniform free play", e.BACKLASH),
        FmuFamily(3, "extra static friction (Stribeck)", e.STRIBECK_FRICTION),
        FmuFamily(7, "torque ripple per motor revolution", e.PERIODIC_DISTURBANCE),
        FmuFamily(8, "periodic error of the linear scale", getattr(e, "SCALE_ERROR", None)),
        FmuFamily(9, "constant load force", e.CONSTANT_LOAD_TORQUE),
        FmuFamily(10, "lower torque limit", e.TORQUE_SATURATION),
        FmuFamily(11, "constant set-point dead time", getattr(e, "SETPOINT_DELAY", None)),
        FmuFamily(12, "slowly growing set-point dead time", getattr(e, "SETPOINT_DELAY", None)),
        FmuFamily(14, "nut force ripple", e.PERIODIC_DISTURBANCE),
        FmuFamily(16, "late load scale", e.SENSOR_TIME_OFFSET),
        FmuFamily(18, "direction-dependent friction", e.ASYMMETRIC_FRICTION),
    ]
    return {f.code: f for f in rows}


#: The families of the set (the FMU's README), by code.
FAMILIES: dict[int, FmuFamily] = _families()
#: Families whose concealed effect the set scores.
EFFECT_CODES: tuple[int, ...] = tuple(c for c in FAMILIES if c != 0)
#: The family of a sweep's seed ``s`` is ``SWEEP_CYCLE[s % len(SWEEP_CYCLE)]``: every effect
#: family once and a clean axis after every third (4 of 15 clean).
SWEEP_CYCLE: tuple[int, ...] = tuple(
    c for i, code in enumerate(EFFECT_CODES) for c in ((0, code) if i % 3 == 0 else (code,))
)

#: Where the family's axes travel (load units): the FMU starts at rest at 0; its
#: position-dependent effects lie within 0.01..0.095 m.
TRAVEL = (0.0, 0.1)
#: Share of the data sheet's torque limit the plan's accelerations ask for (at the top feed).
TORQUE_SHARE = 0.3
#: Seeds of the noise and the plan are offset from the axis seed (no shared streams).
SEED_SHIFT = 60_013


def fmu_path() -> Path:
    from virtual_bus.shipped import SHARED_DIR

    return SHARED_DIR / "plants" / "axis_family.fmu"


def spec_for(
    seed: int, family: int, noise_seed: int = 0, noise: float = 1.0, base: FmuSpec | None = None
) -> FmuSpec:
    """The FMU (``base``'s file and mapping, default the shared family's) of axis ``seed``
    with ``family``'s hidden effect and a noise draw."""
    spec = base if base is not None else FmuSpec(fmu_path())
    return spec.with_parameters(seed=seed, family=family, noise_seed=noise_seed, noise=noise)


# ----------------------------------------------------------------------------------------
# the test plan
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Plan:
    """A test plan's limits (load units, s), from the data sheet (:func:`plan_for`)."""

    travel: tuple[float, float]
    feeds: tuple[float, ...]  # slowest first; the slowest is a creep feed
    accel: float
    jerk_s: float = 0.02


def plan_for(axis: AxisConfig) -> Plan:
    """The plan's limits for a data-sheet axis: accelerations that ask for
    :data:`TORQUE_SHARE` of its torque limit, feeds from a creep feed of 1 mm/s to a rapid of
    150 mm/s (less where the following error k_v would leave would not fit the travel)."""
    kr = axis.transmission_ratio
    j_motor = axis.motor_side_inertia + axis.mechanics.load_mass / kr**2
    limit = axis.control.torque_limit or 50.0 * (axis.friction.coulomb or 1.0)
    accel = min(3.0, max(0.05, TORQUE_SHARE * limit / (j_motor * kr)))
    span = TRAVEL[1] - TRAVEL[0]
    rapid = min(0.15, 0.2 * span * axis.control.kv)
    feeds = (0.001, 0.004, 0.015, 0.05, rapid)
    return Plan(TRAVEL, tuple(sorted(feeds)), accel)


def _move(distance: float, feed: float, accel: float, dt: float, jerk_s: float) -> np.ndarray:
    """Speed samples (one per cycle) of a point-to-point move of ``distance``: a trapezoid at
    ``feed`` and ``accel`` smoothed by a moving average of ``jerk_s`` (jerk-limited), scaled
    so that it travels the distance exactly."""
    d = abs(distance)
    v = min(feed, math.sqrt(d * accel))
    t_acc = v / accel
    t_total = d / v + t_acc
    t = np.arange(0.0, t_total + dt, dt)
    prof = np.minimum.reduce([t / t_acc * v, np.full_like(t, v), (t_total - t) / t_acc * v])
    prof = np.clip(prof, 0.0, None)
    n_avg = max(1, round(jerk_s / dt))
    prof = np.convolve(prof, np.ones(n_avg) / n_avg)
    travel = prof.sum() * dt
    return math.copysign(1.0, distance) * prof * (d / travel) if travel > 0 else prof


def reference(
    plan: Plan, duration_s: float, cycle_s: float, rng: np.random.Generator
) -> np.ndarray:
    """The position reference (one value per position cycle) of a test plan: 0.3 s at rest,
    a move into the travel, then in random order moves between random points at each feed
    in both directions, short reversals (0.1-1 mm, with and without a dwell), creep moves;
    a slow pass over most of the travel once per 12 s."""
    lo, hi = plan.travel
    margin = 0.05 * (hi - lo)
    n_total = max(2, round(duration_s / cycle_s))
    pieces: list[np.ndarray] = [np.zeros(round(0.3 / cycle_s))]
    x = 0.0
    n = len(pieces[0])

    def add(distance: float, feed: float, dwell_s: float) -> None:
        nonlocal x, n
        prof = _move(distance, feed, plan.accel, cycle_s, plan.jerk_s)
        x += float(prof.sum() * cycle_s)
        dwell = np.zeros(max(1, round(dwell_s / cycle_s)))
        pieces.extend([prof, dwell])
        n += len(prof) + len(dwell)

    add(lo + 0.5 * (hi - lo) - x, plan.feeds[-2], 0.1)
    queue: list[tuple[float, float]] = []
    next_pass = 6.0
    while n < n_total:
        if n * cycle_s > next_pass:
            # a slow pass over the travel (feed 15 mm/s) towards the far end
            target = hi - margin if x < 0.5 * (lo + hi) else lo + margin
            add(target - x, plan.feeds[2], 0.1)
            next_pass += 12.0
            continue
        r = rng.random()
        if r < 0.18:
            amp = float(rng.uniform(1e-4, 1e-3))
            feed = float(rng.choice(plan.feeds[1:3]))
            dwell = float(rng.choice([0.0, 0.02, 0.3]))
            sign = 1.0 if rng.random() < 0.5 else -1.0
            if not lo + margin < x + sign * amp < hi - margin:
                sign = -sign
            add(sign * amp, feed, dwell)
            add(-sign * amp, feed, float(rng.uniform(0.05, 0.3)))
            continue
        if not queue:
            queue = [(float(f), s) for f in plan.feeds for s in (1.0, -1.0)]
            queue = [queue[i] for i in rng.permutation(len(queue))]
        feed, sign = queue.pop()
        # slow feeds move a short way (a few seconds at most), fast ones far
        reach = min(hi - lo - 2 * margin, feed * float(rng.uniform(0.8, 2.5)))
        target = x + sign * max(reach, 2e-3)
        if not lo + margin <= target <= hi - margin:
            target = x - sign * max(reach, 2e-3)
        target = min(hi - margin, max(lo + margin, target))
        if abs(target - x) < 5e-4:
            continue
        add(target - x, feed, float(rng.uniform(0.05, 0.4)))
    speed = np.concatenate(pieces)[:n_total]
    return np.concatenate([[0.0], np.cumsum(speed[:-1]) * cycle_s])


# ----------------------------------------------------------------------------------------
# recordings
# ----------------------------------------------------------------------------------------
def record(spec: FmuSpec, axis: AxisConfig, refs: References) -> Trace:
    """The FMU of ``spec`` run on ``refs`` through the project's position loop around it, on
    ``axis``'s controller; the recorded columns (every position cycle)."""
    plant = FmuPlant(spec.load(), axis, float(refs.position[0]))
    try:
        sim = simulate_plant(plant, axis, refs)
    finally:
        plant.close()
    return Trace({name: sim[name] for name in MOTION_COLUMNS})


def references_for(axis: AxisConfig, duration_s: float, rng: np.random.Generator) -> References:
    cycle = axis.control.position_cycle
    pos = reference(plan_for(axis), duration_s, cycle, rng)
    return References.from_position(pos, cycle)


def data_sheet(seed: int, base: FmuSpec | None = None) -> AxisConfig:
    """The nominal axis file of axis ``seed`` (its data sheet; the same for every family)."""
    return nominal_axis(spec_for(seed, 0, base=base).load())


def make_recording(
    seed: int,
    code: int,
    duration_s: float,
    rng: np.random.Generator,
    base: FmuSpec | None = None,
    nominal: AxisConfig | None = None,
) -> tuple[Trace, AxisConfig, References]:
    """A recording of axis ``seed`` with family ``code`` (moves and noise draw from ``rng``),
    the data sheet it was planned from, and its references."""
    nominal = nominal if nominal is not None else data_sheet(seed, base)
    refs = references_for(nominal, duration_s, rng)
    noise_seed = int(rng.integers(1, 2**31 - 1))
    return record(spec_for(seed, code, noise_seed, base=base), nominal, refs), nominal, refs


# ----------------------------------------------------------------------------------------
# cases (the matrix's bookkeeping)
# ----------------------------------------------------------------------------------------
def _code(case: Case) -> int:
    try:
        code = int(case.family.removeprefix("f"))
    except ValueError:
        code = -1
    if code not in FAMILIES:
        raise ValueError(
            f"case {case.name}: family {case.family!r}, allowed "
            + ", ".join(f"f{c:02d}" for c in FAMILIES)
        )
    return code


def case_for(seed: int, code: int, take: int = 0, duration_s: float = 25.0) -> Case:
    """The recording of axis ``seed`` with family ``code`` (``take``: another clean one)."""
    fam = FAMILIES[code]
    what = fam.effect.value if fam.effect else f"none-{take + 1}"
    return Case(f"s{seed}-f{code:02d}-{what}", f"f{code:02d}", fam.effect, seed, duration_s)


def test_set(
    seed: int = 0,
    duration_s: float = 25.0,
    none_per_family: int = 2,
    codes: Sequence[int] = EFFECT_CODES,
) -> list[Case]:
    """Axis ``seed`` with each effect family of ``codes`` once, and ``none_per_family`` clean
    recordings of it (other moves and noise)."""
    cases = [case_for(seed, c, 0, duration_s) for c in codes]
    cases += [case_for(seed, 0, i, duration_s) for i in range(none_per_family)]
    return cases


def _take(case: Case) -> int:
    tail = case.name.rsplit("-", 1)[-1]
    return int(tail) - 1 if case.effect is None and tail.isdigit() else 0


def _rng(case: Case, take: int = 0) -> np.random.Generator:
    return np.random.default_rng([case.seed + SEED_SHIFT, _code(case), _take(case), take])


def generate(case: Case) -> GeneratedCase:
    """The recording of ``case``, its nominal file (the data sheet); ``truth`` is the data
    sheet too: the FMU's inside is not an axis file (scoring uses :func:`expected`)."""
    code = _code(case)
    rec, nominal, refs = make_recording(case.seed, code, case.duration_s, _rng(case))
    return GeneratedCase(
        case=case,
        recording=rec,
        nominal=nominal,
        truth=nominal,
        truth_without=nominal,
        references=refs,
        process_nm=refs.disturbance_nm,
        expected=[] if case.effect is None else [case.effect.value],
        accepted=accepted(code),
    )


def accepted(code: int) -> tuple[str, ...]:
    """Effect names that count as a correct first naming for family ``code``."""
    return FAMILIES[code].accepted_names if FAMILIES[code].effect is not None else ()


def another_recording(gen: GeneratedCase, take: int) -> Trace:
    """A second recording of the same axis and family at another time (``take`` >= 1): other
    moves of the same plan, another noise draw."""
    if take < 1:
        raise ValueError(f"take = {take!r}: a second recording is take 1 or more")
    code = _code(gen.case)
    rng = _rng(gen.case, take)
    rec, _, _ = make_recording(gen.case.seed, code, gen.case.duration_s, rng, None, gen.nominal)
    return rec


def concealment(gen: GeneratedCase) -> dict[str, float]:
    """How hidden the effect is: the same axis with and without it (family 0), noise-free,
    on the same moves: RMS of the difference per signal over the FMU's noise std (torque,
    speed) and over the signal's spread. Empty for a clean case."""
    if gen.case.effect is None:
        return {}
    code = _code(gen.case)
    with_e = record(spec_for(gen.case.seed, code, 0, 0.0), gen.nominal, gen.references)
    without = record(spec_for(gen.case.seed, 0, 0, 0.0), gen.nominal, gen.references)
    model = spec_for(gen.case.seed, 0).load()
    levels = {
        "motor_torque": model.nominal.get("noise_torque_std", 0.0),
        "motor_speed": model.nominal.get("noise_speed_std", 0.0),
    }
    out: dict[str, float] = {}
    for name, level in levels.items():
        diff = with_e[name] - without[name]
        rms = float(np.sqrt(np.mean(diff**2)))
        out[f"snr_{name}"] = rms / level if level > 0 else math.inf
        out[f"share_{name}"] = rms / max(float(np.std(with_e[name])), 1e-300)
    return out


def truth_values(model: FmuModel) -> dict[str, float]:
    """The FMU's ``truth_*`` values (the scoring step only: README)."""
    return {k: v for k, v in model.nominal.items() if k.startswith("truth_")}

"""Recordings of the concealed test set made on the independent plant.

Same cases as :func:`diagnosis.synthetic.test_set` (families, effects, magnitudes,
nominal files with the concealed effect's keys absent and the uncertain parameters 5–10 %
off), but the hidden truth runs on this package's plant and the noise is its own:

* the unrecorded process disturbance is an Ornstein–Uhlenbeck torque (corner 1.5 Hz) plus a
  slow drift, not the synthetic set's 2nd-order Butterworth noise;
* measurement noise is coloured: the torque noise is white noise through a first-order
  low-pass at 300 Hz (current sensor and PWM ripple after the drive's filter), the speed
  noise the same at 400 Hz, each scaled to the family's standard deviation; positions carry
  the sensors' quantisation plus a small white noise (interpolation error of the scale);
* the references come from a separate random stream (seed + 7919);
* the plant's speed filter (a drive setting, :class:`PlantOptions`.speed_filter_s) is written
  into the truth and the nominal file as ``control.speed_filter``, exactly.
"""

from __future__ import annotations

import numpy as np
from scipy import signal as sps

from diagnosis.synthetic import (
    DECIMATION,
    FAMILIES,
    Case,
    GeneratedCase,
    _perturb,
    hidden_axes,
    recorded_columns,
    reference_profile,
)
from plant_sim.physics.simulate import References
from reference_plants.independent.plant import PlantOptions, simulate
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

SEED_SHIFT = 7919


def simulator(axis: AxisConfig, refs: References) -> Trace:
    """Noise-free closed loop of the independent plant (the matrix's plant function)."""
    return simulate(axis, refs.position, refs.speed, refs.disturbance_nm, PlantOptions())


def _coloured(rng: np.random.Generator, n: int, corner_hz: float, fs_hz: float) -> np.ndarray:
    b, a = sps.butter(1, corner_hz, fs=fs_hz)
    raw = sps.lfilter(b, a, rng.standard_normal(n + 500))[500:]
    return raw / max(float(np.std(raw)), 1e-300)


def process_torque(std_nm: float, n: int, cycle_s: float, rng: np.random.Generator) -> np.ndarray:
    """Ornstein–Uhlenbeck torque (corner 1.5 Hz) plus a linear drift, std ``std_nm``."""
    if std_nm <= 0.0:
        return np.zeros(n)
    theta = 2.0 * np.pi * 1.5
    decay = np.exp(-theta * cycle_s)
    kick = np.sqrt(1.0 - decay**2)
    ou = sps.lfilter([kick], [1.0, -decay], rng.standard_normal(n))
    drift = np.linspace(-1.0, 1.0, n) * rng.uniform(-0.5, 0.5)
    total = ou + drift
    return std_nm * total / max(float(np.std(total)), 1e-300)


def _references(case: Case, rng: np.random.Generator) -> References:
    """The inputs of a recording of ``case``: the excitation's position and speed references
    and the unrecorded process torque (drawn from ``rng`` in that order)."""
    fam = FAMILIES[case.family]
    cycle = fam.truth.control.position_cycle
    position = reference_profile(fam.excitation, case.duration_s, cycle, rng)
    refs0 = References.from_position(position, cycle)
    process = process_torque(fam.noise.process_nm, len(position), cycle, rng)
    return References(refs0.position, refs0.speed, process)


def generate(case: Case) -> GeneratedCase:
    """Simulate ``case`` on the independent plant (deterministic in its seed)."""
    rng = np.random.default_rng(case.seed + SEED_SHIFT)
    refs = _references(case, rng)
    # the drive's speed filter is a setting the user made, so the axis files state it exactly
    # (the plant simulates with it either way: it is the plant's default)
    drive = {"control.speed_filter": PlantOptions().speed_filter_s}
    truth, truth_without = (a.with_values(drive) for a in hidden_axes(case, refs, simulator))
    nominal = _perturb(truth_without, rng)
    return GeneratedCase(
        case=case,
        recording=_recorded(simulator(truth, refs), case, rng),
        nominal=nominal,
        truth=truth,
        truth_without=truth_without,
        references=refs,
        process_nm=refs.disturbance_nm,
    )


def _recorded(sim: Trace, case: Case, rng: np.random.Generator) -> Trace:
    """What a recording keeps of the noise-free ``sim``, with coloured torque and speed noise
    and white position noise."""
    fam = FAMILIES[case.family]
    cols = recorded_columns(sim)
    m = len(cols["time"])
    n = len(sim)
    noise = fam.noise
    fs = 1.0 / fam.truth.control.position_cycle
    keep = slice(0, None, DECIMATION)
    torque_noise = _coloured(rng, n, 300.0, fs)[keep][:m]
    speed_noise = _coloured(rng, n, 400.0, fs)[keep][:m]
    cols["motor_torque"] = cols["motor_torque"] + noise.motor_torque * torque_noise
    cols["motor_speed"] = cols["motor_speed"] + noise.motor_speed * speed_noise
    for name in ("motor_position", "load_position"):
        cols[name] = cols[name] + 0.5 * getattr(noise, name) * rng.standard_normal(m)
    return Trace(cols)


def another_recording(gen: GeneratedCase, take: int) -> Trace:
    """A second recording of ``gen``'s hidden truth at another time (``take`` >= 1): the same
    axis, new moves, a new unrecorded load and new noise."""
    if take < 1:
        raise ValueError(f"take = {take!r}: a second recording is take 1 or more")
    rng = np.random.default_rng([gen.case.seed + SEED_SHIFT, take])
    refs = _references(gen.case, rng)
    return _recorded(simulator(gen.truth, refs), gen.case, rng)

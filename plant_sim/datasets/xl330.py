"""Importer of the BAM XL330 pendulum recordings into servo traces (trace-file.md) and axis files.

The recordings come from the public repository of BAM, "Better Actuator Models" (Rhoban,
Duclusaud & Passault, Apache-2.0): a ROBOTIS Dynamixel XL330-M288 servo (DC motor, 288:1
gearbox, one magnetic encoder on the output shaft) swings a pendulum (a point mass ``mass``
at ``length`` from the axis, 0 rad = hanging down) under its own position controller, while
a host writes the goal position and reads the servo's registers every ~5 ms. Where the files
are, their commit and licence: docs/xl330.md; the project does not ship them.

A raw log is one JSON object (written by BAM's ``bam/xl330/record.py``)::

    {"mass": kg, "length": m, "kp": Position P Gain register, "vin": V (nominal supply),
     "motor": "xl330", "trajectory": name,
     "entries": [{"timestamp": s, "goal_position": rad, "position": rad, "speed": rad/s,
                  "load": Present PWM (raw 16-bit two's complement counts),
                  "input_volts": V, "temp": °C, "torque_enable": bool}, ...]}

The servo's controller, as the data set documents it (``bam/xl330/actuator.py`` and
``bam/actuator.py``, VoltageControlledActuator; numbers below)::

    duty = kp * (goal - position) * COUNTS_PER_RAD / (KP_DIVISOR * PWM_LIMIT),  |duty| <= 1
    motor voltage V = input_volts * duty
    torque = kt/R * V - kt^2/R * speed          (DC motor at the output shaft)

KP_DIVISOR = 256 is BAM's empirical value ("manual mentions 128");
:func:`control_law_residual` checks it on every imported file. In the cascade of an axis
file this is a P position loop and a P speed loop whose gain is the motor's back-EMF
damping::

    torque = ksp * (kv * (goal - position) - speed)
    ksp = kt^2/R,   kv = vin * kp * COUNTS_PER_RAD / (KP_DIVISOR * PWM_LIMIT) / kt

with ``vin`` the log's nominal supply. The physical limit is on the duty, not on the torque
(the back-EMF term is not clipped); an axis file cannot say that, so the axis files written
here have no ``torque_limit`` and the importer reports the share of saturated samples.

Columns written (the axis has transmission ratio 1: motor units = load units = rad at the
output shaft, torques in N m at the output shaft, as BAM's parameters are):

- ``position_reference`` = goal_position, ``motor_position`` = position, ``motor_speed`` =
  speed (the servo's Present Velocity, 0.229 rpm per count, converted by the recorder).
- ``motor_torque`` = kt/R * (input_volts * duty - kt * speed), N m: the torque the DC motor
  equation gives for the measured supply, duty and speed (BAM's ``compute_torque``) with the
  published kt and R (:data:`BAM_M1`). It is derived, not measured: the servo has no torque
  sensor, and the XL330 in this mode reports no current.
- no ``disturbance``: gravity on the pendulum, -(mass * G * length) * sin(position +
  q_offset) (BAM's ``Pendulum`` and ``simulate.py``), is a position-periodic load torque of
  period 2 pi rad, and that is how the axis files model it (``[disturbance]``
  periodic_amplitude = mass*G*length, periodic_period = 2 pi, periodic_phase = q_offset).
  Fed as a recorded input instead (computed from the recorded angle) it would cut the
  gravity "spring" out of the loop: on this soft loop gravity (m g l = 0.48 N m/rad near
  the bottom) is stiffer than the controller (kv*ksp = 0.29 N m/rad at kp = 200), and such a
  replay follows the recording much worse (docs/xl330.md). The rod's own mass is not in
  these logs and is left out.
- ``pwm_duty`` and ``input_voltage``: the recorded duty (-1..1) and supply (V), kept for
  checks.

Timing: every column at the log's own (non-uniform) ``timestamp``, the middle of the
register reads of that sample; the goal of that sample was written ~1 ms before it. The
replay (:mod:`diagnosis.replay`) accepts a non-uniform time base.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import (
    AxisConfig,
    AxisKind,
    Control,
    Disturbance,
    Friction,
    Mechanics,
    PositionFeedback,
    dump_axis,
)
from virtual_bus.formats.trace import MIN_ROWS, Trace, first_non_increasing
from virtual_bus.shipped import SHARED_DIR

from ..errors import PlantSimError

#: Encoder counts per output revolution (bam/xl330/actuator.py ENCODER_COUNTS_PER_REV).
COUNTS_PER_REV = 4096
COUNTS_PER_RAD = COUNTS_PER_REV / (2.0 * math.pi)
#: Divisor of the Position P Gain register (bam/xl330/actuator.py KP_DIVISOR: "Empirically
#: observed for XL330 (manual mentions 128)").
KP_DIVISOR = 256
#: The ROBOTIS manual's divisor, kept to show that the data contradict it (tests).
MANUAL_KP_DIVISOR = 128
#: Present PWM at full duty (bam/xl330/actuator.py PWM_LIMIT, "Default Present PWM limit").
PWM_LIMIT = 885
#: Gravity, m/s^2 (bam/testbench.py, Pendulum.compute_bias).
G = 9.80665
#: |duty| at or above this counts as saturated (the PWM register's last count).
SATURATED_DUTY = 884.0 / PWM_LIMIT

#: BAM's published model "m1" (Coulomb + viscous friction) of this XL330: params/xl330/m1.json
#: at commit af2260462471ff45ac18af159b1327ea51d8db15 ("new identification values", the very
#: commit that adds these recordings, so presumably identified on them). Units: kt N m/A (=
#: V s/rad) at the output shaft, R ohm, armature kg m^2 (reflected rotor inertia),
#: friction_base N m (Coulomb), friction_viscous N m s/rad, q_offset rad (encoder zero).
BAM_M1 = {
    "kt": 0.32321138819018436,
    "R": 4.7636501514851926,
    "armature": 0.001643216859746982,
    "friction_base": 0.0069659724474934286,
    "friction_viscous": 0.010494765451601431,
    "q_offset": 0.01795252374733891,
}

#: Position and speed loop cycle of the axis files, s. The XL330's internal loop rate is not
#: in the data set; 1 ms is an assumption (the host's sample time is ~5 ms).
CONTROL_CYCLE_S = 0.001

#: Where the logs are: ``$XL330_DATA``, else ``shared/data/bam_xl330`` beside the repository
#: (the EMPS data's place; third-party data are not part of the repository).
DATA_DIR = Path(os.environ.get("XL330_DATA") or SHARED_DIR / "data" / "bam_xl330")

HEADER_KEYS = ("mass", "length", "kp", "vin", "motor", "entries")
ENTRY_KEYS = ("timestamp", "goal_position", "position", "speed", "load", "input_volts")
MOTOR = "xl330"


class Xl330FileError(PlantSimError, ValueError):
    """A BAM XL330 log is unreadable or lacks what the importer needs; ``key`` names the
    offending JSON key (None for the file as a whole), ``sample`` the entry index."""

    def __init__(self, message: str, *, key: str | None = None, sample: int | None = None):
        super().__init__(message)
        self.key = key
        self.sample = sample


class TorqueOffError(Xl330FileError):
    """A log in which the servo's torque is switched off (``lift_and_drop``)."""


@dataclass(frozen=True)
class Xl330Recording:
    """One raw log in SI units. ``pwm_counts`` is the signed Present PWM."""

    source: Path
    mass_kg: float
    length_m: float
    kp_register: int
    vin_nominal_v: float
    trajectory: str
    time_s: np.ndarray
    goal_rad: np.ndarray
    position_rad: np.ndarray
    speed_rad_s: np.ndarray
    pwm_counts: np.ndarray
    input_v: np.ndarray

    @property
    def duty(self) -> np.ndarray:
        """Recorded duty cycle, -1..1."""
        return self.pwm_counts / PWM_LIMIT

    @property
    def saturated_share(self) -> float:
        """Share of samples at full duty."""
        return float(np.mean(np.abs(self.duty) >= SATURATED_DUTY))

    @property
    def gravity_nm_per_sin(self) -> float:
        """m*g*l of the pendulum (N m)."""
        return self.mass_kg * G * self.length_m


def _number(path: Path, value: object, key: str, sample: int | None = None) -> float:
    where = f"{path}: " + (f"entry {sample}, " if sample is not None else "")
    if isinstance(value, bool) or not isinstance(value, int | float):
        message = f"{where}key {key!r} = {value!r}: expected a number"
        raise Xl330FileError(message, key=key, sample=sample)
    if not math.isfinite(value):
        message = f"{where}key {key!r} = {value!r}: NaN/inf not allowed"
        raise Xl330FileError(message, key=key, sample=sample)
    return float(value)


@dataclass(frozen=True)
class _Header:
    mass_kg: float
    length_m: float
    vin_v: float
    kp_register: int
    trajectory: str


def _header(path: Path, doc: Mapping[str, object]) -> _Header:
    missing = [k for k in HEADER_KEYS if k not in doc]
    if missing:
        raise Xl330FileError(
            f"{path}: missing key(s) {', '.join(missing)}; a BAM XL330 log needs "
            f"{', '.join(HEADER_KEYS)}",
            key=missing[0],
        )
    if doc["motor"] != MOTOR:
        raise Xl330FileError(
            f"{path}: motor {doc['motor']!r}; this importer knows only {MOTOR!r} "
            "(its constants are the XL330's)",
            key="motor",
        )
    positive = {}
    for key in ("mass", "length", "vin"):
        value = _number(path, doc[key], key)
        if not value > 0:
            raise Xl330FileError(f"{path}: key {key!r} = {value!r}: expected > 0", key=key)
        positive[key] = value
    kp = doc["kp"]
    if isinstance(kp, bool) or not isinstance(kp, int) or not 0 < kp <= 16383:
        raise Xl330FileError(
            f"{path}: key 'kp' = {kp!r}: expected the Position P Gain register, an integer "
            "1..16383",
            key="kp",
        )
    return _Header(
        mass_kg=positive["mass"],
        length_m=positive["length"],
        vin_v=positive["vin"],
        kp_register=kp,
        trajectory=str(doc.get("trajectory", "unknown")),
    )


def read_xl330_log(path: str | Path) -> Xl330Recording:
    """Read and check one raw BAM XL330 log (JSON, module docstring).

    Refused (:class:`Xl330FileError` naming file, key and entry): not JSON, missing keys,
    another motor, non-numeric or non-finite values, a PWM outside ±PWM_LIMIT counts,
    non-increasing time, fewer than MIN_ROWS entries, and any entry with the torque off (the
    ``lift_and_drop`` trajectory drops the pendulum: no closed loop to replay).
    """
    path = Path(path)
    if not path.is_file():
        raise Xl330FileError(f"{path}: no such file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Xl330FileError(f"{path}: not a readable JSON file ({exc})") from None
    if not isinstance(doc, dict):
        raise Xl330FileError(f"{path}: top level is {type(doc).__name__}, expected an object")
    header = _header(path, doc)
    entries = doc["entries"]
    if not isinstance(entries, list) or len(entries) < MIN_ROWS:
        n = len(entries) if isinstance(entries, list) else 0
        raise Xl330FileError(f"{path}: {n} entries, at least {MIN_ROWS} needed", key="entries")
    values = {key: np.empty(len(entries)) for key in ENTRY_KEYS}
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise Xl330FileError(f"{path}: entry {i} is not an object", sample=i)
        for key in ENTRY_KEYS:
            if key not in entry:
                raise Xl330FileError(f"{path}: entry {i} lacks key {key!r}", key=key, sample=i)
            values[key][i] = _number(path, entry[key], key, i)
        if entry.get("torque_enable", True) is not True:
            raise TorqueOffError(
                f"{path}: entry {i} (t = {values['timestamp'][i]:.4g} s) has the torque off "
                f"(trajectory {header.trajectory!r}); closed-loop replay needs the servo "
                "enabled throughout",
                key="torque_enable",
                sample=i,
            )
    pwm = values["load"]
    if np.any(pwm != np.round(pwm)) or np.any((pwm < 0) | (pwm > 65535)):
        i = int(np.argmax((pwm != np.round(pwm)) | (pwm < 0) | (pwm > 65535)))
        raise Xl330FileError(
            f"{path}: entry {i}, key 'load' = {pwm[i]!r}: expected the raw Present PWM "
            "register, an integer 0..65535",
            key="load",
            sample=i,
        )
    pwm = np.where(pwm > 32767, pwm - 65536, pwm)
    if np.any(np.abs(pwm) > PWM_LIMIT):
        i = int(np.argmax(np.abs(pwm) > PWM_LIMIT))
        raise Xl330FileError(
            f"{path}: entry {i}, Present PWM {int(pwm[i])} counts: allowed ±{PWM_LIMIT}",
            key="load",
            sample=i,
        )
    i = first_non_increasing(values["timestamp"])
    if i is not None:
        raise Xl330FileError(
            f"{path}: entry {i}, timestamp {values['timestamp'][i]!r} does not increase "
            f"(previous {values['timestamp'][i - 1]!r})",
            key="timestamp",
            sample=i,
        )
    return Xl330Recording(
        source=path,
        mass_kg=header.mass_kg,
        length_m=header.length_m,
        kp_register=header.kp_register,
        vin_nominal_v=header.vin_v,
        trajectory=header.trajectory,
        time_s=values["timestamp"],
        goal_rad=values["goal_position"],
        position_rad=values["position"],
        speed_rad_s=values["speed"],
        pwm_counts=pwm,
        input_v=values["input_volts"],
    )


def law_duty(rec: Xl330Recording, kp_divisor: float = KP_DIVISOR) -> np.ndarray:
    """The documented controller's duty rebuilt from goal and position (unclipped)."""
    return (
        rec.kp_register
        * (rec.goal_rad - rec.position_rad)
        * COUNTS_PER_RAD
        / (kp_divisor * PWM_LIMIT)
    )


def control_law_residual(rec: Xl330Recording, kp_divisor: float = KP_DIVISOR) -> float:
    """RMS of recorded duty minus the documented law, relative to the RMS duty, over the
    unsaturated samples: a check that the file is read the documented way."""
    duty = rec.duty
    ok = np.abs(duty) < SATURATED_DUTY
    residual = duty[ok] - law_duty(rec, kp_divisor)[ok]
    return float(np.sqrt(np.mean(residual**2)) / np.sqrt(np.mean(duty[ok] ** 2)))


def motor_torque_nm(rec: Xl330Recording, params: Mapping[str, float] = BAM_M1) -> np.ndarray:
    """DC-motor torque at the output shaft, kt/R * (V - kt*speed), N m (module docstring)."""
    kt, r = params["kt"], params["R"]
    return kt / r * (rec.input_v * rec.duty - kt * rec.speed_rad_s)


def xl330_trace(rec: Xl330Recording) -> Trace:
    """The recording as a servo trace (columns and timing: module docstring)."""
    return Trace(
        {
            "time": rec.time_s,
            "position_reference": rec.goal_rad,
            "motor_position": rec.position_rad,
            "motor_speed": rec.speed_rad_s,
            "motor_torque": motor_torque_nm(rec),
            "pwm_duty": rec.duty,
            "input_voltage": rec.input_v,
        }
    )


def controller_gains(
    kp_register: int, vin_v: float, params: Mapping[str, float] = BAM_M1
) -> tuple[float, float]:
    """(kv 1/s, ksp N m s/rad) of the axis-file cascade equivalent to the servo's P loop."""
    kt, r = params["kt"], params["R"]
    duty_per_rad = kp_register * COUNTS_PER_RAD / (KP_DIVISOR * PWM_LIMIT)
    return vin_v * duty_per_rad / kt, kt * kt / r


def reference_axis(rec: Xl330Recording, params: Mapping[str, float] = BAM_M1) -> AxisConfig:
    """BAM's model m1 of this bench as an axis file, gravity as a position-periodic torque."""
    kv, ksp = controller_gains(rec.kp_register, rec.vin_nominal_v, params)
    return AxisConfig(
        kind=AxisKind.ROTARY,
        transmission_ratio=1.0,
        mechanics=Mechanics(
            motor_inertia=params["armature"],
            load_mass=rec.mass_kg * rec.length_m**2,
        ),
        friction=Friction(coulomb=params["friction_base"], viscous=params["friction_viscous"]),
        disturbance=Disturbance(
            periodic_amplitude=rec.gravity_nm_per_sin,
            periodic_period=2.0 * math.pi,
            periodic_phase=params["q_offset"],
        ),
        control=Control(
            kv=kv,
            ksp=ksp,
            position_feedback=PositionFeedback.MOTOR,
            position_cycle=CONTROL_CYCLE_S,
            speed_cycle=CONTROL_CYCLE_S,
        ),
    )


def nominal_axis(rec: Xl330Recording, params: Mapping[str, float] = BAM_M1) -> AxisConfig:
    """The diagnosis' starting point: the reference model without Coulomb friction and with
    the encoder zero taken as hanging down (q_offset = 0: gravity phase absent)."""
    ref = reference_axis(rec, params)
    return AxisConfig(
        kind=ref.kind,
        transmission_ratio=ref.transmission_ratio,
        mechanics=ref.mechanics,
        friction=Friction(viscous=ref.friction.viscous),
        disturbance=Disturbance(
            periodic_amplitude=ref.disturbance.periodic_amplitude,
            periodic_period=ref.disturbance.periodic_period,
        ),
        control=ref.control,
    )


def _axis_header(rec: Xl330Recording, what: str) -> str:
    kt, r = BAM_M1["kt"], BAM_M1["R"]
    kv, ksp = controller_gains(rec.kp_register, rec.vin_nominal_v)
    return f"""BAM XL330 pendulum bench, Position P Gain register kp = {rec.kp_register}: {what}
Written by `python -m plant_sim xl330` (plant_sim/datasets/xl330.py; docs/xl330.md). Rotary axis
at the output shaft, transmission ratio 1 (rad, N m). Sources (BAM, Apache-2.0, commit af226046):
  kt = {kt:.6g} N m/A, R = {r:.6g} ohm, armature = {BAM_M1["armature"]:.6g} kg m^2,
  friction_base = {BAM_M1["friction_base"]:.6g} N m, friction_viscous = \
{BAM_M1["friction_viscous"]:.6g} N m s/rad   (params/xl330/m1.json, model m1)
  motor_inertia = armature (the rotor, reflected to the output shaft);
  load_inertia = mass*length^2 = {rec.mass_kg:g}*{rec.length_m:g}^2 (log header; rod mass
  unknown, left out); rigid: no antiresonance, so the split changes nothing here
  controller (bam/xl330/actuator.py):
  duty = kp*e*{COUNTS_PER_REV}/(2 pi)/({KP_DIVISOR}*{PWM_LIMIT}), V = vin*duty,
  torque = kt/R*V - kt^2/R*speed  ->
  kv = vin*kp*{COUNTS_PER_REV}/(2 pi)/({KP_DIVISOR}*{PWM_LIMIT})/kt = {kv:.6g} 1/s
  (vin = {rec.vin_nominal_v:g} V, the log's nominal supply),
  ksp = kt^2/R = {ksp:.6g} N m s/rad (back-EMF damping), P only.
  No torque_limit: the servo clips the duty (|duty| <= 1), not the torque.
  position/speed cycle {CONTROL_CYCLE_S:g} s: assumed (the servo's loop rate is not in the data).
  gravity -m*g*l*sin(q + q_offset) (bam/testbench.py, bam/simulate.py) = position-periodic
  torque: periodic_amplitude = m*g*l = {rec.gravity_nm_per_sin:.6g} N m, period 2 pi rad,
  phase = q_offset = {BAM_M1["q_offset"]:.6g} rad (m1.json; the nominal file leaves it out).
"""


@dataclass(frozen=True)
class ImportedFile:
    """One converted recording: where from, where to, what was read."""

    recording: Xl330Recording
    target: Path
    rows: int


@dataclass(frozen=True)
class ImportResult:
    """Converted traces and the axis files written (one reference + nominal per kp)."""

    traces: list[ImportedFile]
    axis_files: list[Path]


def trace_name(rec: Xl330Recording) -> str:
    return f"kp{rec.kp_register}_{rec.trajectory}.csv"


def import_xl330(sources: Sequence[str | Path], out_dir: str | Path) -> ImportResult:
    """Convert each log to ``OUT_DIR/kp<kp>_<trajectory>.csv`` and write
    ``xl330_kp<kp>_reference.toml`` / ``_nominal.toml`` per distinct kp. Everything is read
    and checked before anything is written."""
    recordings = [read_xl330_log(src) for src in sources]
    by_name: dict[str, Xl330Recording] = {}
    by_kp: dict[int, Xl330Recording] = {}
    for rec in recordings:
        name = trace_name(rec)
        if name in by_name:
            raise Xl330FileError(
                f"{rec.source}: same kp and trajectory as {by_name[name].source} "
                f"(both would become {name}); import them into different directories"
            )
        by_name[name] = rec
        first = by_kp.setdefault(rec.kp_register, rec)
        bench = (first.mass_kg, first.length_m, first.vin_nominal_v)
        if (rec.mass_kg, rec.length_m, rec.vin_nominal_v) != bench:
            raise Xl330FileError(
                f"{rec.source}: mass/length/vin {rec.mass_kg:g}/{rec.length_m:g}/"
                f"{rec.vin_nominal_v:g} differ from {first.source} with the same kp "
                f"({bench[0]:g}/{bench[1]:g}/{bench[2]:g}); one axis file per kp needs one bench"
            )
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise Xl330FileError(f"{out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for name, rec in by_name.items():
        trace = xl330_trace(rec)
        target = out / name
        trace.to_csv(target)
        done.append(ImportedFile(rec, target, len(trace)))
    axis_files = []
    for kp, rec in sorted(by_kp.items()):
        for what, axis in (("reference", reference_axis(rec)), ("nominal", nominal_axis(rec))):
            header = _axis_header(
                rec,
                "BAM's published model m1"
                if what == "reference"
                else "nominal = BAM's m1 WITHOUT Coulomb friction and q_offset (diagnosis start)",
            )
            target = out / f"xl330_kp{kp}_{what}.toml"
            write_atomic(target, dump_axis(axis, header))
            axis_files.append(target)
    return ImportResult(done, axis_files)

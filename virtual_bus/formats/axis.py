"""Axis files (``docs/axis-file.md``): read, validate, derive, write.

An :class:`AxisConfig` is the one description of an axis that every part uses: the simulator
kernel, the simulated drive, the bridge (its control part) and the diagnosis (which writes a
fitted one back with :func:`dump_axis`). Every value is SI; torques and friction are reflected
to the motor shaft (N·m) as in the paper; speeds in friction laws are load speeds.

A key that is absent means "this physics is not in the model" and is held here as ``None``.

Derived quantities follow the paper's section III (eq. 2-4): the elastic element sits between
the motor side (motor + coupling + ball screw, rigid with the motor) and the load, with

    J_l' = J_l / k_r^2          (load inertia reflected to the motor; J_l = M_l for a linear axis)
    k_s' = J_l' * omega_a^2     (so that omega_a = sqrt(k_s'/J_l'), eq. 2)
    omega_r = omega_a * sqrt(1 + R),  R = J_l' / J_motor_side   (eq. 4)
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from enum import Enum
from pathlib import Path
from typing import Any

from .errors import AxisFileError, read_text


class AxisKind(Enum):
    """Linear axis (load unit m) or rotary axis (load unit rad)."""

    LINEAR = "linear"
    ROTARY = "rotary"


class PositionFeedback(Enum):
    """Which measuring system closes the position loop (paper section II.B)."""

    LOAD = "load"  # direct measuring system (linear scale / load encoder)
    MOTOR = "motor"  # motor measuring system


def _fail(key: str, value: object, allowed: str) -> AxisFileError:
    return AxisFileError(f"{key} = {value!r}: {allowed}", key=key, value=value)


@dataclass(frozen=True)
class Range:
    """The values a numeric key allows: ``low`` (excluded when ``low_open``) to ``high``."""

    low: float
    high: float = math.inf
    low_open: bool = False

    def allows(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        return math.isfinite(value) and above and value <= self.high

    def __str__(self) -> str:
        lo = f"({self.low:g}" if self.low_open else f"[{self.low:g}"
        hi = "inf)" if math.isinf(self.high) else f"{self.high:g}]"
        return f"{lo}, {hi}"


#: The allowed range of every numeric key (docs/axis-file.md), checked when a section is
#: built; other tools (the diagnosis's fit bounds) read them from here.
RANGES: dict[str, Range] = {
    "mechanics.motor_inertia": Range(0.0),
    "mechanics.screw_inertia": Range(0.0),
    "mechanics.load_mass": Range(0.0, low_open=True),
    "mechanics.antiresonance": Range(0.0, high=1e6, low_open=True),
    "mechanics.damping_ratio": Range(0.0, high=1.0),
    "mechanics.backlash": Range(0.0, high=0.1),
    "friction.coulomb": Range(0.0, high=1e6),
    "friction.viscous": Range(0.0, high=1e6),
    "friction.coulomb_negative": Range(0.0, high=1e6),
    "friction.viscous_negative": Range(0.0, high=1e6),
    "friction.stribeck": Range(0.0, high=1e6),
    "friction.stribeck_speed": Range(0.0, low_open=True),
    "friction.creep_speed": Range(0.0, low_open=True),
    "disturbance.constant_torque": Range(-1e6, high=1e6),
    "disturbance.periodic_amplitude": Range(0.0, high=1e6),
    "disturbance.periodic_period": Range(0.0, low_open=True),
    "disturbance.periodic_phase": Range(-1e3, high=1e3),
    "control.kv": Range(0.0, high=1e4, low_open=True),
    "control.ksp": Range(0.0, high=1e9, low_open=True),
    "control.tsi": Range(0.0, high=1e3, low_open=True),
    "control.torque_limit": Range(0.0, low_open=True),
    "control.current_lag": Range(0.0, high=1.0),
    "control.delay": Range(0.0, high=0.1),
    "control.speed_cycle": Range(1e-6, high=0.1),
    "control.position_cycle": Range(1e-6, high=1.0),
    "control.velocity_feedforward": Range(0.0, high=1.5),
    "control.acceleration_feedforward": Range(0.0, high=1e6),
    "control.sensor_time_offset": Range(-0.05, high=0.05),
    "control.speed_filter": Range(0.0, high=0.1),
    "control.setpoint_delay": Range(0.0, high=0.1),
    "control.setpoint_delay_rate": Range(-0.01, high=0.01),
    "control.measurement_delay": Range(0.0, high=0.05),
    "control.scale_error_amplitude": Range(0.0, high=0.01),
    "control.scale_error_period": Range(0.0, low_open=True),
    "control.scale_error_phase": Range(-1e3, high=1e3),
    "axis.transmission_ratio": Range(0.0, low_open=True),
}

#: The keys of RANGES per section, in the table's order.
_SECTION_KEYS = {
    section: tuple(key for key in RANGES if key.startswith(section + "."))
    for section in ("axis", "mechanics", "friction", "disturbance", "control")
}


def _check_section(section: str, values: object) -> None:
    """Every key of ``section`` in :data:`RANGES` on ``values`` (a section's dataclass),
    in the table's order; an absent value (None) is not checked."""
    for key in _SECTION_KEYS[section]:
        value = getattr(values, key.partition(".")[2])
        if value is not None and not RANGES[key].allows(value):
            raise _fail(key, value, f"allowed range {RANGES[key]}")


@dataclass(frozen=True)
class Mechanics:
    """``[mechanics]``: inertias, elasticity (eq. 2-4) and backlash.

    ``load_mass`` is kg for a linear axis and kg·m² (``load_inertia`` in the file) for a
    rotary one. ``backlash`` is the TOTAL free play δ between motor side and load, in load
    units; the dead zone spans ±δ/2 around the centred position.
    """

    motor_inertia: float  # kg m^2, J_m incl. coupling
    load_mass: float  # kg (linear) or kg m^2 (rotary)
    screw_inertia: float = 0.0  # kg m^2, rigid with the motor side
    antiresonance: float | None = None  # rad/s, omega_a; None: rigid axis
    damping_ratio: float | None = None  # xi_a of the elastic element
    backlash: float | None = None  # load units, total free play

    def __post_init__(self) -> None:
        # 0 is allowed: a lumped rigid model with all inertia in the load (needs a rigid axis)
        _check_section("mechanics", self)
        if self.damping_ratio is not None and self.antiresonance is None:
            raise _fail(
                "mechanics.damping_ratio",
                self.damping_ratio,
                "needs mechanics.antiresonance (damping of an elastic element the model lacks)",
            )
        if self.antiresonance is not None and self.motor_inertia + self.screw_inertia <= 0.0:
            raise _fail(
                "mechanics.motor_inertia",
                self.motor_inertia,
                "motor_inertia + screw_inertia must be > 0 on an elastic axis (antiresonance "
                "given); 0 is allowed only for a lumped rigid model",
            )
        if self.backlash and self.antiresonance is None:
            raise _fail(
                "mechanics.backlash",
                self.backlash,
                "needs mechanics.antiresonance: the contact stiffness in the dead zone comes "
                "from omega_a (a rigid axis has no flank to hit)",
            )


@dataclass(frozen=True)
class Friction:
    """``[friction]``, reflected to the motor in N·m; speeds are load speeds (load units/s).

    tau_f(v) = coulomb*sign(v) + viscous*v (+ stribeck*exp(-(v/stribeck_speed)^2)*sign(v)),
    with the ``*_negative`` values for v < 0 when direction-dependent friction is modelled.
    ``creep_speed`` (load units/s): absent, sign(v) is set-valued at rest (stiction: a load
    stays at rest while the force is within the static level); given, sign(v) becomes
    clip(v/creep_speed, -1, 1) (pre-sliding creep: a load under a force below the static
    level creeps instead of sticking).
    """

    coulomb: float | None = None
    viscous: float | None = None
    coulomb_negative: float | None = None
    viscous_negative: float | None = None
    stribeck: float | None = None
    stribeck_speed: float | None = None
    creep_speed: float | None = None

    def __post_init__(self) -> None:
        _check_section("friction", self)
        if (self.stribeck is None) != (self.stribeck_speed is None):
            given = "stribeck" if self.stribeck is not None else "stribeck_speed"
            raise _fail(
                f"friction.{given}",
                getattr(self, given),
                "friction.stribeck and friction.stribeck_speed go together",
            )


@dataclass(frozen=True)
class Disturbance:
    """``[disturbance]``: load torques reflected to the motor (N·m).

    Positive ``constant_torque`` is the torque the motor must supply to hold the axis at rest,
    i.e. it opposes positive motion. The position-periodic torque follows the same sign rule:
    tau(x) = periodic_amplitude * sin(2*pi*x/periodic_period + periodic_phase).
    """

    constant_torque: float | None = None
    periodic_amplitude: float | None = None
    periodic_period: float | None = None
    periodic_phase: float | None = None

    def __post_init__(self) -> None:
        _check_section("disturbance", self)
        if (self.periodic_amplitude is None) != (self.periodic_period is None):
            given = (
                "periodic_amplitude" if self.periodic_amplitude is not None else "periodic_period"
            )
            raise _fail(
                f"disturbance.{given}",
                getattr(self, given),
                "disturbance.periodic_amplitude and disturbance.periodic_period go together",
            )
        if self.periodic_phase is not None and self.periodic_amplitude is None:
            raise _fail(
                "disturbance.periodic_phase",
                self.periodic_phase,
                "needs disturbance.periodic_amplitude and periodic_period",
            )


@dataclass(frozen=True)
class Control:
    """``[control]``: the cascade of Fig. 1 (P position, PI speed, current loop)."""

    kv: float  # 1/s, position gain (eq. 1, 7)
    ksp: float  # N m s/rad, speed controller gain
    position_feedback: PositionFeedback = PositionFeedback.LOAD
    tsi: float | None = None  # s, integral time; None: P-only speed loop
    torque_limit: float | None = None  # N m; None: no saturation
    current_lag: float | None = None  # s, first-order lag; None: ideal current loop
    delay: float | None = None  # s, dead time set point -> torque; None: none
    position_cycle: float = 0.001  # s
    speed_cycle: float = 0.000125  # s
    #: gain (0..1.5) on the interpolator's speed added to the speed set point; None: 0
    velocity_feedforward: float | None = None
    #: kg m^2 at the motor: torque set point += value * reference motor acceleration; None: 0
    acceleration_feedforward: float | None = None
    #: s, load measuring system's sample time minus the motor's (positive: load position
    #: older), -0.05..0.05; None: both sampled together
    sensor_time_offset: float | None = None
    #: s, time constant of the drive's first-order low-pass on the measured motor speed (the
    #: speed actual value the PI speed controller uses and the drive reports), 0..0.1;
    #: None or 0: no filter. A controller setting like current_lag, not an effect.
    speed_filter: float | None = None
    #: s, 0..0.1: the drive applies the speed set point (and the torque feed-forward) this
    #: much later than it gets it (bus, the drive's input stage); None: at once
    setpoint_delay: float | None = None
    #: s/s, -0.01..0.01 (needs setpoint_delay): the set point's dead time grows by this much
    #: per second of the run, d(t) = clip(setpoint_delay + rate*t, 0, 0.1); None: constant
    setpoint_delay_rate: float | None = None
    #: s, 0..0.05: every reading the position loop and the recording get (motor and load
    #: position, the speed actual value) is this much old; the drive's own speed loop reads
    #: the encoder at once. Adds to sensor_time_offset's shift of the reading it concerns.
    measurement_delay: float | None = None
    #: load units, 0..0.01: periodic error of the load measuring system (a measurement error,
    #: not a force): it reads x + amplitude*sin(2*pi*x/period + phase)
    scale_error_amplitude: float | None = None
    scale_error_period: float | None = None  # load units, > 0
    scale_error_phase: float | None = None  # rad

    def __post_init__(self) -> None:
        _check_section("control", self)
        if self.setpoint_delay_rate is not None and self.setpoint_delay is None:
            raise _fail(
                "control.setpoint_delay_rate",
                self.setpoint_delay_rate,
                "needs control.setpoint_delay (the dead time at the start of the run)",
            )
        if (self.scale_error_amplitude is None) != (self.scale_error_period is None):
            given = (
                "scale_error_amplitude"
                if self.scale_error_amplitude is not None
                else "scale_error_period"
            )
            raise _fail(
                f"control.{given}",
                getattr(self, given),
                "control.scale_error_amplitude and control.scale_error_period go together",
            )
        if self.scale_error_phase is not None and self.scale_error_amplitude is None:
            raise _fail(
                "control.scale_error_phase",
                self.scale_error_phase,
                "needs control.scale_error_amplitude and scale_error_period",
            )
        ratio = self.position_cycle / self.speed_cycle
        if abs(ratio - round(ratio)) > 1e-6 * ratio or round(ratio) < 1:
            raise _fail(
                "control.position_cycle",
                self.position_cycle,
                f"must be a whole multiple (>= 1) of control.speed_cycle = {self.speed_cycle!r}",
            )

    @property
    def speed_cycles_per_position_cycle(self) -> int:
        return round(self.position_cycle / self.speed_cycle)


@dataclass(frozen=True)
class AxisConfig:
    """One servo axis: ``[axis]`` plus the four sections. Validated when built."""

    kind: AxisKind
    transmission_ratio: float  # k_r, motor rad per load unit
    mechanics: Mechanics
    control: Control
    friction: Friction = Friction()
    disturbance: Disturbance = Disturbance()

    def __post_init__(self) -> None:
        _check_section("axis", self)
        try:  # k_r² in J_l' = J_l / k_r² (section III) must be a finite float > 0
            square = self.transmission_ratio**2
        except OverflowError:
            square = math.inf
        reflected = self.mechanics.load_mass / square if 0.0 < square < math.inf else 0.0
        if not (math.isfinite(reflected) and reflected > 0.0):
            raise AxisFileError(
                f"axis.transmission_ratio = {self.transmission_ratio!r}: the reflected load "
                f"inertia J_l / k_r² = {self.mechanics.load_mass!r} / k_r² is not a finite "
                "number > 0 in floating point; use a ratio whose square is representable"
            )

    # --- derived quantities (paper section III) -------------------------------------------
    @property
    def load_unit(self) -> str:
        return "m" if self.kind is AxisKind.LINEAR else "rad"

    @property
    def motor_side_inertia(self) -> float:
        """kg·m²: motor, coupling and ball screw (rigid with the motor)."""
        return self.mechanics.motor_inertia + self.mechanics.screw_inertia

    @property
    def load_inertia_reflected(self) -> float:
        """kg·m²: J_l' = J_l / k_r² (section III)."""
        return self.mechanics.load_mass / self.transmission_ratio**2

    @property
    def total_inertia(self) -> float:
        """kg·m² at the motor: J_m + J_screw + J_l'."""
        return self.motor_side_inertia + self.load_inertia_reflected

    @property
    def inertia_ratio(self) -> float:
        """R = J_l' / J_motor_side (eq. 4); inf for a lumped model (motor side inertia 0)."""
        if self.motor_side_inertia <= 0.0:
            return math.inf
        return self.load_inertia_reflected / self.motor_side_inertia

    @property
    def is_rigid(self) -> bool:
        return self.mechanics.antiresonance is None

    @property
    def stiffness(self) -> float | None:
        """Stiffness of the screw-nut element in load coordinates, N/m (N·m/rad for rotary):
        k = M_l · omega_a² (eq. 2: omega_a = sqrt(k_s/J_l)). None for a rigid axis."""
        wa = self.mechanics.antiresonance
        return None if wa is None else self.mechanics.load_mass * wa**2

    @property
    def stiffness_reflected(self) -> float | None:
        """k_s' = k / k_r², N·m/rad at the motor."""
        k = self.stiffness
        return None if k is None else k / self.transmission_ratio**2

    @property
    def resonance(self) -> float | None:
        """omega_r = omega_a·sqrt(1 + R), rad/s (eq. 4)."""
        wa = self.mechanics.antiresonance
        return None if wa is None else wa * math.sqrt(1.0 + self.inertia_ratio)

    @property
    def damping_coefficient(self) -> float:
        """c in load coordinates (N·s/m): xi_a = c·omega_a/(2k) (eq. 2) => c = 2·xi_a·k/omega_a."""
        wa, xi, k = self.mechanics.antiresonance, self.mechanics.damping_ratio, self.stiffness
        if wa is None or xi is None or k is None:
            return 0.0
        return 2.0 * xi * k / wa

    def with_values(self, values: Mapping[str, float | None]) -> AxisConfig:
        """A copy with dotted keys replaced (``{"friction.coulomb": 1.3}``), validated again."""
        sections: dict[str, Any] = {
            "mechanics": self.mechanics,
            "friction": self.friction,
            "disturbance": self.disturbance,
            "control": self.control,
        }
        top: dict[str, Any] = {}
        changes: dict[str, dict[str, Any]] = {}
        for dotted, value in values.items():
            section, _, key = dotted.partition(".")
            if section == "axis" and key == "transmission_ratio":
                top[key] = value
                continue
            if section == "mechanics" and key == "load_inertia":
                key = "load_mass"
            if section not in sections or key not in {f.name for f in fields(sections[section])}:
                raise AxisFileError(f"unknown axis key {dotted!r}", key=dotted, value=value)
            changes.setdefault(section, {})[key] = value
        new = {s: replace(sections[s], **c) for s, c in changes.items()}
        return replace(self, **top, **new)

    def value(self, dotted: str) -> float | None:
        """The value of a dotted key (``"mechanics.backlash"``), None when absent."""
        section, _, key = dotted.partition(".")
        if section == "axis":
            return getattr(self, key)
        if section == "mechanics" and key == "load_inertia":
            key = "load_mass"
        return getattr(getattr(self, section), key)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
_REQUIRED = {
    "axis": ("kind", "transmission_ratio"),
    "mechanics": ("motor_inertia",),
    "control": ("kv", "ksp"),
}
_SECTIONS: dict[str, type] = {
    "mechanics": Mechanics,
    "friction": Friction,
    "disturbance": Disturbance,
    "control": Control,
}


def _number(key: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(key, value, f"must be a number, got {type(value).__name__}")
    return float(value)


def _section_values(name: str, table: Mapping[str, Any], kind: AxisKind) -> dict[str, Any]:
    allowed = {f.name for f in fields(_SECTIONS[name])}
    out: dict[str, Any] = {}
    for key, raw in table.items():
        dotted = f"{name}.{key}"
        field = key
        if name == "mechanics" and key in {"load_mass", "load_inertia"}:
            want = "load_mass" if kind is AxisKind.LINEAR else "load_inertia"
            if key != want:
                raise _fail(dotted, raw, f"a {kind.value} axis gives mechanics.{want}")
            field = "load_mass"
        if field not in allowed:
            keys = sorted(allowed | ({"load_inertia"} if name == "mechanics" else set()))
            raise _fail(dotted, raw, f"unknown key; allowed in [{name}]: {', '.join(keys)}")
        if name == "control" and key == "position_feedback":
            choices = [p.value for p in PositionFeedback]
            if raw not in choices:
                raise _fail(dotted, raw, f"must be one of {choices}")
            out[field] = PositionFeedback(raw)
        else:
            out[field] = _number(dotted, raw)
    return out


def axis_from_mapping(doc: Mapping[str, Any]) -> AxisConfig:
    """Build an :class:`AxisConfig` from a parsed TOML document (raises AxisFileError)."""
    for section, table in doc.items():
        if section not in {"axis", *_SECTIONS}:
            allowed = ", ".join(["axis", *_SECTIONS])
            raise _fail(section, "[...]", f"unknown section; allowed: {allowed}")
        if not isinstance(table, Mapping):
            raise _fail(section, table, "must be a [section] table")
    for section, keys in _REQUIRED.items():
        for key in keys:
            if key not in doc.get(section, {}):
                raise AxisFileError(f"missing required key {section}.{key}", key=f"{section}.{key}")
    axis = doc["axis"]
    for key in axis:
        if key not in {"kind", "transmission_ratio"}:
            raise _fail(f"axis.{key}", axis[key], "unknown key; allowed: kind, transmission_ratio")
    kinds = [k.value for k in AxisKind]
    if axis["kind"] not in kinds:
        raise _fail("axis.kind", axis["kind"], f"must be one of {kinds}")
    kind = AxisKind(axis["kind"])
    parts = {name: _section_values(name, doc.get(name, {}), kind) for name in _SECTIONS}
    load_key = "load_mass" if kind is AxisKind.LINEAR else "load_inertia"
    if "load_mass" not in parts["mechanics"]:
        raise AxisFileError(
            f"missing required key mechanics.{load_key}", key=f"mechanics.{load_key}"
        )
    return AxisConfig(
        kind=kind,
        transmission_ratio=_number("axis.transmission_ratio", axis["transmission_ratio"]),
        mechanics=Mechanics(**parts["mechanics"]),
        friction=Friction(**parts["friction"]),
        disturbance=Disturbance(**parts["disturbance"]),
        control=Control(**parts["control"]),
    )


def load_axis(path: str | Path) -> AxisConfig:
    """Read and validate an axis file. Raises AxisFileError naming the file and the key."""
    path = Path(path)
    text = read_text(path, "axis file", AxisFileError)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise AxisFileError(f"{path}: not valid TOML ({exc})") from exc
    try:
        return axis_from_mapping(doc)
    except AxisFileError as exc:
        raise AxisFileError(f"{path}: {exc}", key=exc.key, value=exc.value) from None


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def _fmt(value: object) -> str:
    if isinstance(value, Enum):
        return f'"{value.value}"'
    if isinstance(value, int | float) and not isinstance(value, bool):
        return repr(float(value))  # also numpy scalars: repr(np.float64) is not TOML
    return str(value)


def dump_axis(axis: AxisConfig, header: str = "") -> str:
    """TOML text of an axis (absent physics stays absent); ``header`` becomes comments."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += [
        "[axis]",
        f'kind = "{axis.kind.value}"',
        f"transmission_ratio = {axis.transmission_ratio!r}",
    ]
    for name in _SECTIONS:
        part = getattr(axis, name)
        body = []
        for f in fields(part):
            value = getattr(part, f.name)
            if value is None:
                continue
            key = f.name
            if name == "mechanics" and key == "load_mass" and axis.kind is AxisKind.ROTARY:
                key = "load_inertia"
            body.append(f"{key} = {_fmt(value)}")
        if body:
            lines += ["", f"[{name}]", *body]
    return "\n".join(lines) + "\n"

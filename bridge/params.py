"""The bridge's parameters: ranges, cross-checks and the SDO abort code of every refusal.

:class:`BridgeParams` is frozen and validated on construction; a change is a new instance
(:meth:`BridgeParams.with_value`), so a refused write changes nothing. Every refusal is a
:class:`~bridge.errors.ParameterError` whose ``abort_code`` is what the SDO server answers:

* 0609 0032 (too low) / 0609 0031 (too high): a number outside its range;
* 0609 0030 (value range exceeded): NaN/inf, a boolean other than 0/1, a wrong type;
* 0800 0022 (device state): a parameter locked while the axis is enabled (:data:`LOCKED`).

The regulator's own rules (section VII sampling rule ``cycle < 1/(2 (n+1) kv)``, eq. 14
``T_v >= 20/kv``) are checked by building a :class:`regulator.RegulatorConfig`; when they fail
the written value is "too high" or "too low" according to the direction it moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from regulator import (
    DEFAULT_BETA_T_RAD_S,
    DEFAULT_N,
    DEFAULT_TF_S,
    RegulatorConfig,
    RegulatorConfigError,
)
from virtual_bus.formats.axis import AxisConfig, AxisKind

from .errors import ParameterError, SdoAbort
from .interpolator import MAX_ABS_TARGET
from .scaling import INT32_MAX, MOTOR_INCREMENTS_PER_RAD


@dataclass(frozen=True)
class Bound:
    """Allowed range of a numeric parameter: ``low < v`` (open) or ``low <= v``, ``v <= high``."""

    low: float
    high: float
    unit: str
    low_open: bool = False

    def text(self) -> str:
        lo = f"({self.low:g}" if self.low_open else f"[{self.low:g}"
        return f"{lo}, {self.high:g}] {self.unit}".rstrip()


#: Largest speed set point 60FFh can carry (INTEGER32 increments/s), rad/s.
MAX_SPEED_RAD_S = INT32_MAX / MOTOR_INCREMENTS_PER_RAD

#: Numeric ranges per field (the regulator's cross-field rules come on top).
BOUNDS: dict[str, Bound] = {
    "kv_per_s": Bound(0.0, 1000.0, "1/s", low_open=True),
    "velocity_feedforward": Bound(0.0, 1.5, ""),
    "beta_t_rad_s": Bound(0.0, 1e4, "rad/s", low_open=True),
    "n": Bound(1, 64, ""),
    "tv_s": Bound(0.0, 1000.0, "s", low_open=True),
    "tf_s": Bound(0.0, 100.0, "s", low_open=True),
    "cycle_s": Bound(1e-4, 0.1, "s"),
    "transmission_ratio": Bound(0.0, 1e7, "motor rad per load unit", low_open=True),
    "speed_limit_rad_s": Bound(0.0, MAX_SPEED_RAD_S, "rad/s", low_open=True),
    "following_error_limit": Bound(0.0, 10.0, "load units", low_open=True),
    "discrepancy_limit": Bound(0.0, 10.0, "load units", low_open=True),
    "pdo_loss_tolerance": Bound(0, 255, "cycles"),
    "heartbeat_consumer_ms": Bound(0, 65535, "ms"),
    "feed": Bound(0.0, 100.0, "load units/s", low_open=True),
    "accel": Bound(0.0, 1e6, "load units/s^2"),
    "position_limit_min": Bound(-MAX_ABS_TARGET, MAX_ABS_TARGET, "load units"),
    "position_limit_max": Bound(-MAX_ABS_TARGET, MAX_ABS_TARGET, "load units"),
}
INTEGER_FIELDS = frozenset({"n", "pdo_loss_tolerance", "heartbeat_consumer_ms"})
BOOL_FIELDS = frozenset({"regulator_enabled"})
OPTIONAL_FIELDS = frozenset({"tv_s"})
#: Parameters that may not change while the axis is enabled (SDO abort 0800 0022): the
#: regulator's and the position loop's structure, the cycle and the heartbeat supervision.
LOCKED = frozenset(
    {
        "kv_per_s",
        "velocity_feedforward",
        "regulator_enabled",
        "beta_t_rad_s",
        "n",
        "tv_s",
        "tf_s",
        "cycle_s",
        "transmission_ratio",
        "heartbeat_consumer_ms",
    }
)

#: Section II.B: the two measuring systems must agree "about 0.5 mm or 0.5 deg".
DEFAULT_DISCREPANCY = {AxisKind.LINEAR: 0.5e-3, AxisKind.ROTARY: math.radians(0.5)}
#: Following-error limit default: 5 mm (linear) or 5 deg (rotary) of load travel.
DEFAULT_FOLLOWING_ERROR = {AxisKind.LINEAR: 5e-3, AxisKind.ROTARY: math.radians(5.0)}
DEFAULT_SPEED_LIMIT_RAD_S = 100.0 * math.pi  # 3000 rpm at the motor
DEFAULT_PDO_LOSS_TOLERANCE = 5
DEFAULT_HEARTBEAT_CONSUMER_MS = 250
DEFAULT_FEED = {AxisKind.LINEAR: 0.05, AxisKind.ROTARY: 0.5}
#: Software position limits (2014h): +-2 m (the INTEGER32 nm range of 2010h is +-2.147 m) or
#: +-1000 rad (the interpolator's sanity bound), i.e. no narrower than the objects can express.
DEFAULT_POSITION_LIMIT = {AxisKind.LINEAR: 2.0, AxisKind.ROTARY: MAX_ABS_TARGET}


def _fail(field: str, value: object, code: SdoAbort, allowed: str) -> ParameterError:
    return ParameterError(
        f"{field} = {value!r}: {allowed}", field=field, value=value, abort_code=code
    )


def check_field(field: str, value: object) -> None:
    """Check one field against its own range; raise :class:`ParameterError` with the code."""
    if field in BOOL_FIELDS:
        if not isinstance(value, bool):
            raise _fail(field, value, SdoAbort.VALUE_RANGE, "must be True or False (1 or 0)")
        return
    if field in OPTIONAL_FIELDS and value is None:
        return
    bound = BOUNDS[field]
    if field in INTEGER_FIELDS:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(field, value, SdoAbort.VALUE_RANGE, f"must be an integer in {bound.text()}")
    elif isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _fail(
            field, value, SdoAbort.VALUE_RANGE, f"must be a finite number in {bound.text()}"
        )
    if value < bound.low or (bound.low_open and value == bound.low):
        raise _fail(field, value, SdoAbort.TOO_LOW, f"too low; allowed {bound.text()}")
    if value > bound.high:
        raise _fail(field, value, SdoAbort.TOO_HIGH, f"too high; allowed {bound.text()}")


@dataclass(frozen=True)
class BridgeParams:
    """Everything the cycle needs that a CANopen tool may change (OD objects in brackets).

    kv_per_s [2000h]: position gain k_v, 1/s (eq. 7). regulator_enabled [2001h]: eq. 15 in
    the loop, else omega_r = omega_c (beta still measured). beta_t_rad_s [2002h]: threshold
    beta_T of eq. 15, rad/s (motor). n [2003h]: detector window n + 1 samples. tv_s [2004h]:
    holder decay T_v in s, ``None`` = eq. 14's 20/kv. tf_s [2005h]: low-pass T_f, s.
    cycle_s [1006h]: SYNC period = position cycle, s. transmission_ratio [2006h]: k_r, motor
    rad per load unit. speed_limit_rad_s [2007h]: |omega_r| clamp, rad/s. following_error_limit
    [2008h] and discrepancy_limit [2009h]: load units, stop when exceeded.
    pdo_loss_tolerance [200Ah]: consecutive cycles with a missing TPDO before stopping.
    heartbeat_consumer_ms [1016h:01]: drive heartbeat timeout, ms, 0 = not monitored.
    feed [2011h]: load units/s, accel [2012h]: load units/s², 0 = speed step, of moves started
    by the target-position object. position_limit_min / position_limit_max [2014h:01/02]:
    software travel limits, load units (like CiA 402 607Dh), min < max: moves to targets
    outside are refused and an axis outside them is stopped (bridge.cycle).
    velocity_feedforward [200Bh]: k_vff, 0..1.5, the axis file's
    ``control.velocity_feedforward``: the interpolator's speed times k_vff is added to the
    position controller's output, omega_c = k_r k_v (x_ref - x_l) + k_vff omega_s, as the
    simulator does (docs/axis-file.md).
    """

    kv_per_s: float
    transmission_ratio: float
    cycle_s: float
    regulator_enabled: bool = True
    beta_t_rad_s: float = DEFAULT_BETA_T_RAD_S
    n: int = DEFAULT_N
    tv_s: float | None = None
    tf_s: float = DEFAULT_TF_S
    speed_limit_rad_s: float = DEFAULT_SPEED_LIMIT_RAD_S
    following_error_limit: float = DEFAULT_FOLLOWING_ERROR[AxisKind.LINEAR]
    discrepancy_limit: float = DEFAULT_DISCREPANCY[AxisKind.LINEAR]
    pdo_loss_tolerance: int = DEFAULT_PDO_LOSS_TOLERANCE
    heartbeat_consumer_ms: int = DEFAULT_HEARTBEAT_CONSUMER_MS
    feed: float = DEFAULT_FEED[AxisKind.LINEAR]
    accel: float = 0.0
    position_limit_min: float = -DEFAULT_POSITION_LIMIT[AxisKind.LINEAR]
    position_limit_max: float = DEFAULT_POSITION_LIMIT[AxisKind.LINEAR]
    velocity_feedforward: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            check_field(f.name, getattr(self, f.name))
        if not self.position_limit_min < self.position_limit_max:
            raise ParameterError(
                f"position_limit_min = {self.position_limit_min!r} must be below "
                f"position_limit_max = {self.position_limit_max!r} (load units)",
                field="position_limit_min",
                value=self.position_limit_min,
                abort_code=SdoAbort.TOO_HIGH,
            )
        try:
            self.regulator_config()
        except RegulatorConfigError as exc:
            code = SdoAbort.TOO_LOW if exc.field == "tv_s" else SdoAbort.TOO_HIGH
            field = {"kv": "kv_per_s"}.get(exc.field or "", exc.field or "cycle_s")
            raise ParameterError(
                str(exc), field=field, value=getattr(self, field, exc.value), abort_code=code
            ) from None
        top_speed = self.feed * self.transmission_ratio
        if top_speed > self.speed_limit_rad_s:
            raise ParameterError(
                f"feed = {self.feed!r} load units/s is {top_speed:.6g} rad/s at the motor "
                f"(k_r = {self.transmission_ratio:g}), above speed_limit_rad_s = "
                f"{self.speed_limit_rad_s:.6g} rad/s; allowed feed <= "
                f"{self.speed_limit_rad_s / self.transmission_ratio:.6g} load units/s",
                field="feed",
                value=self.feed,
                abort_code=SdoAbort.TOO_HIGH,
            )

    @classmethod
    def for_axis(cls, axis: AxisConfig, regulator: RegulatorConfig | None = None) -> BridgeParams:
        """Defaults for an axis file: k_v, k_r, the cycle and the velocity feed-forward from
        ``[control]`` (with ``axis.transmission_ratio``); regulator
        parameters from ``regulator`` (or the regulator package's defaults); limits by the
        axis kind."""
        reg = regulator or RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
        return cls(
            kv_per_s=float(reg.kv),
            transmission_ratio=float(axis.transmission_ratio),
            cycle_s=float(reg.cycle_s),
            regulator_enabled=reg.enabled,
            beta_t_rad_s=float(reg.beta_t_rad_s),
            n=int(reg.n),
            tv_s=None if reg.tv_s is None else float(reg.tv_s),
            tf_s=float(reg.tf_s),
            following_error_limit=DEFAULT_FOLLOWING_ERROR[axis.kind],
            discrepancy_limit=DEFAULT_DISCREPANCY[axis.kind],
            feed=min(
                DEFAULT_FEED[axis.kind],
                0.5 * DEFAULT_SPEED_LIMIT_RAD_S / axis.transmission_ratio,
            ),
            position_limit_min=-DEFAULT_POSITION_LIMIT[axis.kind],
            position_limit_max=DEFAULT_POSITION_LIMIT[axis.kind],
            velocity_feedforward=float(axis.control.velocity_feedforward or 0.0),
        )

    def regulator_config(self) -> RegulatorConfig:
        """The :class:`regulator.RegulatorConfig` these parameters describe (may raise)."""
        return RegulatorConfig(
            kv=self.kv_per_s,
            cycle_s=self.cycle_s,
            n=self.n,
            beta_t_rad_s=self.beta_t_rad_s,
            tv_s=self.tv_s,
            tf_s=self.tf_s,
            enabled=self.regulator_enabled,
        )

    def with_value(self, field: str, value: object, *, axis_enabled: bool = False) -> BridgeParams:
        """A copy with ``field`` set to ``value``, or :class:`ParameterError` (nothing changed).

        ``axis_enabled``: the axis is enabled, so :data:`LOCKED` fields are refused with
        0800 0022. A value that passes its own range but breaks a regulator rule together with
        the other parameters is "too high" if it grew and "too low" if it shrank.
        """
        if field not in {f.name for f in fields(self)}:
            raise ParameterError(
                f"unknown parameter {field!r}",
                field=field,
                value=value,
                abort_code=SdoAbort.NO_OBJECT,
            )
        if axis_enabled and field in LOCKED:
            raise _fail(
                field,
                value,
                SdoAbort.DEVICE_STATE,
                "may not change while the axis is enabled; disable it first (2020h = 2)",
            )
        check_field(field, value)
        try:
            return replace(self, **{field: value})
        except ParameterError as exc:
            old = getattr(self, field)
            if old is None and field == "tv_s":
                old = self.regulator_config().effective_tv_s
            grew = isinstance(value, int | float) and old is not None and value > old
            raise ParameterError(
                f"{field} = {value!r} conflicts with the other parameters: {exc}",
                field=field,
                value=value,
                abort_code=SdoAbort.TOO_HIGH if grew else SdoAbort.TOO_LOW,
            ) from None

"""Backlash-suppressing speed regulator of Fig. 6 (paper section VIII, eq. 15).

Once per position-control cycle the regulator takes the interpolator's speed ``omega_s`` and
the position controller's output ``omega_c`` (both rad/s at the motor), measures the vibration
level beta of ``u = omega_s - omega_c`` (Fig. 5, :mod:`regulator.detector`) and returns the
regulated speed set point for the drive,

    lambda  = exp(-beta / beta_T)                                  (eq. 15)
    omega_r = omega_s - lambda (omega_s - omega_c)                 (eq. 15)

Calm axis: beta ~ 0, lambda ~ 1, omega_r = omega_c (ordinary position control, exact).
Vibrating axis: lambda -> 0, omega_r -> omega_s (load sensor disregarded, stable, at the cost
of following error).
"""

from __future__ import annotations

from dataclasses import dataclass

from . import core
from .detector import DetectorConfig, VibrationDetector
from .errors import (
    RegulatorConfigError,
    require_finite_input,
    require_int_at_least,
    require_positive,
)

# Re-exported defaults (defined in core so that compiled code can use them too).
DEFAULT_N = core.DEFAULT_N
DEFAULT_BETA_T_RAD_S = core.DEFAULT_BETA_T_RAD_S
DEFAULT_TF_S = core.DEFAULT_TF_S
DEFAULT_TV_TIMES_KV = core.DEFAULT_TV_TIMES_KV
DEFAULT_ENABLED = True


def default_tv_s(kv: float) -> float:
    """Eq. 14 with eq. 13's lower band end: T_v = 5 / (kv / 4) = 20 / kv, s (kv in 1/s)."""
    return DEFAULT_TV_TIMES_KV / kv


def max_cycle_s(kv: float, n: int) -> float:
    """Section VII's sampling limit: cycle < shortest period / (2 (n + 1)), s.

    The shortest expected vibration period is 1 / kv (upper end of eq. 13, kv in 1/s, f in
    Hz). The cycle time must be strictly below the returned value.
    """
    return 1.0 / (kv * 2.0 * (n + 1))


@dataclass(frozen=True)
class RegulatorConfig:
    """All parameters of :class:`BacklashRegulator` (validated on construction).

    kv:            position gain k_v, 1/s, > 0 (sets the vibration band, eq. 13).
    cycle_s:       position-control cycle, s; 0 < cycle_s < 1 / (2 (n + 1) kv) (section VII).
    n:             detector window of n + 1 samples, integer >= 1 (paper: 4).
    beta_t_rad_s:  vibration threshold beta_T of eq. 15, rad/s at the motor, > 0.
    tv_s:          holder decay time T_v, s; ``None`` means eq. 14's 20 / kv; given values must
                   satisfy eq. 14, T_v >= 5 / (kv / 4) = 20 / kv.
    tf_s:          time constant T_f of the vibration-level low pass, s, > 0.
    enabled:       ``False``: pass omega_c through unchanged but still measure beta.
    """

    kv: float
    cycle_s: float
    n: int = DEFAULT_N
    beta_t_rad_s: float = DEFAULT_BETA_T_RAD_S
    tv_s: float | None = None
    tf_s: float = DEFAULT_TF_S
    enabled: bool = DEFAULT_ENABLED

    def __post_init__(self) -> None:
        kv = require_positive("kv", self.kv, "1/s")
        cycle_s = require_positive("cycle_s", self.cycle_s, "s")
        n = require_int_at_least("n", self.n, 1)
        require_positive("beta_t_rad_s", self.beta_t_rad_s, "rad/s")
        require_positive("tf_s", self.tf_s, "s")
        if not isinstance(self.enabled, bool):
            raise RegulatorConfigError(
                f"enabled = {self.enabled!r}: must be True or False",
                field="enabled",
                value=self.enabled,
            )
        limit = max_cycle_s(kv, n)
        if not cycle_s < limit:
            raise RegulatorConfigError(
                f"cycle_s = {self.cycle_s!r}: must be < {limit:.6g} s, the sampling rule of "
                f"section VII (cycle < shortest vibration period / (2 (n + 1)), shortest period "
                f"1 / kv = {1.0 / kv:.6g} s from eq. 13, n = {n})",
                field="cycle_s",
                value=self.cycle_s,
            )
        if self.tv_s is not None:
            tv_s = require_positive("tv_s", self.tv_s, "s")
            low = default_tv_s(kv)
            if tv_s < low * (1.0 - 1e-12):
                raise RegulatorConfigError(
                    f"tv_s = {self.tv_s!r}: must be >= {low:.6g} s, eq. 14 (T_v >= 5 / f with "
                    f"the lowest vibration frequency f = kv / 4 of eq. 13, kv = {kv:g} 1/s), "
                    f"or None for that value",
                    field="tv_s",
                    value=self.tv_s,
                )

    @property
    def effective_tv_s(self) -> float:
        """T_v actually used, s: ``tv_s`` or, if ``None``, eq. 14's 20 / kv."""
        return default_tv_s(self.kv) if self.tv_s is None else float(self.tv_s)

    def detector_config(self) -> DetectorConfig:
        """The vibration-detector part of this configuration."""
        return DetectorConfig(
            n=self.n, cycle_s=float(self.cycle_s), tv_s=self.effective_tv_s, tf_s=float(self.tf_s)
        )


class BacklashRegulator:
    """Speed regulator of Fig. 6; call :meth:`step` once per position-control cycle.

    >>> reg = BacklashRegulator(kv=25.0, cycle_s=0.001)
    >>> reg.step(10.0, 9.5)   # omega_s, omega_c in rad/s at the motor -> omega_r
    9.5
    """

    def __init__(
        self,
        kv: float,
        cycle_s: float,
        *,
        n: int = DEFAULT_N,
        beta_t_rad_s: float = DEFAULT_BETA_T_RAD_S,
        tv_s: float | None = None,
        tf_s: float = DEFAULT_TF_S,
        enabled: bool = DEFAULT_ENABLED,
    ) -> None:
        self._init(
            RegulatorConfig(
                kv=kv,
                cycle_s=cycle_s,
                n=n,
                beta_t_rad_s=beta_t_rad_s,
                tv_s=tv_s,
                tf_s=tf_s,
                enabled=enabled,
            )
        )

    @classmethod
    def from_config(cls, config: RegulatorConfig) -> BacklashRegulator:
        """A regulator running with ``config``."""
        if not isinstance(config, RegulatorConfig):
            raise RegulatorConfigError(
                f"config = {config!r}: must be a RegulatorConfig", field="config", value=config
            )
        regulator = cls.__new__(cls)
        regulator._init(config)
        return regulator

    def _init(self, config: RegulatorConfig) -> None:
        self._config = config
        self._beta_t_rad_s = float(config.beta_t_rad_s)
        self._enabled = config.enabled
        self._detector = VibrationDetector(config.detector_config())
        self._lambda = 1.0

    @property
    def config(self) -> RegulatorConfig:
        """The configuration this regulator runs with."""
        return self._config

    def step(self, omega_s: float, omega_c: float) -> float:
        """One position-control cycle: return the regulated speed omega_r (rad/s, motor).

        ``omega_s``: interpolator speed, ``omega_c``: position controller output (eq. 7), both
        rad/s at the motor. Disabled regulator: returns ``omega_c`` unchanged (lambda reported
        as 1) while beta is still measured. Raises
        :class:`~regulator.errors.RegulatorInputError` (nothing changed) on non-finite input.
        """
        omega_s = require_finite_input("omega_s", omega_s)
        omega_c = require_finite_input("omega_c", omega_c)
        beta = self._detector.step(omega_s - omega_c)
        if not self._enabled:
            self._lambda = 1.0
            return omega_c
        self._lambda = float(core.switching_factor(beta, self._beta_t_rad_s))
        return float(core.regulated_speed(omega_s, omega_c, self._lambda))

    def reset(self) -> None:
        """Back to the initial state: detector empty, beta = 0, lambda = 1."""
        self._detector.reset()
        self._lambda = 1.0

    @property
    def vibration_level(self) -> float:
        """Vibration level beta after the last step, rad/s at the motor."""
        return self._detector.vibration_level

    @property
    def switching_factor(self) -> float:
        """Switching factor lambda of eq. 15 after the last step (1 when disabled)."""
        return self._lambda

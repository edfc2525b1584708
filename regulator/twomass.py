"""The linearised elastic two-mass axis of section III and its speed loop of section V.

Motor side (J_m, the motor's own inertia with coupling and screw) and load side (J_l, reflected
to the motor) joined by a spring k_s and a damper c_s; the backlash closed. With
s = j omega, all speeds at the motor, torques in N m:

* eq. 2: ``W_m(s) = omega_m / tau_m = 1 / ((J_m + J_l) s) * P / Q``,
* eq. 3: ``W_l(s) = omega_l / tau_m = 1 / ((J_m + J_l) s) * P_a / Q``,
  with omega_a = sqrt(k_s / J_l), omega_r = sqrt(k_s (1/J_m + 1/J_l)), xi = c_s omega / (2 k_s),
  P = 1 + 2 xi_a s/omega_a + (s/omega_a)^2, P_a = 1 + 2 xi_a s/omega_a,
  Q = 1 + 2 xi_r s/omega_r + (s/omega_r)^2;
* eq. 4: R = J_l / J_m, H = omega_r / omega_a = sqrt(1 + R);
* eq. 6a: the PI speed loop on the motor speed,
  ``G_sm = omega_m / omega_c``
  ``= (k_sp T_si s + 1) P / (T_si (J_m + J_l) s^2 Q + (k_sp T_si s + 1) P)``,
  here with the PI written ``k_sp (T_si s + 1) / (T_si s)`` (the printed ``k_sp T_si s + 1``
  leaves k_sp off the integral term, which is then no torque; the simulator and the
  independent plant integrate with k_sp / T_si), the drive's current loop as a first-order
  lag ``1 / (1 + s T_i)`` (T_i = 0: the paper's ideal current loop) and an optional delay.

Pure numpy; used as the analytic reference of the frequency-response measurement
(:mod:`regulator.frequency_response`, `python -m hil freqresp`'s Bode figure, the tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import RegulatorConfigError, require_positive


@dataclass(frozen=True)
class TwoMass:
    """Section III's elastic axis, reflected to the motor (rad, N m, kg m^2).

    motor_inertia_kgm2: J_m (motor, coupling, screw); load_inertia_kgm2: J_l reflected to
    the motor (M / k_r^2 for a linear axis); antiresonance_rad_s: omega_a; damping_ratio:
    xi_a (xi_r = xi_a omega_r / omega_a follows from the same damper, section III).
    """

    motor_inertia_kgm2: float
    load_inertia_kgm2: float
    antiresonance_rad_s: float
    damping_ratio: float = 0.0

    def __post_init__(self) -> None:
        require_positive("motor_inertia_kgm2", self.motor_inertia_kgm2, "kg m^2")
        require_positive("load_inertia_kgm2", self.load_inertia_kgm2, "kg m^2")
        require_positive("antiresonance_rad_s", self.antiresonance_rad_s, "rad/s")
        xi = self.damping_ratio
        if not (isinstance(xi, int | float) and math.isfinite(xi) and 0.0 <= xi < 1.0):
            raise RegulatorConfigError(
                f"damping_ratio = {xi!r}: must be in [0, 1)", field="damping_ratio", value=xi
            )

    @property
    def total_inertia_kgm2(self) -> float:
        return self.motor_inertia_kgm2 + self.load_inertia_kgm2

    @property
    def inertia_ratio(self) -> float:
        """R of eq. 4."""
        return self.load_inertia_kgm2 / self.motor_inertia_kgm2

    @property
    def resonance_rad_s(self) -> float:
        """omega_r = omega_a sqrt(1 + R) (eq. 4)."""
        return self.antiresonance_rad_s * math.sqrt(1.0 + self.inertia_ratio)

    @property
    def resonance_damping_ratio(self) -> float:
        """xi_r = c_s omega_r / (2 k_s) = xi_a omega_r / omega_a."""
        return self.damping_ratio * self.resonance_rad_s / self.antiresonance_rad_s

    def _pq(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        wa, wr = self.antiresonance_rad_s, self.resonance_rad_s
        xa, xr = self.damping_ratio, self.resonance_damping_ratio
        p = 1.0 + 2.0 * xa * s / wa + (s / wa) ** 2
        pa = 1.0 + 2.0 * xa * s / wa
        q = 1.0 + 2.0 * xr * s / wr + (s / wr) ** 2
        return p, pa, q

    def motor_admittance(self, frequency_hz: np.ndarray) -> np.ndarray:
        """W_m(j omega) of eq. 2, rad/s per N m."""
        s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
        p, _, q = self._pq(s)
        return p / (self.total_inertia_kgm2 * s * q)

    def load_admittance(self, frequency_hz: np.ndarray) -> np.ndarray:
        """W_l(j omega) of eq. 3, rad/s (at the motor) per N m."""
        s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
        _, pa, q = self._pq(s)
        return pa / (self.total_inertia_kgm2 * s * q)

    def speed_loop(
        self,
        frequency_hz: np.ndarray,
        ksp: float,
        tsi_s: float,
        current_lag_s: float = 0.0,
        delay_s: float = 0.0,
    ) -> np.ndarray:
        """omega_m / omega_c of the PI speed loop (eq. 6a), with the current loop as a
        first-order lag (0: ideal, eq. 6a itself) and a pure delay of the set point."""
        require_positive("ksp", ksp, "N m s/rad")
        require_positive("tsi_s", tsi_s, "s")
        s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
        pi = ksp * (1.0 + 1.0 / (tsi_s * s))  # (k_sp T_si s + 1) / (T_si s)
        lag = 1.0 / (1.0 + s * current_lag_s)
        open_loop = pi * lag * self.motor_admittance(frequency_hz)
        return open_loop / (1.0 + open_loop) * np.exp(-s * delay_s)

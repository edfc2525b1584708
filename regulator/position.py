"""P position controller of the cascade (paper section V, eq. 7), separable from the regulator.

``omega_c = k_r * k_v * (x_ref - x_fb)``: the following error on the load scale (load units,
m or rad) times the position gain (1/s) times the transmission ratio (motor rad per load unit)
gives the speed set point in rad/s at the motor. Kept apart from
:class:`~regulator.speed_regulator.BacklashRegulator` so that a drive bridge can run the
position loop and the regulator in separate places.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import core
from .errors import require_finite_input, require_positive


@dataclass(frozen=True)
class PositionControllerConfig:
    """kv_per_s: position gain k_v, 1/s, > 0. transmission_ratio: k_r, motor rad per load
    unit, > 0 (e.g. 100*pi rad/m for a 20 mm screw pitch)."""

    kv_per_s: float
    transmission_ratio: float

    def __post_init__(self) -> None:
        require_positive("kv_per_s", self.kv_per_s, "1/s")
        require_positive("transmission_ratio", self.transmission_ratio, "motor rad per load unit")


class PositionController:
    """P position controller on the load scale; :meth:`step` once per position cycle.

    >>> pc = PositionController(kv_per_s=25.0, transmission_ratio=100.0)
    >>> pc.step(0.002, 0.001)   # x_ref, x_fb in load units -> omega_c in rad/s
    2.5
    """

    def __init__(self, kv_per_s: float, transmission_ratio: float) -> None:
        self._config = PositionControllerConfig(kv_per_s, transmission_ratio)
        self._kv_per_s = float(kv_per_s)
        self._ratio = float(transmission_ratio)
        self.last_error = 0.0
        """Following error x_ref - x_fb of the last step, load units."""
        self.last_output_rad_s = 0.0
        """omega_c of the last step, rad/s at the motor."""

    @classmethod
    def from_config(cls, config: PositionControllerConfig) -> PositionController:
        """A controller running with ``config``."""
        return cls(config.kv_per_s, config.transmission_ratio)

    @property
    def config(self) -> PositionControllerConfig:
        """The configuration this controller runs with."""
        return self._config

    @property
    def kv_per_s(self) -> float:
        """Position gain k_v, 1/s."""
        return self._kv_per_s

    @property
    def transmission_ratio(self) -> float:
        """Transmission ratio k_r, motor rad per load unit."""
        return self._ratio

    def step(self, x_ref: float, x_fb: float) -> float:
        """Eq. 7: return omega_c (rad/s, motor) for reference and feedback in load units.

        Raises :class:`~regulator.errors.RegulatorInputError` (nothing changed) on non-finite
        input.
        """
        x_ref = require_finite_input("x_ref", x_ref)
        x_fb = require_finite_input("x_fb", x_fb)
        omega_c = float(core.position_command(x_ref, x_fb, self._kv_per_s, self._ratio))
        self.last_error = x_ref - x_fb
        self.last_output_rad_s = omega_c
        return omega_c

    def reset(self) -> None:
        """Clear the monitoring values (the P controller itself has no state)."""
        self.last_error = 0.0
        self.last_output_rad_s = 0.0

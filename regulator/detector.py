"""Vibration detector of Fig. 5 (paper section VII) as a Python class around :mod:`.core`.

One :meth:`VibrationDetector.step` per position-control cycle with
``u = omega_s - omega_c`` (rad/s at the motor); the result is the vibration level beta
(rad/s). The algorithm itself lives in :func:`regulator.core.detector_step` so that the
simulator can compile the identical code with numba.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import core
from .errors import require_finite_input, require_int_at_least, require_positive


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of the vibration detector (Fig. 5).

    n:        window of ``n + 1`` samples (paper: n = 4), integer >= 1.
    cycle_s:  position-control cycle = detector sampling time, s, > 0.
    tv_s:     holder decay time constant T_v (eq. 14 recommends >= 5 / f), s, > 0.
    tf_s:     time constant T_f of the smoothing low pass, s, > 0.
    """

    n: int
    cycle_s: float
    tv_s: float
    tf_s: float

    def __post_init__(self) -> None:
        require_int_at_least("n", self.n, 1)
        require_positive("cycle_s", self.cycle_s, "s")
        require_positive("tv_s", self.tv_s, "s")
        require_positive("tf_s", self.tf_s, "s")


class VibrationDetector:
    """Stateful vibration detector; see :mod:`regulator.core` for the exact rules."""

    def __init__(self, config: DetectorConfig) -> None:
        self._config = config
        self._n = int(config.n)
        self._cycle_s = float(config.cycle_s)
        self._tv_s = float(config.tv_s)
        self._tf_s = float(config.tf_s)
        # a list of Python floats, not a float64 array: core.detector_step reads and writes
        # it element by element, and a numpy scalar costs about twice a float per operation
        # (same IEEE binary64 arithmetic, so the same bits; tests/regulator/test_detector.py
        # checks them against the function compiled by numba as the simulator runs it)
        self._state = [0.0] * core.detector_state_size(self._n)

    @property
    def config(self) -> DetectorConfig:
        """The configuration this detector runs with."""
        return self._config

    def step(self, u_rad_s: float) -> float:
        """Feed ``u = omega_s - omega_c`` (rad/s) of one cycle; return beta (rad/s).

        Raises :class:`~regulator.errors.RegulatorInputError` (state unchanged) if ``u_rad_s``
        is not a finite real number.
        """
        u = require_finite_input("u_rad_s", u_rad_s)
        return float(
            core.detector_step(self._state, self._n, self._cycle_s, self._tv_s, self._tf_s, u)
        )

    def reset(self) -> None:
        """Forget all inputs: empty window, nothing held, beta = 0."""
        core.detector_reset(self._state)

    @property
    def vibration_level(self) -> float:
        """Vibration level beta after the last step, rad/s (0 before the first)."""
        return float(core.detector_beta(self._state))

    @property
    def holder_output(self) -> float:
        """Output y of the decaying holder after the last step (before the low pass), rad/s."""
        return float(core.detector_holder_output(self._state))

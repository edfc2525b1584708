"""Vibration detection and backlash suppression (Mohammadiasl, sections IV-VIII).

Pure and I/O-free; stepped once per position-control cycle. Speeds in rad/s at the motor
shaft, kv in 1/s, times in s. Decisions on the paper's ambiguities: ``docs/regulator.md``.

>>> from regulator import BacklashRegulator
>>> reg = BacklashRegulator(kv=25.0, cycle_s=0.001)
>>> omega_r = reg.step(10.0, 9.9)        # omega_s, omega_c -> omega_r
>>> reg.vibration_level, reg.switching_factor
(0.0, 1.0)

Modules: :mod:`.core` (numba-compilable algorithm), :mod:`.detector` (Fig. 5),
:mod:`.speed_regulator` (Fig. 6, eq. 15), :mod:`.position` (eq. 7), :mod:`.analysis` and
:mod:`.describing` (eqs. 1, 5, 12-14, FFT condition monitoring, limit-cycle prediction).
"""

from .analysis import (
    BandVerdict,
    condition_monitoring,
    dominant_frequency_hz,
    following_error,
    min_decay_time_s,
    restitution_frequency_hz,
    vibration_band_hz,
)
from .describing import (
    LimitCycle,
    deadzone_amplitude_for_gain,
    deadzone_df,
    deadzone_first_harmonic,
    predict_limit_cycle,
)
from .detector import DetectorConfig, VibrationDetector
from .errors import AnalysisError, RegulatorConfigError, RegulatorError, RegulatorInputError
from .position import PositionController, PositionControllerConfig
from .speed_regulator import (
    DEFAULT_BETA_T_RAD_S,
    DEFAULT_ENABLED,
    DEFAULT_N,
    DEFAULT_TF_S,
    DEFAULT_TV_TIMES_KV,
    BacklashRegulator,
    RegulatorConfig,
    default_tv_s,
    max_cycle_s,
)

__all__ = [
    "DEFAULT_BETA_T_RAD_S",
    "DEFAULT_ENABLED",
    "DEFAULT_N",
    "DEFAULT_TF_S",
    "DEFAULT_TV_TIMES_KV",
    "AnalysisError",
    "BacklashRegulator",
    "BandVerdict",
    "DetectorConfig",
    "LimitCycle",
    "PositionController",
    "PositionControllerConfig",
    "RegulatorConfig",
    "RegulatorConfigError",
    "RegulatorError",
    "RegulatorInputError",
    "VibrationDetector",
    "condition_monitoring",
    "deadzone_amplitude_for_gain",
    "deadzone_df",
    "deadzone_first_harmonic",
    "default_tv_s",
    "dominant_frequency_hz",
    "following_error",
    "max_cycle_s",
    "min_decay_time_s",
    "predict_limit_cycle",
    "restitution_frequency_hz",
    "vibration_band_hz",
]

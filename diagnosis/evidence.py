"""A recording's scales (peak torque, top speed, following error, the measured load speed
and position): the bounds of :mod:`.parameters` and the "absent" values of :mod:`.effects`
scale with them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

from .replay import ReplayInput


# ----------------------------------------------------------------------------------------
# what the recording says about scales
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DataScales:
    """Scales of one recording: torques N·m, speeds/positions in load units."""

    torque_peak: float  # 99.5th percentile of |motor_torque|
    torque_max: float  # max |motor_torque|
    speed_max: float  # max |reference speed|
    span: float  # travel of the reference
    following_error: float  # std of the feedback following error
    sample_time_s: float
    speed: np.ndarray  # actual load speed at the recording samples (smoothed derivative)
    accel: np.ndarray  # actual load acceleration
    position: np.ndarray  # feedback position (load units)


def _derivatives(x: np.ndarray, dt: float, window_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    win = max(5, 2 * round(window_s / dt / 2) + 1)
    win = min(win, len(x) - (1 - len(x) % 2))
    v = sps.savgol_filter(x, win, 3, deriv=1, delta=dt)
    a = sps.savgol_filter(x, win, 3, deriv=2, delta=dt)
    return v, a


def data_scales(inp: ReplayInput) -> DataScales:
    rec = inp.recorded
    tau = np.abs(rec["motor_torque"])
    ref = rec["position_reference"]
    dt = float(np.median(np.diff(inp.time_s)))
    if "load_position" in rec and inp.feedback.value == "load":
        pos = rec["load_position"]
    else:
        pos = rec["motor_position"] / inp.transmission_ratio
    v, a = _derivatives(pos, dt)
    v_ref = np.gradient(ref, inp.time_s)
    return DataScales(
        torque_peak=max(float(np.percentile(tau, 99.5)), 1e-12),
        torque_max=max(float(tau.max()), 1e-12),
        speed_max=max(float(np.max(np.abs(v_ref))), 1e-12),
        span=max(float(np.ptp(ref)), 1e-12),
        following_error=max(float(np.std(ref - pos)), 1e-12),
        sample_time_s=dt,
        speed=v,
        accel=a,
        position=pos,
    )

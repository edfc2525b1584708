"""What one recording says before any model is fitted: its scales (peak torque, top speed,
following error), the measured load speed and acceleration, rigid-body inverse-dynamics
estimates, and the features of a residual that start an effect's fit (direction offset,
position-periodic peaks). Used by :mod:`.parameters` (bounds) and :mod:`.effects` (starts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

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


def inverse_dynamics(inp: ReplayInput, axis: AxisConfig, scales: DataScales) -> dict[str, float]:
    """Least-squares starting values from the rigid-body torque balance on moving samples:

        τ = J·k_r·a + c·sign(v) + b·v + τ_0            (symmetric)
        τ = J·k_r·a + c₊·[v>0] − c₋·[v<0] + b₊·v⁺ + b₋·v⁻   (direction-dependent)

    with v, a the measured load speed/acceleration (Savitzky-Golay). Returns estimates keyed
    by axis keys (load_mass from J − J_motor_side); only a start for the simulation fit."""
    v, a = scales.speed, scales.accel
    tau = inp.recorded["motor_torque"]
    moving = np.abs(v) > 0.02 * scales.speed_max
    if moving.sum() < 20:
        return {}
    kr = axis.transmission_ratio
    s = np.sign(v[moving])
    vm, am, tm = v[moving], a[moving], tau[moving]
    sym = np.column_stack([kr * am, s, vm, np.ones_like(vm)])
    coef, *_ = np.linalg.lstsq(sym, tm, rcond=None)
    pos = (s > 0).astype(float)
    neg = (s < 0).astype(float)
    asym = np.column_stack([kr * am, pos, -neg, vm * pos, vm * neg])
    coef2, *_ = np.linalg.lstsq(asym, tm, rcond=None)
    j_load = coef[0] - axis.motor_side_inertia
    out = {
        "friction.coulomb": float(coef[1]),
        "friction.viscous": float(coef[2]),
        "disturbance.constant_torque": float(coef[3]),
        "friction.coulomb_positive": float(coef2[1]),
        "friction.coulomb_negative": float(coef2[2]),
        "friction.viscous_positive": float(coef2[3]),
        "friction.viscous_negative": float(coef2[4]),
    }
    if j_load > 0.0:
        out["mechanics.load_mass"] = float(j_load * kr**2)
    return out


def direction_offset(r: np.ndarray, v: np.ndarray, vmax: float) -> float | None:
    pos, neg = v > 0.05 * vmax, v < -0.05 * vmax
    if pos.sum() < 10 or neg.sum() < 10:
        return None
    return float(np.median(r[pos]) - np.median(r[neg]))


def periodic_peaks(
    residual_torque: np.ndarray, scales: DataScales, n_peaks: int = 2
) -> list[tuple[float, float, float]]:
    """Top peaks (period, A·cos φ, A·sin φ) of the torque residual against position: the
    moving samples are averaged in position bins (a quarter of the shortest period looked
    for), the binned residual's spectrum over position (FFT, zero-padded four times) gives
    the candidate periods, and a least-squares sine fit on the samples their amplitude and
    phase. The starts of the periodic disturbance."""
    v, x = scales.speed, scales.position
    moving = np.abs(v) > 0.05 * scales.speed_max
    if moving.sum() < 50:
        return []
    xm, rm = x[moving], residual_torque[moving] - np.mean(residual_torque[moving])
    step = float(np.median(np.abs(v[moving]))) * scales.sample_time_s
    p_lo = max(8.0 * step, scales.span / 2000.0)
    p_hi = scales.span / 3.0
    if not p_hi > p_lo:
        return []
    width = p_lo / 4.0
    edges_lo = float(xm.min())
    idx = np.floor((xm - edges_lo) / width).astype(int)
    n_bins = int(idx.max()) + 1
    sums = np.bincount(idx, rm, n_bins)
    counts = np.bincount(idx, None, n_bins)
    binned = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    size = 4 * (1 << (n_bins - 1).bit_length())
    power = np.abs(np.fft.rfft(binned, size)) ** 2
    freqs = np.fft.rfftfreq(size, width)  # cycles per load unit
    with np.errstate(divide="ignore"):
        periods = np.where(freqs > 0, 1.0 / freqs, np.inf)
    band = (periods >= p_lo) & (periods <= p_hi)
    peaks = sps.argrelmax(np.where(band, power, 0.0))[0]
    peaks = peaks[band[peaks]]
    peaks = peaks[np.argsort(power[peaks])[::-1]][:n_peaks]
    out = []
    for i in peaks:
        per = float(periods[i])
        phase = 2.0 * np.pi * xm / per
        basis = np.column_stack([np.sin(phase), np.cos(phase)])
        (a, b), *_ = np.linalg.lstsq(basis, rm, rcond=None)
        out.append((per, float(a), float(b)))
    return out


@dataclass(frozen=True)
class Evidence:
    """What the current model leaves in the residual: the recording and its simulation."""

    inp: ReplayInput
    simulated: Trace
    scales: DataScales

"""Frequency response of a drive's speed loop over the bus (paper Fig. 2, section V).

The bridge excites the speed set point 60FFh with a periodic multisine
(:class:`regulator.frequency_response.Multisine`) around an optional slow feed, records the
set point it sent (omega_r), the speed actual value 606Ch and the torque 6077h at the SYNC
rate, and estimates

* the speed loop ``omega_m / omega_r`` (Fig. 2; it includes the one cycle the set point waits
  for the next SYNC) with its standard deviation from the spread of the periods,
* the motor admittance ``omega_m / tau_m`` (eq. 2) where the layout carries the torque,
* the antiresonance omega_a (the notch, :func:`regulator.frequency_response.antiresonance`)
  and the speed loop's -3 dB bandwidth.

The excitation is motion like any other: a :class:`~bridge.interpolator.Table` whose speed is
``offset + excitation / k_r`` and whose position is its integral, played with full velocity
feed-forward (200Bh = 1) and the regulator off, so the set point the drive gets is the
excitation plus the position loop holding the axis on that path (eq. 7) -- the axis does not
drift. Its path must lie inside the travel limits 2014h (refused before anything moves); the
cycle's supervision stops it on any stop reason, and the test's torque limit on top
(:attr:`StopReason.TEST_LIMIT`). Then the axis is disabled and the parameters restored;
nothing is stored.

Standstill (offset 0) with backlash: the motor rattles in the open gap and sees only its own
inertia -- no notch ("not resolved"). A slow feed without speed reversals and a load that
keeps the gap closed (weight, preload, a constant load torque) give the linear response the
paper's Fig. 2 shows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from regulator.frequency_response import (
    Antiresonance,
    Bandwidth,
    Frf,
    Multisine,
    antiresonance,
    bandwidth,
    estimate,
)

from ..cycle import BridgeState
from ..errors import BridgeConfigError
from ..interpolator import Table
from ..layout import Signal
from ..node import Bridge
from .session import CommissioningStopped, Recording, disable, enable, play, stopped_error


@dataclass(frozen=True)
class ExcitationPlan:
    """The test: the multisine, how many periods of each realization (the first is dropped as
    transient), how many realizations (1: the multisine as given; more: random phases, seeds
    0, 1, ..., whose spread enters the uncertainty), the feed the axis moves at meanwhile
    (load units/s; 0: standstill), the ramp in and out of that feed (s), the torque limit
    (N m, or per mille without 6076h), the notch band (Hz), the axis file's damping ratio of
    the transmission (None: not stated; :func:`regulator.admittance_fit.fit_two_mass`)."""

    multisine: Multisine
    periods: int = 6
    realizations: int = 1
    offset_speed: float = 0.0
    ramp_s: float = 0.5
    torque_limit: float = math.inf
    notch_band_hz: tuple[float, float] | None = None
    sheet_damping: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.periods, bool) or not isinstance(self.periods, int) or self.periods < 3:
            raise BridgeConfigError(
                f"periods = {self.periods!r}: at least 3 (one transient, two to average)"
            )
        if (
            isinstance(self.realizations, bool)
            or not isinstance(self.realizations, int)
            or not 1 <= self.realizations <= 64
        ):
            raise BridgeConfigError(f"realizations = {self.realizations!r}: 1..64")
        if not math.isfinite(self.offset_speed):
            raise BridgeConfigError(f"offset_speed = {self.offset_speed!r}: a finite speed")
        if not (math.isfinite(self.ramp_s) and self.ramp_s >= 0.0):
            raise BridgeConfigError(f"ramp_s = {self.ramp_s!r}: >= 0 s")
        if not self.torque_limit > 0.0:
            raise BridgeConfigError(f"torque_limit = {self.torque_limit!r}: > 0")

    @property
    def cycle_s(self) -> float:
        return self.multisine.cycle_s

    def ramp_samples(self) -> int:
        return math.ceil(self.ramp_s / self.cycle_s) if self.offset_speed else 0

    def table(self, start: float, kr: float) -> Table:
        """Ramp in, the periods, ramp out: speed and its integral from ``start``."""
        n_ramp = self.ramp_samples()
        ramp = np.linspace(0.0, 1.0, n_ramp + 1)[1:] if n_ramp else np.empty(0)
        offset = self.offset_speed * np.concatenate(
            [ramp, np.ones(self.excited_samples), ramp[::-1], [0.0]]
        )
        excitation = np.concatenate([np.zeros(n_ramp), self.signal(), np.zeros(n_ramp + 1)])
        speed = offset + excitation / kr
        position = start + np.concatenate([[0.0], np.cumsum(speed[:-1]) * self.cycle_s])
        return Table(position, speed)

    @property
    def excited_samples(self) -> int:
        return self.realizations * self.periods * self.multisine.period_samples

    def signal(self) -> np.ndarray:
        """The excitation (set-point units): the realizations one after the other."""
        if self.realizations == 1:
            return self.multisine.signal(self.periods)
        return np.concatenate(
            [self.multisine.realization(m).signal(self.periods) for m in range(self.realizations)]
        )

    def excited(self) -> slice:
        """The samples of the recording that hold the excitation."""
        n = self.ramp_samples()
        return slice(n, n + self.excited_samples)

    def estimate(self, u: np.ndarray, y: np.ndarray) -> Frf:
        """The frequency response of the excited samples of ``u`` -> ``y``."""
        sl = self.excited()
        return estimate(self.multisine, u[sl], y[sl], 1, self.realizations)


#: freqresp.json's keys of the two-mass fit (:class:`regulator.admittance_fit.TwoMassFit`
#: attribute each; None without a fit).
FIT_FIELDS = {
    "damping_ratio": "damping_ratio",
    "resonance_rad_s": "resonance_rad_s",
    "two_mass_inertia_kgm2": "inertia_kgm2",
    "two_mass_reduced_chi2": "reduced_chi2",
    "two_mass_vs_rigid_p": "p_rigid",
}


@dataclass(frozen=True)
class FrequencyResponse:
    """What the test measured."""

    loop: Frf  # omega_m / omega_r
    admittance: Frf | None  # omega_m / tau_m (None: no torque in the layout)
    antiresonance: Antiresonance
    bandwidth: Bandwidth
    recording: Recording
    torque_unit: str
    plan: ExcitationPlan

    def summary(self) -> dict[str, object]:
        a, b = self.antiresonance, self.bandwidth
        return {
            "antiresonance_rad_s": a.rad_s,
            "antiresonance_hz": a.hz,
            "antiresonance_uncertainty_rad_s": a.uncertainty_rad_s,
            "antiresonance_resolved": a.resolved,
            "antiresonance_method": a.method,
            "antiresonance_reason": a.reason,
            "notch_depth_db": a.depth_db,
            "loop_notch_rad_s": a.loop_notch_rad_s,
            **{key: getattr(a.fit, name, None) for key, name in FIT_FIELDS.items()},
            "admittance_notch_rad_s": None
            if math.isnan(a.admittance_notch_rad_s)
            else a.admittance_notch_rad_s,
            "jackknife_std_rad_s": a.jackknife_std_rad_s,
            "bandwidth_hz": None if math.isnan(b.frequency_hz) else b.frequency_hz,
            "bandwidth_range_hz": [b.low_hz, b.high_hz],
            "periods_averaged": self.loop.periods,
            "lines": int(self.loop.frequency_hz.size),
            "resolution_hz": self.plan.multisine.resolution_hz,
            "band_hz": [self.plan.multisine.f_min_hz, self.plan.multisine.f_max_hz],
            "amplitude_rad_s": self.plan.multisine.amplitude,
            "offset_speed": self.plan.offset_speed,
            "torque_peak": float(np.max(np.abs(self.recording.torque))),
            "torque_unit": self.torque_unit,
            "travel": float(np.ptp(self.recording.load_position)),
        }

    def describe(self) -> str:
        a, b = self.antiresonance, self.bandwidth
        shape = (
            f"damping {a.fit.damping_ratio:.3f}, resonance {a.fit.resonance_rad_s:.1f} rad/s"
            if a.fit is not None
            else f"notch {a.depth_db:.1f} dB"
        )
        notch = (
            f"antiresonance {a.rad_s:.1f} rad/s ({a.hz:.2f} Hz) +- {a.uncertainty_rad_s:.1f} "
            f"rad/s (about 95 %, {a.method}; {shape})"
            if a.resolved
            else f"no antiresonance resolved: {a.reason}"
        )
        bw = (
            f"speed-loop bandwidth (-3 dB) {b.frequency_hz:.1f} Hz "
            f"[{b.low_hz:.1f}, {b.high_hz:.1f}]"
            if not math.isnan(b.frequency_hz)
            else "speed loop above -3 dB over the whole band"
        )
        return f"{notch}; {bw}"


def measure(bridge: Bridge, plan: ExcitationPlan) -> FrequencyResponse:
    """Run the test on a started bridge (module docstring); CommissioningStopped when the
    axis stopped, ParameterError when the path leaves 2014h (nothing moved then)."""
    c = bridge.controller
    kept = c.params
    if c.params.cycle_s != plan.cycle_s:
        raise BridgeConfigError(
            f"the multisine is sampled every {plan.cycle_s:g} s, the bridge cycles every "
            f"{c.params.cycle_s:g} s"
        )
    test_params = kept.with_value("regulator_enabled", False).with_value(
        "velocity_feedforward", 1.0
    )
    what = "frequency response"
    try:
        enable(bridge, test_params, what)
        table = plan.table(c.position_reference, kept.transmission_ratio)
        c.check_path(table)  # refused before anything moves
        recording = play(bridge, table, plan.torque_limit, what)
        if c.state is not BridgeState.RUNNING:
            raise stopped_error(c, what)
    finally:
        disable(bridge)
        if c.state is not BridgeState.STOPPED:
            c.set_params(kept)
    loop = plan.estimate(recording.omega_r, recording.motor_speed)
    has_torque = any(Signal.TORQUE in f.signals for f in bridge.layout.frames)
    admittance = plan.estimate(recording.torque, recording.motor_speed) if has_torque else None
    if np.max(np.abs(loop.response)) < 0.05:
        raise CommissioningStopped(
            f"{what}: the drive did not follow the excitation (|omega_m / omega_r| below "
            "0.05 at every line): check the mode, 60FFh scaling and the drive's enable",
            reason=c.stop_reason,
        )
    band = plan.notch_band_hz or (
        max(plan.multisine.f_min_hz, 4.0 * plan.multisine.resolution_hz),
        plan.multisine.f_max_hz,
    )
    notch = antiresonance(loop, band[0], band[1], admittance, plan.sheet_damping)
    return FrequencyResponse(
        loop,
        admittance,
        notch,
        bandwidth(loop),
        recording,
        c.scaling.torque_unit,
        plan,
    )

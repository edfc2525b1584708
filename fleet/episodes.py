"""Vibration episodes: the paper's detector (Fig. 5) run offline over a chunk stream.

Detector input, per sample (rad/s at the motor):

* with the interpolator's reference in the recording (trace column ``position_reference``):
  ``u = ω_s − ω_c`` exactly as on line (section VII): ``ω_s = k_r·dx_ref/dt`` and the position
  controller's output ``ω_c = k_r·k_v·(x_ref − x_fb)`` of eq. 7, ``x_fb`` the load position
  (position loop on the load scale) or ``θ_m / k_r`` (on the motor encoder);
* without it (a candump log carries only the set point ``w`` the bridge sent): eq. 7 read
  backwards gives the reference the position controller saw, ``x_ref = x_fb + w / (k_r k_v)``,
  exact while the regulator passes ω_c through (λ = 1, i.e. whenever the axis is calm), and
  ``u = k_r·dx_ref/dt − w`` as above.

β comes from :func:`regulator.core.detector_step`, compiled here as in the simulator's kernel,
with the detector parameters of :class:`regulator.RegulatorConfig` (n = 4, T_v of eq. 14, T_f,
β_T). An episode starts where the switching factor λ = exp(−β/β_T) of eq. 15 falls below 1/2
(the regulator would have faded the load sensor at least half out) and ends where β falls
below half that level again; episodes shorter than one period of the lowest band frequency,
or than :data:`MIN_PERIODS` periods of their own dominant frequency, are dropped. Each
episode's dominant frequency is the spectral peak of ``u`` within it
(:func:`regulator.analysis.condition_monitoring`, searched in k_v/8 .. min(4 k_v, Nyquist)
so that a vibration outside eq. 13's band is seen as such), with its eq. 13 verdict.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numba
import numpy as np

from regulator import RegulatorConfig
from regulator import core as _core
from regulator.analysis import condition_monitoring, vibration_band_hz
from regulator.errors import RegulatorError

from .chunks import Chunk, backward_difference
from .errors import RecordingError

_step = numba.njit(cache=True, nogil=True, inline="always")(_core.detector_step)

#: An episode must last this many periods of its own dominant frequency (a limit cycle is
#: sustained; one or two swings after a shock are a transient).
MIN_PERIODS = 3.0
#: Samples of ``u`` kept per episode for its spectrum (the most recent ones).
MAX_EPISODE_SAMPLES = 1 << 15


@numba.njit(cache=True, nogil=True)
def _detect(state, n, cycle_s, tv_s, tf_s, u, beta_out):  # pragma: no cover - compiled
    for i in range(u.shape[0]):
        beta_out[i] = _step(state, n, cycle_s, tv_s, tf_s, u[i])


class Verdict(enum.Enum):
    """Eq. 13 verdict of an episode or a recording."""

    IN_BAND = "in_band"  # backlash-type limit cycle: k_v/4 <= f <= k_v
    OUTSIDE_BAND = "outside_band"  # vibrates, but not at a backlash limit cycle's frequency
    NONE = "none"  # no vibration episode


@dataclass(frozen=True)
class Episode:
    """One vibration episode.

    start_s, end_s: recording time, s. frequency_hz: dominant frequency. band_hz: eq. 13 band
    for the axis' k_v. amplitude: following-error amplitude of the oscillation, load units
    (spectral amplitude of u / (k_r k_v), eq. 7). peak_beta_rad_s: largest β. speed: mean load
    speed, load units/s (sign = direction). position_min/max: load position range.
    """

    start_s: float
    end_s: float
    frequency_hz: float
    band_low_hz: float
    band_high_hz: float
    verdict: Verdict
    amplitude: float
    peak_beta_rad_s: float
    speed: float
    position_min: float
    position_max: float

    @property
    def direction(self) -> str:
        return "+" if self.speed > 0 else "-" if self.speed < 0 else "0"


@dataclass(frozen=True)
class DetectorSetup:
    """What the offline detector needs of the axis: k_v (1/s), k_r, the sampling interval."""

    kv_per_s: float
    transmission_ratio: float
    feedback_on_load: bool
    dt_s: float

    def regulator(self) -> RegulatorConfig:
        """The detector's parameters; raises RegulatorConfigError if dt breaks section VII."""
        return RegulatorConfig(kv=self.kv_per_s, cycle_s=self.dt_s)


class _Open:
    """The episode that is running: bounded buffers of u and its operating condition."""

    def __init__(self, t0: float) -> None:
        self.start_s = t0
        self.end_s = t0
        self.u = np.empty(MAX_EPISODE_SAMPLES)
        self.count = 0
        self.peak_beta = 0.0
        self.speed_sum = 0.0
        self.samples = 0
        self.pos_min = math.inf
        self.pos_max = -math.inf

    def add(
        self, t: np.ndarray, u: np.ndarray, beta: np.ndarray, speed: np.ndarray, pos: np.ndarray
    ) -> None:
        if t.size == 0:
            return
        self.end_s = float(t[-1])
        k = u.size
        if k >= MAX_EPISODE_SAMPLES:
            self.u[:] = u[-MAX_EPISODE_SAMPLES:]
            self.count = MAX_EPISODE_SAMPLES
        else:
            keep = min(self.count, MAX_EPISODE_SAMPLES - k)
            if keep < self.count:
                self.u[:keep] = self.u[self.count - keep : self.count]
            self.u[keep : keep + k] = u
            self.count = keep + k
        self.peak_beta = max(self.peak_beta, float(beta.max()))
        self.speed_sum += float(speed.sum())
        self.samples += k
        self.pos_min = min(self.pos_min, float(pos.min()))
        self.pos_max = max(self.pos_max, float(pos.max()))


class EpisodeFinder:
    """Streams chunks through the detector and collects :class:`Episode` s (bounded memory)."""

    def __init__(self, setup: DetectorSetup) -> None:
        cfg = setup.regulator()
        self.setup = setup
        self._n = int(cfg.n)
        self._tv = float(cfg.effective_tv_s)
        self._tf = float(cfg.tf_s)
        self._beta_t = float(cfg.beta_t_rad_s)
        self.beta_on = self._beta_t * math.log(2.0)  # lambda = exp(-beta / beta_T) < 1/2
        self.beta_off = 0.5 * self.beta_on
        self._state = np.zeros(_core.detector_state_size(self._n))
        self._open: _Open | None = None
        self._min_len_s = 4.0 / setup.kv_per_s  # one period of the band's lowest frequency
        self._last_ref = math.nan
        self.episodes: list[Episode] = []
        self.max_beta = 0.0

    # -- detector input ------------------------------------------------------------------------
    def _u(self, c: Chunk) -> tuple[np.ndarray, np.ndarray]:
        """(u, load speed) of a chunk, rad/s at the motor and load units/s."""
        s = self.setup
        kr = s.transmission_ratio
        if s.feedback_on_load and c.load_position is not None:
            fb = c.load_position
        else:
            fb = c.motor_position_rad / kr
        if c.position_reference is not None and np.all(np.isfinite(c.position_reference)):
            x = c.position_reference
            speed = backward_difference(x, self._last_ref, s.dt_s)
            self._last_ref = float(x[-1])
            omega_c = kr * s.kv_per_s * (x - fb)  # eq. 7
            return kr * speed - omega_c, speed
        w = c.speed_setpoint_rad_s
        if w is None or not np.all(np.isfinite(w)):
            raise RecordingError(
                "needs a 'position_reference' or 'speed_setpoint' column to run the vibration "
                "detector (Fig. 5)"
            )
        # eq. 7 read backwards: the reference the position controller saw, exact while the
        # regulator passes omega_c through (lambda = 1)
        x = fb + w / (kr * s.kv_per_s)
        speed = backward_difference(x, self._last_ref, s.dt_s)
        self._last_ref = float(x[-1])
        return kr * speed - w, speed

    # -- streaming -------------------------------------------------------------------------------
    def feed(self, c: Chunk) -> None:
        """Run one chunk through the detector and update the episodes."""
        if len(c) == 0:
            return
        u, speed = self._u(c)
        u = np.ascontiguousarray(u, dtype=np.float64)
        beta = np.empty_like(u)
        _detect(self._state, self._n, self.setup.dt_s, self._tv, self._tf, u, beta)
        self.max_beta = max(self.max_beta, float(beta.max()))
        pos = (
            c.load_position
            if c.load_position is not None
            else (c.motor_position_rad / self.setup.transmission_ratio)
        )
        t = c.time_s
        i = 0
        n = u.size
        while i < n:
            if self._open is None:
                above = np.nonzero(beta[i:] > self.beta_on)[0]
                if above.size == 0:
                    return
                i += int(above[0])
                self._open = _Open(float(t[i]))
            below = np.nonzero(beta[i:] < self.beta_off)[0]
            j = n if below.size == 0 else i + int(below[0])
            self._open.add(t[i:j], u[i:j], beta[i:j], speed[i:j], pos[i:j])
            if j < n:
                self._close()
            i = j

    def finish(self) -> list[Episode]:
        """Close a running episode at the end of the recording; the episodes found."""
        if self._open is not None:
            self._close()
        return self.episodes

    def _close(self) -> None:
        ep, self._open = self._open, None
        if ep is None or ep.end_s - ep.start_s < self._min_len_s or ep.count < 16:
            return
        s = self.setup
        nyquist = 0.5 / s.dt_s
        f_hi = min(4.0 * s.kv_per_s, nyquist)
        try:
            verdict = condition_monitoring(
                ep.u[: ep.count], s.dt_s, s.kv_per_s, f_min_hz=s.kv_per_s / 8.0, f_max_hz=f_hi
            )
        except RegulatorError:
            return
        if math.isnan(verdict.frequency_hz):
            return
        if (ep.end_s - ep.start_s) * verdict.frequency_hz < MIN_PERIODS:
            return  # one swing after a shock is a transient, not a sustained vibration
        band = vibration_band_hz(s.kv_per_s)
        self.episodes.append(
            Episode(
                start_s=ep.start_s,
                end_s=ep.end_s,
                frequency_hz=verdict.frequency_hz,
                band_low_hz=band[0],
                band_high_hz=band[1],
                verdict=Verdict.IN_BAND if verdict.in_band else Verdict.OUTSIDE_BAND,
                amplitude=verdict.amplitude / (s.transmission_ratio * s.kv_per_s),
                peak_beta_rad_s=ep.peak_beta,
                speed=ep.speed_sum / max(ep.samples, 1),
                position_min=ep.pos_min,
                position_max=ep.pos_max,
            )
        )

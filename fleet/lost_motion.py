"""Lost motion at reversals, from the two measuring systems (section II.B, Fig. 1).

While the axis moves steadily in one direction the motor side pushes the load through one
flank of the backlash, so the difference of the two measuring systems

    d = θ_m / k_r − x_l        (load units)

sits at one level; after a reversal the other flank carries the load and ``d`` sits at a level
lower by the lost motion: the backlash δ plus the change of elastic wind-up (2 τ_f / k_s, small
on a stiff axis). This is the reversal error of ISO 230-2 measured by the machine itself.

Per reversal the level before is the median of ``d`` over the last ``window`` *steady* samples
of the run that ends, the level after the median over the first ``window`` steady samples of
the next run; steady means moving in one direction, at least ``settle_s`` after the run began
(the position loop has settled, 5 / k_v) and not accelerating (reference acceleration below
``accel_limit``), so that inertia has not carried the load across the gap. Each reversal with
enough steady samples on both sides gives one value; the estimate is their median, its
uncertainty the standard error of a median (1.2533 σ / √n) or, for a single reversal, the
spread within its windows. Only ``2 × window`` samples are kept per run: memory is bounded
whatever the recording's length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .chunks import Chunk, backward_difference


@dataclass(frozen=True)
class LostMotion:
    """Result, load units: the lost motion, its standard uncertainty, the reversals it rests
    on, and the backlash estimate: the lost motion less the elastic wind-up
    ``|Δτ_m| k_r / k`` that the measured change of motor torque across the reversals causes in
    the axis' stiffness ``k`` (nan when the axis file is rigid or the torque is not in N·m).
    """

    value: float
    uncertainty: float
    reversals: int
    backlash: float


class _Run:
    def __init__(self, direction: int, t0: float, window: int) -> None:
        self.direction = direction
        self.t0 = t0
        self.first = np.empty(window)
        self.n_first = 0
        self.last = np.empty(window)  # ring of the last steady samples
        self.first_torque = np.empty(window)
        self.last_torque = np.empty(window)
        self.n_last = 0
        self.pos = 0

    def add(self, d: np.ndarray, torque: np.ndarray) -> None:
        w = self.first.size
        if self.n_first < w:
            k = min(w - self.n_first, d.size)
            self.first[self.n_first : self.n_first + k] = d[:k]
            self.first_torque[self.n_first : self.n_first + k] = torque[:k]
            self.n_first += k
        tail, tail_torque = d[-w:], torque[-w:]
        for value, tq in zip(tail, tail_torque, strict=True):  # at most `window` per call
            self.last[self.pos] = value
            self.last_torque[self.pos] = tq
            self.pos = (self.pos + 1) % w
        self.n_last = min(self.n_last + tail.size, w)

    def last_values(self) -> tuple[np.ndarray, np.ndarray]:
        n = self.n_last
        if n < self.last.size:
            return self.last[:n], self.last_torque[:n]
        return self.last, self.last_torque


class LostMotionEstimator:
    """Streams chunks; :meth:`result` gives the lost motion at the reversals seen.

    transmission_ratio: k_r, motor rad per load unit. kv_per_s: position gain (settling time
    5/k_v). speed_threshold: load units/s below which the axis counts as not moving in either
    direction. accel_limit: load units/s² above which a sample is not steady. window: steady
    samples per side of a reversal. dt_s: sampling interval.
    """

    def __init__(
        self,
        transmission_ratio: float,
        kv_per_s: float,
        dt_s: float,
        speed_threshold: float,
        accel_limit: float,
        window: int = 200,
        stiffness: float | None = None,
    ) -> None:
        self.kr = transmission_ratio
        self.stiffness = stiffness
        self.settle_s = 5.0 / kv_per_s
        self.dt_s = dt_s
        self.v_thr = speed_threshold
        self.a_thr = accel_limit
        self.window = window
        self.min_samples = max(10, window // 4)
        self._run: _Run | None = None
        self._prev_run: _Run | None = None
        self._values: list[float] = []
        self._spreads: list[float] = []
        self._torque_steps: list[float] = []
        self._last_ref = math.nan
        self._last_speed = math.nan

    def _speed_accel(self, c: Chunk) -> tuple[np.ndarray, np.ndarray]:
        """Load speed (units/s) and acceleration (units/s²) of the reference, else the motor."""
        if c.position_reference is not None and np.all(np.isfinite(c.position_reference)):
            x = c.position_reference
        else:
            x = c.motor_position_rad / self.kr
        v = backward_difference(x, self._last_ref, self.dt_s)
        self._last_ref = float(x[-1])
        pv = self._last_speed if math.isfinite(self._last_speed) else v[0]
        a = np.diff(np.concatenate(([pv], v))) / self.dt_s
        self._last_speed = float(v[-1])
        if c.position_reference is None:
            # a differentiated encoder is noisy: judge steadiness on a 10-sample mean
            k = min(10, a.size)
            a = np.convolve(a, np.ones(k) / k, mode="same")
        return v, a

    def feed(self, c: Chunk) -> None:
        if c.load_position is None or len(c) < 2:
            return
        d = c.motor_position_rad / self.kr - c.load_position
        v, a = self._speed_accel(c)
        direction = np.where(v > self.v_thr, 1, np.where(v < -self.v_thr, -1, 0))
        t = c.time_s
        # split the chunk where the direction changes between +1 and -1 (0 keeps the run)
        i, n = 0, d.size
        while i < n:
            cur = self._run.direction if self._run else 0
            if cur == 0:
                moving = np.nonzero(direction[i:] != 0)[0]
                if moving.size == 0:
                    return
                i += int(moving[0])
                self._start(int(direction[i]), float(t[i]))
                continue
            flip = np.nonzero(direction[i:] == -cur)[0]
            j = n if flip.size == 0 else i + int(flip[0])
            seg = slice(i, j)
            steady = (
                (direction[seg] == cur)
                & (t[seg] - self._run.t0 >= self.settle_s)
                & (np.abs(a[seg]) <= self.a_thr)
            )
            self._run.add(d[seg][steady], c.motor_torque[seg][steady])
            if j < n:
                self._start(-cur, float(t[j]))
            i = j

    def _start(self, direction: int, t0: float) -> None:
        if self._run is not None and self._prev_run is not None:
            self._pair(self._prev_run, self._run)  # the run that ends now is complete
        self._prev_run = self._run
        self._run = _Run(direction, t0, self.window)

    def _pair(self, before: _Run, after: _Run) -> None:
        """One reversal: the level of ``before``'s last steady samples vs ``after``'s first."""
        if before.n_last < self.min_samples or after.n_first < self.min_samples:
            return
        a, ta = before.last_values()
        b, tb = after.first[: after.n_first], after.first_torque[: after.n_first]
        self._values.append(abs(float(np.median(b)) - float(np.median(a))))
        self._torque_steps.append(abs(float(np.median(tb)) - float(np.median(ta))))
        self._spreads.append(
            math.hypot(1.4826 * _mad(a) / math.sqrt(a.size), 1.4826 * _mad(b) / math.sqrt(b.size))
        )

    def result(self) -> LostMotion | None:
        """The estimate over all reversals seen (None when there was none to measure)."""
        if self._prev_run is not None and self._run is not None:
            self._pair(self._prev_run, self._run)
            self._prev_run = None
        if not self._values:
            return None
        values = np.asarray(self._values)
        if values.size >= 2:
            unc = 1.2533 * float(values.std(ddof=1)) / math.sqrt(values.size)
        else:
            unc = self._spreads[0]
        value = float(np.median(values))
        backlash = math.nan
        if self.stiffness:
            windup = float(np.median(self._torque_steps)) * self.kr / self.stiffness
            backlash = max(value - windup, 0.0)
        return LostMotion(value, unc, int(values.size), backlash)


def _mad(x: np.ndarray) -> float:
    return float(np.median(np.abs(x - np.median(x))))

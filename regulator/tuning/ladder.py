"""Provoking the limit cycle: the escalation of test motions, in a documented order, within
the travel limits and the torque limit (docs/commissioning.md, section 10).

A backlash limit cycle needs a kick that throws the load into the gap (section X: a
disturbance opens it, and when it is released friction reverses the net force on the load).
A motion that does not provoke it tells nothing about beta_T, so the reference trial (the
regulator off) is played with each rung in turn until one limit-cycles:

1. the user's own motion (``--motion FILE``), where given;
2. the default motion (:meth:`TuningMotion.for_axis`): a gentle deceleration from the feed to
   the slow feed; its measured torque calibrates the rungs after it;
3. a **sharp deceleration** into the gap: the acceleration raised until the peak torque,
   extrapolated from what the default motion measured (the friction at constant speed and the
   peak above it, which grows with the acceleration), reaches :data:`TORQUE_SHARE` of the
   torque limit;
4. the same deceleration to a **creep feed** (a quarter of the slow feed), where less friction
   holds the gap closed;
5. a **reversal**: the sharp deceleration through zero to the slow feed backwards, across the
   gap;
6. a **load pulse** where the runner can apply one (offline: the plant's disturbance input;
   a drive: a torque offset its PDOs carry): section X's push in the direction of motion at the
   slow feed, at half of it, at the creep feed, then at the feed, :data:`PULSE_SHARE` of the
   torque limit for T_v and released. A push provokes a cycle only within a band of feeds
   (FMU axis 2031, seen seeds: at 6-12 mm/s, not at 4 or 15 mm/s, whatever the push's
   length from T_v to 2 s), so the pulse is tried at feeds a factor 2 apart.

A rung whose path leaves the travel limits, or that the torque limit leaves no room for, is
skipped with the reason; the refusal names every rung and what it measured.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..units import length
from .judge import Record
from .motion import MotionProfile, TuningMotion

#: The peak torque a provoking motion may reach, as a share of the torque limit.
TORQUE_SHARE = 0.5
#: Section X's disturbance against its axis' torque limit (20 of 120 N m): the load pulse.
PULSE_SHARE = 20.0 / 120.0
#: The creep feed as a share of the slow feed.
CREEP_SHARE = 0.25
#: The load pulse's middle feed as a share of the slow feed (between it and the creep feed).
HALF_SHARE = 0.5
#: The largest factor by which a sharp deceleration exceeds the default acceleration.
MAX_SHARPEN = 100.0
#: The load pulse at the feed: the slow feed this share of the feed (no deceleration to speak
#: of, the pulse alone provokes).
FEED_PULSE = 0.9
#: A sharper deceleration must be at least this factor above the default one to be tried.
MIN_SHARPEN = 1.5


@dataclass(frozen=True)
class Rung:
    """One step of the ladder: a motion to play (``profile``) or why it was skipped."""

    name: str
    description: str
    profile: MotionProfile | None
    skipped: str | None = None


@dataclass(frozen=True)
class TorqueModel:
    """What the axis file says of the torque a motion needs (used where no torque is
    measured): inertia at the motor (kg m^2), k_r (rad per load unit), friction at the motor
    (N m, N m per load unit/s)."""

    inertia_kgm2: float
    kr: float
    coulomb_nm: float = 0.0
    viscous: float = 0.0


#: The peak torque of a ramp against its mean: the position loop's overshoot at the corners.
OVERSHOOT = 2.0


def torque_fit(record: Record, profile: MotionProfile, cycle_s: float) -> TorqueModel | None:
    """The torque the default motion needed, fitted by least squares over the samples where
    the reference moves (tau = tau_c sign(v) + c v + J k_r a, at the motor, the reference's
    speed and acceleration): the friction and the inertia the axis showed, whatever its data
    sheet says; None without torque or with a fit that is not physical."""
    n = profile.speed.size
    if record.torque is None or record.torque.size < n:
        return None
    v = profile.speed
    a = np.gradient(v) / cycle_s
    moving = v != 0.0
    if np.count_nonzero(moving) < 10:
        return None
    design = np.column_stack([np.sign(v), v, a])[moving]
    coef, *_ = np.linalg.lstsq(design, record.torque[:n][moving], rcond=None)
    coulomb, viscous, inertia = (float(c) for c in coef)
    if not inertia > 0.0:
        return None
    return TorqueModel(inertia, 1.0, max(coulomb, 0.0), max(viscous, 0.0))


class Ladder:
    """The rungs of the module docstring for one axis. ``base``: the default motion;
    ``travel``: (lowest, highest) position the motion may reach relative to where the axis
    stands; ``pulse``: the runner can apply a load pulse (else that rung is skipped, saying
    ``no_pulse``); ``user``: the user's motion (a profile, not repeated)."""

    def __init__(
        self,
        base: TuningMotion,
        cycle_s: float,
        kv: float,
        repeats: int,
        torque_limit: float,
        travel: tuple[float, float] = (-math.inf, math.inf),
        unit: str = "m",
        pulse: bool = False,
        no_pulse: str = "the drive offers no torque offset",
        user: MotionProfile | None = None,
        model: TorqueModel | None = None,
    ) -> None:
        self.base = base
        self.cycle_s, self.kv, self.repeats = cycle_s, kv, repeats
        self.torque_limit = torque_limit
        self.travel = travel
        self.unit = unit
        self.pulse, self.no_pulse = pulse, no_pulse
        self.user = user
        self.model = model

    def _rung(self, name: str, motion: TuningMotion) -> Rung:
        profile = motion.profile(self.cycle_s, self.kv, name)
        return self._checked(name, motion.describe(self.unit), profile)

    def _checked(self, name: str, description: str, profile: MotionProfile) -> Rung:
        lo, hi = profile.excursion()
        if lo < self.travel[0] or hi > self.travel[1]:
            u = self.unit
            return Rung(
                name,
                description,
                None,
                f"its path {length(lo, u)}..{length(hi, u)} from here leaves the travel "
                f"{length(self.travel[0], u)}..{length(self.travel[1], u)}",
            )
        return Rung(name, description, profile.repeated(self.repeats))

    def rungs(self) -> Iterator[Rung]:
        """The rungs in order; after the default motion's rung the caller sets
        :attr:`calibration` to its (record, profile) before asking for the next."""
        self.calibration: tuple[Record, MotionProfile] | None = None
        if self.user is not None:
            yield self._checked(self.user.name, "your motion", self.user)
        yield self._rung("deceleration", self.base)
        accel, why = self._sharp_accel()
        b = self.base
        creep = b.low_feed * CREEP_SHARE
        if accel is None:
            for name in ("sharp deceleration", "sharp deceleration to a creep feed", "reversal"):
                yield Rung(name, "", None, why)
        else:
            yield self._rung("sharp deceleration", b.with_changes(accel=accel))
            yield self._rung(
                "sharp deceleration to a creep feed",
                b.with_changes(accel=accel, low_feed=creep),
            )
            yield self._rung("reversal", b.with_changes(accel=accel, reverse=True))
        pulse, why = self._pulse()
        for name, feed in (
            ("load pulse", b.low_feed),
            ("load pulse at half the slow feed", HALF_SHARE * b.low_feed),
            ("load pulse at a creep feed", creep),
            ("load pulse at the feed", FEED_PULSE * b.feed),
        ):
            if pulse is None:
                yield Rung(name, "", None, why)
            else:
                yield self._rung(name, b.with_changes(low_feed=feed, pulse_nm=pulse))

    def _budget(self) -> tuple[float, float] | None:
        """(friction torque at the feed, peak torque per unit of acceleration) of the base
        motion: fitted to what it measured, else the axis file's model; None when neither
        is known."""
        model = None
        if self.calibration is not None:
            model = torque_fit(*self.calibration, self.cycle_s)
        model = model or self.model
        if model is None:
            return None
        friction = model.coulomb_nm + model.viscous * self.base.feed
        return friction, OVERSHOOT * model.inertia_kgm2 * model.kr

    def _sharp_accel(self) -> tuple[float | None, str]:
        budget = self._budget()
        a0 = self.base.accel
        if budget is None:
            return None, "no torque measured and no inertia known to size a sharper deceleration"
        friction, per_accel = budget
        if not math.isfinite(self.torque_limit):
            return a0 * MAX_SHARPEN / 10.0, ""
        room = TORQUE_SHARE * self.torque_limit - friction
        accel = min(room / per_accel, a0 * MAX_SHARPEN) if room > 0 else 0.0
        if accel < MIN_SHARPEN * a0:
            return None, (
                f"the torque limit {self.torque_limit:g} leaves no room for a sharper "
                f"deceleration (friction {friction:.3g}, {TORQUE_SHARE:.0%} of the limit)"
            )
        return accel, ""

    def _pulse(self) -> tuple[float | None, str]:
        if not self.pulse:
            return None, self.no_pulse
        budget = self._budget()
        friction = budget[0] if budget is not None else 0.0
        if not math.isfinite(self.torque_limit):
            return None, "no torque limit to size a load pulse by"
        pulse = min(PULSE_SHARE * self.torque_limit, TORQUE_SHARE * self.torque_limit - friction)
        if pulse <= 0.0:
            return None, f"the torque limit {self.torque_limit:g} leaves no room for a load pulse"
        return pulse, ""

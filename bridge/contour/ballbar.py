"""The circular test's evaluation: ISO 230-4's figures and the decomposition of a ballbar
report, from the path the two axes took on the data arc of each direction.

ISO 230-4 figures (all from the radial deviation ``Δr = |p - c| - R`` of the measured points):

* **circular deviation G** per direction: the smallest radial distance between two concentric
  circles that enclose the path, centred on its least-squares circle (LSC);
* **bidirectional circular deviation G(b)**: the same for both paths together (one LSC);
* **circular hysteresis H**: the largest radial difference between the two paths at the same
  angle;
* **radial deviation F** (max, min): the path against the nominal circle about the commanded
  centre.

The decomposition: the radial deviation of both directions (``d = +1`` counter-clockwise,
``-1`` clockwise) is fitted by least squares with the signatures a ballbar report names, each
an analytic consequence of one error on the circle ``x = R cos θ``, ``y = R sin θ``:

======================  =======================================  ================================
error                   what it does to the axes                 radial signature
======================  =======================================  ================================
centre offset           ``x + e_x``, ``y + e_y``                 ``e_x cos θ + e_y sin θ``
radius                  both axes scaled alike, lag              ``c_0`` (+ ``c_d d``)
scale mismatch          ``x (1 + s_x)``, ``y (1 + s_y)``         ``R (s_x - s_y)/2 · cos 2θ``
squareness              ``x + γ y`` (Y leans towards +X by γ)    ``γ R/2 · sin 2θ``
servo mismatch          x lags its command by τ_x, y by τ_y      ``d F (τ_x - τ_y)/2 · sin 2θ``
backlash X (step)       x trails its motor by b_x/2              ``d b_x/2 · sgn(sin θ) cos θ``
backlash Y (step)       y trails its motor by b_y/2              ``-d b_y/2 · sgn(cos θ) sin θ``
======================  =======================================  ================================

(servo mismatch: a position loop of gain k_v lags its command by ``τ = 1/k_v`` at a feed far
below its bandwidth, so ``x(t) = R cos(ω(t - τ_x))``; ``|p|² = R²(1 + sin 2φ sin(ω(τ_x - τ_y)))``
-- a tilted ellipse whose tilt changes sign with the direction of travel, where squareness's
does not.) A backlash step is what a loop closed on the motor encoder shows at an axis
reversal; a loop closed on the load scale (paper Fig. 1) closes it and leaves a **reversal
spike**: after the reversal the load stands still while the motor crosses the gap, and the
path bulges outwards. The spikes are not a smooth signature: the fit leaves out a window after
each quadrant transition (grown until the residual is back in the noise), and each spike is
measured in the residual of the fit -- height (signed, outwards positive) and width (degrees
of the circle at half its height), per transition and direction.

With the two measuring systems of each axis (paper section II.B: motor encoder and load
scale), the backlash of an axis is also measured directly as its **lost motion**: the
difference ``θ_m / k_r - x_l`` sits at one level while the axis moves one way and at another
after it reverses; the change between the middles of the two half circles is the gap plus the
change of the elastic wind-up (the motor torque's change times ``k_r / stiffness``, subtracted
when the stiffness is known). That is the backlash a load-scale loop hides from the contour.

A signature is **named** when its size on the circle exceeds :data:`NAMING_FLOOR` and four
standard errors of its fit; servo mismatch and squareness are told apart by their
direction-dependence, so naming either needs both directions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import ContourError
from .circular import CircularTest, Direction

#: The smallest amplitude on the circle a signature is named at (load units: 1 µm): below
#: it a ballbar's own uncertainty (ISO 230-4 asks for its statement) would hide it.
NAMING_FLOOR = 1e-6
#: Standard errors a named signature must exceed.
NAMING_SIGMAS = 4.0
#: Widest spike window after a quadrant transition, degrees.
MAX_SPIKE_DEG = 60.0
#: The quadrant transitions: angle (deg) and the axis that reverses there.
TRANSITIONS = ((0.0, "X"), (90.0, "Y"), (180.0, "X"), (270.0, "Y"))


@dataclass(frozen=True)
class MeasuredPath:
    """One direction's run on the data arc: the axes' load positions ``x``, ``y`` (load
    units); optionally each axis's motor position over k_r (``motor_x``, ``motor_y``, load
    units) and motor torque (``torque_x``, ``torque_y``, N·m), for the lost motion."""

    direction: Direction
    x: np.ndarray
    y: np.ndarray
    motor_x: np.ndarray | None = None
    motor_y: np.ndarray | None = None
    torque_x: np.ndarray | None = None
    torque_y: np.ndarray | None = None

    def __post_init__(self) -> None:
        x = np.asarray(self.x, dtype=float)
        y = np.asarray(self.y, dtype=float)
        if x.ndim != 1 or x.shape != y.shape or x.size < 64:
            raise ContourError(
                f"a measured path needs x and y of equal length (>= 64 samples), not "
                f"{x.shape} and {y.shape}"
            )
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise ContourError("a measured path must be finite")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        for name in ("motor_x", "motor_y", "torque_x", "torque_y"):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v, dtype=float)
                if v.shape != x.shape:
                    raise ContourError(f"{name} has {v.shape} samples, the path {x.shape}")
                object.__setattr__(self, name, v)


@dataclass(frozen=True)
class DirectionFigures:
    """ISO 230-4's figures of one direction (load units)."""

    direction: Direction
    circular_deviation: float  # G, about the LSC centre
    radial_deviation_max: float  # F max, about the commanded centre
    radial_deviation_min: float  # F min
    lsc_centre: tuple[float, float]


@dataclass(frozen=True)
class Spike:
    """A reversal spike: the quadrant transition (angle, the axis reversing), the direction
    of travel, its height (load units, outwards positive) and width (degrees at half height)."""

    angle_deg: float
    axis: str
    direction: Direction
    height: float
    width_deg: float


@dataclass(frozen=True)
class Signature:
    """A fitted signature: its name, value in its own unit, amplitude on the circle (load
    units), the amplitude's standard error, whether it is named, and a sentence."""

    name: str
    value: float
    unit: str
    amplitude: float
    standard_error: float
    named: bool
    text: str


@dataclass(frozen=True)
class BallbarReport:
    """Everything :func:`analyse` found (module docstring), load units and seconds."""

    radius: float
    feed: float
    directions: tuple[DirectionFigures, ...]
    bidirectional_deviation: float | None
    hysteresis: float | None
    signatures: tuple[Signature, ...]
    spikes: tuple[Spike, ...]
    lost_motion: dict[str, float] = field(default_factory=dict)
    backlash: dict[str, float] = field(default_factory=dict)
    residual_std: float = 0.0

    def signature(self, name: str) -> Signature:
        for s in self.signatures:
            if s.name == name:
                return s
        raise KeyError(name)

    @property
    def named(self) -> tuple[str, ...]:
        """The signatures named, largest first."""
        named = sorted((s for s in self.signatures if s.named), key=lambda s: -abs(s.amplitude))
        return tuple(s.name for s in named)

    @property
    def contour_error(self) -> float:
        """The one figure per test: G(b) with both directions, else the one G."""
        if self.bidirectional_deviation is not None:
            return self.bidirectional_deviation
        return self.directions[0].circular_deviation

    def summary(self) -> dict[str, object]:
        """A JSON-ready summary (µm, ms, degrees; names as a report prints them)."""
        um = 1e6
        out: dict[str, object] = {
            "radius_mm": self.radius * 1e3,
            "feed_mm_min": self.feed * 6e4,
            "circular_deviation_um": {
                d.direction.name.lower(): d.circular_deviation * um for d in self.directions
            },
            "radial_deviation_um": {
                d.direction.name.lower(): [d.radial_deviation_min * um, d.radial_deviation_max * um]
                for d in self.directions
            },
            "bidirectional_circular_deviation_um": _scaled(self.bidirectional_deviation, um),
            "circular_hysteresis_um": _scaled(self.hysteresis, um),
            "signatures": {
                s.name: {
                    "value": s.value,
                    "unit": s.unit,
                    "amplitude_um": s.amplitude * um,
                    "standard_error_um": s.standard_error * um,
                    "named": s.named,
                }
                for s in self.signatures
            },
            "named": list(self.named),
            "reversal_spikes": [
                {
                    "angle_deg": s.angle_deg,
                    "axis": s.axis,
                    "direction": s.direction.name.lower(),
                    "height_um": s.height * um,
                    "width_deg": s.width_deg,
                }
                for s in self.spikes
            ],
            "lost_motion_um": {k: v * um for k, v in self.lost_motion.items()},
            "backlash_um": {k: v * um for k, v in self.backlash.items()},
            "residual_std_um": self.residual_std * um,
        }
        return out

    def lines(self) -> list[str]:
        """The report as text, a line per finding."""
        um = 1e6
        out = [
            f"circle R = {self.radius * 1e3:g} mm at F = {self.feed * 6e4:g} mm/min",
        ]
        for d in self.directions:
            out.append(
                f"  {d.direction.label}: G = {d.circular_deviation * um:.2f} µm, radial "
                f"deviation {d.radial_deviation_min * um:+.2f}..{d.radial_deviation_max * um:+.2f}"
                " µm"
            )
        if self.bidirectional_deviation is not None:
            out.append(
                f"  bidirectional G(b) = {self.bidirectional_deviation * um:.2f} µm, hysteresis "
                f"H = {(self.hysteresis or 0.0) * um:.2f} µm"
            )
        for s in self.signatures:
            mark = "NAMED" if s.named else "     "
            out.append(f"  {mark} {s.text}")
        for k, v in self.lost_motion.items():
            b = self.backlash.get(k)
            extra = "" if b is None else f" (backlash {b * um:.2f} µm less the elastic wind-up)"
            out.append(f"  lost motion {k} (motor encoder vs scale): {v * um:.2f} µm{extra}")
        for sp in self.spikes:
            out.append(
                f"  reversal spike at {sp.angle_deg:g}° ({sp.axis} reverses), "
                f"{sp.direction.name.lower()}: {sp.height * um:+.2f} µm, {sp.width_deg:.1f}° wide"
            )
        return out


def _scaled(v: float | None, k: float) -> float | None:
    return None if v is None else v * k


# --- geometry -------------------------------------------------------------------------------
def lsc_centre(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """The least-squares circle (Kåsa's algebraic fit, exact for points on a circle): centre
    and radius."""
    a = np.column_stack((x, y, np.ones_like(x)))
    b = x * x + y * y
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = sol[0] / 2, sol[1] / 2
    return float(cx), float(cy), float(math.sqrt(sol[2] + cx * cx + cy * cy))


def _deviation(x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
    return np.hypot(x - cx, y - cy)


def _unit_angle(x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """The angle of each point about the centre, degrees in [0, 360)."""
    return np.mod(np.degrees(np.arctan2(y - cy, x - cx)), 360.0)


def _after(angle: np.ndarray, at: float, d: int) -> np.ndarray:
    """Degrees travelled since passing ``at`` in direction ``d``, in [0, 360)."""
    return np.mod(d * (angle - at), 360.0)


# --- the fit ------------------------------------------------------------------------------------
_NAMES = (
    "radius",
    "radius difference between directions",
    "centre offset X",
    "centre offset Y",
    "scale mismatch",
    "squareness",
    "servo mismatch",
    "backlash X",
    "backlash Y",
)


def _basis(theta: np.ndarray, d: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.column_stack(
        (
            np.ones_like(theta),
            d,
            c,
            s,
            np.cos(2 * theta),
            np.sin(2 * theta),
            d * np.sin(2 * theta),
            0.5 * d * np.sign(s) * c,
            -0.5 * d * np.sign(c) * s,
        )
    )


def _robust_std(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r)))) if r.size else 0.0


def analyse(
    test: CircularTest,
    paths: Sequence[MeasuredPath],
    *,
    windup_per_nm: dict[str, float] | None = None,
) -> BallbarReport:
    """ISO 230-4 figures and the decomposition (module docstring) of one or two directions
    of the circular test ``test``. ``windup_per_nm``: per axis ("X", "Y") the elastic
    wind-up per N·m of motor torque, ``k_r / stiffness`` (load units per N·m), subtracted from
    the lost motion when the paths carry motor positions and torques."""
    if not paths or len(paths) > 2:
        raise ContourError(f"a circular test has one or two directions, not {len(paths)}")
    if len(paths) == 2 and paths[0].direction is paths[1].direction:
        raise ContourError("two paths of a circular test need both directions")
    cx, cy = test.centre
    R = test.radius
    figures = []
    thetas, drs, ds = [], [], []
    for p in paths:
        lx, ly, _ = lsc_centre(p.x, p.y)
        r_lsc = _deviation(p.x, p.y, lx, ly)
        r_nom = _deviation(p.x, p.y, cx, cy) - R
        figures.append(
            DirectionFigures(
                p.direction,
                float(r_lsc.max() - r_lsc.min()),
                float(r_nom.max()),
                float(r_nom.min()),
                (lx, ly),
            )
        )
        thetas.append(np.arctan2(p.y - cy, p.x - cx))
        drs.append(r_nom)
        ds.append(np.full(p.x.size, float(p.direction.sign)))
    theta, dr, d = np.concatenate(thetas), np.concatenate(drs), np.concatenate(ds)
    both = len(paths) == 2
    bidirectional = hysteresis = None
    if both:
        ax = np.concatenate([p.x for p in paths])
        ay = np.concatenate([p.y for p in paths])
        lx, ly, _ = lsc_centre(ax, ay)
        r_all = _deviation(ax, ay, lx, ly)
        bidirectional = float(r_all.max() - r_all.min())
        hysteresis = _hysteresis(thetas, drs)
    basis = _basis(theta, d)
    columns = list(range(basis.shape[1]))
    if not both:  # one direction cannot tell d-terms from common ones
        columns = [0, 2, 3, 4, 5, 7, 8]
    angle = np.mod(np.degrees(theta), 360.0)
    extents = dict.fromkeys((t, int(k)) for t, _ in TRANSITIONS for k in (1, -1))
    extents = {key: 20.0 for key in extents}
    coef = np.zeros(basis.shape[1])
    cov = np.zeros((basis.shape[1], basis.shape[1]))
    residual = dr
    sigma = 0.0
    for _ in range(3):
        keep = np.ones(theta.size, dtype=bool)
        for (at, sign), ext in extents.items():
            keep &= ~((d == sign) & (_after(angle, at - sign * 2.0, sign) < ext + 2.0))
        a = basis[keep][:, columns]
        sol, *_ = np.linalg.lstsq(a, dr[keep], rcond=None)
        coef[:] = 0.0
        coef[columns] = sol
        residual = dr - basis @ coef
        sigma = _robust_std(residual[keep])
        dof = max(int(keep.sum()) - len(columns), 1)
        s2 = float(np.sum(residual[keep] ** 2)) / dof
        inv = np.linalg.pinv(a.T @ a)
        cov[:] = 0.0
        cov[np.ix_(columns, columns)] = s2 * inv
        extents = {key: _spike_extent(residual, angle, d, key[0], key[1], sigma) for key in extents}
    spikes = tuple(
        s
        for (at, sign), ext in sorted(extents.items(), key=lambda kv: (-kv[0][1], kv[0][0]))
        if (s := _spike(residual, angle, d, at, sign, ext, sigma, _step(coef, at, sign)))
        is not None
    )
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    signatures = _signatures(coef, se, test, both)
    lost, backlash = _lost_motion(paths, test, windup_per_nm or {})
    return BallbarReport(
        R,
        test.feed,
        tuple(figures),
        bidirectional,
        hysteresis,
        signatures,
        spikes,
        lost,
        backlash,
        sigma,
    )


def _hysteresis(thetas: list[np.ndarray], drs: list[np.ndarray]) -> float:
    """Largest |Δr_ccw - Δr_cw| at the same angle (each path interpolated on a 0.1° grid)."""
    grid = np.radians(np.arange(0.0, 360.0, 0.1))
    curves = []
    for th, r in zip(thetas, drs, strict=True):
        a = np.mod(th, 2 * math.pi)
        order = np.argsort(a)
        curves.append(np.interp(grid, a[order], r[order], period=2 * math.pi))
    return float(np.max(np.abs(curves[0] - curves[1])))


def _spike_extent(
    residual: np.ndarray, angle: np.ndarray, d: np.ndarray, at: float, sign: int, sigma: float
) -> float:
    """Degrees after the transition until the residual is back within the noise for good."""
    sel = d == sign
    since = _after(angle[sel], at, sign)
    near = since < MAX_SPIKE_DEG
    if not np.any(near):
        return 0.0
    r = residual[sel][near]
    a = since[near]
    out = np.abs(r) > max(4.0 * sigma, 0.1 * NAMING_FLOOR)
    if not np.any(out):
        return 0.0
    return float(min(a[out].max() + 1.0, MAX_SPIKE_DEG))


def _step(coef: np.ndarray, at: float, sign: int) -> float:
    """The fitted backlash steps' jump of the radial deviation where the path passes the
    transition at ``at`` degrees in direction ``sign`` (after less before)."""
    eps = math.radians(1e-3)
    th = np.array([math.radians(at) - sign * eps, math.radians(at) + sign * eps])
    b = _basis(th, np.full(2, float(sign)))[:, 7:] @ coef[7:]
    return float(b[1] - b[0])


def _spike(
    residual: np.ndarray,
    angle: np.ndarray,
    d: np.ndarray,
    at: float,
    sign: int,
    extent: float,
    sigma: float,
    step: float = 0.0,
) -> Spike | None:
    """The spike after one transition in one direction, if it stands out of the noise: the
    residual's excursion beyond both levels a backlash step joins (``step``: the step's jump;
    the residual is measured against the level after it, so the level before is ``-step``):
    a path that only moves from one level to the other has no spike."""
    sel = d == sign
    if not np.any(sel) or extent <= 0.0:
        return None
    since = _after(angle[sel], at - sign * 2.0, sign) - 2.0
    window = since < extent
    if not np.any(window):
        return None
    r = residual[sel][window]
    a = since[window]
    order = np.argsort(a)
    r, a = r[order], a[order]
    top, bottom = max(0.0, -step), min(0.0, -step)
    r = np.where(r > top, r - top, np.where(r < bottom, r - bottom, 0.0))
    k = int(np.argmax(np.abs(r)))
    height = float(r[k])
    if abs(height) <= max(NAMING_SIGMAS * sigma, 0.1 * NAMING_FLOOR):
        return None
    half = abs(height) / 2
    above = np.sign(height) * r >= half
    lo = hi = k
    while lo > 0 and above[lo - 1]:
        lo -= 1
    while hi < r.size - 1 and above[hi + 1]:
        hi += 1
    axis = dict(TRANSITIONS)[at]
    return Spike(at, axis, Direction(sign), height, float(a[hi] - a[lo]))


def _signatures(
    coef: np.ndarray, se: np.ndarray, test: CircularTest, both: bool
) -> tuple[Signature, ...]:
    R, F = test.radius, test.feed
    um = 1e6
    c = dict(zip(_NAMES, coef, strict=True))
    e = dict(zip(_NAMES, se, strict=True))

    def sig(name: str, value: float, unit: str, amp: float, err: float, text: str, can: bool):
        named = bool(can and abs(amp) > max(NAMING_FLOOR, NAMING_SIGMAS * err))
        return Signature(name, float(value), unit, float(amp), float(err), named, text)

    offset = math.hypot(c["centre offset X"], c["centre offset Y"])
    offset_err = math.hypot(e["centre offset X"], e["centre offset Y"])
    scale = 2 * c["scale mismatch"] / R
    square = 2 * c["squareness"] / R
    lag = 2 * c["servo mismatch"] / F
    bx, by = c["backlash X"], c["backlash Y"]
    lagging = "X lags Y" if lag > 0 else "Y lags X"
    return (
        sig(
            "radius",
            c["radius"],
            "m",
            c["radius"],
            e["radius"],
            f"radius deviation {c['radius'] * um:+.2f} µm (mean path radius against the "
            "programmed one: the position loops' lag, a scale error common to both axes)",
            False,
        ),
        sig(
            "centre offset",
            offset,
            "m",
            offset,
            offset_err,
            f"centre offset X {c['centre offset X'] * um:+.2f} µm, "
            f"Y {c['centre offset Y'] * um:+.2f} µm",
            True,
        ),
        sig(
            "scale mismatch",
            scale * 1e6,
            "µm/m",
            c["scale mismatch"],
            e["scale mismatch"],
            f"scale mismatch X - Y {scale * 1e6:+.1f} µm/m (an ellipse along the axes, "
            f"{abs(c['scale mismatch']) * um:.2f} µm)",
            True,
        ),
        sig(
            "squareness",
            square * 1e6,
            "µm/m",
            c["squareness"],
            e["squareness"],
            f"squareness {square * 1e6:+.1f} µm/m (the axes enclose 90° "
            f'{"-" if square >= 0 else "+"} {abs(math.degrees(square)) * 3600:.2f}"; an ellipse '
            f"at 45° the same both ways, {abs(c['squareness']) * um:.2f} µm)",
            both,
        ),
        sig(
            "servo mismatch",
            lag * 1e3,
            "ms",
            c["servo mismatch"],
            e["servo mismatch"],
            f"servo mismatch {abs(lag) * 1e3:.3f} ms, {lagging} (an ellipse at 45° whose tilt "
            f"changes with the direction, {abs(c['servo mismatch']) * um:.2f} µm: unequal k_v, "
            "eq. 1)",
            both,
        ),
        sig(
            "backlash X",
            bx,
            "m",
            bx / 2,
            e["backlash X"] / 2,
            f"backlash X (contour step at 0°/180°) {bx * um:+.2f} µm",
            True,
        ),
        sig(
            "backlash Y",
            by,
            "m",
            by / 2,
            e["backlash Y"] / 2,
            f"backlash Y (contour step at 90°/270°) {by * um:+.2f} µm",
            True,
        ),
    )


def _lost_motion(
    paths: Sequence[MeasuredPath], test: CircularTest, windup: dict[str, float]
) -> tuple[dict[str, float], dict[str, float]]:
    """Per axis: the change of ``motor - load`` between the middles of the half circles the
    axis runs one way and the other (module docstring); the backlash after the wind-up."""
    cx, cy = test.centre
    lost: dict[str, float] = {}
    backlash: dict[str, float] = {}
    for axis, halves in (("X", (90.0, 270.0)), ("Y", (0.0, 180.0))):
        values, torques = [], []
        for p in paths:
            motor = p.motor_x if axis == "X" else p.motor_y
            load = p.x if axis == "X" else p.y
            torque = p.torque_x if axis == "X" else p.torque_y
            if motor is None:
                continue
            angle = _unit_angle(p.x, p.y, cx, cy)
            diff = motor - load
            levels, tq = [], []
            for mid in halves:
                sel = np.abs(np.mod(angle - mid + 180.0, 360.0) - 180.0) <= 45.0
                if not np.any(sel):
                    break
                levels.append(float(np.median(diff[sel])))
                if torque is not None:
                    tq.append(float(np.median(torque[sel])))
            if len(levels) == 2:
                values.append(abs(levels[0] - levels[1]))
                if len(tq) == 2:
                    torques.append(abs(tq[0] - tq[1]))
        if values:
            lost[axis] = float(np.mean(values))
            if axis in windup and len(torques) == len(values):
                backlash[axis] = max(lost[axis] - float(np.mean(torques)) * windup[axis], 0.0)
    return lost, backlash

"""Bounded, multi-start simulation-error fitting of axis-file parameters.

The cost is the output error of the *closed-loop simulation* (:mod:`.replay`) against the
recording on the training samples: per compared signal the residual divided by a fixed scale
(see :class:`Objective`), squared, averaged over samples and summed over signals.

Robust: residuals pass :func:`robust` (soft-L1 beyond three RMS residuals) before they are
squared.

Search (the paper's section IX fitted M_l and the friction with Nelder-Mead on 1600 samples;
here): every parameter is bounded and normalised (``u = value/scale`` or ``ln(value/scale)``);
a global stage scores a scrambled Sobol sample of the box plus the given starting points
(data-derived ones from :mod:`.effects`); the best few distinct points start
``scipy.optimize.least_squares`` (trust-region reflective, bounds, forward differences with a
1 % step so that the stick-slip events of Coulomb friction, which move by whole substeps, do
not fake the gradient); the best end point wins. A parameter that only takes discrete values
(the dead time, whole speed cycles in the kernel) is profiled over its grid first and the
continuous ones are fitted at the best grid value.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from concurrent.futures import Executor
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import qmc

from plant_sim.physics.model import KernelOptions
from virtual_bus.formats.axis import AxisConfig

from .errors import DiagnosisOptionError
from .replay import ReplayInput, compared_quantity, replay

#: Relative finite-difference step of the least-squares Jacobian (1 %: the stick-slip events
#: of Coulomb friction move by whole substeps and would fake a smaller step's gradient).
DIFF_STEP = 1e-2

#: Pseudo-keys of the periodic disturbance, fitted as A·cos(φ) and A·sin(φ) (linear in the
#: torque, no wrap-around of the phase), converted to periodic_amplitude / periodic_phase.
PERIODIC_COS = "disturbance.periodic_amplitude*cos(phase)"
PERIODIC_SIN = "disturbance.periodic_amplitude*sin(phase)"

#: Residual (in scale units) given to non-finite simulation outputs of an unstable parameter
#: set, and the clip of every scaled residual (keeps the cost finite).
UNSTABLE_RESIDUAL = 1e6


@dataclass(frozen=True)
class Parameter:
    """One free parameter: a dotted axis key (or a periodic pseudo-key) with its bounds,
    starting value and normalisation scale; ``log``: fitted as ln(value/scale) (low > 0)."""

    key: str
    low: float
    high: float
    start: float
    scale: float
    log: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise DiagnosisOptionError(
                f"parameter {self.key}: bounds [{self.low!r}, {self.high!r}] must be finite, "
                "low < high"
            )
        if not self.scale > 0.0:
            raise DiagnosisOptionError(f"parameter {self.key}: scale {self.scale!r} must be > 0")
        if self.log and self.low <= 0.0:
            raise DiagnosisOptionError(
                f"parameter {self.key}: log scale needs low > 0, got {self.low!r}"
            )
        object.__setattr__(self, "start", self.clip(self.start))

    def clip(self, value: float) -> float:
        return float(min(self.high, max(self.low, value)))

    def to_u(self, value: float) -> float:
        value = self.clip(value)
        return math.log(value / self.scale) if self.log else value / self.scale

    def from_u(self, u: float) -> float:
        value = self.scale * math.exp(u) if self.log else u * self.scale
        return self.clip(value)

    @property
    def u_bounds(self) -> tuple[float, float]:
        return self.to_u(self.low), self.to_u(self.high)


@dataclass(frozen=True)
class DiscreteParameter:
    """A parameter profiled over a grid of values (dead time: whole speed cycles)."""

    key: str
    values: tuple[float, ...]
    start: float

    def __post_init__(self) -> None:
        if not self.values:
            raise DiagnosisOptionError(f"parameter {self.key}: empty grid")


@dataclass(frozen=True)
class FitSpec:
    """What to fit: ``base`` (with any fixed additions), the free parameters, more starting
    points (partial mappings key -> value; missing keys take the parameter's start), an
    optional discrete parameter, and the kernel options held for the whole fit."""

    base: AxisConfig
    parameters: tuple[Parameter, ...]
    extra_starts: tuple[Mapping[str, float], ...] = ()
    discrete: DiscreteParameter | None = None
    options: KernelOptions = field(default_factory=KernelOptions)
    n_global: int = 8

    @property
    def n_free(self) -> int:
        return len(self.parameters) + (1 if self.discrete is not None else 0)

    def start_values(self) -> dict[str, float]:
        values = {p.key: p.start for p in self.parameters}
        if self.discrete is not None:
            values[self.discrete.key] = self.discrete.start
        return values


def plain_floats(axis: AxisConfig) -> AxisConfig:
    """``axis`` with every numeric value a Python float (numpy scalars would be written as
    ``np.float64(...)`` by :func:`virtual_bus.formats.axis.dump_axis`, which is not TOML)."""
    changes: dict[str, float | None] = {}
    for section in ("mechanics", "friction", "disturbance", "control"):
        part = getattr(axis, section)
        for f in fields(part):
            value = getattr(part, f.name)
            if isinstance(value, np.generic):
                changes[f"{section}.{f.name}"] = float(value)
    if isinstance(axis.transmission_ratio, np.generic):
        changes["axis.transmission_ratio"] = float(axis.transmission_ratio)
    return axis.with_values(changes) if changes else axis


def axis_with(base: AxisConfig, values: Mapping[str, float]) -> AxisConfig:
    """``base`` with ``values`` applied (periodic pseudo-keys converted to amplitude/phase)."""
    plain = {k: float(v) for k, v in values.items() if k not in (PERIODIC_COS, PERIODIC_SIN)}
    if PERIODIC_COS in values or PERIODIC_SIN in values:
        c = values.get(PERIODIC_COS, 0.0)
        s = values.get(PERIODIC_SIN, 0.0)
        plain["disturbance.periodic_amplitude"] = math.hypot(c, s)
        plain["disturbance.periodic_phase"] = math.atan2(s, c)
    return plain_floats(base.with_values(plain))


#: Scaled residual beyond which the loss grows like |r| instead of r² (soft-L1): a residual
#: scale is the model's RMS residual, so 3 leaves noise alone and keeps a few extreme events
#: (a saturated loop integrating an unrecorded disturbance) from ruling the fit and the test.
ROBUST_SCALE = 3.0


def robust(r: np.ndarray) -> np.ndarray:
    """Pseudo-residual whose square is the soft-L1 loss 2c²(sqrt(1 + (r/c)²) − 1), c =
    ROBUST_SCALE: ≈ r for |r| << c, grows like sqrt(2c|r|) beyond. Least squares on it is
    ``least_squares(loss="soft_l1")``; the held-out test uses it unchanged."""
    c = ROBUST_SCALE
    return np.sign(r) * c * np.sqrt(2.0 * (np.sqrt(1.0 + (r / c) ** 2) - 1.0))


class Objective:
    """Output error of the closed-loop replay; residuals per signal over the whole recording.

    ``scales``: per signal the divisor of its residual. The engine uses the RMS residual of
    the re-fitted nominal model per signal (the maximum-likelihood weighting of a multi-output
    output-error fit: every signal counts by how well a model can follow it, not by its unit
    or by how much of it the reference alone explains). Thread-safe (read-only data); counts
    simulations in ``n_simulations``.
    """

    def __init__(self, inp: ReplayInput, train: np.ndarray, scales: Mapping[str, float]) -> None:
        self.inp = inp
        self.train = np.asarray(train, dtype=bool)
        self.scales = dict(scales)
        self.signals = tuple(s for s in inp.signals if s in self.scales)
        self._recorded = {s: inp.compared(s) for s in self.signals}
        self._lock = threading.Lock()
        self.n_simulations = 0

    def residuals(self, axis: AxisConfig, options: KernelOptions) -> dict[str, np.ndarray]:
        """(recorded − simulated)/scale per signal, full length; non-finite -> UNSTABLE."""
        with np.errstate(all="ignore"):
            sim = replay(axis, self.inp, options, self.signals)
            out: dict[str, np.ndarray] = {}
            for s in self.signals:
                simulated = compared_quantity(self.inp, s, sim[s])
                r = (self._recorded[s] - simulated) / self.scales[s]
                r = np.where(np.isfinite(r), r, UNSTABLE_RESIDUAL)
                out[s] = np.clip(r, -UNSTABLE_RESIDUAL, UNSTABLE_RESIDUAL)
        with self._lock:
            self.n_simulations += 1
        return out

    def vector(self, res: Mapping[str, np.ndarray], mask: np.ndarray | None = None) -> np.ndarray:
        """Concatenated scaled residuals on ``mask`` (default: training samples) through
        :func:`robust`, divided by sqrt(samples) so that the sum of squares is the mean
        robust loss over samples, summed over signals."""
        m = self.train if mask is None else mask
        n = max(1, int(m.sum()))
        return np.concatenate([robust(res[s][m]) for s in self.signals]) / math.sqrt(n)

    def cost(self, res: Mapping[str, np.ndarray], mask: np.ndarray | None = None) -> float:
        v = self.vector(res, mask)
        return float(v @ v)


@dataclass(frozen=True)
class FitResult:
    """Best point of a fit: values of the free parameters, the fitted axis, training cost."""

    values: dict[str, float]
    axis: AxisConfig
    cost: float
    residuals: dict[str, np.ndarray]
    n_free: int
    n_simulations: int
    starts_tried: int
    message: str
    options: KernelOptions = field(default=KernelOptions())


Progress = Callable[[int], None]


def _sobol(n: int, dim: int, seed: int) -> np.ndarray:
    if n <= 0 or dim == 0:
        return np.empty((0, dim))
    m = max(1, math.ceil(math.log2(max(n, 2))))
    pts = qmc.Sobol(dim, scramble=True, seed=seed).random_base2(m)
    return pts[:n]


def _fit_continuous(
    spec: FitSpec,
    fixed: Mapping[str, float],
    objective: Objective,
    max_nfev: int,
    n_starts: int,
    seed: int,
    progress: Progress | None,
    pool: Executor | None = None,
) -> FitResult:
    params = spec.parameters
    count = [0]

    def run(values: Mapping[str, float]) -> dict[str, np.ndarray]:
        axis = axis_with(spec.base, {**values, **fixed})
        res = objective.residuals(axis, spec.options)
        count[0] += 1
        if progress is not None:
            progress(1)
        return res

    def values_of(u: np.ndarray) -> dict[str, float]:
        return {p.key: p.from_u(float(x)) for p, x in zip(params, u, strict=True)}

    if not params:
        res = run({})
        return FitResult(
            values=dict(fixed),
            axis=axis_with(spec.base, fixed),
            cost=objective.cost(res),
            residuals=res,
            n_free=spec.n_free,
            n_simulations=count[0],
            starts_tried=1,
            message="nothing free",
            options=spec.options,
        )
    lo = np.array([p.u_bounds[0] for p in params])
    hi = np.array([p.u_bounds[1] for p in params])
    candidates: list[np.ndarray] = [np.array([p.to_u(p.start) for p in params])]
    for extra in spec.extra_starts:
        candidates.append(np.array([p.to_u(extra.get(p.key, p.start)) for p in params]))
    scored: list[tuple[float, np.ndarray, dict[str, np.ndarray]]] = []
    for u in candidates:
        res = run(values_of(u))
        scored.append((objective.cost(res), u, res))
    for unit in _sobol(spec.n_global, len(params), seed):
        u = lo + unit * (hi - lo)
        res = run(values_of(u))
        scored.append((objective.cost(res), u, res))
    scored.sort(key=lambda item: item[0])
    starts: list[np.ndarray] = []
    for _, u, _ in scored:
        if all(np.max(np.abs(u - s)) > 0.05 for s in starts):
            starts.append(u)
        if len(starts) >= n_starts:
            break
    best_cost, best_u, best_res = scored[0]
    messages = []
    cache: dict[bytes, dict[str, np.ndarray]] = {}

    def fun(u: np.ndarray) -> np.ndarray:
        key = np.asarray(u, dtype=float).tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = run(values_of(u))
        return objective.vector(cache[key])

    def jac(u: np.ndarray) -> np.ndarray:
        """Forward differences with scipy's relative step of 1 %, the columns' simulations
        run in ``pool`` (the kernel releases the GIL); a step that would leave the box goes
        the other way."""
        f0 = fun(u)
        steps = []
        for j in range(len(u)):
            h = DIFF_STEP * max(1.0, abs(float(u[j])))
            if u[j] + h > hi[j]:
                h = -h
            uj = np.array(u, dtype=float)
            uj[j] += h
            steps.append((uj, h))

        def column(item: tuple[np.ndarray, float]) -> np.ndarray:
            uj, h = item
            return (objective.vector(run(values_of(uj))) - f0) / h

        cols = list(pool.map(column, steps)) if pool is not None else [column(x) for x in steps]
        return np.column_stack(cols)

    for u0 in starts:
        u0 = np.clip(u0, lo, hi)
        sol = least_squares(
            fun,
            u0,
            jac=jac if pool is not None else "2-point",
            bounds=(lo, hi),
            method="trf",
            diff_step=DIFF_STEP,
            x_scale=1.0,
            ftol=1e-4,
            xtol=1e-4,
            gtol=1e-8,
            max_nfev=max_nfev,
        )
        cost = float(2.0 * sol.cost)
        messages.append(sol.message)
        if cost < best_cost:
            best_cost = cost
            best_u = sol.x
            best_res = run(values_of(sol.x))
    values = {**values_of(best_u), **fixed}
    return FitResult(
        values=values,
        axis=axis_with(spec.base, values),
        cost=objective.cost(best_res),
        residuals=best_res,
        n_free=spec.n_free,
        n_simulations=count[0],
        starts_tried=len(starts),
        message="; ".join(dict.fromkeys(messages)),
        options=spec.options,
    )


def fit(
    spec: FitSpec,
    objective: Objective,
    max_nfev: int = 30,
    n_starts: int = 2,
    seed: int = 0,
    progress: Progress | None = None,
    pool: Executor | None = None,
) -> FitResult:
    """Fit ``spec`` to ``objective``'s training samples (see the module docstring);
    ``pool`` runs the simulations of a Jacobian's columns in parallel."""
    if spec.discrete is None:
        return _fit_continuous(spec, {}, objective, max_nfev, n_starts, seed, progress, pool)
    disc = spec.discrete
    frozen = FitSpec(spec.base, (), options=spec.options)
    start = spec.start_values()
    profile: list[tuple[float, float]] = []
    for value in disc.values:
        res = _fit_continuous(
            frozen, {**start, disc.key: value}, objective, max_nfev, 1, seed, progress, pool
        )
        profile.append((res.cost, value))
    profile.sort()
    results = [
        _fit_continuous(
            spec, {disc.key: value}, objective, max_nfev, n_starts, seed, progress, pool
        )
        for _, value in profile[:1]
    ]
    best = min(results, key=lambda r: r.cost)
    sims = len(disc.values) + sum(r.n_simulations for r in results)
    return FitResult(
        values=best.values,
        axis=best.axis,
        cost=best.cost,
        residuals=best.residuals,
        n_free=spec.n_free,
        n_simulations=sims,
        starts_tried=sum(r.starts_tried for r in results),
        message=best.message,
        options=spec.options,
    )
